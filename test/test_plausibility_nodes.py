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

pytestmark = pytest.mark.dds

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
    from beams_common.beacon_map import EUROBOT_BEACON_MAP
    from beams_common.calibration_file import SensorCalibration, save_calibration

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

    from beams_common.bearing_correction import BearingCorrection

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

    from beams_common.beacon_map import EUROBOT_BEACON_MAP
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
