"""Two robots on one beacon set, over DDS (issue 7, "Several robots").

BeAMS beacons serve any number of robots without synchronisation: each robot runs its own sim_world_node,
driver_node, triangulation_node and ekf_node in its own namespace, from its own side of the table, on its
own random trajectory and noise seeds (the simulated sensors do not see the other robot's body).
Each robot's ToTal and EKF poses must follow its own truth within the accuracy of issues 4 and 5,
and be far from the other robot's truth (so a topic crossing namespaces could not go unnoticed).
"""

import importlib.util
import math
import pathlib

import numpy as np
import pytest

pytestmark = pytest.mark.dds

# The shared system-test helpers (robot parameters, the probe, errors against the truth).
_spec = importlib.util.spec_from_file_location(
    "system_faults_helpers", pathlib.Path(__file__).with_name("test_system_faults.py"))
system = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(system)

# namespace -> seed of its trajectory and noises, start pose (x, y, theta) on its side of the table
ROBOTS = {"robot_a": (11, [0.4, 1.0, 0.0]), "robot_b": (23, [2.6, 1.0, math.pi])}
RUN_S = 12.0
# The other robot is this far (m, mean) from a robot's estimates: the trajectories really differ.
OTHER_ROBOT_MIN_DISTANCE_M = 0.2


def test_two_robots_share_the_beacons_without_cross_talk(start_node, rclpy_node):
    probes = {}
    for namespace, (seed, start_pose) in ROBOTS.items():
        probes[namespace] = system.RobotProbe(namespace)
        probes[namespace].attach(rclpy_node)
        parameters = system.robot_parameters(seed, sim_world={"start_pose": start_pose})
        system.start_robot(start_node, parameters, namespace)
    assert rclpy_node.spin_until(lambda: all(len(p.ekf) > 20 for p in probes.values()),
                                 system.START_TIMEOUT_S), "a robot has no EKF estimate"
    started = {namespace: probe.ekf[0][0] for namespace, probe in probes.items()}
    assert rclpy_node.spin_until(
        lambda: all(p.latest_truth_stamp() > started[n] + system.SETTLE_S + RUN_S for n, p in probes.items()),
        3 * RUN_S)

    for namespace, probe in probes.items():
        position, heading = probe.ekf_errors(started[namespace] + system.SETTLE_S)
        total_position, total_heading = probe.total_errors()
        print(f"{namespace}: EKF RMS {system.rms(position):.4f} m {np.degrees(system.rms(heading)):.3f} deg, "
              f"ToTal RMS {system.rms(total_position):.4f} m {np.degrees(system.rms(total_heading)):.3f} deg")
        assert len(position) > 10 * RUN_S, f"{namespace}: {len(position)} EKF poses in {RUN_S} s"
        assert system.rms(position) < system.EKF_RMS_BOUND_M, \
            f"{namespace}: EKF RMS {system.rms(position):.4f} m"
        assert system.rms(heading) < system.EKF_HEADING_RMS_BOUND_RAD
        assert len(total_position) > 2 * RUN_S, f"{namespace}: {len(total_position)} accepted ToTal poses"
        assert system.rms(total_position) < system.TOTAL_RMS_BOUND_M
        assert system.rms(total_heading) < system.TOTAL_HEADING_RMS_BOUND_RAD
        # one driver per namespace: 10 revolutions a second on this robot's topic, not twice that
        window = started[namespace] + system.SETTLE_S, started[namespace] + system.SETTLE_S + RUN_S
        revolutions = [t for t, _ in probe.revolutions if window[0] <= t < window[1]]
        assert len(revolutions) / RUN_S == pytest.approx(10.0, abs=1.0)
    a, b = probes.values()
    other = system.errors_against_truth(np.array(a.ekf), np.array(b.truth))[0]
    assert np.mean(other) > OTHER_ROBOT_MIN_DISTANCE_M, "both robots drove the same path: no cross-talk test"
