"""Issue 18's single-node reproductions over DDS, each node its own process: an implausible calibration
refused wherever a file is loaded (start-up, ~/reload_calibration, `ros2 param set calibration_file`) by
the three nodes that load one; `~/set_pose` with a covariance of 1e300 or 1e12 refused with the reason
(the EKF then still takes a good pose and publishes); a fourth beacon not on the map left out while
ToTal still fixes the robot; a revolution stamped late or early refused by ToTal, its status not
tracking."""

import math
import time
from pathlib import Path

import pytest

START_TIMEOUT_S = 40.0
WAIT_S = 20.0
VARIANCE_RAD2 = float(math.radians(0.1) ** 2)
STATIC_POSE = (1.3, 0.7, 0.4)
NODES = (
    ("beams_driver", "driver_node", {"source": "sim", "sim_static_pose": list(STATIC_POSE)}),
    ("beams_triangulation", "triangulation_node", {}),
    ("beams_ekf", "ekf_node", {}),
)


def _calibration(tmp_path: Path, name: str, **values) -> Path:
    """A calibration file of the Eurobot map with the given bearing correction / offset."""
    from beams_common.calibration.calibration_file import SensorCalibration, save_calibration
    from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP

    path = tmp_path / name
    save_calibration(SensorCalibration(beacon_map=EUROBOT_BEACON_MAP, **values), path)
    return path


def _set_calibration_file(rclpy_node, executable: str, path: Path):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    value = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=str(path))
    request = SetParameters.Request(parameters=[Parameter(name="calibration_file", value=value)])
    (result,) = rclpy_node.call(
        SetParameters, f"/{executable}/set_parameters", request, START_TIMEOUT_S
    ).results
    return result


@pytest.mark.parametrize(
    ("correction", "reason"),
    [
        ({"rotation_bias_coefficients": (3.0, 0.0, 0.0, 0.0)}, "rotation_bias reaches 172 deg"),
        ({"power_bias_coefficients": (1e300, 0.0, 0.0, 0.0)}, "power_bias reaches 6.69e+299 deg"),
    ],
    ids=["rotation bias 3 rad", "power bias 1e300"],
)
def test_an_implausible_calibration_is_refused_wherever_it_is_loaded(
    start_node, rclpy_node, tmp_path, correction, reason
):
    from std_srvs.srv import Trigger

    from beams_common.calibration.bearing_correction import BearingCorrection

    bad = _calibration(tmp_path, "implausible.yaml", bearing_correction=BearingCorrection(**correction))
    good = _calibration(tmp_path, "good.yaml")
    # one node at a time: no bearings reach the triangulation or the EKF meanwhile (until the fix of
    # issue 18's logger defect lands, a WARN refusal before the reload's ERROR one would kill the node)
    for package, executable, params in NODES:
        node = start_node(package, executable, params)
        # `ros2 param set calibration_file`: refused with the reason, the parameter unchanged
        result = _set_calibration_file(rclpy_node, executable, bad)
        assert not result.successful and reason in result.reason, (executable, result.reason)
        # a good file is taken; the implausible one written over it is refused by the reload service
        assert _set_calibration_file(rclpy_node, executable, good).successful
        good.write_text(bad.read_text())
        reply = rclpy_node.call(Trigger, f"/{executable}/reload_calibration", Trigger.Request(), WAIT_S)
        assert not reply.success and reason in reply.message, (executable, reply.message)
        assert "the one in use stays" in reply.message
        good.write_text(_calibration(tmp_path, "again.yaml").read_text())
        assert node.process.poll() is None, node.log()
        node.assert_clean_exit()
    for package, executable, params in NODES:  # and at start-up: one line, exit 2
        node = start_node(package, executable, {**params, "calibration_file": str(bad)})
        assert node.wait_exit(WAIT_S) == 2, node.log()
        refusals = [line for line in node.log().splitlines() if "invalid parameters" in line]
        assert len(refusals) == 1 and reason in refusals[0] and "Traceback" not in node.log()


def _operator_pose(covariance_diagonal):
    from geometry_msgs.msg import PoseWithCovarianceStamped

    pose = PoseWithCovarianceStamped()
    pose.header.frame_id = "map"
    pose.pose.pose.position.x, pose.pose.pose.position.y = 1.0, 1.0
    pose.pose.pose.orientation.w = 1.0
    covariance = [0.0] * 36
    covariance[0], covariance[7], covariance[35] = covariance_diagonal
    pose.pose.covariance = covariance
    return pose


def test_set_pose_refuses_a_covariance_beyond_the_table_and_a_good_pose_still_publishes(
    start_node, rclpy_node
):
    from nav_msgs.msg import Odometry

    from beams_msgs.srv import SetPose

    ekf = start_node("beams_ekf", "ekf_node", {})
    estimates = rclpy_node.subscribe(Odometry, "beams/ekf/odometry")
    for variance in (1e300, 1e12):
        request = SetPose.Request(pose=_operator_pose((variance, variance, 0.01)))
        reply = rclpy_node.call(SetPose, "/ekf_node/set_pose", request, START_TIMEOUT_S)
        assert not reply.success and "no information" in reply.message, reply.message
    reply = rclpy_node.call(
        SetPose, "/ekf_node/set_pose", SetPose.Request(pose=_operator_pose((0.01, 0.01, 0.01))), WAIT_S
    )
    assert reply.success, reply.message
    # the widest pose the bound allows is taken too, and the filter publishes it (not wedged)
    reply = rclpy_node.call(
        SetPose, "/ekf_node/set_pose", SetPose.Request(pose=_operator_pose((16.0, 16.0, 30.0))), WAIT_S
    )
    assert reply.success, reply.message
    wide = lambda: any(e.pose.covariance[0] == pytest.approx(16.0) for e in estimates)  # noqa: E731
    assert rclpy_node.spin_until(wide, WAIT_S), [e.pose.covariance[0] for e in estimates]
    assert ekf.process.poll() is None


def _time(seconds: float):
    from builtin_interfaces.msg import Time

    nanoseconds = round(seconds * 1e9)
    return Time(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def _revolution(beacons: dict[int, tuple[float, float]], stamp_s: float, revolution: int):
    """The exact bearings of `beacons` from STATIC_POSE, stamped within 0.06 s before stamp_s."""
    from beams_msgs.msg import BeaconBearing, BeaconBearingArray

    x, y, theta = STATIC_POSE
    msg = BeaconBearingArray(revolution=revolution, period=0.1)
    msg.header.stamp = _time(stamp_s - 0.1)
    msg.header.frame_id = "beams_sensor"
    for k, (beacon_id, (bx, by)) in enumerate(beacons.items()):
        bearing = math.remainder(math.atan2(by - y, bx - x) - theta, 2 * math.pi)
        item = BeaconBearing(beacon_id=beacon_id, bearing=bearing, variance=VARIANCE_RAD2)
        item.header.stamp = _time(stamp_s - 0.02 * (len(beacons) - 1 - k))
        msg.bearings.append(item)
    return msg


def _status(rclpy_node, node_name: str) -> str:
    return rclpy_node.diagnostic_values(node_name).get("status", "")


def test_total_leaves_an_unknown_beacon_out_and_refuses_late_or_early_revolutions(start_node, rclpy_node):
    from diagnostic_msgs.msg import DiagnosticArray

    from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
    from beams_msgs.msg import BeaconBearingArray, TriangulatedPose

    node = start_node("beams_triangulation", "triangulation_node", {"use_odometry": False})
    publisher = rclpy_node.node.create_publisher(BeaconBearingArray, "beams/bearings", 10)
    poses = rclpy_node.subscribe(TriangulatedPose, "beams/pose")
    rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    assert rclpy_node.spin_until(lambda: publisher.get_subscription_count() > 0, START_TIMEOUT_S), node.log()
    # another team's beacon (id 9, not on the map) in every revolution, at the turret's 10 Hz
    with_stranger = {**EUROBOT_BEACON_MAP.as_dict(), 9: (1.5, 2.2)}

    def play(duration_s: float, offset_s: float = 0.0, first: int = 0) -> int:
        """Revolutions at 10 Hz stamped now + offset_s; returns the next revolution number."""
        revolution = first
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            publisher.publish(_revolution(with_stranger, time.time() + offset_s, revolution))
            revolution += 1
            rclpy_node.spin_for(0.1)
        return revolution

    revolution = play(3.0)
    accepted = [p for p in poses if p.accepted]
    # every revolution gave an accepted pose (a few may be lost at discovery), from the three map beacons
    assert len(accepted) >= 20, f"{len(accepted)} accepted poses in 30 revolutions"
    assert accepted[-1].pose.pose.position.x == pytest.approx(STATIC_POSE[0], abs=1e-6)
    assert 9 not in accepted[-1].beacon_ids
    assert rclpy_node.spin_until(lambda: _status(rclpy_node, "triangulation_node") == "tracking", 3.0)
    assert float(rclpy_node.diagnostic_values("triangulation_node")["bearings_unknown_beacon"]) >= 20
    for offset_s, words in ((-1.0, "behind the receiving clock"), (0.5, "ahead of the receiving clock")):
        count = len(poses)
        revolution = play(2.0, offset_s, revolution)
        assert len(poses) == count, f"a revolution stamped {offset_s} s off gave a pose"
        values = rclpy_node.diagnostic_values("triangulation_node")
        assert values.get("status") in ("degraded", "lost"), values
        assert words in values.get("last_refusal", ""), values
        assert float(values["bearings_stamp_refused"]) > 0
    play(3.0, 0.0, revolution)
    assert poses[-1].accepted
    assert rclpy_node.spin_until(lambda: _status(rclpy_node, "triangulation_node") == "tracking", 3.0)
    assert node.process.poll() is None


def test_ekf_refuses_a_total_pose_stamped_late_or_early_and_fuses_the_correct_ones(
    start_node, rclpy_node, total_pose_message
):
    """Issue 18's leftover, through the pose intake (issue 21): with odometry at 50 Hz covering the last
    2 s, a ToTal fix stamped 1 s late (which the history covers: taken as current it would initialise the
    filter a second in the past) or 0.5 s early is refused with its reason on /diagnostics and the filter
    stays uninitialised; a fix in another frame is refused as such; the correct fixes initialise it."""
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from std_srvs.srv import Trigger

    from beams_msgs.msg import TriangulatedPose

    node = start_node("beams_ekf", "ekf_node", {"odometry_history_s": 2.0})
    odometry = rclpy_node.node.create_publisher(Odometry, "odom", 50)
    fixes = rclpy_node.node.create_publisher(TriangulatedPose, "beams/pose", 10)
    estimates = rclpy_node.subscribe(Odometry, "beams/ekf/odometry")
    rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    connected = lambda: odometry.get_subscription_count() > 0 and fixes.get_subscription_count() > 0  # noqa: E731
    assert rclpy_node.spin_until(connected, START_TIMEOUT_S), node.log()

    def drive(duration_s: float, fix_offset_s: float | None = None, frame_id: str = "map") -> None:
        """Odometry of the standing robot stamped now, as fast as the probe spins (~20-50 Hz); a fix
        each 0.1 s stamped 0.05 s before now + fix_offset_s (a revolution's middle, as
        triangulation_node stamps it)."""
        end = time.monotonic() + duration_s
        next_fix = time.monotonic() + 0.1
        while time.monotonic() < end:
            now_s = time.time()
            message = Odometry()
            message.header.stamp = _time(now_s)
            message.header.frame_id, message.child_frame_id = "odom", "base_link"
            message.pose.pose.orientation.w = 1.0
            odometry.publish(message)
            if fix_offset_s is not None and time.monotonic() >= next_fix:
                fixes.publish(total_pose_message(now_s + fix_offset_s - 0.05, STATIC_POSE, frame_id))
                next_fix += 0.1
            rclpy_node.executor.spin_once(timeout_sec=0.01)

    def counter(key: str) -> float:
        return float(rclpy_node.diagnostic_values("ekf_node").get(key, 0.0))

    drive(2.5)  # the history fills; no fix yet
    assert counter("initialisations") == 0
    for offset_s, key, words in (
        (-1.0, "total_pose_stamp_refused", "behind the receiving clock"),
        (0.5, "total_pose_stamp_refused", "ahead of the receiving clock"),
        (0.0, "total_poses_wrong_frame", "in frame 'odom'"),
    ):
        before = counter(key)
        drive(1.5, offset_s, "odom" if key == "total_poses_wrong_frame" else "map")
        rclpy_node.spin_for(1.2)  # the next /diagnostics (1 Hz)
        values = rclpy_node.diagnostic_values("ekf_node")
        assert float(values.get("initialisations", 0)) == 0, values  # never taken
        assert float(values.get(key, 0)) >= before + 8, (key, values)  # 15 fixes sent, a few may be lost
        assert words in values.get("last_refusal", ""), values
    assert not estimates, "the filter published an estimate from a refused fix"
    drive(1.0, 0.0)  # the correct fixes: the first initialises, the next ones are ignored while tracking
    rclpy_node.spin_for(1.2)
    assert counter("initialisations") == 1, rclpy_node.diagnostic_values("ekf_node")
    assert estimates, "no estimate after a correct fix"
    pose = estimates[-1].pose.pose.position
    assert (pose.x, pose.y) == (
        pytest.approx(STATIC_POSE[0], abs=1e-3),
        pytest.approx(STATIC_POSE[1], abs=1e-3),
    )
    # reset: a late fix again is refused, a correct one taken (a second initialisation)
    rclpy_node.call(Trigger, "/ekf_node/reset", Trigger.Request(), WAIT_S)
    refused = counter("total_pose_stamp_refused")
    drive(1.0, -1.0)
    drive(1.0, 0.0)
    rclpy_node.spin_for(1.2)
    assert counter("total_pose_stamp_refused") >= refused + 5
    assert counter("initialisations") == 2
    assert node.process.poll() is None and "Traceback" not in node.log()
