"""Input-rate status (issue 18, diagnostic_updater's FrequencyStatus): sim_world_node says ERROR while
its odometry is down (the rehearsed odometry_dropout_s fault) and OK again after; driver_node shows its
revolution rate (~10 Hz, the turret's) and stays OK."""

import time

import pytest

pytestmark = pytest.mark.dds

UP_TIMEOUT_S = 60.0
DROPOUT_S = (4.0, 8.0)  # match time of the odometry dropout


def test_sim_world_odometry_dropout_is_error_and_the_driver_rate_is_shown(start_node, rclpy_node):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    statuses: dict[str, list] = {"sim_world_node": [], "driver_node": []}

    def on_diagnostics(msg) -> None:
        for status in msg.status:
            for name, seen in statuses.items():
                if f"/{name}:" in status.name:
                    seen.append((time.monotonic(), status))

    rclpy_node.node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 50)
    world = start_node("beams_sim", "sim_world_node", {"odometry_dropout_s": list(DROPOUT_S)})
    driver = start_node("beams_driver", "driver_node")

    def said(name: str, predicate) -> bool:
        return any(predicate(status) for _, status in statuses[name])

    def no_odometry(status) -> bool:
        return status.level == DiagnosticStatus.ERROR and "odometry at 0.0 Hz over 2 s" in status.message

    assert rclpy_node.spin_until(lambda: said("sim_world_node", no_odometry), UP_TIMEOUT_S), (
        world.log(),
        [s.message for _, s in statuses["sim_world_node"][-5:]],
    )
    down_at = next(t for t, s in statuses["sim_world_node"] if no_odometry(s))
    # back once the dropout ends and the window refills (2 s at 50 Hz, judged OK from 25 Hz)
    assert rclpy_node.spin_until(
        lambda: any(t > down_at and s.level == DiagnosticStatus.OK for t, s in statuses["sim_world_node"]),
        UP_TIMEOUT_S,
    ), [s.message for _, s in statuses["sim_world_node"][-5:]]
    # nothing said before the dropout began: the first status not OK is about it, inside it
    first_bad = next(s for _, s in statuses["sim_world_node"] if s.level != DiagnosticStatus.OK)
    match_s = float(next(kv.value for kv in first_bad.values if kv.key == "match_time_s"))
    assert first_bad.message.startswith("odometry at") and "below 25 Hz" in first_bad.message, (
        first_bad.message
    )
    assert DROPOUT_S[0] <= match_s <= DROPOUT_S[1], match_s
    last_driver = statuses["driver_node"][-1][1]
    values = {kv.key: float(kv.value) for kv in last_driver.values if kv.key == "revolution_rate_hz"}
    assert 8.0 <= values["revolution_rate_hz"] <= 12.0, values
    # no rate condition on the driver: its only remark is the honest default's (no calibration file)
    assert last_driver.level == DiagnosticStatus.WARN, last_driver.message
    assert last_driver.message.startswith("uncalibrated") and " Hz" not in last_driver.message, (
        last_driver.message
    )
    assert driver.process.poll() is None
