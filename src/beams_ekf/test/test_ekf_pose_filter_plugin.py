"""A new filter is a new module, not an edit to the localiser: a second PoseFilter, written here as a
newcomer would write one beside bearing_ekf.py, runs in the unchanged Localiser (its timing, late bearings
and counters) on the same synthetic match as the EKF."""

from math import hypot

import numpy as np

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.pose2d import Pose2D, compose
from beams_ekf.bearing_ekf import BearingEkf, gate_threshold
from beams_ekf.localiser import Localiser
from beams_ekf.pose_filter import BearingOutcome, BearingReason, PoseFilter, rejected
from beams_thesis.replay import accuracy, replay
from beams_thesis.synthetic import synthetic_match

EUROBOT_BEACONS = EUROBOT_BEACON_MAP.as_dict()

OFFSET = (0.03, -0.01)
START_COVARIANCE = np.diag([1e-6, 1e-6, 1e-6])


class DeadReckoning:
    """The simplest PoseFilter: odometry alone, every bearing declined (uncertainty grows with travel)."""

    def __init__(self, beacons_xy, sensor_offset_m) -> None:
        self.configure(beacons_xy, sensor_offset_m, None, 0.999)
        self._pose: Pose2D | None = None
        self._covariance = np.eye(3)

    def configure(self, beacons_xy, sensor_offset_m, process_noise, gate_probability) -> None:
        self.beacons_xy = dict(beacons_xy)
        self.sensor_offset_m = tuple(sensor_offset_m)
        self.gate = gate_threshold(gate_probability)

    @property
    def initialised(self) -> bool:
        return self._pose is not None

    @property
    def pose(self) -> Pose2D:
        return self._pose

    @property
    def covariance(self) -> np.ndarray:
        return self._covariance.copy()

    def initialise(self, pose: Pose2D, covariance: np.ndarray) -> None:
        self._pose, self._covariance = tuple(pose), np.array(covariance, dtype=float)

    def reset(self) -> None:
        self._pose = None

    def state(self):
        return self._pose, self._covariance.copy()

    def restore(self, state) -> None:
        self._pose, self._covariance = state[0], state[1].copy()

    def predict(self, increment: Pose2D) -> None:
        self._pose = compose(self._pose, increment)
        travelled = hypot(increment[0], increment[1])
        self._covariance = self._covariance + np.diag([1e-4, 1e-4, 1e-4]) * travelled

    def add_time_noise(self, position_variance_m2: float, heading_variance_rad2: float) -> None:
        self._covariance = self._covariance + np.diag([position_variance_m2] * 2 + [heading_variance_rad2])

    def update_bearing(
        self, beacon_id, bearing_rad, variance_rad2, lever=None, uncorrected_window_rad=0.0
    ) -> BearingOutcome:
        return rejected(BearingReason.NOT_USED)


def test_a_second_pose_filter_runs_in_the_unchanged_localiser():
    match = synthetic_match(10.0, seed=7, sensor_offset_m=OFFSET)
    dead_reckoning: PoseFilter = DeadReckoning(EUROBOT_BEACONS, OFFSET)
    results = {}
    for name, pose_filter in (
        ("dead reckoning", dead_reckoning),
        ("ekf", BearingEkf(EUROBOT_BEACONS, OFFSET)),
    ):
        results[name] = replay(
            Localiser(pose_filter),
            match.times_s,
            match.odometry,
            match.bearings,
            match.truth_at,
            tuple(match.truth[0]),
            START_COVARIANCE,
        )
    # the localiser drove the second filter exactly as odometry composes: its estimate is the odometry
    # brought to the start pose, and it counted every bearing the filter declined
    last = results["dead reckoning"]
    expected = compose(
        tuple(match.truth[0]), tuple(match.odometry[np.searchsorted(match.times_s, last.times_s[-1])])
    )
    assert np.allclose(last.estimates[-1][:2], expected[:2], atol=1e-3)
    assert last.counts.get("bearings_accepted", 0) == 0 and sum(last.counts.values()) > 0
    # and the bearings are what makes the difference: the EKF is an order of magnitude closer to the truth
    drift = accuracy(results["dead reckoning"]).rms_position_m
    ekf = accuracy(results["ekf"]).rms_position_m
    assert ekf < 0.004 and drift > 10 * ekf
