"""driver_node: BeAMS bearings, once per turret revolution, from the simulated sensor or the serial device.

Publishes `beams/bearings` (beams_msgs/BeaconBearingArray, sensor-data QoS) and `/diagnostics`.
The simulated source (the default) follows the robot's true pose on `beams/sim/ground_truth`
(or a static pose) edge by edge; the serial source reads the sensor microcontroller's edge captures.
Both go through the same decoder and variance model; the calibration file's bearing corrections
(power bias, rotation bias; thesis ch. 7) are applied to the published bearings.
"""

import sys
from dataclasses import replace

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.node import Node

from beams_driver.angles import wrap_to_pi
from beams_driver.bearing_correction import BearingCorrection
from beams_driver.calibration_file import SensorCalibration, load_calibration
from beams_driver.codes import BIT_TIME_S, code_family, codes_from_strings, validate_codes
from beams_driver.decoder import MIN_CODES_SEEN, BearingDecoder, DecodedRevolution
from beams_driver.edges import TURRET_PERIOD_S
from beams_driver.node_support import (
    BEARINGS_QOS,
    Diagnostics,
    ParameterValidationError,
    declare_beacon_map,
    declare_choice,
    declare_parameter,
    load_calibration_parameter,
    run_node,
    serve_calibration_reload,
)
from beams_driver.ros_messages import pose2d_of, seconds_to_stamp, stamp_to_seconds
from beams_driver.sensor_sim import SensorSimConfig, SensorSimulator, beacons_from_map
from beams_driver.serial_protocol import DEFAULT_BAUDRATE
from beams_driver.serial_source import DeviceNotFoundError, DeviceOpenError, SerialEdgeSource
from beams_driver.sim_world import OtherRobots, TruthHistory
from beams_driver.variance import VARIANCE_MODES, VarianceModel
from beams_msgs.msg import BeaconBearing, BeaconBearingArray

SERIAL_POLL_PERIOD_S = 0.01
# The simulated sensor's noise models; the serial source's receiver is the thesis hardware.
SIM_NOISE_MODELS = {"thesis_hardware": SensorSimConfig.thesis_hardware, "ideal": SensorSimConfig}


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
        always = {int(i) for i in occluded if i >= 0}
        if list(flat_windows) == [-1.0]:
            return cls(always, [])
        if len(flat_windows) % 3:
            raise ParameterValidationError(
                f"sim_occlusion_windows needs triples [beacon_id, start_s, end_s], got {list(flat_windows)}"
            )
        windows = [
            (int(flat_windows[k]), float(flat_windows[k + 1]), float(flat_windows[k + 2]))
            for k in range(0, len(flat_windows), 3)
        ]
        if any(not 0.0 <= start < end for _, start, end in windows):
            raise ParameterValidationError(f"sim_occlusion_windows: need 0 <= start_s < end_s, got {windows}")
        return cls(always, windows)

    @property
    def ids(self) -> set[int]:
        return self.always | {beacon_id for beacon_id, _, _ in self.windows}

    def __call__(self, beacon_id: int, time_s: float) -> bool:
        since_s = time_s - self.origin_s
        return beacon_id in self.always or any(
            beacon_id == hidden and start_s <= since_s < end_s for hidden, start_s, end_s in self.windows
        )


def truth_sample(msg: Odometry) -> tuple[float, float, float, float, float, float]:
    """(stamp, x, y, theta, speed, yaw rate) of a ground-truth message, as TruthHistory stores it."""
    x, y, heading = pose2d_of(msg.pose.pose)
    return (stamp_to_seconds(msg.header.stamp), x, y, heading, msg.twist.twist.linear.x,
            msg.twist.twist.angular.z)


class DriverNode(Node):
    def __init__(self) -> None:
        super().__init__("driver_node")
        self.diagnostics = Diagnostics(self, "driver")
        self.frame_id = declare_parameter(self, "frame_id", "beams_sensor", "Frame of the turret (sensor).")
        self.source = declare_choice(
            self, "source", "sim", ("sim", "serial"), "Edge source: simulated sensor or serial device."
        )
        self.codes = self._declare_codes()
        self.sim_config = self._declare_noise_model()
        min_codes = declare_parameter(
            self,
            "min_complete_codes",
            MIN_CODES_SEEN,
            "Complete codes a window must show to give a bearing (thesis section 2.5.2: 2).",
            minimum=1,
            maximum=10,
        )
        self.decoder = BearingDecoder(
            self.codes,
            self._declare_variance_model(),
            min_codes_seen=min_codes,
            receiver=self.sim_config.receiver,
        )
        calibration = load_calibration_parameter(self)
        self.correction = calibration.bearing_correction if calibration else BearingCorrection()
        serve_calibration_reload(self, self._apply_calibration)
        self.publisher = self.create_publisher(BeaconBearingArray, "beams/bearings", BEARINGS_QOS)
        if self.source == "sim":
            self._start_simulated_source()
        else:
            self._start_serial_source()
        self.get_logger().info(
            f"{self.source} source, codes {[str(c) for c in self.codes]}, variance mode "
            f"{self.decoder.variance_model.mode}, publishing {self.resolve_topic_name('beams/bearings')}"
        )

    # ---- parameters ----

    def _declare_codes(self):
        code_count = declare_parameter(
            self, "code_count", 5, "Number of codes of the family C_i (thesis eq. 2.6).", minimum=1, maximum=9
        )
        custom_codes = declare_parameter(
            self,
            "custom_codes",
            [""],
            "Custom code list as bit strings (e.g. '10111111'), code i+1 = entry i; [''] for the family.",
        )
        bit_time_s = declare_parameter(
            self, "bit_time_s", BIT_TIME_S, "Bit time T0 of the codes (s).", minimum=1e-6, maximum=1e-3
        )
        try:
            custom = [c for c in custom_codes if c]
            codes = codes_from_strings(custom, bit_time_s) if custom else code_family(code_count, bit_time_s)
            validate_codes(codes)
        except ValueError as error:
            raise ParameterValidationError(f"codes: {error}") from None
        return codes

    def _declare_noise_model(self) -> SensorSimConfig:
        """The simulated receiver (sim_noise_model), whose minimum burst the decoder and variances know."""
        if self.source != "sim":
            return SensorSimConfig.thesis_hardware(codes=tuple(self.codes))
        name = declare_choice(
            self,
            "sim_noise_model",
            "thesis_hardware",
            tuple(SIM_NOISE_MODELS),
            "Simulated sensor noise: thesis_hardware (sections 5.5-5.7) or ideal (OOK, constant edge noise).",
        )
        return SIM_NOISE_MODELS[name](codes=tuple(self.codes))

    def _declare_variance_model(self) -> VarianceModel:
        mode = declare_choice(self, "variance_mode", "exact", VARIANCE_MODES, "Bearing variance model.")
        natural = declare_parameter(
            self,
            "natural_variance_rad2",
            SensorSimConfig().natural_variance_rad2,
            "Natural (noise) variance added to the code variance (rad^2).",
            minimum=0.0,
            maximum=1e-2,
        )
        constant = declare_parameter(
            self,
            "constant_variance_rad2",
            1e-6,
            "Variance of every bearing in variance_mode 'constant' (rad^2).",
            minimum=1e-12,
            maximum=1e-2,
        )
        return VarianceModel(
            self.codes,
            mode,
            natural_variance_rad2=natural,
            constant_variance_rad2=constant,
            min_burst_fraction=self.sim_config.min_burst_fraction,
            min_burst_gap_exponent=self.sim_config.min_burst_gap_exponent,
        )

    def _apply_calibration(self, calibration: SensorCalibration) -> str:
        self.correction = calibration.bearing_correction
        return "power and rotation bias corrections replaced"

    # ---- simulated source ----

    def _start_simulated_source(self) -> None:
        simulated_map = declare_beacon_map(
            self, prefix="sim_beacon_", what="Simulated beacon (true position)"
        )
        beacons = beacons_from_map(simulated_map)
        unknown = sorted(set(simulated_map.ids) - {c.code_id for c in self.codes})
        if unknown:
            raise ParameterValidationError(f"sim_beacon_ids {unknown} have no code in the code list")
        self.static_pose = declare_parameter(
            self,
            "sim_static_pose",
            [0.0],
            "Fixed robot pose [x, y, theta] for the simulated sensor; [0.0] follows beams/sim/ground_truth.",
        )
        if len(self.static_pose) not in (1, 3):
            raise ParameterValidationError("sim_static_pose must be [x, y, theta] or [0.0]")
        offset = declare_parameter(
            self, "sim_turret_offset_m", [0.0, 0.0], "True turret centre in base_link [x, y] (m), simulated."
        )
        occluded = declare_parameter(
            self, "sim_occluded_beacons", [-1], "Beacons the simulation hides ([-1]: none)."
        )
        occlusion_windows = declare_parameter(
            self,
            "sim_occlusion_windows",
            [-1.0],
            "Beacons hidden for a while: [beacon_id, start_s, end_s, ...], seconds since the first "
            "simulated revolution ([-1.0]: none).",
        )
        self.occlusion = OcclusionSchedule.from_parameters(occluded, occlusion_windows)
        self.other_robots = self._declare_other_robots(
            dict(zip(simulated_map.ids, map(tuple, simulated_map.xy), strict=True)),
            lambda t: self.simulator.turret_position(self._pose_source()(t)),
        )
        spurious_rate = declare_parameter(
            self,
            "sim_stray_ir_rate_hz",
            0.0,
            "Rate of stray infrared bursts (Hz).",
            minimum=0.0,
            maximum=10000.0,
        )
        bias_file = declare_parameter(
            self,
            "sim_bias_file",
            "",
            "Calibration file whose power and rotation biases the simulated sensor injects (empty: none).",
        )
        injected = self._load_injected_biases(bias_file)
        seed = declare_parameter(
            self, "sim_seed", 1, "Seed of the simulated sensor's noise.", minimum=0, maximum=2**31
        )
        config = replace(self.sim_config, spurious_rate_hz=spurious_rate)
        self.simulator = SensorSimulator(
            config,
            beacons,
            np.random.default_rng(seed),
            power_bias_rad=injected.power_bias if injected else None,
            rotation_bias_rad=injected.rotation_bias if injected else None,
            turret_offset_m=(float(offset[0]), float(offset[1])),
            occlusion=self._hidden,
        )
        self.ground_truth = TruthHistory()
        self.next_revolution_start_s: float | None = None
        self.create_subscription(Odometry, "beams/sim/ground_truth", self._on_ground_truth, 50)
        self.create_timer(TURRET_PERIOD_S, self._simulate_due_revolutions)

    def _declare_other_robots(self, beacons: dict[int, tuple[float, float]], sensor_position) -> OtherRobots:
        topics = declare_parameter(
            self,
            "sim_other_robots",
            [""],
            "Ground-truth topics (nav_msgs/Odometry) of the other robots on the table, whose bodies hide "
            "beacons from the simulated sensor, e.g. ['/robot_b/beams/sim/ground_truth'] ([''] : none).",
        )
        radius_m = declare_parameter(
            self,
            "sim_other_robot_radius_m",
            0.04,
            "Radius of another robot's body in the beacons' plane (m): there stands its own BeAMS sensor, "
            "8 cm wide (thesis ch. 2).",
            minimum=0.0,
            maximum=1.0,
        )
        own_topic = self.resolve_topic_name("beams/sim/ground_truth")
        other_robots = OtherRobots(beacons, radius_m, sensor_position)
        for topic in filter(None, topics):
            if self.resolve_topic_name(topic) == own_topic:
                raise ParameterValidationError(f"sim_other_robots: {topic} is this robot's own ground truth")
            self.create_subscription(
                Odometry, topic, lambda msg, topic=topic: self._on_other_robot(topic, msg), 50
            )
        return other_robots

    def _hidden(self, beacon_id: int, time_s: float) -> bool:
        """The simulated sensor's occlusion: the schedule's beacons, and those behind another robot."""
        return self.occlusion(beacon_id, time_s) or self.other_robots(beacon_id, time_s)

    def _load_injected_biases(self, path: str) -> BearingCorrection | None:
        if not path:
            return None
        try:
            return load_calibration(path).bearing_correction
        except (OSError, ValueError) as error:
            raise ParameterValidationError(f"sim_bias_file: {error}") from None

    def _on_ground_truth(self, msg: Odometry) -> None:
        if not self.ground_truth.add(*truth_sample(msg)):
            self.diagnostics.increment("ground_truth_rejected_non_finite")

    def _on_other_robot(self, topic: str, msg: Odometry) -> None:
        if not self.other_robots.add(topic, *truth_sample(msg)):
            self.diagnostics.increment("other_robot_truth_rejected_non_finite")

    def _pose_source(self):
        if len(self.static_pose) == 3:
            pose = tuple(float(v) for v in self.static_pose)
            return lambda t: pose
        return self.ground_truth.pose_at

    def _simulate_due_revolutions(self) -> None:
        now_s = self.get_clock().now().nanoseconds * 1e-9
        start_s = self.next_revolution_start_s
        if start_s is None or start_s > now_s or now_s - start_s > 1.0:
            # First revolution, or the clock jumped (bag loop, sim time reset): restart from now.
            self.next_revolution_start_s = now_s - TURRET_PERIOD_S
            self.occlusion.origin_s = now_s - TURRET_PERIOD_S
            self.decoder.reset()
            return
        while start_s + TURRET_PERIOD_S <= now_s:
            end_s = start_s + TURRET_PERIOD_S
            if len(self.static_pose) == 1 and not self.ground_truth.covers(start_s, end_s):
                self.diagnostics.set_level("warn", "waiting for beams/sim/ground_truth")
                self.diagnostics.increment("revolutions_skipped_no_pose")
                self.decoder.reset()  # the next revolution does not follow the last one decoded
            else:
                self._publish(self.decoder.decode(self.simulator.revolution(self._pose_source(), start_s)))
            start_s = end_s
        self.next_revolution_start_s = start_s
        self.diagnostics.set("windows_hidden_by_other_robots", self.other_robots.hidden_windows)

    # ---- serial source ----

    def _start_serial_source(self) -> None:
        device = declare_parameter(self, "device", "/dev/ttyUSB0", "Serial device of the BeAMS sensor.")
        baud_rate = declare_parameter(
            self, "baud_rate", DEFAULT_BAUDRATE, "Serial baud rate.", minimum=9600, maximum=12_000_000
        )
        self.serial = SerialEdgeSource(
            device,
            baud_rate,
            read_timeout_s=SERIAL_POLL_PERIOD_S / 2,
            clock=lambda: self.get_clock().now().nanoseconds * 1e-9,
            log=self.get_logger().warning,
        )
        self.serial_reconnections = 0
        try:
            self.serial.open()
        except (DeviceNotFoundError, DeviceOpenError) as error:
            raise ParameterValidationError(f"device: {error}") from None
        self.create_timer(SERIAL_POLL_PERIOD_S, self._read_serial)

    def _read_serial(self) -> None:
        revolutions = self.serial.read()
        if self.serial.reconnections != self.serial_reconnections:
            # A window cut by the disconnection must not be joined to the new stream's first one.
            self.serial_reconnections = self.serial.reconnections
            self.decoder.reset()
        for edges in revolutions:
            self._publish(self.decoder.decode(edges))
        for reason, count in self.serial.drops.items():
            self.diagnostics.set(f"serial_drops_{reason}", count)
        self.diagnostics.set("serial_connected", self.serial.connected)
        self.diagnostics.set("serial_reconnections", self.serial.reconnections)
        if not self.serial.connected:
            self.diagnostics.set_level("error", f"serial device {self.serial.device} lost, reconnecting")

    # ---- publishing ----

    def _publish(self, decoded: DecodedRevolution) -> None:
        msg = BeaconBearingArray()
        msg.header.stamp = seconds_to_stamp(decoded.start_time_s)
        msg.header.frame_id = self.frame_id
        msg.revolution = decoded.revolution % 2**32
        msg.period = decoded.period_s
        msg.bearings = [self._bearing_message(b) for b in decoded.bearings]
        msg.rejected_windows = min(len(decoded.rejections), 2**16 - 1)
        self.publisher.publish(msg)
        self.diagnostics.increment("revolutions")
        self.diagnostics.increment("bearings", len(msg.bearings))
        for rejection in decoded.rejections:
            self.diagnostics.increment(f"rejected_{rejection.kind}")
        self.diagnostics.set_level("ok", f"{len(msg.bearings)} bearings in the last revolution")

    def _bearing_message(self, decoded) -> BeaconBearing:
        msg = BeaconBearing()
        msg.header.stamp = seconds_to_stamp(decoded.stamp_s)
        msg.header.frame_id = self.frame_id
        msg.beacon_id = decoded.beacon_id
        msg.bearing = float(wrap_to_pi(self.correction.correct(decoded.bearing, decoded.angular_window)))
        msg.variance = float(decoded.variance)
        msg.angular_window = float(decoded.angular_window)
        msg.rising_angle = float(decoded.rising_angle)
        msg.falling_angle = float(decoded.falling_angle)
        msg.codes_seen = decoded.codes_seen
        return msg


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(DriverNode, args))


if __name__ == "__main__":
    main()
