"""The simulated edge source (`source: sim`, declared to the driver by setup.py's beams_driver.edge_sources
entry point): the edge-level simulation of the sensor (sensor_sim.py) following the robot's true pose as
it arrives (beams/sim/ground_truth) or a static pose, with beacons hidden by a schedule or by the other
robots' bodies (occlusion.py). Pure: the driver's SourceHost feeds it the pose streams.
"""

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from beams_common.calibration.calibration_file import load_calibration
from beams_common.config.geometry_parameters import beacon_map_check, beacon_map_of, beacon_map_specs
from beams_common.config.parameters import ParameterSpec, is_topic_name
from beams_common.geometry.pose2d import Pose2D
from beams_common.interfaces import topics
from beams_driver.codes import BeaconCode
from beams_driver.edge_source import EdgeSourceKind, SourceHealth, SourceHost, SourcePoll
from beams_driver.edges import TURRET_PERIOD_S
from beams_driver.receiver import ReceiverModel
from beams_sim.occlusion import TRUTH_MAX_EXTRAPOLATION_S, OtherRobots, truth_buffer, truth_covers
from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator, beacons_from_map

GROUND_TRUTH_TOPIC = topics.GROUND_TRUTH
# A clock that jumped this far ahead (s) restarts the simulation from now instead of catching up.
MAX_CATCH_UP_S = 1.0


class OcclusionSchedule:
    """Beacons the simulated sensor cannot see: always, or during windows of time since the simulation
    started (a robot or a hand in front of a beacon), as the sensor simulator's occlusion callable."""

    def __init__(self, always: set[int], windows: list[tuple[int, float, float]]) -> None:
        self.always = always
        self.windows = windows
        self.origin_s = 0.0

    @classmethod
    def from_parameters(cls, occluded: list[int], flat_windows: list[float]) -> "OcclusionSchedule":
        """[-1] and [-1.0] mean none; windows come as [beacon_id, start_s, end_s, ...]."""
        windows = [  # [-1.0] holds no triple
            (int(flat_windows[k]), float(flat_windows[k + 1]), float(flat_windows[k + 2]))
            for k in range(0, len(flat_windows) - 2, 3)
        ]
        return cls({int(i) for i in occluded if i >= 0}, windows)

    @property
    def ids(self) -> set[int]:
        return self.always | {beacon_id for beacon_id, _, _ in self.windows}

    def __call__(self, beacon_id: int, time_s: float) -> bool:
        since_s = time_s - self.origin_s
        return beacon_id in self.always or any(
            beacon_id == hidden and start_s <= since_s < end_s for hidden, start_s, end_s in self.windows
        )


def _windows_check(values: Mapping[str, Any]) -> str | None:
    flat = list(values["sim_occlusion_windows"])
    if flat == [-1.0]:
        return None
    if len(flat) % 3:
        return f"sim_occlusion_windows needs triples [beacon_id, start_s, end_s], got {flat}"
    windows = [tuple(flat[k : k + 3]) for k in range(0, len(flat), 3)]
    if any(not 0.0 <= start < end for _, start, end in windows):
        return f"sim_occlusion_windows: need 0 <= start_s < end_s, got {windows}"
    return None


def _static_pose_check(value: list[float]) -> str | None:
    return None if len(value) in (1, 3) else f"sim_static_pose must be [x, y, theta] or [0.0], got {value}"


def _topics_check(value: list[str]) -> str | None:
    bad = [topic for topic in value if topic and not is_topic_name(topic)]
    return f"sim_other_robots: {bad} are not valid topic names" if bad else None


# The simulated sensor's noise models (sensor_sim.SensorSimConfig).
SIM_NOISE_MODELS = {"thesis_hardware": SensorSimConfig.thesis_hardware, "ideal": SensorSimConfig}


def simulated_sensor(values: Mapping[str, Any], codes: Sequence[BeaconCode]) -> SensorSimConfig:
    """The simulated sensor of sim_noise_model."""
    return SIM_NOISE_MODELS[values["sim_noise_model"]](codes=tuple(codes))


def simulated_receiver(values: Mapping[str, Any], codes: Sequence[BeaconCode]) -> ReceiverModel:
    """The simulated sensor's receiver, the one the decoder then expects."""
    return simulated_sensor(values, codes).receiver


PARAMETERS = (
    ParameterSpec(
        "sim_noise_model",
        "thesis_hardware",
        "Simulated sensor noise: thesis_hardware (sections "
        "5.5-5.7: window-dependent asymmetric edge noise, AGC, table 5.1's window biases, a 0.23 deg "
        "power bias) or ideal (OOK noise, constant edge noise).",
        choices=tuple(SIM_NOISE_MODELS),
    ),
    *beacon_map_specs("sim_beacon_", "Simulated beacon (true position)", runtime=False),
    ParameterSpec(
        "sim_static_pose",
        [0.0],
        f"Fixed robot pose [x, y, theta] for the simulated sensor; [0.0] follows {GROUND_TRUTH_TOPIC}.",
        minimum=-100.0,
        maximum=100.0,
        check=_static_pose_check,
    ),
    ParameterSpec(
        "sim_turret_offset_m",
        [0.0, 0.0],
        "True turret centre in base_link [x, y] (m), simulated.",
        minimum=-1.0,
        maximum=1.0,
        length=2,
    ),
    ParameterSpec(
        "sim_occluded_beacons", [-1], "Beacons the simulation hides ([-1]: none).", minimum=-1, maximum=255
    ),
    ParameterSpec(
        "sim_occlusion_windows",
        [-1.0],
        "Beacons hidden for a while: [beacon_id, start_s, end_s, "
        "...], seconds since the first simulated revolution ([-1.0]: none).",
        minimum=-1.0,
        maximum=1e6,
    ),
    ParameterSpec(
        "sim_other_robots",
        [""],
        "Ground-truth topics (nav_msgs/Odometry) of the other robots on "
        "the table, whose bodies hide beacons from the simulated sensor, e.g. "
        "['/robot_b/beams/sim/ground_truth'] ([''] : none).",
        check=_topics_check,
    ),
    ParameterSpec(
        "sim_other_robot_radius_m",
        0.04,
        "Radius of another robot's body in the beacons' plane (m): "
        "there stands its own BeAMS sensor, 8 cm wide (thesis ch. 2).",
        minimum=0.0,
        maximum=1.0,
    ),
    ParameterSpec(
        "sim_stray_ir_rate_hz", 0.0, "Rate of stray infrared bursts (Hz).", minimum=0.0, maximum=10000.0
    ),
    ParameterSpec(
        "sim_bias_file",
        "",
        "Calibration file whose power and rotation biases the simulated sensor injects (empty: none).",
    ),
    ParameterSpec("sim_sensor_seed", 1, "Seed of the simulated sensor's noise.", minimum=0, maximum=2**31),
)


class SimulatedSource:
    """The simulated sensor as an EdgeSource: revolutions are simulated as the node's clock passes them."""

    def __init__(self, values: Mapping[str, Any], codes: Sequence[BeaconCode], host: SourceHost) -> None:
        simulated_map = beacon_map_of(values, "sim_beacon_")
        unknown = sorted(set(simulated_map.ids) - {c.code_id for c in codes})
        if unknown:
            raise ValueError(f"sim_beacon_ids {unknown} have no code in the code list")
        static = values["sim_static_pose"]
        self.static_pose: Pose2D | None = tuple(map(float, static)) if len(static) == 3 else None
        self.occlusion = OcclusionSchedule.from_parameters(
            values["sim_occluded_beacons"], values["sim_occlusion_windows"]
        )
        self.ground_truth = truth_buffer()
        self.other_robots = OtherRobots(
            simulated_map.as_dict(),
            values["sim_other_robot_radius_m"],
            lambda t: self.simulator.turret_position(self._pose_at(t)),
        )
        try:
            injected = load_calibration(values["sim_bias_file"]) if values["sim_bias_file"] else None
        except (OSError, ValueError) as error:  # named as the parameter, as calibration_file is
            raise ValueError(f"sim_bias_file: {error}") from None
        offset = values["sim_turret_offset_m"]
        self.simulator = SensorSimulator(
            replace(simulated_sensor(values, codes), spurious_rate_hz=values["sim_stray_ir_rate_hz"]),
            beacons_from_map(simulated_map),
            np.random.default_rng(values["sim_sensor_seed"]),
            power_bias_rad=injected.bearing_correction.power_bias if injected else None,
            rotation_bias_rad=injected.bearing_correction.rotation_bias if injected else None,
            turret_offset_m=(float(offset[0]), float(offset[1])),
            occlusion=self._hidden,
        )
        self.next_revolution_start_s: float | None = None
        self.counts = {
            "revolutions_skipped_no_pose": 0,
            "ground_truth_rejected_non_finite": 0,
            "other_robot_truth_rejected_non_finite": 0,
        }
        self._waiting = False
        self._broken = False
        own_topic = host.resolve_topic(GROUND_TRUTH_TOPIC)
        host.subscribe_poses(GROUND_TRUTH_TOPIC, self._on_ground_truth)
        for topic in filter(None, values["sim_other_robots"]):
            if host.resolve_topic(topic) == own_topic:
                raise ValueError(f"sim_other_robots: {topic} is this robot's own ground truth")
            host.subscribe_poses(topic, lambda *sample, topic=topic: self._on_other_robot(topic, *sample))

    def _on_ground_truth(self, stamp_s: float, pose: Pose2D, twist: tuple[float, float]) -> None:
        if not self.ground_truth.add(stamp_s, pose, twist):
            self.counts["ground_truth_rejected_non_finite"] += 1

    def _on_other_robot(self, topic: str, stamp_s: float, pose: Pose2D, twist: tuple[float, float]) -> None:
        if not self.other_robots.add(topic, stamp_s, *pose, *twist):
            self.counts["other_robot_truth_rejected_non_finite"] += 1

    def _pose_at(self, t: float) -> Pose2D:
        if self.static_pose is not None:
            return self.static_pose
        truth = self.ground_truth
        pose = truth.pose_at(t)
        if pose is None and truth.oldest_time_s is not None:
            # a pass straddling the end of a revolution the truth only just covers (the truth stream
            # stopped): the truth's reach holds rather than no pose
            reach_s = truth.newest_stamp_s + TRUTH_MAX_EXTRAPOLATION_S
            pose = truth.pose_at(min(max(t, truth.oldest_time_s), reach_s))
        return pose

    def _hidden(self, beacon_id: int, time_s: float) -> bool:
        """The simulated sensor's occlusion: the schedule's beacons, and those behind another robot."""
        return self.occlusion(beacon_id, time_s) or self.other_robots(beacon_id, time_s)

    def poll(self, now_s: float) -> SourcePoll:
        start_s = self.next_revolution_start_s
        if start_s is None or start_s > now_s or now_s - start_s > MAX_CATCH_UP_S:
            # first revolution, or the clock jumped (bag loop, sim time reset): restart from now
            self.next_revolution_start_s = now_s - TURRET_PERIOD_S
            self.occlusion.origin_s = now_s - TURRET_PERIOD_S
            self._broken = True
            return SourcePoll()
        poll = SourcePoll(continuity_broken=self._broken)
        self._broken = False
        while start_s + TURRET_PERIOD_S <= now_s:
            end_s = start_s + TURRET_PERIOD_S
            self._waiting = self.static_pose is None and not truth_covers(self.ground_truth, start_s, end_s)
            start_s = end_s
            if not self._waiting:
                poll.revolutions.append(self.simulator.revolution(self._pose_at, end_s - TURRET_PERIOD_S))
                continue
            self.counts["revolutions_skipped_no_pose"] += 1
            # the next revolution does not follow the last one decoded
            if poll.revolutions:
                self._broken = True
                break
            poll.continuity_broken = True
        self.next_revolution_start_s = start_s
        return poll

    def health(self) -> SourceHealth:
        values = {**self.counts, "windows_hidden_by_other_robots": self.other_robots.hidden_windows}
        if self._waiting:
            return SourceHealth("warn", f"waiting for {GROUND_TRUTH_TOPIC}", values)
        return SourceHealth("ok", None, values)

    def close(self) -> None:
        pass


EDGE_SOURCE = EdgeSourceKind(
    "sim",
    PARAMETERS,
    SimulatedSource,
    together=(beacon_map_check("sim_beacon_"), _windows_check),
    receiver=simulated_receiver,
)
