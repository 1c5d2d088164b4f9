"""replay_bag on a bag the demo recorded (every node a process, talking over DDS): the replayed ToTal and
EKF poses against the live nodes' poses recorded in the same bag, and the command against the truth."""

import math
import os
import pathlib
import subprocess
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
INSTALL_BASE = pathlib.Path(os.environ.get("BEAMS_INSTALL_BASE", ROOT / "install"))
# The demo's duration includes its processes' start: on the 2 shared cores under a load of 5 the EKF's
# first estimate came 3.4-5.5 s after the first odometry, and 12 s left the bag 3 of its statuses.
DEMO_DURATION_S = 15.0


def run(command: list[str], env: dict[str, str] | None = None) -> str:
    """Run a command (bounded); its stdout, after asserting a clean exit."""
    completed = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120, check=False)
    assert completed.returncode == 0, completed.stdout + completed.stderr
    assert "Traceback" not in completed.stderr, completed.stderr
    return completed.stdout


def differences(replayed, live) -> np.ndarray:
    """(position m, |heading| rad) differences of two `trajectory_metrics.Track`s at their common stamps."""
    live_poses = live.by_stamp()
    pairs = [(pose, live_poses[t]) for t, pose in replayed.by_stamp().items() if t in live_poses]
    return np.array(
        [(math.hypot(a[0] - b[0], a[1] - b[1]), abs(math.remainder(a[2] - b[2], math.tau))) for a, b in pairs]
    ).reshape(-1, 2)


def test_replay_of_a_demo_bag(tmp_path, ros_env):
    """A 15 s demo, then the replay. The replay runs the pure objects the nodes wrap, in stamp order; the
    live nodes saw the messages in arrival order. Tolerances against the live poses, from five 12 s demos
    (and earlier 10-15 s ones, one with a load average of 8 on the 2 cores):
    - ToTal: node and replay run `TriangulationPipeline`, where a revolution waits for the odometry that
      covers its last bearing, so arrival order does not matter. Measured 79% bit-equal and the others
      within 0.01 um (floating-point order); before the waiting, 50-83% bit-equal and max 5.5 mm (the
      node extrapolated the odometry of revolutions that arrived first). A revolution whose odometry
      comes more than a revolution late (a starved node) is still extrapolated or refused: all within
      10 mm, half bit-equal; the node counts those (`revolutions_estimated_before_their_odometry` on
      /diagnostics), and the poses off by 1 um or more are no more than that count and 5% (the revolutions
      of the last second, not reported yet).
    - EKF, started from the live EKF's first estimate (the bag misses the pose that initialised it): live,
      bearings arriving before the odometry of their instant were applied with extrapolated turret
      positions, later ones again when a starved ekf_node fell behind. Measured max 1.9-3.4 mm and
      0.14-0.28 deg, 95% quantiles up to 2.0 mm and 0.15 deg, RMS up to 1.2 mm; under load, 95% quantiles
      3.5 mm and 0.34 deg. A live EKF that started from a poor pose and gated most bearings once made a
      41 mm step at 2 of 154 stamps (a bearing at the edge of its gate, taken on one side only); hence
      quantiles: 95% within 5 mm and 0.5 deg, RMS within 5 mm.
    Then the replay from ToTal's first pose against the truth, and the command as a user runs it.
    """
    from rosbags.interfaces import QosDurability, QosReliability
    from rosbags.rosbag2 import Reader

    from beams_tools.bag_io import beams_typestore, read_messages
    from beams_tools.bag_replay import live_tracks, replay_bag
    from beams_tools.trajectory_metrics import errors_against_truth, rms

    # ros_env's own ROS_HOME: a demo's ekf_node resuming the learnt states an earlier run left in
    # ~/.ros/beams made its estimates differ from the replay's (which starts from the priors) by 5-6 mm at
    # the 95 % quantile, against 1.7-1.9 mm from the priors (2026-11-28)
    env = ros_env
    run(
        [
            sys.executable,
            "-m",
            "beams_bringup.demo",
            "--duration",
            str(DEMO_DURATION_S),
            "--output",
            str(tmp_path / "demo"),
        ],
        env,
    )
    bag = tmp_path / "demo" / "bag"
    typestore = beams_typestore()
    # Recorded as `ros2 bag record` does: fully qualified names, each with its publishers' offered
    # profiles (reliable, volatile, depth 10 for the nodes' topics; the graph does not report history).
    with Reader(bag) as reader:
        offered = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert {
        "/odom",
        "/beams/bearings",
        "/beams/sim/ground_truth",
        "/beams/ekf/odometry",
        "/diagnostics",
        "/tf",
    } <= set(offered), offered
    assert all(topic.startswith("/") for topic in offered)
    for topic in ("/odom", "/beams/bearings", "/beams/ekf/odometry", "/beams/pose"):
        assert len(offered[topic]) == 1, (topic, offered[topic])
        assert offered[topic][0].reliability == QosReliability.RELIABLE
        assert offered[topic][0].durability == QosDurability.VOLATILE
    # the status topics beside the estimates, latched: each message names its node and process, expires
    # 2 s after its stamp, and the EKF's names an estimate the bag holds; the demo's figure draws it
    ekf_stamps = {
        (m.header.stamp.sec, m.header.stamp.nanosec)
        for _, _, m in read_messages(bag, typestore, ["/beams/ekf/odometry"])
    }
    said_by_topic = {}
    for topic, node in (
        ("/beams/ekf/status", "/ekf_node"),
        ("/beams/triangulation/status", "/triangulation_node"),
    ):
        assert offered[topic][0].durability == QosDurability.TRANSIENT_LOCAL, offered[topic]
        said = said_by_topic[topic] = [m for _, _, m in read_messages(bag, typestore, [topic])]
        # at each change and at least once a second (a loaded machine delays the timer by a fraction)
        stamps_s = [m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in said]
        assert len(said) >= 3 and max(np.diff(stamps_s)) <= 1.5, (topic, stamps_s)
        assert {m.node for m in said} == {node} and len({m.instance for m in said}) == 1, topic
        assert all(
            (m.valid_until.sec - m.header.stamp.sec) * 10**9 + m.valid_until.nanosec - m.header.stamp.nanosec
            == 2 * 10**9
            for m in said
        ), topic
        assert any(m.status == m.TRACKING for m in said), [m.message for m in said[-3:]]
    # the EKF's level when it last said tracking: a few mm, within its 5 cm alert limit (on a loaded
    # machine the end of a demo may be degraded by a revolution that arrived past the stamp tolerance)
    last = [m for m in said_by_topic["/beams/ekf/status"] if m.status == m.TRACKING][-1]
    assert 0.0 < last.horizontal_protection_level_m < last.horizontal_alert_limit_m
    judged = [
        (m.estimate_stamp.sec, m.estimate_stamp.nanosec)
        for _, _, m in read_messages(bag, typestore, ["/beams/ekf/status"])
        if m.estimate_stamp.sec
    ]
    assert len(judged) >= 5 and sum(stamp in ekf_stamps for stamp in judged) >= 0.9 * len(judged), judged[-5:]
    assert (tmp_path / "demo" / "trajectory.png").stat().st_size > 10_000

    replayed = replay_bag(bag, tmp_path / "like_live", typestore=typestore, start_like_live=True)
    live_total, live_ekf = live_tracks(bag, typestore)
    total = differences(replayed.total, live_total)
    # live poses before the bag's first odometry have no replayed twin (see ReplayPipelines.on_bearings),
    # and a starved triangulation_node drops revolutions (best-effort QoS) that the bag holds
    assert len(total) >= 0.9 * min(len(live_total.rows), len(replayed.total.rows)), (len(total), live_total)
    assert len(total) >= 20, f"only {len(total)} live ToTal poses to compare: see {tmp_path / 'demo'}"
    assert total[:, 0].max() < 0.01
    assert np.mean(total[:, 0] < 1e-6) >= 0.5
    early = [
        int(value.value)
        for _, _, message in read_messages(bag, typestore, ["/diagnostics"])
        for status in message.status
        if "/triangulation_node:" in status.name
        for value in status.values
        if value.key == "revolutions_estimated_before_their_odometry"
    ]
    assert early, "no count of revolutions estimated before their odometry in triangulation_node's reports"
    differing = int(np.sum(total[:, 0] >= 1e-6))
    assert differing <= early[-1] + 0.05 * len(total), (differing, early[-1], len(total))
    ekf = differences(replayed.ekf, live_ekf)
    # every live estimate at an odometry stamp the bag holds, from the replay's start on, has a twin
    # (the recorder can miss odometry messages under load, the live EKF published those stamps)
    odometry_stamps = {row[1] for row in replayed.odometry.rows}
    start = replayed.ekf.rows[0][1]
    replayable = [t for t in live_ekf.by_stamp() if t >= start and t in odometry_stamps]
    assert len(ekf) == len(replayable)
    assert len(ekf) >= 20, f"the live EKF published {len(live_ekf.rows)} estimates: see {tmp_path / 'demo'}"
    assert np.quantile(ekf[:, 0], 0.95) < 0.005
    assert np.quantile(ekf[:, 1], 0.95) < math.radians(0.5)
    assert np.sqrt(np.mean(ekf[:, 0] ** 2)) < 0.005

    # Replayed from ToTal's first pose: ToTal within 1 cm RMS of the truth the demo recorded, and the EKF
    # within issue 5's targets (1 cm, 0.3 deg RMS) over the whole run, and within 3 cm at every stamp.
    # The first ToTal fix of a match used to be uncompensated (no odometry yet), up to 3 cm off with a
    # covariance of a few mm: the EKF started from it gated most bearings for 6.6 s in one demo. Such a
    # fix is now refused; three 20 s demos measured RMS 2.2-2.7 mm and 0.07 deg, at most 8 mm.
    own = replay_bag(bag, tmp_path / "from_total", typestore=typestore)
    truth = own.truth.array()
    total_position, _ = errors_against_truth(own.total.array(), truth)
    assert rms(total_position) < 0.01
    position, heading = errors_against_truth(own.ekf.array(), truth)
    # an estimate at (nearly) every odometry stamp from ToTal's first pose on (the driver may start late)
    odometry_stamps = own.odometry.array()[:, 1]
    assert len(position) >= 0.95 * np.sum(odometry_stamps >= own.total.array()[0, 1])
    assert rms(position) < 0.01
    assert math.degrees(rms(heading)) < 0.3
    assert position.max() < 0.03

    # The command as a user runs it: summary, plot, a new MCAP bag with the outputs and the inputs.
    replay_bag_command = INSTALL_BASE / "beams_tools" / "lib" / "beams_tools" / "replay_bag"
    stdout = run(
        [str(replay_bag_command), str(bag), str(tmp_path / "replay"), "--plot", str(tmp_path / "replay.png")]
    )
    assert "| EKF |" in stdout and "x real time" in stdout and "replayed EKF vs live" in stdout
    assert (tmp_path / "replay.png").stat().st_size > 10_000
    assert "mcap" in (tmp_path / "replay" / "metadata.yaml").read_text()
    topics = {topic for topic, _, _ in read_messages(tmp_path / "replay", typestore)}
    assert {
        "/beams/pose",
        "/beams/pose_cov",
        "/beams/ekf/odometry",
        "/beams/ekf/pose",
        "/odom",
        "/beams/bearings",
        "/beams/sim/ground_truth",
    } <= topics
