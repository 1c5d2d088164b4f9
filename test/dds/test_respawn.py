"""A node that dies comes back (issue 18): the demo's supervisor restarts it after RESPAWN_DELAY_S, as
`ros2 launch` does with respawn (beams.launch.py; its real-tool check is in test_ros2_cli.py).

The whole robot runs under the supervisor the demo uses, ekf_node as its hot standby pair (two
processes, beams_common.ros.standby); each node in turn is killed with SIGKILL (no chance to clean up), the
EKF's active process twice in a row (the second kill hits the standby that took over from the first).
The killed node's own output is seen again, and the longest silence of the EKF's output
(beams/ekf/odometry) in the SILENCE_WINDOW_S after the kill is at most EKF_BACK_S, issue 18's 2 s:
- the driver or the triangulation killed: the EKF goes on (predicting on odometry), silent <= 0.1 s;
- the odometry source (sim_world_node) killed: the EKF's output needs it back, RESPAWN_DELAY_S (0.25 s)
  plus its start-up (imports 0.5 s of CPU, its 600-s trajectory 0.8 s, its node 0.4 s): 1.6 s measured
  with the machine to itself; beside the other DDS worker its start-up waits for a core, 2.2-3.7 s in
  make test (2026-11-27), so this test is marked `alone` and runs after the others;
- ekf_node's active process killed: its standby, its modules already imported, takes the role the
  instant the kernel frees it and starts the node (rclpy and the node's construction, 0.1 s idle; DDS
  discovery, about 0.2 s with the project's Fast DDS profile; ToTal's next fix, at most 0.1 s): 0.45 and
  0.49 s measured here under a load of 5-6, 0.41 and 0.46 s at a load of 2 (2026-11-25); 0.35-0.51 s
  idle and 0.41-0.50 s under a load of 5-6 in bench/bench_integrity.py. Restarted alone instead
  (ekf_standby:=false), its own start-up (filterpy's imports, 1.6 s of CPU) brought it back in 1.5 s
  idle and 2.2-2.7 s under a load of 4-6; 2.8-5.2 s under a load of 7-11 against the standby's 0.34-0.55 s
  (2026-11-27, the two alternated).
After each kill of the EKF, once the dead process has left the graph (its 5-s lease): one ekf_node in
the graph, the other process of the pair holding the role, and the killed one respawned and waiting; the
process that took over resumed the learnt states of its checkpoint (beams_ekf.checkpoint).
A second test kills a lone ekf_node and starts it again: the learnt states and runtime-set parameters of
its checkpoint come back exactly.
"""

import itertools
import os
import signal
import time

import pytest

pytestmark = pytest.mark.dds

UP_TIMEOUT_S = 60.0
EKF_BACK_S = 2.0  # issue 18: "sees the EKF back within 2 s"
SILENCE_WINDOW_S = 8.0  # longer than the DDS lease (5 s): a killed node has left the graph by its end
# the killed node's own output: the respawn delay, a Python node's start-up on a loaded machine, the
# EKF's first fix from a ToTal pose
NODE_BACK_S = 15.0
# every node once, then the EKF's active process again after the first takeover and respawn
KILLED = ("sim_world_node", "driver_node", "triangulation_node", "ekf_node", "ekf_node")
STANDBY_WAITING = "standby: waiting for the role"
CHECKPOINT_PERIOD_S = 2.0
RESUMED = "resumed the learnt states of OdometryErrorStates, PowerBiasStates"


@pytest.fixture
def supervised_robot(ros_env, tmp_path):
    from beams_bringup.demo import node_commands, sensor_setup
    from beams_sim.simulated_match import SENSOR_MODELS
    from beams_tools.supervisor import NodeSupervisor

    # uncalibrated: the EKF learns the power bias and the odometry errors (the plain defaults)
    sensor = sensor_setup(SENSOR_MODELS[0], tmp_path, calibrated=False)
    commands = node_commands(600.0, sensor)
    for name in ("ekf_node", "ekf_standby"):  # a checkpoint before the first kill
        commands[name] += ["-p", f"checkpoint_period_s:={CHECKPOINT_PERIOD_S}"]
    supervisor = NodeSupervisor(commands, ros_env, tmp_path)
    supervisor.start()
    try:
        yield supervisor
    finally:
        statuses = supervisor.stop()
        logs = {name: node.log_path.read_text(errors="replace") for name, node in supervisor.nodes.items()}
        assert all(status == 0 for status in statuses.values()), (statuses, logs)
        assert not any("Traceback" in log for log in logs.values()), logs


@pytest.mark.alone
def test_each_node_killed_in_turn_and_the_ekf_twice_the_ekf_output_is_back_within_2_s(
    rclpy_node, supervised_robot
):
    from nav_msgs.msg import Odometry

    from beams_common.ros.node_support import BEARINGS_QOS
    from beams_msgs.msg import BeaconBearingArray, TriangulatedPose
    from beams_tools.robot_processes import RESPAWN_DELAY_S

    supervisor = supervised_robot
    assert sorted(supervisor.nodes) == sorted([*KILLED[:3], "ekf_node", "ekf_standby"])
    arrivals: dict[str, list[float]] = {}

    def record(topic: str, msg_type, qos=10) -> None:
        times = arrivals.setdefault(topic, [])
        rclpy_node.node.create_subscription(msg_type, topic, lambda _msg: times.append(time.monotonic()), qos)

    ekf_topic = "/beams/ekf/odometry"
    record(ekf_topic, Odometry)
    record("/beams/sim/ground_truth", Odometry)
    record("/beams/bearings", BeaconBearingArray, BEARINGS_QOS)
    record("/beams/pose", TriangulatedPose)
    outputs = {
        "sim_world_node": "/beams/sim/ground_truth",
        "driver_node": "/beams/bearings",
        "triangulation_node": "/beams/pose",
        "ekf_node": "/beams/ekf/odometry",
    }
    events: list[str] = []

    def supervised(predicate):
        def check() -> bool:
            events.extend(supervisor.poll())
            return predicate()

        return check

    def logs() -> str:
        return "\n".join(
            f"{n.name}:\n{n.log_path.read_text(errors='replace')}" for n in supervisor.nodes.values()
        )

    def seen_after(topic: str, since: float) -> bool:
        return any(t > since for t in arrivals[topic])

    started = time.monotonic()
    assert rclpy_node.spin_until(
        supervised(lambda: all(seen_after(topic, started) for topic in outputs.values())), UP_TIMEOUT_S
    ), logs()
    silences: list[float] = []
    for name in KILLED:
        rclpy_node.spin_until(supervised(lambda: False), 1.0)  # a second of normal running first
        process = supervisor.active(name)  # of the EKF's pair, the active one
        assert process is not None, f"no process of {name} holds its role: {events}\n{logs()}"
        node = supervisor.nodes[process]
        restarts = node.restarts
        killed_at = time.monotonic()
        os.kill(supervisor.pid(process), signal.SIGKILL)

        def node_back(node=node, restarts=restarts, topic=outputs[name], since=killed_at + 1.0) -> bool:
            return node.restarts > restarts and seen_after(topic, since)

        assert rclpy_node.spin_until(supervised(node_back), NODE_BACK_S), (
            f"{process} not back within {NODE_BACK_S} s: {events}\n{logs()}"
        )
        rclpy_node.spin_until(
            supervised(lambda end=killed_at + SILENCE_WINDOW_S: time.monotonic() > end), 60.0
        )
        silence_s = longest_silence(arrivals[ekf_topic], killed_at, killed_at + SILENCE_WINDOW_S)
        silences.append(silence_s)
        print(
            f"{process} killed: longest EKF silence {silence_s:.2f} s (respawn delay {RESPAWN_DELAY_S:g} s)"
        )
        assert silence_s <= EKF_BACK_S, (
            f"EKF silent {silence_s:.2f} s after killing {process}: {events}\n{logs()}"
        )
        if name == "ekf_node":
            assert_one_active_and_one_waiting(rclpy_node, supervisor, killed=process)
            # the process that took over resumed what the killed one learnt
            took_over = supervisor.nodes[supervisor.active("ekf_node")].log_path.read_text(errors="replace")
            assert RESUMED in took_over.rsplit("standby: took the role", 1)[-1], took_over
    print(f"longest EKF silences (s): {[round(s, 2) for s in silences]}")
    assert [node.restarts for node in supervisor.nodes.values()] == [1] * len(supervisor.nodes), events
    assert all(
        exit_status == -signal.SIGKILL for node in supervisor.nodes.values() for exit_status in node.exits
    )


def assert_one_active_and_one_waiting(rclpy_node, supervisor, killed: str) -> None:
    """After a kill of the EKF's active process and the dead one's lease: one ekf_node in the graph, held
    by the other process of the pair; the killed one respawned and waiting as the standby."""
    names = [name for name, _namespace in rclpy_node.node.get_node_names_and_namespaces()]
    assert names.count("ekf_node") == 1, names
    other = next(name for name in supervisor.processes_of("ekf_node") if name != killed)
    assert supervisor.active("ekf_node") == other
    assert supervisor.pid(killed) is not None
    since_restart = supervisor.nodes[killed].log_path.read_text(errors="replace").rsplit("--- restart", 1)[-1]
    assert STANDBY_WAITING in since_restart and "standby: took the role" not in since_restart, since_restart


def longest_silence(arrivals: list[float], start: float, end: float) -> float:
    """The longest interval without an arrival within [start, end] (s)."""
    inside = [start, *sorted(t for t in arrivals if start < t < end), end]
    return max(later - earlier for earlier, later in itertools.pairwise(inside))


def test_a_node_refusing_its_parameters_is_not_restarted(ros_env, tmp_path):
    """Exit status 2 (run_node's start-up refusal) would come again at every start: given up, said."""
    from beams_tools.supervisor import NodeSupervisor

    script = ["python", "-c", "import sys; sys.exit(2)"]
    crash = ["python", "-c", "import os; os.kill(os.getpid(), 9)"]
    supervisor = NodeSupervisor({"refuses": script, "crashes": crash}, ros_env, tmp_path, respawn_delay_s=0.1)
    supervisor.start()
    deadline = time.monotonic() + 20.0
    events: list[str] = []
    while time.monotonic() < deadline and supervisor.nodes["crashes"].restarts < 2:
        events += supervisor.poll()
        time.sleep(0.02)
    supervisor.stop()
    assert (
        "not restarted" in supervisor.nodes["refuses"].gave_up and supervisor.nodes["refuses"].restarts == 0
    )
    assert supervisor.nodes["crashes"].restarts >= 2, events
    assert any("SIGKILL" in event for event in events), events
    assert supervisor.nodes["crashes"].log_path.read_text().count("--- restart") >= 2


def test_a_killed_ekf_node_resumes_its_learnt_states_and_runtime_parameters_exactly(
    rclpy_node, start_node, ros_env
):
    """A checkpoint seeded with learnt states (no input changes them): ekf_node resumes them, a runtime
    change of gate_probability is checkpointed, kill -9; started again, it says it resumed both, has the
    gate back, and the checkpoint of its clean stop holds the seeded states and covariance exactly."""
    import pathlib

    import numpy as np
    import yaml
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import GetParameters, SetParameters

    from beams_common.config.geometry_parameters import BeaconGeometry
    from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
    from beams_ekf.checkpoint import RuntimeChanges, save_checkpoint
    from beams_ekf.localiser import build_localiser
    from beams_ekf.parameters import EKF_PARAMETERS, filter_settings

    defaults, geometry = EKF_PARAMETERS.defaults(), BeaconGeometry(EUROBOT_BEACON_MAP, (0.0, 0.0))
    ekf = build_localiser(EUROBOT_BEACON_MAP.as_dict(), (0.0, 0.0), filter_settings(defaults)).ekf
    ekf.initialise((1.0, 1.0, 0.0), np.eye(3) * 0.01)
    blocks, mean, covariance = ekf.learnt_states()
    mean = mean + 1e-3 * np.arange(1, len(mean) + 1)  # learnt: away from the prior
    covariance = 0.5 * covariance + 1e-8 * np.ones_like(covariance)
    ekf.resume_learnt(blocks, mean, covariance)
    path = pathlib.Path(ros_env["ROS_HOME"]) / "beams" / "ekf_node_checkpoint.yaml"
    assert save_checkpoint(path, ekf, geometry, RuntimeChanges(defaults)) == ""
    params = {"checkpoint_period_s": 1.0}

    first = start_node("beams_ekf", "ekf_node", params=params)
    assert rclpy_node.spin_until(lambda: RESUMED in first.log(), UP_TIMEOUT_S), first.log()
    value = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=0.99)
    request = SetParameters.Request(parameters=[Parameter(name="gate_probability", value=value)])
    (result,) = rclpy_node.call(SetParameters, "/ekf_node/set_parameters", request, UP_TIMEOUT_S).results
    assert result.successful, result.reason

    def checkpointed() -> bool:
        return "gate_probability" in (yaml.safe_load(path.read_text())["runtime_parameters"] or {})

    assert rclpy_node.spin_until(checkpointed, 10.0), path.read_text()
    first.stop(signal.SIGKILL)

    second = start_node("beams_ekf", "ekf_node", params=params)
    said = "parameters set back: ['gate_probability']"
    assert rclpy_node.spin_until(lambda: said in second.log(), UP_TIMEOUT_S), second.log()
    assert RESUMED in second.log() and "not taken back" not in second.log(), second.log()
    request = GetParameters.Request(names=["gate_probability"])
    (gate,) = rclpy_node.call(GetParameters, "/ekf_node/get_parameters", request, UP_TIMEOUT_S, 1.0).values
    assert gate.double_value == 0.99
    second.assert_clean_exit()  # the clean stop writes the checkpoint
    document = yaml.safe_load(path.read_text())
    assert document["states"]["blocks"] == blocks
    assert np.array_equal(document["states"]["mean"], mean)
    assert np.array_equal(document["states"]["covariance"], covariance)
    assert document["runtime_parameters"] == {
        "gate_probability": {"value": 0.99, "replaced": defaults["gate_probability"]}
    }
