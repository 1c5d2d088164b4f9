"""`make demo`: a simulated Eurobot match with every BeAMS node running as its own process.

Starts sim_world_node, driver_node (simulated sensor), triangulation_node and ekf_node with its hot
standby (two processes, beams_common.ros.standby) from the install tree (the executables `ros2 run`
starts; `--one-process`: the last three as nodes of one process, beams_bringup's `robot`), records every
topic to an MCAP bag as `ros2 bag record` does (fully qualified names, the publishers' offered QoS
profiles in the metadata), prints live progress (pose errors against the truth, bearings per second,
rejected windows), stops the nodes with SIGINT and leaves a trajectory plot and a summary table in the
output directory.

By default every node runs with its own defaults, as a new user's robot would: the driver uncalibrated
(WARN "uncalibrated" on /diagnostics, `calibrated: false` on beams/bearings) and the EKF estimating the
power bias while the robot drives (self-calibration, docs/self_calibration.md). `--calibrated` gives the
driver a perfect chapter-7 calibration instead: a file in the output directory whose power-bias correction
is the simulated receiver's bias inverted. `--sensor-model` chooses the simulated receiver (driver_node's
sim_noise_model); for the ideal one the driver gets that receiver's natural variance (the defaults are the
thesis hardware's). The summary names the calibration state and gives the EKF's mean NEES (3 for a
consistent filter) beside the RMS errors.
"""

import argparse
import datetime
import os
import pathlib
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from beams_common.calibration.calibration_file import SensorCalibration, save_calibration
from beams_common.config.command_line import command
from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.interfaces import topics
from beams_common.ros.messages import planar_covariance, pose2d_of
from beams_common.ros.node_support import BEARINGS_QOS
from beams_common.ros.status_topic import STATUS_CODES, STATUS_QOS
from beams_msgs.msg import BeaconBearingArray, LocalisationStatus, TriangulatedPose
from beams_sim.simulated_match import SENSOR_MODELS, calibration_of, sensor_config_of
from beams_tools.bag_events import stamp_ns
from beams_tools.bag_io import BagRecorder, beams_typestore, fully_qualified
from beams_tools.replay_settings import installed_params_file
from beams_tools.robot_processes import ONE_PROCESS, PARAMS_FILE, process_commands, robot_processes
from beams_tools.supervisor import NodeSupervisor
from beams_tools.trajectory_metrics import (
    RunTracks,
    errors_against_truth,
    plot_run,
    rms,
    rms_table,
)

ROOT = pathlib.Path.cwd()
INSTALL_BASE = pathlib.Path(os.environ.get("BEAMS_INSTALL_BASE", ROOT / "install"))
# Every topic of the suite, with its type, recorded to the bag.
TOPICS = {
    topics.GROUND_TRUTH: Odometry,
    topics.ODOMETRY: Odometry,
    topics.BEARINGS: BeaconBearingArray,
    topics.POSE: TriangulatedPose,
    topics.POSE_COV: PoseWithCovarianceStamped,
    topics.EKF_ODOMETRY: Odometry,
    topics.EKF_POSE: PoseWithCovarianceStamped,
    topics.EKF_STATUS: LocalisationStatus,
    topics.TRIANGULATION_STATUS: LocalisationStatus,
    topics.MARKERS: MarkerArray,
    topics.DIAGNOSTICS: DiagnosticArray,
    topics.TF: TFMessage,
}
STATUS_TOPICS = (topics.EKF_STATUS, topics.TRIANGULATION_STATUS)  # latched: the current one at once
PROGRESS_PERIOD_S = 5.0
START_TIMEOUT_S = 30.0


def bag_qos(profile: QoSProfile) -> Qos:
    """An rclpy profile as a bag's offered_qos_profiles entry (the policies have the same names)."""

    def duration(value) -> QosTime:
        return QosTime(*divmod(value.nanoseconds, 1_000_000_000))

    return Qos(
        history=QosHistory[profile.history.name],
        depth=profile.depth,
        reliability=QosReliability[profile.reliability.name],
        durability=QosDurability[profile.durability.name],
        deadline=duration(profile.deadline),
        lifespan=duration(profile.lifespan),
        liveliness=QosLiveliness[profile.liveliness.name],
        liveliness_lease_duration=duration(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=profile.avoid_ros_namespace_conventions,
    )


def offered_qos_profiles(node: Node, topic: str) -> list[Qos]:
    """The profiles the topic's publishers offer, from the ROS graph (what `ros2 bag record` stores)."""
    return [bag_qos(info.qos_profile) for info in node.get_publishers_info_by_topic(fully_qualified(topic))]


def ros_type_name(msg_type: type) -> str:
    module = msg_type.__module__.split(".")
    return f"{module[0]}/{module[1]}/{msg_type.__name__}"


@dataclass
class MatchRecord(RunTracks):
    """The tracks of the live match and the counts the progress lines show."""

    bearings: int = 0
    revolutions: int = 0
    rejected_windows: int = 0
    poses_rejected: int = 0
    uncalibrated_revolutions: int = 0

    def on_message(self, topic: str, msg) -> None:
        tracks = {
            topics.GROUND_TRUTH: self.truth,
            topics.ODOMETRY: self.odometry,
            topics.EKF_ODOMETRY: self.ekf,
        }
        if topic in tracks:
            tracks[topic].add(0, stamp_ns(msg.header.stamp), pose2d_of(msg.pose.pose))
            if topic == topics.EKF_ODOMETRY:
                self.ekf_covariances.append(planar_covariance(msg.pose.covariance))
        elif topic == topics.BEARINGS:
            self.revolutions += 1
            self.uncalibrated_revolutions += not msg.calibrated
            self.bearings += len(msg.bearings)
            self.rejected_windows += msg.rejected_windows
        elif topic == topics.EKF_STATUS:
            status = next(name for name, code in STATUS_CODES.items() if code == msg.status)
            self.ekf_integrity.add(0, stamp_ns(msg.header.stamp), msg.horizontal_protection_level_m, status)
            self.ekf_integrity.alert_limit_m = msg.horizontal_alert_limit_m
        elif topic == topics.POSE:
            if msg.accepted:
                self.total.add(0, stamp_ns(msg.header.stamp), pose2d_of(msg.pose.pose))
            else:
                self.poses_rejected += 1


@dataclass(frozen=True)
class SensorSetup:
    """The simulated receiver and how the driver is configured for it (its summary line)."""

    model: str
    driver_arguments: tuple[str, ...]
    description: str


def sensor_setup(sensor_model: str, output: pathlib.Path, calibrated: bool) -> SensorSetup:
    """driver_node's arguments for a sensor model: sim_noise_model, for the ideal receiver its natural
    variance (the defaults are the thesis hardware's) and, `calibrated`, for a receiver with a power bias,
    a calibration file that removes it (written to the output)."""
    config = sensor_config_of(sensor_model)
    arguments = ["-p", f"sim_noise_model:={sensor_model}"]
    description = f"sensor model {sensor_model}"
    if config.hardware is None:
        arguments += ["-p", f"natural_variance_rad2:={config.natural_variance_rad2!r}"]
        arguments += ["-p", "natural_variance_slope_rad2_per_rad:=0.0"]
        description += f", natural variance {config.natural_variance_rad2:.3g} rad^2"
    correction = calibration_of(config)
    if correction.is_identity:
        description += ", no power bias to calibrate"
    elif not calibrated:
        description += ", UNCALIBRATED (the driver's default): the EKF self-calibrates the power bias"
    else:
        path = output / "calibration.yaml"
        # the driver takes only the bearing correction from it; the geometry is the default map's
        save_calibration(
            SensorCalibration(EUROBOT_BEACON_MAP, correction, created_utc=SensorCalibration.now_utc()),
            path,
        )
        arguments += ["-p", f"calibration_file:={path}"]
        description += f", power bias corrected by {path.name} (the simulated bias inverted)"
    return SensorSetup(sensor_model, tuple(arguments), description)


def node_commands(
    duration_s: float, sensor: SensorSetup, standby: bool = True, one_process: bool = False
) -> dict[str, list[str]]:
    """The command of each robot process (installed executable, beams_params.yaml, the demo's overrides),
    by process name: a node with a hot standby has two (`RobotNode.processes`) unless `standby` is off;
    with `one_process`, `robot_processes`' one process (the driver's overrides then reach its every node)."""
    params_file = installed_params_file()
    if params_file is None:
        raise FileNotFoundError(f"{PARAMS_FILE} of beams_bringup is not installed: run `make build`")
    overrides = {
        "sim_world_node": ["-p", f"duration_s:={duration_s}"],
        "driver_node": sensor.driver_arguments,
        ONE_PROCESS.executable: sensor.driver_arguments,
    }
    processes = robot_processes(one_process)
    ros_arguments = {
        node.executable: ["--params-file", str(params_file), *overrides.get(node.executable, ())]
        for node in processes
    }
    return process_commands(INSTALL_BASE, ros_arguments, processes, standby)


def progress_line(record: MatchRecord, elapsed_s: float, bearings_per_s: float) -> str:
    truth = record.truth.array()
    ekf_position, ekf_heading = errors_against_truth(record.ekf.array(), truth)
    total_position, _ = errors_against_truth(record.total.array(), truth)
    ekf = (
        f"EKF error {1000 * ekf_position[-1]:6.1f} mm {np.degrees(ekf_heading[-1]):5.2f} deg"
        if len(ekf_position)
        else "EKF waiting for its first pose"
    )
    total = f"ToTal RMS {1000 * rms(total_position):6.1f} mm" if len(total_position) else "ToTal no pose yet"
    return (
        f"t={elapsed_s:5.1f} s  {ekf} | {total} | {bearings_per_s:5.1f} bearings/s | "
        f"{record.rejected_windows} rejected windows | {record.poses_rejected} poses gated out"
    )


def nees_against_truth(track: np.ndarray, covariances: list[np.ndarray], truth: np.ndarray) -> np.ndarray:
    """NEES (chi-square, 3 dof, for a consistent filter) of each estimate of a track (rows: segment,
    stamp s, x, y, theta) with its 3x3 covariance, against the truth interpolated at its stamp (rows
    outside the truth's span, or with a covariance that is not positive definite, are left out)."""
    values = []
    if len(truth) < 2:
        return np.empty(0)
    heading = np.unwrap(truth[:, 4])
    for row, covariance in zip(track, covariances, strict=True):
        if not truth[0, 1] <= row[1] <= truth[-1, 1]:
            continue
        error = np.array(
            [
                row[2] - np.interp(row[1], truth[:, 1], truth[:, 2]),
                row[3] - np.interp(row[1], truth[:, 1], truth[:, 3]),
                wrap_to_pi(row[4] - np.interp(row[1], truth[:, 1], heading)),
            ]
        )
        try:
            values.append(float(error @ np.linalg.solve(covariance, error)))
        except np.linalg.LinAlgError:
            continue
    return np.array(values)


def summary_table(record: MatchRecord, sensor: SensorSetup) -> str:
    tracks = record.in_map("truth")  # dead reckoning from the true start
    rows = (("odometry", tracks["odometry"]), ("ToTal (accepted)", tracks["ToTal"]), ("EKF", tracks["EKF"]))
    nees = nees_against_truth(record.ekf.array(), record.ekf_covariances, tracks["truth"])
    state = (
        f"uncalibrated ({record.uncalibrated_revolutions} of {record.revolutions} revolutions flagged "
        "calibrated: false)"
        if record.uncalibrated_revolutions
        else "calibrated"
    )
    lines = [f"Simulated {sensor.description}.", f"Driver: {state}.", "", *rms_table(rows, tracks["truth"])]
    lines += [
        "",
        f"EKF mean NEES {nees.mean() if len(nees) else float('nan'):.2f} over {len(nees)} estimates "
        "(3 for a consistent filter; chi-square, 3 dof)",
        f"revolutions {record.revolutions}, bearings {record.bearings}, "
        f"rejected windows {record.rejected_windows}, ToTal poses gated out {record.poses_rejected}",
    ]
    return "\n".join(lines)


@command("demo", clean=False)
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--duration", type=float, default=90.0, help="match duration (s), default 90")
    parser.add_argument(
        "--output", type=pathlib.Path, default=None, help="output directory (default out/demo-<time>)"
    )
    parser.add_argument(
        "--sensor-model",
        choices=SENSOR_MODELS,
        default=SENSOR_MODELS[0],
        help="simulated receiver (driver_node's sim_noise_model), default %(default)s",
    )
    parser.add_argument(
        "--calibrated",
        action="store_true",
        help="give the driver a perfect chapter-7 calibration (default: uncalibrated, self-calibrating)",
    )
    parser.add_argument(
        "--one-process",
        action="store_true",
        help="driver_node, triangulation_node and ekf_node as nodes of one process (beams_bringup's robot)",
    )
    options = parser.parse_args(argv)
    output = options.output or ROOT / "out" / f"demo-{datetime.datetime.now():%Y%m%d-%H%M%S}"
    output.mkdir(parents=True, exist_ok=True)
    sensor = sensor_setup(options.sensor_model, output, options.calibrated)
    env = dict(os.environ)
    env.setdefault("ROS_DOMAIN_ID", "0")  # ROS 2's default: `ros2 topic echo` in another shell sees the demo
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    print(
        f"demo: {options.duration:.0f} s match, {sensor.description}, domain {env['ROS_DOMAIN_ID']}, "
        f"output in {output}"
    )

    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node("beams_demo_recorder")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    record = MatchRecord()
    typestore = beams_typestore()
    # every node restarted when it dies, as `ros2 launch` does with respawn (beams.launch.py)
    supervisor = NodeSupervisor(
        node_commands(options.duration, sensor, one_process=options.one_process), env, output
    )
    supervisor.start()
    statuses: dict[str, int] = {}
    interrupted = False
    try:
        with BagRecorder(output / "bag", typestore) as recorder:
            recorded: set[str] = set()
            for topic, msg_type in TOPICS.items():

                def on_raw(raw: bytes, topic=topic, msg_type=msg_type) -> None:
                    msg = deserialize_message(raw, msg_type)
                    stamp_ns = node.get_clock().now().nanoseconds
                    # a message came, so its publisher is known: the graph has its profile now
                    offered = offered_qos_profiles(node, topic) if topic not in recorded else []
                    recorded.add(topic)
                    recorder.write(fully_qualified(topic), ros_type_name(msg_type), stamp_ns, raw, offered)
                    record.on_message(topic, msg)

                qos = {topics.BEARINGS: BEARINGS_QOS, **dict.fromkeys(STATUS_TOPICS, STATUS_QOS)}.get(
                    topic, 50
                )
                node.create_subscription(msg_type, topic, on_raw, qos, raw=True)
            started = time.monotonic()
            next_progress = started + PROGRESS_PERIOD_S
            bearings_at_last_line = 0
            while time.monotonic() - started < options.duration + 1.0:
                executor.spin_once(timeout_sec=0.05)
                if time.monotonic() >= next_progress:
                    rate = (record.bearings - bearings_at_last_line) / PROGRESS_PERIOD_S
                    bearings_at_last_line = record.bearings
                    print(progress_line(record, time.monotonic() - started, rate), flush=True)
                    next_progress += PROGRESS_PERIOD_S
                if not record.truth.rows and time.monotonic() - started > START_TIMEOUT_S:
                    print("demo: no ground truth after 30 s; see the node logs in", output, file=sys.stderr)
                    break
                for event in supervisor.poll():
                    print(f"demo: {event}; its log: {output}", file=sys.stderr, flush=True)
                if any(node.gave_up for node in supervisor.nodes.values()):
                    print("demo: a node cannot run; see the node logs in", output, file=sys.stderr)
                    break
    except KeyboardInterrupt:
        interrupted = True
    finally:
        statuses = supervisor.stop()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()

    table = summary_table(record, sensor)
    (output / "summary.md").write_text(table + "\n")
    plot_run(record, "truth", output / "trajectory.png", "BeAMS demo: simulated Eurobot match")
    print()
    print(table)
    print(f"\nbag: {output / 'bag'} ({recorder.messages_written} messages, MCAP)")
    print(f"plot: {output / 'trajectory.png'}; node logs: {output}/*.log")
    restarts = {name: node.restarts for name, node in supervisor.nodes.items() if node.restarts}
    if restarts:
        print(f"demo: nodes restarted after dying: {restarts}", file=sys.stderr)
    bad = [f"{name} exited {status}" for name, status in statuses.items() if status != 0]
    if bad:
        print("demo: " + ", ".join(bad), file=sys.stderr)
        return 1
    return 130 if interrupted else 0


if __name__ == "__main__":
    sys.exit(main())
