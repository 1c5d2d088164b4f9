"""Issue 18's reproductions on the running system, over DDS, every node its own process: wrong inputs that
are well-formed, relayed by fault_relay_node between the simulated robot and the localisation nodes.

sim_world_node publishes its odometry and ground truth on raw topics and driver_node its bearings on
`beams/bearings_raw` (remapped); the relay republishes them to the topics the nodes read, as a faulty
bridge, clock or robot would, one fault at a time: bearings restamped 1 s late, then 0.5 s early, then
the odometry shifted by +100 m for good, then another team's beacon (id 9, not on the map) added to
every revolution. Measured against the simulator's ground truth:

- each stamp fault makes ekf_node's and triangulation_node's status leave "tracking" within
  STATUS_BOUND_S, with the reason on /diagnostics; the odometry jump is counted and degrades the EKF;
- no EKF output is farther than MISLEADING_BOUND_M from the truth while its status says tracking (the
  issue's EKF was 0.32-0.45 m off with the late or early stamps and 35 m then 77 m off after the jump,
  all while "tracking"): its position error over the whole run stays within that bound;
- with the fourth beacon ToTal keeps fixing the robot (the issue's node threw the revolution away: one
  pose in 8 s);
- last, a calibration that moves a beacon by 4 cm (not refused: a calibration may correct 5 cm) is
  flagged by the EKF as making the recent bearings worse.
"""

import importlib.util
import math
import pathlib
import time

import numpy as np

# The shared system-test helpers (robot parameters, the probe, errors against the truth).
_spec = importlib.util.spec_from_file_location(
    "system_faults_helpers", pathlib.Path(__file__).with_name("test_system_faults.py")
)
system = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(system)
NODE_EXECUTABLES, START_TIMEOUT_S, RobotProbe = (
    system.NODE_EXECUTABLES,
    system.START_TIMEOUT_S,
    system.RobotProbe,
)

# From a fault's start to a status other than "tracking" on /diagnostics (published once a second): the
# stamp check refuses the first faulty revolution, the next publication says so.
STATUS_BOUND_S = 2.5
# The EKF's position error bound over the whole run, faults included: issue 5's accuracy is ~1 cm RMS;
# a refused input must leave it there (10 cm is twice ToTal's gate, far below the issue's 0.32-77 m).
MISLEADING_BOUND_M = 0.1
FAULT_S = 3.0
RECOVER_S = 4.0
# After a fault that cost the EKF its bearings for FAULT_S it is re-initialised; its protection level then
# stays above the 5 cm alert limit (degraded, honestly) until the solutions without each beacon agree
# again: 6-19 s measured.
PROTECTION_RECOVERY_S = 20.0
# With the fourth beacon, ToTal's accepted poses per revolution: the simulated match gives about 0.9
# without it (the 1/|D| gate near the critical circle); the issue's node gave 1 in 80.
MIN_ACCEPTED_FRACTION = 0.5


class Relay:
    """fault_relay_node (its own process, as the fault campaign runs it) between the robot's publishers and
    its filters: the test sets its faults through its parameters. In the test's own process the relay
    shared the interpreter with the probe and, on a loaded machine, held messages past the nodes' stamp
    tolerance (0.25 s): faults the test did not inject."""

    def __init__(self, graph, start_node) -> None:
        self.graph = graph
        self.process = start_node("beams_tools", "fault_relay_node", {})

    def set(self, name: str, value: float | int) -> None:
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        request = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
        (result,) = self.graph.call(SetParameters, "/fault_relay_node/set_parameters", request, 5.0).results
        assert result.successful, result.reason


def _statuses(probe: RobotProbe, tag: str, since: float) -> list[str]:
    return [
        values.get("status", "") for arrival, _, values in probe.diagnostics.get(tag, []) if arrival > since
    ]


def _latest(probe: RobotProbe, tag: str) -> dict[str, str]:
    reports = probe.diagnostics.get(tag, [])
    return reports[-1][2] if reports else {}


def _leaves_tracking(graph, probe: RobotProbe, tag: str, since: float) -> bool:
    return graph.spin_until(
        lambda: any(s not in ("tracking", "") for s in _statuses(probe, tag, since)), STATUS_BOUND_S
    )


def _tracking_again(graph, probe: RobotProbe, tag: str, timeout_s: float) -> bool:
    return graph.spin_until(lambda: _latest(probe, tag).get("status") == "tracking", timeout_s)


def test_implausible_inputs_never_make_a_misleading_estimate(start_node, rclpy_node, tmp_path):
    parameters = system.robot_parameters(seed=31)
    remaps = {
        "sim_world": ["-r", "odom:=odom_raw", "-r", "beams/sim/ground_truth:=beams/sim/ground_truth_raw"],
        "driver": ["-r", "beams/bearings:=beams/bearings_raw"],
    }
    probe = RobotProbe("")
    probe.attach(rclpy_node)
    relay = Relay(rclpy_node, start_node)
    nodes = {
        name: start_node(*NODE_EXECUTABLES[name], parameters[name], extra_args=remaps.get(name))
        for name in NODE_EXECUTABLES
    }
    graph = rclpy_node
    assert graph.spin_until(lambda: _latest(probe, "ekf").get("status") == "tracking", START_TIMEOUT_S), (
        f"the EKF never tracked: {_latest(probe, 'ekf')}\n{nodes['ekf'].log()}"
    )
    assert _tracking_again(graph, probe, "triangulation", 5.0), _latest(probe, "triangulation")
    graph.spin_for(2.0)

    for offset_s, words in ((-1.0, "behind the receiving clock"), (0.5, "ahead of the receiving clock")):
        start = time.monotonic()
        relay.set("bearing_stamp_offset_s", offset_s)
        for tag in ("ekf", "triangulation"):
            assert _leaves_tracking(graph, probe, tag, start), (
                f"{tag} still tracking with {offset_s} s stamps"
            )
        graph.spin_for(max(0.0, start + FAULT_S - time.monotonic()))
        values = _latest(probe, "ekf")
        assert float(values.get("bearings_stamp_refused", 0)) > 0 and words in values.get("last_refusal", "")
        relay.set("bearing_stamp_offset_s", 0.0)
        assert _tracking_again(graph, probe, "ekf", RECOVER_S + PROTECTION_RECOVERY_S), _latest(probe, "ekf")

    start = time.monotonic()
    relay.set("odometry_offset_x_m", 100.0)  # for good: the odometry source "reset" 100 m away
    assert _leaves_tracking(graph, probe, "ekf", start), "the EKF kept tracking across a 100 m jump"
    assert float(_latest(probe, "ekf").get("odometry_jumps", 0)) >= 1
    assert _tracking_again(graph, probe, "ekf", RECOVER_S + PROTECTION_RECOVERY_S), _latest(probe, "ekf")

    relay.set("unknown_beacon_id", 9)
    revolutions, accepted = len(probe.revolutions), len(probe.total)
    graph.spin_for(FAULT_S)
    relay.set("unknown_beacon_id", 0)
    strangers = sum(9 in ids for _, ids in probe.revolutions[revolutions:])
    assert strangers >= FAULT_S * 5, f"{strangers} revolutions with the unknown beacon relayed"
    fraction = (len(probe.total) - accepted) / max(len(probe.revolutions) - revolutions, 1)
    assert fraction >= MIN_ACCEPTED_FRACTION, f"ToTal accepted {fraction:.2f} of the revolutions"
    assert float(_latest(probe, "triangulation").get("bearings_unknown_beacon", 0)) > 0
    # another team's beacon is no fault of the EKF's: it stays tracking (the next report at the latest)
    assert _tracking_again(graph, probe, "ekf", 1.5), str(_latest(probe, "ekf"))

    position, _ = probe.ekf_errors()
    assert len(position) > 200
    worst = float(np.max(position))
    assert worst < MISLEADING_BOUND_M, f"the EKF was {worst:.3f} m off the truth"
    assert not math.isnan(worst)

    _calibration_that_makes_the_fixes_worse_is_flagged(graph, probe, tmp_path)
    for node in nodes.values():
        assert node.process.poll() is None, node.log()


def _calibration_that_makes_the_fixes_worse_is_flagged(graph, probe: RobotProbe, tmp_path) -> None:
    """A calibration moving beacon 3 by 4 cm (within the 5 cm a calibration may correct, so not refused)
    disagrees with the recent bearings: the EKF applies it, says WARNING in the reload's reply, counts it
    and leaves tracking."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter
    from std_srvs.srv import Trigger

    from beams_common.calibration.calibration_file import SensorCalibration, save_calibration
    from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP, BeaconMap

    path = tmp_path / "calibration.yaml"
    save_calibration(SensorCalibration(beacon_map=EUROBOT_BEACON_MAP), path)
    request = SetParameters.Request(
        parameters=[Parameter("calibration_file", value=str(path)).to_parameter_msg()]
    )
    (result,) = graph.call(SetParameters, "/ekf_node/set_parameters", request, START_TIMEOUT_S).results
    assert result.successful, result.reason
    graph.spin_for(2.0)  # recent bearings under the calibrated (here: nominal) geometry
    xy = EUROBOT_BEACON_MAP.xy
    moved = BeaconMap.from_lists(EUROBOT_BEACON_MAP.ids, xy[:, 0], [xy[0, 1], xy[1, 1], xy[2, 1] + 0.04])
    save_calibration(SensorCalibration(beacon_map=moved), path)
    start = time.monotonic()
    reply = graph.call(Trigger, "/ekf_node/reload_calibration", Trigger.Request(), START_TIMEOUT_S)
    assert (
        reply.success and "WARNING: the new calibration makes the recent bearings worse" in reply.message
    ), reply.message
    assert _leaves_tracking(graph, probe, "ekf", start), "the EKF kept tracking with a worse calibration"
    assert float(_latest(probe, "ekf").get("calibrations_flagged_worse", 0)) >= 1
