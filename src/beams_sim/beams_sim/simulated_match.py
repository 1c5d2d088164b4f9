"""A whole simulated Eurobot match, offline: the test bench of the triangulation, EKF and calibration.

`simulate_match(duration_s, seed)` runs the trajectory, the edge-level sensor simulator and the decoder
revolution by revolution, and the wheel odometry at 50 Hz, as the ROS nodes would but without ROS or real
time: a `SimulatedMatch` of ground truth and odometry at the odometry's instants (map -> odom is
`initial_pose`), one `DecodedRevolution` per turret revolution and `true_bearing` to judge them. Everything
follows from `seed` (three streams: trajectory, sensor, odometry); chapter 7's imperfections and occlusions go
to the sensor simulator. A 90 s match takes about 2 s on one core (bench/bench_serial.py)."""

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from beams_common.calibration.bearing_correction import BearingCorrection
from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP, BeaconMap
from beams_common.geometry.pose2d import compose
from beams_driver.codes import BeaconCode
from beams_driver.decoder import BearingDecoder, DecodedBearing, DecodedRevolution, VarianceSource
from beams_driver.edges import RevolutionEdges
from beams_driver.variance import CorrectedVariance, EdgeVariances, VarianceMode, VarianceModel
from beams_sim.parameters import SIM_WORLD_PARAMETERS
from beams_sim.sensor_sim import (
    BiasFunction,
    Occlusion,
    PoseAt,
    SensorSimConfig,
    SensorSimulator,
    SimulatedBeacon,
    beacons_from_map,
)
from beams_sim.sim_source import SIM_NOISE_MODELS
from beams_sim.world import (
    MATCH_DURATION_S,
    TABLE_LENGTH_M,
    TABLE_WIDTH_M,
    EurobotTrajectory,
    OdometryDrift,
    OdometrySimulator,
    Pose2D,
    PoseTwistSamples,
)

ODOMETRY_RATE_HZ = 50.0


@dataclass(frozen=True)
class SimulatedMatch:
    """The outcome of `simulate_match`: truth, odometry and decoded revolutions of one match."""

    trajectory: EurobotTrajectory
    beacon_map: BeaconMap
    true_beacons: tuple[SimulatedBeacon, ...]
    turret_offset_m: tuple[float, float]
    initial_pose: Pose2D
    ground_truth: PoseTwistSamples
    odometry: PoseTwistSamples
    revolutions: list[DecodedRevolution]
    edges: list[RevolutionEdges] | None

    def truth_at(self, t: float) -> Pose2D:
        """True map pose at any instant."""
        return self.trajectory.pose_at(t)

    def turret_at(self, t: float) -> Pose2D:
        """Map pose of the turret centre at instant t (the true offset applied)."""
        return compose(self.trajectory.pose_at(t), (*self.turret_offset_m, 0.0))

    def true_bearing(self, beacon_id: int, t: float) -> float:
        """Bearing (rad, (-pi, pi], sensor frame) of the true beacon from the turret centre at instant t."""
        beacon = next(b for b in self.true_beacons if b.beacon_id == beacon_id)
        turret_x, turret_y, theta = self.turret_at(t)
        return float(wrap_to_pi(math.atan2(beacon.y_m - turret_y, beacon.x_m - turret_x) - theta))

    def corrected(
        self, correction: BearingCorrection, variance: VarianceSource | None = None
    ) -> "SimulatedMatch":
        """The match with every bearing corrected as driver_node publishes it (eq. 7.18 and 7.24, at the
        decoded window); with `variance`, the variance that model gives (the same edges decoded with it)."""

        def published(b: DecodedBearing) -> DecodedBearing:
            v = b.variance if variance is None else float(variance.variance(b.beacon_id, b.angular_window))
            return replace(b, bearing=float(correction.correct(b.bearing, b.angular_window)), variance=v)

        revolutions = [replace(r, bearings=[published(b) for b in r.bearings]) for r in self.revolutions]
        return replace(self, revolutions=revolutions)


def simulate_match(
    duration_s: float = MATCH_DURATION_S,
    seed: int = 0,
    *,
    trajectory: EurobotTrajectory | None = None,
    beacon_map: BeaconMap = EUROBOT_BEACON_MAP,
    true_beacons: Sequence[SimulatedBeacon] | None = None,
    sensor_config: SensorSimConfig | None = None,
    variance_model: VarianceSource | None = None,
    power_bias_rad: BiasFunction | None = None,
    rotation_bias_rad: BiasFunction | None = None,
    turret_offset_m: tuple[float, float] = (0.0, 0.0),
    occlusion: Occlusion | None = None,
    odometry_drift: OdometryDrift | None = None,
    odometry_rate_hz: float = ODOMETRY_RATE_HZ,
    wheel_base_m: float = SIM_WORLD_PARAMETERS.default("wheel_base_m"),
    keep_edges: bool = False,
) -> SimulatedMatch:
    """Run a match offline (the module docstring): true_beacons where the beacons really stand (default
    on beacon_map), variance_model the driver's (default "exact" with the sensor's natural variance)."""
    if not duration_s > 0.0 or not odometry_rate_hz > 0.0:
        raise ValueError(f"duration_s ({duration_s}) and odometry_rate_hz ({odometry_rate_hz}) must be > 0")
    trajectory_seed, sensor_seed, odometry_seed = np.random.SeedSequence(seed).spawn(3)
    if trajectory is None:
        trajectory = EurobotTrajectory.random(_as_int(trajectory_seed), duration_s)
    config = sensor_config or SensorSimConfig()
    beacons = tuple(true_beacons) if true_beacons is not None else beacons_from_map(beacon_map)
    simulator = SensorSimulator(
        config,
        beacons,
        np.random.default_rng(sensor_seed),
        power_bias_rad=power_bias_rad,
        rotation_bias_rad=rotation_bias_rad,
        turret_offset_m=turret_offset_m,
        occlusion=occlusion,
    )
    # the receiver's minimum burst in the window correction, as driver_node decodes
    decoder = BearingDecoder(
        config.codes, variance_model or default_variance_model(config.codes, config), receiver=config.receiver
    )
    revolutions, edges = _run_sensor(
        simulator, decoder, trajectory.pose_at, duration_s, config.period_s, keep_edges
    )
    odometry_simulator = OdometrySimulator(
        trajectory, odometry_drift, seed=_as_int(odometry_seed), wheel_base_m=wheel_base_m
    )
    start = odometry_simulator.advance(0.0)
    odometry = _concatenate(start, odometry_simulator.run(odometry_rate_hz, until_s=duration_s))
    return SimulatedMatch(
        trajectory=trajectory,
        beacon_map=beacon_map,
        true_beacons=beacons,
        turret_offset_m=(float(turret_offset_m[0]), float(turret_offset_m[1])),
        initial_pose=trajectory.pose_at(0.0),
        ground_truth=_ground_truth(trajectory, odometry.stamp_s),
        odometry=odometry,
        revolutions=revolutions,
        edges=edges,
    )


def default_variance_model(
    codes: Sequence[BeaconCode],
    config: SensorSimConfig,
    natural_variance_rad2: float | None = None,
    mode: VarianceMode = "exact",
) -> VarianceModel:
    """The variance of `mode` (chapter 4) plus a natural variance (section 5.6; default the simulated
    sensor's), for the receiver's minimum burst."""
    return VarianceModel(
        codes,
        mode,
        turret_speed_rad_s=config.turret_speed_rad_s,
        natural_variance_rad2=(
            config.natural_variance_rad2 if natural_variance_rad2 is None else natural_variance_rad2
        ),
        min_burst_fraction=config.min_burst_fraction,
        min_burst_gap_exponent=config.min_burst_gap_exponent,
    )


def table_natural_variance_rad2(
    config: SensorSimConfig, beacon_map: BeaconMap = EUROBOT_BEACON_MAP, step_m: float = 0.05
) -> float:
    """The constant natural variance (rad^2) that matches the receiver's edge noise on the table: the driver's
    model holds one constant (section 5.6) while the thesis hardware's noise grows with the window (fig. 5.3),
    so its mean over a grid of step_m on the table, each beacon at the window its distance gives (C_k's
    noise). The ideal receiver's constant is returned as it is."""
    if config.hardware is None:
        return config.natural_variance_rad2
    xs = np.arange(0.5 * step_m, TABLE_LENGTH_M, step_m)
    ys = np.arange(0.5 * step_m, TABLE_WIDTH_M, step_m)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 1, 2)
    distances = np.linalg.norm(grid - np.asarray(beacon_map.xy, dtype=float)[None, :, :], axis=-1)
    windows = config.window_rad(distances)
    return float(np.mean(config.hardware.natural_variance_rad2(windows, None)))


SENSOR_MODELS = tuple(SIM_NOISE_MODELS)


def sensor_config_of(sensor_model: str, codes: Sequence[BeaconCode] | None = None) -> SensorSimConfig:
    """The simulated receiver of a sensor model ("thesis_hardware" or "ideal"), as driver_node's
    sim_noise_model names it."""
    if sensor_model not in SIM_NOISE_MODELS:
        raise ValueError(f"sensor model {sensor_model!r} is not one of {SENSOR_MODELS}")
    config = SIM_NOISE_MODELS[sensor_model]()
    return config if codes is None else replace(config, codes=tuple(codes))


def calibration_of(config: SensorSimConfig) -> BearingCorrection:
    """A perfect chapter-7 calibration of the receiver: the inverse of its power bias (none for ideal)."""
    return config.hardware.power_bias_correction() if config.hardware is not None else BearingCorrection()


def simulated_edge_variances(config: SensorSimConfig) -> EdgeVariances:
    """The simulated receiver's true (rising, falling) edge-noise variances (rad^2) at a window, for the
    power-bias correction's variance (`beams_driver.variance.CorrectedVariance`)."""

    def edge_variances(code: BeaconCode, angular_window_rad: float) -> tuple[float, float]:
        rising, falling = config.hardware.edge_std_rad(angular_window_rad, code)
        return float(rising) ** 2, float(falling) ** 2

    return edge_variances


def calibrated_match(
    sensor_model: str, duration_s: float = MATCH_DURATION_S, seed: int = 0, **options: object
) -> SimulatedMatch:
    """A match as a calibrated robot's driver publishes it: the exact variance with
    `table_natural_variance_rad2`, bearings corrected by `calibration_of`; options to `simulate_match`."""
    config = sensor_config_of(sensor_model)
    correction = calibration_of(config)
    model = default_variance_model(config.codes, config, table_natural_variance_rad2(config))
    variance = (
        model
        if correction.is_identity
        else CorrectedVariance(model, correction, simulated_edge_variances(config))
    )
    match = simulate_match(duration_s, seed, sensor_config=config, variance_model=variance, **options)  # type: ignore[arg-type]
    return match if correction.is_identity else match.corrected(correction)


def simulated_bearings(
    config: SensorSimConfig,
    model: VarianceModel,
    beacons: Sequence[SimulatedBeacon],
    pose_at: PoseAt,
    revolutions: int,
    seed: int,
) -> list[tuple[int, float, float, float]]:
    """(beacon id, bearing, published variance, window) a driver decoder (the config's receiver, the
    model's variances) gives on the simulated sensor: the recording of a rehearsal (tests, bench)."""
    simulator = SensorSimulator(config, beacons, np.random.default_rng(seed))
    decoder = BearingDecoder(config.codes, model, receiver=config.receiver)
    runs, _ = _run_sensor(simulator, decoder, pose_at, revolutions * config.period_s, config.period_s, False)
    return [(b.beacon_id, b.bearing, b.variance, b.angular_window) for r in runs for b in r.bearings]


def _run_sensor(
    simulator: SensorSimulator,
    decoder: BearingDecoder,
    pose_at: PoseAt,
    duration_s: float,
    period_s: float,
    keep_edges: bool,
) -> tuple[list[DecodedRevolution], list[RevolutionEdges] | None]:
    """Every complete revolution of the match, simulated then decoded."""
    count = math.floor(duration_s / period_s + 1e-9)
    decoded: list[DecodedRevolution] = []
    kept: list[RevolutionEdges] | None = [] if keep_edges else None
    for k in range(count):
        edges = simulator.revolution(pose_at, k * period_s)
        decoded.append(decoder.decode(edges))
        if kept is not None:
            kept.append(edges)
    return decoded, kept


def _ground_truth(trajectory: EurobotTrajectory, stamps_s: np.ndarray) -> PoseTwistSamples:
    x, y, heading, _, speed, yaw_rate = trajectory.states_at(stamps_s).T
    return PoseTwistSamples(stamps_s, x, y, np.asarray(wrap_to_pi(heading)), speed, yaw_rate)


def _concatenate(first: PoseTwistSamples, rest: PoseTwistSamples) -> PoseTwistSamples:
    fields = ("stamp_s", "x_m", "y_m", "theta_rad", "speed_mps", "yaw_rate_radps")
    return PoseTwistSamples(**{f: np.concatenate([getattr(first, f), getattr(rest, f)]) for f in fields})


def _as_int(sequence: np.random.SeedSequence) -> int:
    """A plain integer seed from a spawned sequence (the constructors take ints)."""
    return int(sequence.generate_state(1)[0])
