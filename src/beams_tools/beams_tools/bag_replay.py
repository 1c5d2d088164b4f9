"""replay_bag: the triangulation and the EKF (thesis fig. 8.1) over a recorded rosbag2 bag, offline.

    replay_bag INPUT_BAG OUTPUT_BAG [--plot PNG] [--storage mcap|sqlite3] [--start-like-live]
               [--params-file YAML] [--namespace NS]

Feeds the bag's `beams/bearings`, `odom` and `beams/sim/ground_truth` to the pure objects the nodes wrap,
as fast as the CPU allows, and writes their outputs next to a copy of the inputs into a new bag, with a
plot and a summary (RMS errors against the truth, agreement with the live nodes' recorded outputs). Time
is the messages' stamps, never their arrival (reordered within `REORDER_WINDOW_S`; a topic's own stamps
jumping back by more than `TIME_JUMP_S` reset both pipelines, a topic recorded late does not); bad input
is counted and skipped. The parameters are the
nodes' (beams_bringup's beams_params.yaml by default), validated by their tables.
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rosbags.rosbag2 import Reader

from beams_common.config.command_line import command
from beams_common.geometry.angles import wrap_to_pi
from beams_common.interfaces import topics
from beams_common.ros.messages import pose2d_of
from beams_ekf.outcomes import Estimate
from beams_ekf.parameters import EKF_PARAMETERS
from beams_tools.bag_events import (
    BEARINGS_TOPIC,
    BEARINGS_TYPE,
    LIVE_EKF_TOPIC,
    LIVE_POSE_TOPIC,
    NODES_QOS,
    NS_PER_S,
    ODOMETRY_TOPIC,
    ODOMETRY_TYPE,
    POSE_COV_TYPE,
    POSE_TYPE,
    TIME_JUMP,
    TRUTH_TOPIC,
    Event,
    bag_topics,
    in_stamp_order,
    namespaced_topic,
    read_events,
    relative_topic,
    stamp_ns,
)
from beams_tools.bag_io import BagRecorder, beams_typestore
from beams_tools.bag_messages import MessageBuilder
from beams_tools.replay_pipelines import ReplayPipelines, ReplayResult, live_estimates
from beams_tools.replay_settings import (
    ReplaySettings,
    installed_params_file,
    load_node_parameters,
    settings_from_parameters,
)
from beams_tools.trajectory_metrics import Track, plot_run, rms, rms_table
from beams_triangulation.gating import PoseEstimate
from beams_triangulation.parameters import TRIANGULATION_PARAMETERS
from beams_triangulation.revolution import RevolutionPose


# -- the replay -----------------------------------------------------------------------------------------
@dataclass
class _Run:
    """The state of one replay: pipelines, output bag and result."""

    pipelines: ReplayPipelines
    recorder: BagRecorder
    build: MessageBuilder
    typestore: Any
    map_frame: str
    # the robot's namespace: the output topics are in it, as the inputs were
    namespace: str = ""
    result: ReplayResult = field(default_factory=ReplayResult)
    segment: int = 0

    def __post_init__(self) -> None:
        self.result.ekf_integrity.alert_limit_m = self.pipelines.settings.ekf_values[
            "horizontal_alert_limit_m"
        ]

    def write(self, topic: str, msgtype: str, stamp: int, message: Any) -> None:
        self.recorder.write(
            namespaced_topic(topic, self.namespace),
            msgtype,
            stamp,
            self.typestore.serialize_cdr(message, msgtype),
            [NODES_QOS],
        )
        self.result.messages_out += 1

    def handle(self, event: Event) -> None:
        topic = namespaced_topic(event.topic, self.namespace)
        # the inputs, unchanged, with their recorded QoS (the nodes' for an older bag without)
        self.recorder.write(topic, event.msgtype, event.bag_ns, event.raw, event.offered_qos or [NODES_QOS])
        self.result.messages_out += 1
        stamp, message = stamp_ns(event.message.header.stamp), event.message
        if event.topic == TRUTH_TOPIC:
            self.result.truth.add(self.segment, stamp, pose2d_of(message.pose.pose))
        elif event.topic == ODOMETRY_TOPIC:
            self.result.odometry.add(self.segment, stamp, pose2d_of(message.pose.pose))
            estimate, poses = self.pipelines.on_odometry(message)
            if estimate is not None:
                self._write_ekf(estimate, stamp, message)
            self.write_total(poses, event.due_ns)
        else:
            self.write_total(self.pipelines.on_bearings(message), event.due_ns)

    def write_total(self, poses: list[RevolutionPose], due: int) -> None:
        """ToTal's poses (those of a revolution that gave none are not published)."""
        for outcome in poses:
            if isinstance(outcome.result, PoseEstimate):
                self._write_total(outcome.result, outcome.stamp_s, due)

    def _write_ekf(self, estimate: Estimate, stamp: int, odometry: Any) -> None:
        self.result.ekf.add(self.segment, stamp, estimate.pose)
        self.result.ekf_covariances.append(estimate.covariance)
        level, verdict = self.pipelines.judgement
        self.result.ekf_integrity.add(
            self.segment, stamp, math.nan if level is None else level.horizontal_m, verdict.status
        )
        message = self.build.ekf_odometry(estimate, stamp, odometry, self.map_frame)
        self.write(LIVE_EKF_TOPIC, ODOMETRY_TYPE, stamp, message)
        self.write(topics.EKF_POSE, POSE_COV_TYPE, stamp, self.build.stamped(message.header, message.pose))

    def _write_total(self, estimate: PoseEstimate, stamp_s: float, due: int) -> None:
        stamp = round(stamp_s * 1e9)  # triangulation_node's time_message rounding
        message = self.build.triangulated_pose(estimate, stamp, self.map_frame)
        self.write(LIVE_POSE_TOPIC, POSE_TYPE, due, message)
        if estimate.accepted:
            self.result.total.add(self.segment, stamp, (estimate.x, estimate.y, estimate.heading))
            self.write(topics.POSE_COV, POSE_COV_TYPE, due, self.build.stamped(message.header, message.pose))


def replay_bag(
    input_bag: pathlib.Path,
    output_bag: pathlib.Path,
    settings: ReplaySettings | None = None,
    *,
    typestore: Any = None,
    storage: str = "mcap",
    map_frame: str = "map",
    start_like_live: bool = False,
    namespace: str = "",
) -> ReplayResult:
    """Replay a bag through both pipelines and write the outputs (with the inputs) to a new bag. namespace:
    the robot whose topics are replayed, its outputs written in the same namespace; start_like_live: the EKF
    starts from the live EKF's first recorded estimate (`LiveStart`) instead of ToTal's first pose."""
    typestore = typestore if typestore is not None else beams_typestore()
    pipelines = ReplayPipelines(settings or settings_from_parameters({}, {}))
    use_odometry = pipelines.settings.triangulation.use_odometry
    pipelines.expect_odometry = use_odometry and ODOMETRY_TOPIC in bag_topics(input_bag, namespace)
    if start_like_live:
        pipelines.live_start = live_estimates(input_bag, typestore, namespace)
        if not pipelines.live_start:
            raise ValueError(f"{input_bag} has no {LIVE_EKF_TOPIC} message to start from")
    started = time.perf_counter()
    last_ns: int | None = None
    with BagRecorder(pathlib.Path(output_bag), typestore, storage) as recorder:
        run = _Run(pipelines, recorder, MessageBuilder(typestore), typestore, map_frame, namespace)
        events = read_events(pathlib.Path(input_bag), typestore, run.result.counts, namespace)
        for event in in_stamp_order(events):
            if event is TIME_JUMP:
                run.write_total(pipelines.flush(), last_ns)
                run.segment += 1
                pipelines.reset()
                continue
            run.result.messages_in += 1
            run.result.span_s += 0.0 if last_ns is None else max(0.0, (event.due_ns - last_ns) * 1e-9)
            last_ns = event.due_ns
            run.handle(event)
        run.write_total(pipelines.flush(), last_ns)
    result = run.result
    result.wall_s = time.perf_counter() - started
    result.counts.update(pipelines.counts)
    result.counts.update({f"ekf_{k}": v for k, v in pipelines.localiser.stats.counts.items()})
    return result


# -- figures --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Agreement:
    """Replayed against live poses at the same stamps (after `settle_s` from the first common stamp)."""

    matched: int
    max_position_m: float
    max_heading_rad: float
    rms_position_m: float


def agreement(replayed: Track, live: Track, settle_s: float = 0.0) -> Agreement:
    """Differences of two tracks at their common stamps (exact ns), from settle_s after the first one."""
    live_poses = live.by_stamp()
    pairs = sorted((t, pose, live_poses[t]) for t, pose in replayed.by_stamp().items() if t in live_poses)
    if pairs:
        start = pairs[0][0] + round(settle_s * NS_PER_S)
        pairs = [p for p in pairs if p[0] >= start]
    if not pairs:
        return Agreement(0, math.nan, math.nan, math.nan)
    position = np.array([math.hypot(a[0] - b[0], a[1] - b[1]) for _, a, b in pairs])
    heading = np.array([abs(wrap_to_pi(a[2] - b[2])) for _, a, b in pairs])
    return Agreement(len(pairs), float(position.max()), float(heading.max()), rms(position))


def live_tracks(input_bag: pathlib.Path, typestore: Any, namespace: str = "") -> tuple[Track, Track]:
    """(accepted ToTal poses, EKF estimates) the live nodes (of a robot's namespace) published, as recorded
    in the bag."""
    total, ekf = Track(), Track()
    live_topics = (LIVE_POSE_TOPIC, LIVE_EKF_TOPIC)
    with Reader(pathlib.Path(input_bag)) as reader:
        wanted = [c for c in reader.connections if relative_topic(c.topic, namespace) in live_topics]
        for connection, _, raw in reader.messages(connections=wanted) if wanted else ():
            message = typestore.deserialize_cdr(raw, connection.msgtype)
            stamp = stamp_ns(message.header.stamp)
            if relative_topic(connection.topic, namespace) == LIVE_EKF_TOPIC:
                ekf.add(0, stamp, pose2d_of(message.pose.pose))
            elif message.accepted:
                total.add(0, stamp, pose2d_of(message.pose.pose))
    return total, ekf


def summary(result: ReplayResult, live: tuple[Track, Track] | None = None) -> str:
    """The summary table: RMS errors against the truth, counts, speed, agreement with the live nodes."""
    tracks = result.in_map("ekf")  # dead reckoning from the EKF's first estimate
    truth = tracks["truth"]
    lines = []
    if len(truth):
        names = (
            ("odometry (from the first EKF pose)", "odometry"),
            ("ToTal (accepted)", "ToTal"),
            ("EKF", "EKF"),
        )
        lines += rms_table(((label, tracks[name]) for label, name in names), truth)
        lines.append("")
    lines.append(", ".join(f"{key} {value}" for key, value in sorted(result.counts.items())))
    lines.append(
        f"{result.messages_in} messages in {result.wall_s:.2f} s: {result.messages_per_s:.0f} "
        f"messages/s, {result.real_time_factor:.1f} x real time; {result.messages_out} written"
    )
    if live is not None:
        for name, replayed, recorded in (("ToTal", result.total, live[0]), ("EKF", result.ekf, live[1])):
            a = agreement(replayed, recorded)
            if a.matched:
                lines.append(
                    f"replayed {name} vs live at {a.matched} common stamps: max "
                    f"{1000 * a.max_position_m:.2f} mm, {math.degrees(a.max_heading_rad):.3f} deg "
                    f"(RMS {1000 * a.rms_position_m:.2f} mm)"
                )
    return "\n".join(lines)


@command("replay_bag")
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="replay_bag", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("input_bag", type=pathlib.Path, help="rosbag2 directory (sqlite3 or MCAP)")
    parser.add_argument("output_bag", type=pathlib.Path, help="new bag directory (must not exist)")
    parser.add_argument(
        "--plot",
        type=pathlib.Path,
        help="figure (PNG): the trajectories; the EKF's error, 3-sigma and protection level on its status",
    )
    parser.add_argument(
        "--start-like-live",
        action="store_true",
        help="start the EKF from the live EKF's first estimate recorded in the bag (to "
        "compare with the live run) instead of ToTal's first pose",
    )
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="output storage")
    parser.add_argument(
        "--namespace",
        default="",
        help="the robot whose topics to replay (e.g. robot1 for /robot1/odom, ...); "
        "default: the topics without a namespace",
    )
    parser.add_argument(
        "--params-file",
        type=pathlib.Path,
        default=installed_params_file(),
        help="ROS parameter file with triangulation_node and ekf_node sections, validated as "
        "the nodes validate it (default: beams_bringup's beams_params.yaml)",
    )
    options = parser.parse_args(argv)
    settings = settings_from_parameters(
        load_node_parameters(options.params_file, TRIANGULATION_PARAMETERS),
        load_node_parameters(options.params_file, EKF_PARAMETERS),
    )
    typestore = beams_typestore()
    result = replay_bag(
        options.input_bag,
        options.output_bag,
        settings,
        typestore=typestore,
        storage=options.storage,
        start_like_live=options.start_like_live,
        namespace=options.namespace,
    )
    if not result.counts[f"messages_{BEARINGS_TOPIC}"]:
        topic = namespaced_topic(BEARINGS_TOPIC, options.namespace)
        raise ValueError(
            f"{options.input_bag}: no {BEARINGS_TYPE} on {topic}, nothing replayed ({result.counts})"
        )
    live = live_tracks(options.input_bag, typestore, options.namespace)
    if options.plot:
        plot_run(result, "ekf", options.plot, "BeAMS bag replay")  # the odometry from the EKF's first pose
    print(summary(result, live))
    print(f"bag: {options.output_bag}" + (f"; plot: {options.plot}" if options.plot else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
