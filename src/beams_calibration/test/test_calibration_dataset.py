"""The calibration dataset: averaging a capture, refusing bad ones, and the atomic YAML file."""

import math
import os
import re
from pathlib import Path

import numpy as np
import pytest

from beams_calibration.dataset import (
    BeaconObservation,
    Configuration,
    Dataset,
    DatasetError,
    append_configuration,
    average_capture,
    capture_bearing_problem,
    load_dataset,
    save_dataset,
    to_arrays,
)
from beams_common.calibration import calibration_file
from beams_common.geometry.beacon_map import BeaconMap
from beams_common.intake.validation import MAX_REASON_CHARS

PRIOR = BeaconMap.from_lists((1, 2, 3), (1.151, 0.600, 0.049), (0.049, 0.907, 0.049))


def _configuration(x_m: float, beacons: tuple[int, ...] = (1, 2, 3)) -> Configuration:
    observations = tuple(BeaconObservation(i, 0.5 * i - 1.0, 0.12 + 0.01 * i, 5e-4, 100) for i in beacons)
    return Configuration(x_m, 0.5, math.pi / 2, observations, 100, "2026-11-22T03:30:00Z", f"at {x_m}")


def test_average_is_circular_across_the_cut():
    rng = np.random.default_rng(2)
    # Bearings of beacon 1 straddle +-pi: an arithmetic mean would give about 0.
    bearings = np.asarray(np.pi + rng.normal(0.0, 1e-3, 100))
    revolutions = [
        {1: (float(np.angle(np.exp(1j * b))), 0.15), 2: (0.3 + 1e-3 * (k % 2), 0.11), 3: (-1.0, 0.13)}
        for k, b in enumerate(bearings)
    ]
    observations = average_capture(revolutions, (1, 2, 3))
    first = observations[0]
    assert first.beacon_id == 1 and first.revolutions == 100
    assert abs(np.angle(np.exp(1j * (first.bearing_rad - np.mean(bearings))))) < 1e-9
    assert first.spread_rad == pytest.approx(np.std(bearings), rel=1e-6)
    assert observations[1].window_rad == pytest.approx(0.11)


def test_a_missing_beacon_is_refused():
    revolutions = [{1: (0.1, 0.1), 2: (0.2, 0.1)} for _ in range(10)]
    with pytest.raises(DatasetError, match="beacon 3 seen in 0 of 10"):
        average_capture(revolutions, (1, 2, 3))
    # Missed in a few revolutions only: accepted, with the count recorded.
    revolutions = [{1: (0.1, 0.1), 2: (0.2, 0.1), **({3: (0.3, 0.1)} if k else {})} for k in range(10)]
    assert average_capture(revolutions, (1, 2, 3))[2].revolutions == 9


def test_a_moving_robot_is_refused():
    revolutions = [{1: (0.1 + 0.001 * k, 0.1)} for k in range(20)]  # drifts by 1.1 deg
    with pytest.raises(DatasetError, match="did the robot move"):
        average_capture(revolutions, (1,))
    with pytest.raises(DatasetError, match="no revolution"):
        average_capture([], (1,))


def test_file_round_trip_is_readable_yaml(tmp_path: Path):
    dataset = Dataset(PRIOR, (_configuration(0.1), _configuration(0.2)))
    path = tmp_path / "dataset.yaml"
    save_dataset(dataset, path)
    loaded = load_dataset(path)
    assert loaded.configurations == dataset.configurations
    np.testing.assert_array_equal(loaded.beacon_map.xy, PRIOR.xy)
    text = path.read_text()
    assert text.startswith("# BeAMS calibration dataset") and "bearing_rad" in text


def test_append_creates_then_grows_the_file(tmp_path: Path):
    path = tmp_path / "sub" / "dataset.yaml"
    append_configuration(path, PRIOR, _configuration(0.1))
    dataset = append_configuration(path, PRIOR, _configuration(0.2))
    assert (
        [c.x_m for c in load_dataset(path).configurations]
        == [0.1, 0.2]
        == [c.x_m for c in dataset.configurations]
    )
    assert len(load_dataset(tmp_path / "sub" / "dataset.yaml.bak").configurations) == 1


def test_a_crash_while_appending_loses_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    path = tmp_path / "dataset.yaml"
    append_configuration(path, PRIOR, _configuration(0.1))
    real_replace = os.replace

    def crash_on_target(source, destination):
        if Path(destination) == path:
            raise OSError("killed mid-write")
        real_replace(source, destination)

    monkeypatch.setattr(calibration_file.os, "replace", crash_on_target)
    with pytest.raises(OSError, match="killed"):
        append_configuration(path, PRIOR, _configuration(0.2))
    monkeypatch.undo()
    assert [c.x_m for c in load_dataset(path).configurations] == [0.1]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("configurations: [", "not valid YAML"),
        ("format: beams-calibration-dataset\nversion: 1\n", "missing entry 'beacons'"),
        ("format: other\n", "format"),
    ],
)
def test_malformed_files_are_named(tmp_path: Path, text: str, message: str):
    path = tmp_path / "dataset.yaml"
    path.write_text(text)
    with pytest.raises(DatasetError, match=message):
        load_dataset(path)
    with pytest.raises(FileNotFoundError):
        load_dataset(tmp_path / "missing.yaml")


def test_arrays_keep_configurations_with_the_three_beacons():
    dataset = Dataset(PRIOR, (_configuration(0.1), _configuration(0.2, beacons=(1, 3)), _configuration(0.3)))
    arrays = to_arrays(dataset)
    assert arrays.count == 2 and arrays.beacon_ids == (1, 2, 3)
    np.testing.assert_array_equal(arrays.poses[:, 0], [0.1, 0.3])
    np.testing.assert_allclose(arrays.bearings_rad[0], [-0.5, 0.0, 0.5])
    np.testing.assert_allclose(arrays.windows_rad[1], [0.13, 0.14, 0.15])


@pytest.fixture(scope="module")
def thesis_captures():
    """The 48 configurations of section 7.3.1 captured by the thesis-hardware sensor (uncalibrated, its
    power and rotation biases, turret offset, beacons where table 7.3 found them, placement error), on
    table 7.1's a-priori map."""
    from beams_thesis import thesis_setup

    return thesis_setup.thesis_dataset(5, revolutions=20)


def test_a_correct_capture_with_the_thesis_hardware_sensor_passes(thesis_captures):
    for c in thesis_captures.configurations:
        assert (
            capture_bearing_problem((c.x_m, c.y_m, c.theta_rad), c.observations, thesis_captures.beacon_map)
            == ""
        )


@pytest.mark.parametrize(
    ("name", "mistake"),
    [
        ("theta off by pi", lambda x, y, theta: (x, y, theta + math.pi)),
        ("half a metre off", lambda x, y, theta: (x + 0.5, y, theta)),
        # the grid mirrored about the table's middle (x = 0.6 m), as if read from the other side
        ("mirrored", lambda x, y, theta: (1.2 - x, y, math.pi - theta)),
    ],
)
def test_a_mistyped_reference_pose_is_refused_with_both_poses(thesis_captures, name, mistake):
    configuration = thesis_captures.configurations[4]  # (1.08, 0.84), theta 0: far from its mirror image
    pose = mistake(configuration.x_m, configuration.y_m, configuration.theta_rad)
    problem = capture_bearing_problem(pose, configuration.observations, thesis_captures.beacon_map)
    stated = f"({pose[0]:.3f} m, {pose[1]:.3f} m, {math.degrees(pose[2]):.1f} deg)"
    assert problem.startswith(f"reference pose {stated} is"), name
    assert len(f"refused: {problem} (force: true records it)") <= MAX_REASON_CHARS  # the reply is not cut
    given = re.search(r"the pose its bearings give \((\S+) m, (\S+) m, (\S+) deg\)", problem)
    assert given, problem
    x_m, y_m, theta_deg = map(float, given.groups())
    assert math.hypot(x_m - configuration.x_m, y_m - configuration.y_m) < 0.05
    assert abs(theta_deg - math.degrees(configuration.theta_rad)) < 3.0
