"""The thesis's calibration setup (section 7.3.1) and a dataset captured on it by a simulated sensor.

Table 7.1 gives the manually measured beacons, table 7.3 the coordinates the calibration found
(used here as the true beacons, up to 4.5 mm away), table 7.2 the twelve reference positions, and
eq. 7.3 the four reference orientations: 48 configurations.
"""

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from beams_calibration.dataset import Configuration, Dataset, average_capture, now_utc
from beams_common.beacon_map import BeaconMap
from beams_common.bearing_correction import IDENTITY_CORRECTION, BearingCorrection
from beams_driver.codes import BeaconCode
from beams_driver.decoder import BearingDecoder
from beams_driver.sensor_sim import SensorSimConfig, SensorSimulator
from beams_triangulation.total import expected_bearings

# Table 7.1: a-priori beacon coordinates (m).
PRIOR_BEACONS = BeaconMap.from_lists((1, 2, 3), (1.151, 0.600, 0.049), (0.049, 0.907, 0.049))
# Table 7.3 (after calibration): where the beacons really were (m).
TRUE_BEACONS = BeaconMap.from_lists((1, 2, 3), (1.1504, 0.6045, 0.0452), (0.0449, 0.9068, 0.0515))
# Table 7.2: reference positions (m).
REFERENCE_POSITIONS = np.array(
    [
        (0.12, 0.84),
        (1.08, 0.84),
        (0.36, 0.76),
        (0.84, 0.76),
        (0.20, 0.52),
        (0.44, 0.52),
        (0.76, 0.52),
        (1.00, 0.52),
        (0.60, 0.36),
        (0.28, 0.20),
        (0.92, 0.20),
        (0.60, 0.12),
    ]
)
# Eq. 7.3: reference orientations (rad).
REFERENCE_ORIENTATIONS = (0.0, np.pi / 2, np.pi, -np.pi / 2)
# Section 7.3.3: the turret centre found about (-1, -1.1) mm from the structure's centre.
THESIS_TURRET_OFFSET_M = (-0.0010, -0.0011)

# Table 7.5: position RMS (mm) and orientation RMS (deg) of lines 1-11 in the thesis's experiment.
THESIS_TABLE_7_5 = (
    (8.75, 0.4297),
    (6.67, 0.3316),
    (6.21, 0.3157),
    (6.27, 0.3175),
    (6.78, 0.3984),
    (6.40, 0.3345),
    (2.95, 0.1741),
    (2.79, 0.2715),
    (2.49, 0.1788),
    (2.34, 0.1756),
    (2.16, 0.1806),
)

# Operator placement error of the robot on the grid (m, rad), per axis: section 7.3.1 expects the grid and
# the placement within about 2 mm in all; the square sensor aligns with the grid lines to a tenth of a degree.
PLACEMENT_SIGMA = (0.0008, float(np.radians(0.07)))

# One revolution's decoded bearings: {beacon_id: (bearing_rad, window_rad)}.
Revolution = Mapping[int, tuple[float, float]]
MeasureRevolutions = Callable[[tuple[float, float, float], int], Sequence[Revolution]]


def reference_poses(
    positions: np.ndarray = REFERENCE_POSITIONS, orientations: Sequence[float] = REFERENCE_ORIENTATIONS
) -> np.ndarray:
    """The configurations (eq. 7.4, 7.5) as an (n, 3) array, position-major."""
    return np.array([(x, y, theta) for x, y in positions for theta in orientations], dtype=float)


def geometric_dataset(
    poses: np.ndarray,
    beacons: BeaconMap = TRUE_BEACONS,
    correction: BearingCorrection = IDENTITY_CORRECTION,
    turret_offset_m: tuple[float, float] = (0.0, 0.0),
    prior_map: BeaconMap | None = None,
) -> Dataset:
    """A noise-free dataset: bearings from geometry with `correction`'s biases applied (eq. 7.17,
    7.24), windows from the simulator's beam model at the true turret-beacon distances."""
    config = SensorSimConfig()
    configurations = []
    for pose in np.asarray(poses, dtype=float):
        bearings = expected_bearings(beacons.xy, pose, turret_offset_m)
        c, s = np.cos(pose[2]), np.sin(pose[2])
        dx, dy = turret_offset_m
        turret = pose[:2] + np.array([c * dx - s * dy, s * dx + c * dy])
        windows = config.window_rad(np.hypot(*(beacons.xy - turret).T))
        measured = correction.apply_bias(bearings, windows)
        revolution = {i: (float(b), float(w)) for i, b, w in zip(beacons.ids, measured, windows, strict=True)}
        observations = average_capture([revolution], beacons.ids)
        configurations.append(Configuration(float(pose[0]), float(pose[1]), float(pose[2]), observations, 1))
    return Dataset(prior_map or beacons, tuple(configurations))


class _NoVariance:
    """The calibration uses mean bearings only; the decoder's variance is not needed."""

    def variance(self, code: int | BeaconCode, angular_window_rad: float) -> float:
        return 0.0


class SimulatedSensor:
    """The driver's edge-level simulator and decoder, measuring a static robot (a MeasureRevolutions).

    `correction` holds the injected power and rotation biases (the simulator adds them, eq. 7.17
    and 7.24); `beacons` are the true beacon positions; `turret_offset_m` the true turret centre.
    """

    def __init__(
        self,
        beacons: BeaconMap,
        rng: np.random.Generator,
        *,
        correction: BearingCorrection = IDENTITY_CORRECTION,
        turret_offset_m: tuple[float, float] = (0.0, 0.0),
        config: SensorSimConfig | None = None,
    ) -> None:
        self.config = config or SensorSimConfig()
        biased = not correction.is_identity
        self._simulator = SensorSimulator(
            self.config,
            beacons,
            rng,
            power_bias_rad=correction.power_bias if biased else None,
            rotation_bias_rad=correction.rotation_bias if biased else None,
            turret_offset_m=turret_offset_m,
        )
        self._decoder = BearingDecoder(self.config.codes, _NoVariance())
        self._time_s = 0.0

    def __call__(self, pose: tuple[float, float, float], revolutions: int) -> list[Revolution]:
        samples = []
        for _ in range(revolutions):
            edges = self._simulator.revolution(lambda _t: pose, self._time_s)
            self._time_s += self.config.period_s
            decoded = self._decoder.decode(edges)
            samples.append({b.beacon_id: (b.bearing, b.angular_window) for b in decoded.bearings})
        return samples


def capture_dataset(
    measure: MeasureRevolutions,
    poses: np.ndarray,
    prior_map: BeaconMap = PRIOR_BEACONS,
    revolutions: int = 100,
    *,
    placement_sigma: tuple[float, float] = (0.0, 0.0),
    rng: np.random.Generator | None = None,
) -> Dataset:
    """Record every pose as the calibration node does: `revolutions` revolutions averaged per beacon.

    placement_sigma (m, rad): the operator places the robot only that well (section 7.3.1 expects
    about 2 mm); the robot is measured where it really stands and recorded at the reference pose.
    """
    rng = rng or np.random.default_rng(0)
    sigmas = np.array([placement_sigma[0], placement_sigma[0], placement_sigma[1]])
    configurations = []
    for index, pose in enumerate(poses):
        actual = np.asarray(pose, dtype=float) + rng.normal(0.0, 1.0, 3) * sigmas
        samples = measure((float(actual[0]), float(actual[1]), float(actual[2])), revolutions)
        observations = average_capture(samples, prior_map.ids)
        configurations.append(
            Configuration(
                float(pose[0]),
                float(pose[1]),
                float(pose[2]),
                observations,
                revolutions,
                recorded_utc=now_utc(),
                label=f"C{index + 1}",
            )
        )
    return Dataset(prior_map, tuple(configurations))
