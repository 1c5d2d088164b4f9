"""sim_world_node over DDS: the true pose and the odometry it publishes, and its refusal of bad parameters."""

import math

import numpy as np
import pytest

WAIT_S = 20.0
ZERO_DRIFT = {
    "odometry_left_scale_error": 0.0,
    "odometry_right_scale_error": 0.0,
    "odometry_wheel_base_error": 0.0,
    "odometry_slip_std": 0.0,
    "odometry_noise_m_per_sqrt_m": 0.0,
}


def stamp_s(msg) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def planar(msg) -> tuple[float, float, float]:
    pose = msg.pose.pose
    return (pose.position.x, pose.position.y, 2.0 * math.atan2(pose.orientation.z, pose.orientation.w))


def match_offset(trajectory, stamps: np.ndarray, poses: np.ndarray) -> tuple[float, float]:
    """The match time of the first stamp that puts every pose on the trajectory, and the worst error (m)."""
    grid = np.arange(0.0, trajectory.duration_s, 0.001)
    first = trajectory.states_at(grid)[:, :2]
    best = float(grid[np.argmin(np.hypot(*(first - poses[0, :2]).T))])
    worst = math.inf
    for step_s in (1e-3, 2e-5, 4e-7):  # each pass spans the previous step, 50x finer
        candidates = best + step_s * np.arange(-50, 51)
        errors = [
            np.hypot(*(trajectory.poses_at(c + stamps - stamps[0])[:, :2] - poses[:, :2]).T).max()
            for c in candidates
        ]
        best, worst = float(candidates[int(np.argmin(errors))]), float(np.min(errors))
    return best, worst


def test_publishes_truth_and_perfect_odometry_at_50_hz_in_a_namespace(start_node, rclpy_node) -> None:
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from tf2_msgs.msg import TFMessage

    from beams_sim.world import EurobotTrajectory

    transforms = rclpy_node.subscribe(TFMessage, "/tf", 100)
    truth = rclpy_node.subscribe(Odometry, "/robot1/beams/sim/ground_truth")
    odometry = rclpy_node.subscribe(
        Odometry, "/robot1/odom", qos_profile_sensor_data
    )  # best effort matches too
    start_node(
        "beams_sim",
        "sim_world_node",
        {"trajectory_seed": 3, "duration_s": 20.0, **ZERO_DRIFT},
        namespace="/robot1",
    )
    assert rclpy_node.spin_until(lambda: len(truth) >= 100 and len(odometry) >= 100, WAIT_S)

    assert {(m.header.frame_id, m.child_frame_id) for m in truth} == {("map", "base_link")}
    assert {(m.header.frame_id, m.child_frame_id) for m in odometry} == {("odom", "base_link")}
    stamps = np.array([stamp_s(m) for m in truth])
    assert np.median(np.diff(stamps)) == pytest.approx(0.02, rel=0.05)

    trajectory = EurobotTrajectory.random(seed=3, duration_s=20.0)
    poses = np.array([planar(m) for m in truth])
    offset, worst = match_offset(trajectory, stamps, poses)
    assert worst < 2e-6  # every published pose is the trajectory's at its own stamp (float noise)
    speeds = np.array([m.twist.twist.linear.x for m in truth])
    expected = [trajectory.twist_at(offset + s - stamps[0])[0] for s in stamps]
    np.testing.assert_allclose(speeds, expected, atol=1e-6)

    # Perfect odometry is the truth seen from the start pose (the random trajectory starts at (0.4, 1, 0)).
    by_stamp = {stamp_s(m): planar(m) for m in truth}
    paired = [(planar(m), by_stamp[stamp_s(m)]) for m in odometry if stamp_s(m) in by_stamp]
    assert len(paired) >= 50
    for (x, y, theta), (tx, ty, ttheta) in paired:
        assert math.hypot(x - (tx - 0.4), y - (ty - 1.0)) < 1e-3
        assert abs(math.remainder(theta - ttheta, 2.0 * math.pi)) < 1e-4

    # odom -> base_link on /tf (shared by every namespace: frames as configured), the odometry's pose
    odometry_by_stamp = {stamp_s(m): planar(m) for m in odometry}
    checked = 0
    for message in transforms:
        (transform,) = message.transforms
        assert (transform.header.frame_id, transform.child_frame_id) == ("odom", "base_link")
        pose = odometry_by_stamp.get(stamp_s(transform))
        if pose is not None:
            t, q = transform.transform.translation, transform.transform.rotation
            assert (t.x, t.y, 2.0 * math.atan2(q.z, q.w)) == pytest.approx(pose, abs=1e-9)
            checked += 1
    assert checked >= 50


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"trajectory": "banana"}, "trajectory must be one of"),
        (
            {"trajectory": "waypoints", "waypoints_x": [0.5, 2.95, 2.95], "waypoints_y": [1.0, 1.0, 1.9]},
            "leaves the table",
        ),
        ({"odometry_slip_std": -0.1}, "slip_std"),
    ],
)
def test_refuses_bad_parameters_with_one_clear_line(start_node, params: dict, message: str) -> None:
    node = start_node("beams_sim", "sim_world_node", params)
    assert node.wait_exit(WAIT_S) == 2
    log = node.log()
    assert message in log and "Traceback" not in log
