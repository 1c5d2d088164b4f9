"""The whole suite on the real turret firmware without hardware: the virtual turret, over DDS.

`virtual_turret` (beams_sim) runs sim_world_node's match and the shipped turret image in simavr in real
time on a pseudo-terminal, its pins driven by the edge-level simulator following that match's robot;
driver_node reads it (`source: serial`), triangulation_node and ekf_node localise. The EKF's error against
beams/sim/ground_truth must stay within the simulated source's bounds (as test_system_faults.py and
test_system_multi_robot.py judge them), at ten revolutions a second.
Skipped, with the reason, where `make hil` could not build the firmware or the harness.
"""

import importlib.util
import pathlib
import sys

import numpy as np
import pytest

sys.path.insert(0, str(pathlib.Path(__file__).parents[1] / "hil"))
import turret_hil

pytestmark = pytest.mark.skipif(bool(turret_hil.missing()), reason=turret_hil.missing() or "ready")

# The shared system-test helpers (robot parameters, the probe, errors against the truth, the bounds).
_spec = importlib.util.spec_from_file_location(
    "system_faults_helpers", pathlib.Path(__file__).with_name("test_system_faults.py")
)
system = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(system)

SEED = 31
RUN_S = 12.0


def cpu_s(pid: int) -> float:
    """User and system CPU seconds of a process and its children that exited or still run."""
    fields = pathlib.Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    children = pathlib.Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    ticks = sum(int(v) for v in fields[11:15]) / 100.0  # utime stime cutime cstime, USER_HZ
    return ticks + sum(cpu_s(int(child)) for child in children)


def test_the_suite_localises_through_the_virtual_turret(start_node, rclpy_node, tmp_path) -> None:
    import time

    parameters = system.robot_parameters(SEED)
    probe = system.RobotProbe("")
    probe.attach(rclpy_node)
    link = tmp_path / "turret"
    turret = start_node(
        "beams_sim",
        "virtual_turret",
        parameters["sim_world"],
        arguments=["--link", str(link), "--seed", str(SEED + 2)],
    )
    assert rclpy_node.spin_until(link.exists, 20.0), f"no pty at {link}\n{turret.log()}"
    driver = start_node("beams_driver", "driver_node", {"source": "serial", "device": str(link)})
    start_node("beams_triangulation", "triangulation_node", parameters["triangulation"])
    start_node("beams_ekf", "ekf_node", parameters["ekf"])
    assert rclpy_node.spin_until(lambda: len(probe.ekf) > 20, system.START_TIMEOUT_S), (
        f"no EKF estimate through the virtual turret\n{turret.log()}"
    )
    started = probe.ekf[0][0]
    processes = (turret.process.pid, driver.process.pid)
    cpu_from_s, wall_from_s = [cpu_s(pid) for pid in processes], time.monotonic()
    assert rclpy_node.spin_until(
        lambda: probe.latest_truth_stamp() > started + system.SETTLE_S + RUN_S, 3 * RUN_S
    )
    turret_cpu, driver_cpu = (
        (cpu_s(pid) - before) / (time.monotonic() - wall_from_s)
        for pid, before in zip(processes, cpu_from_s, strict=True)
    )

    position, heading = probe.ekf_errors(started + system.SETTLE_S)
    total_position, total_heading = probe.total_errors()
    print(
        f"virtual turret: EKF RMS {system.rms(position) * 1e3:.2f} mm {np.degrees(system.rms(heading)):.3f} "
        f"deg over {len(position)} poses, ToTal RMS {system.rms(total_position) * 1e3:.2f} mm; "
        f"CPU: virtual turret (with simavr) {100 * turret_cpu:.0f} %, driver_node {100 * driver_cpu:.0f} %"
    )
    assert len(position) > 10 * RUN_S, f"{len(position)} EKF poses in {RUN_S} s"
    assert system.rms(position) < system.EKF_RMS_BOUND_M
    assert system.rms(heading) < system.EKF_HEADING_RMS_BOUND_RAD
    assert system.rms(total_position) < system.TOTAL_RMS_BOUND_M
    assert system.rms(total_heading) < system.TOTAL_HEADING_RMS_BOUND_RAD
    window = started + system.SETTLE_S, started + system.SETTLE_S + RUN_S
    revolutions = [t for t, _ in probe.revolutions if window[0] <= t < window[1]]
    assert len(revolutions) / RUN_S == pytest.approx(10.0, abs=1.0)
