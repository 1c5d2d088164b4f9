"""estimate_noise end to end: bags of a still robot on the thesis-hardware simulator, written with rosbags
(MCAP and sqlite3), through the installed console script; its parameter file read by the driver's table.
Its refusals through the console script's function in this process (its exit status, its stderr)."""

import math
import os
import pathlib
import subprocess

import pytest

from beams_common.config.parameters import ParameterTable, load_parameter_file
from beams_driver.estimate_noise import main
from beams_driver.parameters import DRIVER_PARAMETERS
from beams_sim.sensor_sim import SensorSimConfig
from beams_sim.sim_source import PARAMETERS as SIM_PARAMETERS
from beams_sim.simulated_match import simulate_match
from beams_sim.world import EurobotTrajectory
from beams_tools.bag_io import beams_typestore
from beams_tools.bag_messages import simulated_messages, write_bag

ROOT = pathlib.Path(__file__).resolve().parents[2]
INSTALL_BASE = pathlib.Path(os.environ.get("BEAMS_INSTALL_BASE", ROOT / "install"))
COMMAND = INSTALL_BASE / "beams_driver" / "lib" / "beams_driver" / "estimate_noise"
HARDWARE = SensorSimConfig.thesis_hardware()
POSES = [(1.5, 1.0, 0.0), (0.9, 1.2, 1.0), (2.0, 0.5, -2.0)]


def _bag(
    path: pathlib.Path, trajectory: EurobotTrajectory, seed: int, storage: str, duration_s: float = 60.0
) -> pathlib.Path:
    match = simulate_match(duration_s, seed, trajectory=trajectory, sensor_config=HARDWARE)
    return write_bag(path, simulated_messages(match, beams_typestore()), beams_typestore(), storage=storage)


def _run(*arguments: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(COMMAND), *arguments],
        capture_output=True,
        text=True,
        timeout=120,
        env=dict(os.environ),
    )


@pytest.fixture(scope="module")
def still_bags(tmp_path_factory):
    directory = tmp_path_factory.mktemp("noise")
    return [
        _bag(directory / f"pose{k}", EurobotTrajectory.static(pose, 60.0), k, ("mcap", "sqlite3")[k % 2])
        for k, pose in enumerate(POSES)
    ]


def test_estimate_noise_writes_a_driver_parameter_file_with_the_injected_noise(still_bags, tmp_path):
    """Table, plot and parameter file: the natural variance within 15% of the injected one at the mean
    window (the band of src/beams_driver/test/test_driver_noise_estimation.py), the file accepted by the
    driver's parameter table as `--params-file` would be; a published variance flagged as understated,
    every fitted one ok."""
    output, plot = tmp_path / "noise.yaml", tmp_path / "noise.png"
    result = _run(*map(str, still_bags), "-o", str(output), "--plot", str(plot))
    assert result.returncode == 0, result.stderr
    rows = [line for line in result.stdout.splitlines() if "pose" in line.split(" ")[0]]
    assert len(rows) == 3 * len(POSES)
    # simulate_match publishes the thesis hardware's mean natural variance (6.8e-7 rad^2): ratios 1.1-1.6
    assert any(row.split()[9] == "understated" for row in rows)
    assert all(row.split()[-1] == "ok" for row in rows)
    assert plot.stat().st_size > 10_000
    table = DRIVER_PARAMETERS + ParameterTable("driver_node", SIM_PARAMETERS)
    values = load_parameter_file(output, table)
    window = values["natural_variance_reference_window_rad"]
    rising, falling = HARDWARE.hardware.edge_std_rad(window, None)
    injected = float(rising**2 + falling**2) / 4.0
    assert values["natural_variance_rad2"] == pytest.approx(injected, rel=0.15)
    assert math.radians(5.0) < window < math.radians(8.0)


def test_estimate_noise_refuses_a_moving_robot_and_a_bag_without_bearings(tmp_path, capsys):
    """A bag of a moving robot (10 s: 100 revolutions, twice the bearings per beacon it needs): exit 2
    with one line naming the beacon and the movement; a bag with no bearings topic, or a path that is no
    bag: exit 2 with the reason."""
    moving = _bag(tmp_path / "moving", EurobotTrajectory.random(3, 10.0), 3, "mcap", 10.0)
    empty = write_bag(tmp_path / "empty", [], beams_typestore())
    for bag, reason in (
        (moving, "the robot moved"),
        (empty, "no /beams/bearings"),
        (tmp_path / "nothing", "not a readable rosbag2 bag"),
    ):
        capsys.readouterr()
        assert main([str(bag)]) == 2
        stderr = capsys.readouterr().err
        assert reason in stderr and stderr.count("\n") == 1, stderr
