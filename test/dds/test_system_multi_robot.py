"""Two robots on one beacon set, over DDS (issue 7, "Several robots").

BeAMS beacons serve any number of robots without synchronisation: each robot runs its own sim_world_node,
driver_node, triangulation_node and ekf_node in its own namespace, from its own side of the table, on its
own random trajectory and noise seeds. Each robot's ToTal and EKF poses must follow its own truth within
the accuracy of issues 4 and 5, and be far from the other robot's truth (so a topic crossing namespaces
could not go unnoticed).

A robot also stands in the way: the simulated sensor follows the other robot's ground truth
(`sim_other_robots`) and loses a beacon exactly while the other robot's body crosses the line of sight.
"""

import importlib.util
import math
import pathlib
from typing import Any

import numpy as np
import pytest

# The shared system-test helpers (robot parameters, the probe, errors against the truth).
_spec = importlib.util.spec_from_file_location(
    "system_faults_helpers", pathlib.Path(__file__).with_name("test_system_faults.py")
)
system = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(system)

# namespace -> seed of its trajectory and noises, start pose (x, y, theta) on its side of the table
ROBOTS = {"robot_a": (11, [0.4, 1.0, 0.0]), "robot_b": (23, [2.6, 1.0, math.pi])}
RUN_S = 12.0
# The other robot is this far (m, mean) from a robot's estimates: the trajectories really differ.
OTHER_ROBOT_MIN_DISTANCE_M = 0.2
# Robot A stands still facing +y, beacon 3 (3.062, 1.0) to its right; robot B loops around (2.0, 1.0),
# crossing A's line of sight to beacon 3 twice a loop (B-spline control points, m).
STANDING_POSE = [0.4, 1.0, math.pi / 2]
BEACON_3 = (3.062, 1.0)
LOOP_X = [2.0, 2.2, 2.0, 1.8] * 4
LOOP_Y = [0.4, 1.0, 1.6, 1.0] * 4
# A body reaching the beacons' plane as wide as the robot: several hidden passes per crossing.
BODY_RADIUS_M = 0.15
# Passes with B this close to the edge of its shadow (m) are not judged (B moves 1 cm in 20 ms).
SHADOW_EDGE_M = 0.03


def test_two_robots_share_the_beacons_without_cross_talk(start_node, rclpy_node):
    probes = {}
    for namespace, (seed, start_pose) in ROBOTS.items():
        probes[namespace] = system.RobotProbe(namespace)
        probes[namespace].attach(rclpy_node)
        parameters = system.robot_parameters(seed, sim_world={"start_pose": start_pose})
        system.start_robot(start_node, parameters, namespace)
    check_robots_localised(rclpy_node, probes)


def check_robots_localised(graph, probes: dict[str, Any]) -> dict[str, tuple[float, float]]:
    """Let two running robots drive RUN_S seconds past their settling, then check each against its own
    truth (EKF and ToTal bounds of issues 4 and 5), its revolutions (one driver per namespace) and that
    the other robot's truth is far from its estimates; {namespace: (EKF RMS position m, heading rad)}.
    Also serves test_system_hosts.py (the same robots on separate hosts)."""
    assert graph.spin_until(lambda: all(len(p.ekf) > 20 for p in probes.values()), system.START_TIMEOUT_S), (
        "a robot has no EKF estimate"
    )
    started = {namespace: probe.ekf[0][0] for namespace, probe in probes.items()}
    assert graph.spin_until(
        lambda: all(p.latest_truth_stamp() > started[n] + system.SETTLE_S + RUN_S for n, p in probes.items()),
        3 * RUN_S,
    )

    ekf_rms = {}
    for namespace, probe in probes.items():
        position, heading = probe.ekf_errors(started[namespace] + system.SETTLE_S)
        total_position, total_heading = probe.total_errors()
        print(
            f"{namespace}: EKF RMS {system.rms(position):.4f} m {np.degrees(system.rms(heading)):.3f} deg, "
            f"ToTal RMS {system.rms(total_position):.4f} m {np.degrees(system.rms(total_heading)):.3f} deg"
        )
        assert len(position) > 10 * RUN_S, f"{namespace}: {len(position)} EKF poses in {RUN_S} s"
        assert system.rms(position) < system.EKF_RMS_BOUND_M, (
            f"{namespace}: EKF RMS {system.rms(position):.4f} m"
        )
        assert system.rms(heading) < system.EKF_HEADING_RMS_BOUND_RAD
        assert len(total_position) > 2 * RUN_S, f"{namespace}: {len(total_position)} accepted ToTal poses"
        assert system.rms(total_position) < system.TOTAL_RMS_BOUND_M
        assert system.rms(total_heading) < system.TOTAL_HEADING_RMS_BOUND_RAD
        # one driver per namespace: 10 revolutions a second on this robot's topic, not twice that
        window = started[namespace] + system.SETTLE_S, started[namespace] + system.SETTLE_S + RUN_S
        revolutions = [t for t, _ in probe.revolutions if window[0] <= t < window[1]]
        assert len(revolutions) / RUN_S == pytest.approx(10.0, abs=1.0)
        ekf_rms[namespace] = (system.rms(position), system.rms(heading))
    a, b = probes.values()
    other = system.errors_against_truth(np.array(a.ekf), np.array(b.truth))[0]
    assert np.mean(other) > OTHER_ROBOT_MIN_DISTANCE_M, "both robots drove the same path: no cross-talk test"
    return ekf_rms


def distance_to_segment(point: np.ndarray, a: tuple[float, float], b: tuple[float, float]) -> np.ndarray:
    """Distance (m) of each point (n, 2) to the segment [a, b]."""
    a_xy, b_xy = np.asarray(a), np.asarray(b)
    along = np.clip((point - a_xy) @ (b_xy - a_xy) / np.sum((b_xy - a_xy) ** 2), 0.0, 1.0)
    return np.hypot(*(a_xy + along[:, None] * (b_xy - a_xy) - point).T)


def test_a_robot_hides_the_beacon_behind_it_from_the_other(start_node, rclpy_node):
    from beams_driver.edges import TURRET_PERIOD_S

    probe_a, probe_b = system.RobotProbe("robot_a"), system.RobotProbe("robot_b")
    for probe in (probe_a, probe_b):
        probe.attach(rclpy_node)
    standing = {"trajectory": "static", "static_pose": list(STANDING_POSE), "start_pose": list(STANDING_POSE)}
    parameters = system.robot_parameters(
        11,
        sim_world=standing,
        driver={
            "sim_other_robots": ["/robot_b/beams/sim/ground_truth"],
            "sim_other_robot_radius_m": BODY_RADIUS_M,
        },
    )
    system.start_robot(start_node, parameters, "robot_a")
    start_node(
        "beams_sim",
        "sim_world_node",
        {
            "trajectory": "waypoints",
            "waypoints_x": LOOP_X,
            "waypoints_y": LOOP_Y,
            "duration_s": system.MATCH_S,
            "publish_tf": False,
        },
        "robot_b",
    )
    assert rclpy_node.spin_until(lambda: len(probe_a.ekf) > 20 and probe_b.truth, system.START_TIMEOUT_S)
    started = max(probe_a.ekf[0][0], probe_b.truth[0][0])
    assert rclpy_node.spin_until(
        lambda: probe_b.latest_truth_stamp() > started + system.SETTLE_S + RUN_S, 3 * RUN_S
    )

    # When each revolution of A passed over beacon 3, where B stood, and whether A saw the beacon.
    x, y, heading = STANDING_POSE
    bearing = (math.atan2(BEACON_3[1] - y, BEACON_3[0] - x) - heading) % (2 * math.pi)
    revolutions = [
        (t, ids)
        for t, ids in probe_a.revolutions
        if started + system.SETTLE_S <= t < probe_b.latest_truth_stamp() - TURRET_PERIOD_S
    ]
    pass_s = np.array([t for t, _ in revolutions]) + bearing / (2 * math.pi) * TURRET_PERIOD_S
    b_truth = np.array(probe_b.truth)
    b_xy = np.column_stack(
        [np.interp(pass_s, b_truth[:, 0], b_truth[:, 1]), np.interp(pass_s, b_truth[:, 0], b_truth[:, 2])]
    )
    distance = distance_to_segment(b_xy, (x, y), BEACON_3)
    seen = np.array([3 in ids for _, ids in revolutions])
    behind = distance < BODY_RADIUS_M - SHADOW_EDGE_M
    clear = distance > BODY_RADIUS_M + SHADOW_EDGE_M
    hidden_windows = probe_a.counter("driver", "windows_hidden_by_other_robots")
    print(
        f"robot B across the line of sight in {behind.sum()} of {len(revolutions)} revolutions: "
        f"beacon 3 seen in {seen[behind].sum()} of them, and in {seen[clear].sum()} of the {clear.sum()} "
        f"clear ones; driver: {hidden_windows:.0f} windows hidden"
    )
    assert behind.sum() >= 10, "robot B did not cross the line of sight: nothing was tested"
    assert not seen[behind].any(), "robot A saw beacon 3 through robot B"
    assert seen[clear].mean() > 0.95, "robot A lost beacon 3 with robot B out of the way"
    assert hidden_windows >= behind.sum()
    # A still knows where it stands: two beacons and odometry carry the EKF through each crossing.
    position, heading_error = probe_a.ekf_errors(started + system.SETTLE_S)
    assert system.rms(position) < system.EKF_RMS_BOUND_M
    assert system.rms(heading_error) < system.EKF_HEADING_RMS_BOUND_RAD
