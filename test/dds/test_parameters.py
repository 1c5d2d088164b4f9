"""Parameters as ROS users meet them, over DDS: a bad value at start-up is one line and exit 2 (the same
reason the offline replay gives), a runtime change is applied with the start-up validation or refused
with its reason, and a read-only parameter refuses `ros2 param set` (rcl_interfaces/SetParameters, the
service `ros2 param set` calls)."""

import math

import numpy as np
import pytest
import yaml

from beams_common.config.parameters import ParameterError
from beams_tools.replay_settings import load_node_parameters
from beams_triangulation.parameters import TRIANGULATION_PARAMETERS

WAIT_S = 20.0
BEACONS = {1: (-0.062, -0.062), 2: (-0.062, 2.062), 3: (3.062, 1.0)}
VARIANCE_RAD2 = float(np.deg2rad(0.1) ** 2)


@pytest.mark.parametrize(
    ("package", "executable", "params", "reason"),
    [
        # issue 15's start-up reproductions: each used to end in a traceback and exit 1
        ("beams_triangulation", "triangulation_node", {"beacon_ids": [1]}, "beacon_ids needs 3 to 64 values"),
        ("beams_triangulation", "triangulation_node", {"turret_offset_m": [0.1]}, "turret_offset_m needs 2"),
        (
            "beams_ekf",
            "ekf_node",
            {"default_pose_sigma": [math.nan, 0.1, 0.1]},
            "default_pose_sigma must be finite",
        ),
        ("beams_triangulation", "triangulation_node", {"max_inverse_abs_d": -1.0}, "max_inverse_abs_d"),
        ("beams_sim", "sim_world_node", {"trajectory": "spiral"}, "trajectory must be one of"),
        ("beams_triangulation", "triangulation_node", {"beacon_ids": []}, "beacon_ids has no value"),
        ("beams_driver", "driver_node", {"sim_turret_offset_m": [math.nan]}, "sim_turret_offset_m needs 2"),
        ("beams_driver", "driver_node", {"sim_turret_offset_m": [math.nan, 0.0]}, "must be finite"),
        (
            "beams_driver",
            "driver_node",
            {"sim_static_pose": [math.nan, 1.0, 0.0]},
            "sim_static_pose must be finite",
        ),
        ("beams_driver", "driver_node", {"sim_other_robots": ["not a topic!"]}, "are not valid topic names"),
    ],
)
def test_a_bad_start_up_value_is_one_line_and_exit_2(start_node, package, executable, params, reason):
    node = start_node(package, executable, params)
    assert node.wait_exit(WAIT_S) == 2, node.log()
    log = node.log()
    assert reason in log and "invalid parameters" in log, log
    assert "Traceback" not in log


def test_a_malformed_command_line_is_one_line_and_exit_2(start_node):
    """An unquoted list on the command line is rcl's parse error: one line, exit 2, no traceback."""
    node = start_node("beams_driver", "driver_node", extra_args=["-p", "sim_other_robots:=['not"])
    assert node.wait_exit(WAIT_S) == 2, node.log()
    assert "invalid command-line arguments" in node.log() and "Traceback" not in node.log()


def test_the_replay_refuses_a_parameter_file_with_the_reason_the_node_gives(start_node, tmp_path):
    """The same out-of-range value: the node exits 2 naming it, the replay raises the same sentence."""
    params = {"max_position_std_m": 5000.0}
    node = start_node("beams_triangulation", "triangulation_node", params)
    assert node.wait_exit(WAIT_S) == 2
    params_file = tmp_path / "params.yaml"
    params_file.write_text(yaml.safe_dump({"/**/triangulation_node": {"ros__parameters": params}}))
    with pytest.raises(ParameterError) as refused:
        load_node_parameters(params_file, TRIANGULATION_PARAMETERS)
    reason = str(refused.value).split(": ", 1)[1]  # after the file's name
    assert reason == "max_position_std_m = 5000.0 is above its maximum 1000.0"
    assert reason in node.log()


def _set(rclpy_node, node_name: str, **values):
    """ros2 param set, as the command does it: rcl_interfaces/srv/SetParameters on /<node>/set_parameters."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    request = SetParameters.Request(
        parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
    )
    return rclpy_node.call(SetParameters, f"/{node_name}/set_parameters", request, WAIT_S).results


def _get(rclpy_node, node_name: str, name: str):
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python

    request = GetParameters.Request(names=[name])
    response = rclpy_node.call(GetParameters, f"/{node_name}/get_parameters", request, WAIT_S)
    return parameter_value_to_python(response.values[0])


def _revolution(pose, beacons=BEACONS, revolution=0):
    from beams_common.interfaces.bearing_messages import BearingFields, nanoseconds
    from beams_common.ros.messages import bearing_array

    x, y, theta = pose
    stamp_ns = nanoseconds(1000.0)
    fields = [
        BearingFields(
            stamp_ns,
            beacon_id,
            math.remainder(math.atan2(by - y, bx - x) - theta, 2 * math.pi),
            VARIANCE_RAD2,
        )
        for beacon_id, (bx, by) in beacons.items()
    ]
    return bearing_array(stamp_ns, fields, period_s=0.1, revolution=revolution)


def test_runtime_changes_are_applied_validated_or_refused(start_node, rclpy_node, tmp_path):
    from beams_msgs.msg import BeaconBearingArray, TriangulatedPose

    # stamps at 1000 s, not on the node's clock: the stamp plausibility check off
    params = {"use_odometry": False, "max_stamp_age_s": 0.0, "max_stamp_lead_s": 0.0}
    node = start_node("beams_triangulation", "triangulation_node", params)
    publisher = rclpy_node.node.create_publisher(BeaconBearingArray, "beams/bearings", 10)
    poses = rclpy_node.subscribe(TriangulatedPose, "beams/pose")
    pose = (1.3, 0.7, 0.4)
    assert rclpy_node.publish_until(publisher, _revolution(pose), lambda: bool(poses), WAIT_S), node.log()
    assert poses[-1].accepted

    # a gate applied at runtime: the same revolution is now rejected by it
    (result,) = _set(rclpy_node, "triangulation_node", max_position_std_m=1e-9)
    assert result.successful, result.reason
    count = len(poses)
    assert rclpy_node.publish_until(publisher, _revolution(pose), lambda: len(poses) > count, WAIT_S)
    assert not poses[-1].accepted and "std" in poses[-1].reason

    # out of range, and a beacon map whose lists disagree: refused with the reason, nothing changes
    (result,) = _set(rclpy_node, "triangulation_node", max_position_std_m=-1.0)
    assert not result.successful
    (result,) = _set(rclpy_node, "triangulation_node", beacon_x=[0.0, 1.0])
    assert not result.successful and "beacon_x needs 3 to 64 values" in result.reason
    assert _get(rclpy_node, "triangulation_node", "beacon_x") == [-0.062, -0.062, 3.062]
    # ... and the behaviour in use stays: the gate of 1e-9 m still rejects the pose
    count = len(poses)
    assert rclpy_node.publish_until(publisher, _revolution(pose), lambda: len(poses) > count, WAIT_S)
    assert not poses[-1].accepted and "std" in poses[-1].reason
    (result,) = _set(rclpy_node, "triangulation_node", max_position_std_m=0.05)
    assert result.successful

    # a moved beacon, applied: the pose the node computes moves with it
    moved = {**BEACONS, 3: (3.062, 1.2)}
    (result,) = _set(rclpy_node, "triangulation_node", beacon_y=[moved[i][1] for i in (1, 2, 3)])
    assert result.successful, result.reason
    count = len(poses)
    assert rclpy_node.publish_until(publisher, _revolution(pose, moved), lambda: len(poses) > count, WAIT_S)
    p = poses[-1].pose.pose.position
    assert poses[-1].accepted and (p.x, p.y) == pytest.approx(pose[:2], abs=1e-9)

    # read-only: refused by the parameter service, the value stays
    (result,) = _set(rclpy_node, "triangulation_node", use_odometry=True)
    assert not result.successful and "read-only" in result.reason
    assert _get(rclpy_node, "triangulation_node", "use_odometry") is False

    # a calibration file that cannot be read is refused; the geometry stays
    (result,) = _set(rclpy_node, "triangulation_node", calibration_file=str(tmp_path / "missing.yaml"))
    assert not result.successful and "missing.yaml" in result.reason
    assert _get(rclpy_node, "triangulation_node", "calibration_file") == ""
    assert node.process.poll() is None and "Traceback" not in node.log()


def test_a_change_is_validated_in_on_set_and_applied_in_post_set(rclpy_node):
    """apply_runtime_changes on a node in this process: prepare refuses with its reason (nothing is
    applied, the values stay), an accepted change is applied once rclpy has set it."""
    from rclpy.parameter import Parameter

    from beams_common.config.parameters import ParameterSpec, ParameterTable
    from beams_common.ros.parameters import apply_runtime_changes, declare_table

    table = ParameterTable(
        "test_node",
        (
            ParameterSpec("gain", 1.0, "A gain.", minimum=0.0, maximum=10.0, runtime=True),
            ParameterSpec("limit", 5.0, "Above the gain.", minimum=0.0, maximum=10.0, runtime=True),
        ),
    )
    node = rclpy_node.node
    current = declare_table(node, table)
    applied: list[tuple[float, float]] = []  # (the value applied, the node's parameter value then)

    def prepare(values: dict, changed: set[str]):
        if values["gain"] > values["limit"]:
            raise ValueError(f"gain {values['gain']} above limit {values['limit']}")
        gain = values["gain"]
        return lambda: applied.append((gain, node.get_parameter("gain").value))

    apply_runtime_changes(node, table, current, prepare)
    for gain, limit in ((2.0, 5.0), (7.0, 5.0), (3.0, 2.0), (4.0, 5.0), (11.0, 5.0)):
        results = node.set_parameters_atomically(
            [Parameter("gain", value=gain), Parameter("limit", value=limit)]
        )
        ok = gain <= limit <= 10.0 and gain <= 10.0
        assert results.successful is ok, (gain, limit, results.reason)
        if not ok and gain <= 10.0:
            assert f"gain {gain} above limit {limit}" == results.reason
    # applied in post-set (the parameter already set), only the accepted ones, in order
    assert applied == [(2.0, 2.0), (4.0, 4.0)]
    assert current == {"gain": 4.0, "limit": 5.0}
    assert node.get_parameter("gain").value == 4.0 and node.get_parameter("limit").value == 5.0


def test_every_node_declares_each_parameter_read_only_or_runtime(start_node, rclpy_node):
    """`ros2 param describe` tells which is which: the descriptor's read_only flag is the spec's."""
    from rcl_interfaces.srv import DescribeParameters

    from beams_ekf.parameters import EKF_PARAMETERS

    start_node("beams_ekf", "ekf_node")
    request = DescribeParameters.Request(names=list(EKF_PARAMETERS.names))
    response = rclpy_node.call(DescribeParameters, "/ekf_node/describe_parameters", request, WAIT_S)
    described = {d.name: d for d in response.descriptors}
    assert set(described) == set(EKF_PARAMETERS.names)
    for spec in EKF_PARAMETERS.specs:
        assert described[spec.name].read_only is (not spec.runtime), spec.name
        assert described[spec.name].description.startswith(spec.description)
