"""Every executable starts from the install tree, answers over DDS, and exits 0 without a traceback
on SIGINT and on SIGTERM (issue 2)."""

import signal

import pytest

EXECUTABLES = [
    ("beams_sim", "sim_world_node"),
    ("beams_driver", "driver_node"),
    ("beams_triangulation", "triangulation_node"),
    ("beams_ekf", "ekf_node"),
    ("beams_calibration", "calibration_node"),
]
ANSWER_TIMEOUT_S = 20.0


@pytest.mark.parametrize("signal_number", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize(("package", "executable"), EXECUTABLES, ids=[e for _, e in EXECUTABLES])
def test_executable_answers_and_exits_cleanly(rclpy_node, start_node, package, executable, signal_number):
    from diagnostic_msgs.msg import DiagnosticArray

    diagnostics = rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    node = start_node(package, executable)

    def reported() -> bool:
        return any(
            executable.removesuffix("_node") in status.name for msg in diagnostics for status in msg.status
        )

    assert rclpy_node.spin_until(reported, ANSWER_TIMEOUT_S), (
        f"{executable} published nothing on /diagnostics within {ANSWER_TIMEOUT_S} s:\n{node.log()}"
    )
    node.assert_clean_exit(signal_number)


def test_invalid_parameter_is_refused_with_a_clear_message(start_node):
    node = start_node("beams_driver", "driver_node", params={"variance_mode": "guess"})
    status = node.wait_exit(ANSWER_TIMEOUT_S)
    output = node.log()
    assert status == 2, output
    assert "variance_mode" in output and "Traceback" not in output, output


def test_executor_choice_falls_back_and_refuses_nonsense(rclpy_node, start_node, ros_env):
    """BEAMS_EXECUTOR=single_threaded runs a streaming node on rclpy's SingleThreadedExecutor (the
    fallback from the EventsExecutor); an unknown value is refused at start-up with a clear message."""
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data

    ros_env["BEAMS_EXECUTOR"] = "single_threaded"
    odometry = rclpy_node.subscribe(Odometry, "odom", qos_profile_sensor_data)
    fallback = start_node("beams_sim", "sim_world_node")
    assert rclpy_node.spin_until(lambda: len(odometry) > 20, ANSWER_TIMEOUT_S), fallback.log()
    fallback.assert_clean_exit(signal.SIGTERM)
    ros_env["BEAMS_EXECUTOR"] = "fastest"
    refused = start_node("beams_ekf", "ekf_node")
    assert refused.wait_exit(ANSWER_TIMEOUT_S) == 2, refused.log()
    assert "BEAMS_EXECUTOR='fastest'" in refused.log() and "Traceback" not in refused.log()
