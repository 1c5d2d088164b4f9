"""The robot's nodes in one process (`ros2 run beams_bringup robot`, the launch file's one_process:=true):
driver_node, triangulation_node and ekf_node on one executor, beside sim_world_node's simulated robot.
The EKF's poses come out; each node answers the parameter services as it does alone (`ros2 param get`
and `set`: /<node>/get_parameters, /<node>/set_parameters); a stop signal to the process group, once or
twice as under `ros2 launch`, ends it with 0, no traceback, and each node's clean stop: ekf_node's
checkpoint written with the gate set at runtime (its period far longer than the test: only the stop
writes it)."""

import os
import pathlib
import signal
import time

import pytest

pytestmark = pytest.mark.dds

UP_TIMEOUT_S = 40.0
STOP_TIMEOUT_S = 15.0
SECOND_SIGNAL_DELAY_S = 0.05  # launch's second SIGINT follows the terminal's at once
# a parameter of each node's own table, as its section of the parameter file sets it
OWN_PARAMETERS = {
    "driver_node": "code_count",
    "triangulation_node": "publish_markers",
    "ekf_node": "gate_probability",
}


@pytest.mark.parametrize("signals", [(signal.SIGINT,), (signal.SIGINT, signal.SIGINT)], ids=["once", "twice"])
def test_the_one_process_robot_publishes_answers_per_node_and_stops_cleanly(
    rclpy_node, start_node, ros_env, signals
):
    import yaml
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import GetParameters, SetParameters

    from beams_tools.replay_settings import installed_params_file

    poses = rclpy_node.subscribe(PoseWithCovarianceStamped, "/beams/ekf/pose")
    start_node("beams_sim", "sim_world_node")
    # the launch file's parameter file, then an override of one node's parameter (every node is given it)
    arguments = ["--params-file", str(installed_params_file()), "-p", "checkpoint_period_s:=3600.0"]
    robot = start_node("beams_bringup", "robot", extra_args=arguments, own_process_group=True)
    assert rclpy_node.spin_until(lambda: len(poses) >= 5, UP_TIMEOUT_S), robot.log()
    names = [name for name, _namespace in rclpy_node.node.get_node_names_and_namespaces()]
    assert all(names.count(node) == 1 for node in OWN_PARAMETERS), names

    for node, name in OWN_PARAMETERS.items():
        request = GetParameters.Request(names=[name])
        (value,) = rclpy_node.call(GetParameters, f"/{node}/get_parameters", request, UP_TIMEOUT_S).values
        assert value.type != ParameterType.PARAMETER_NOT_SET, (node, name)
    value = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=0.99)
    request = SetParameters.Request(parameters=[Parameter(name="gate_probability", value=value)])
    (result,) = rclpy_node.call(SetParameters, "/ekf_node/set_parameters", request, UP_TIMEOUT_S).results
    assert result.successful, result.reason
    # a parameter another node of the process declares is not ekf_node's
    request = GetParameters.Request(names=["code_count"])
    assert not rclpy_node.call(GetParameters, "/ekf_node/get_parameters", request, UP_TIMEOUT_S).values

    for k, sig in enumerate(signals):
        if k:
            time.sleep(SECOND_SIGNAL_DELAY_S)
        if robot.process.poll() is None:
            os.killpg(robot.process.pid, sig)
    assert robot.wait_exit(STOP_TIMEOUT_S) == 0, robot.log()
    assert "Traceback" not in robot.log(), robot.log()
    checkpoint = pathlib.Path(ros_env["ROS_HOME"]) / "beams" / "ekf_node_checkpoint.yaml"
    document = yaml.safe_load(checkpoint.read_text())
    assert document["runtime_parameters"]["gate_probability"]["value"] == 0.99, document
