"""Issue 19 offline: the driver's defaults publish honest variances, and the EKF's defaults stay
consistent on the thesis hardware uncalibrated (the power bias self-calibrated) as well as calibrated.

Matches of the thesis-hardware receiver decoded with driver_node's default variance model
(bench_self_calibration's `default_driver_matches`), replayed through ekf_node's default filter.
"""

import math
import pathlib
import sys

import numpy as np
import pytest

from beams_common.calibration.calibration_file import load_calibration
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_driver.parameters import SENSOR_PARAMETERS, corrected_variance_of, variance_model_of
from beams_ekf.power_bias_states import THESIS_EXPERIMENT_WINDOWS_RAD, PowerBiasStates
from beams_ekf.self_calibration import save_self_calibration
from beams_sim.simulated_match import calibration_of, sensor_config_of, simulate_match
from beams_sim.world import EurobotTrajectory

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "bench"))
from bench_self_calibration import (
    bias_curve_error_rad,
    default_driver_matches,
    nees_series,
    run,
    windows_against_band,
)

# issue 19's bands: spread / published variance of a still robot's bearings, mean NEES of a match
SPREAD_BAND = (0.7, 1.43)
NEES_BAND = (2.0, 4.5)
# a still robot; at (0.4, 1.0) beacons 1 and 2 are 1.1 m away, where the power-bias correction is steep in
# the window (0.26 rad/rad): without what the noisy window adds, their calibrated spread is 1.7 and 1.9
# times the published variance (docs/self_calibration.md)
STILL_POSES = [(1.5, 1.0, 0.0), (0.4, 1.0, 0.0), (2.5, 0.4, 1.0), (0.8, 1.7, -2.0)]
# the self-calibrating filter's first 30 s (its warm-up): not overconfident, at most 2x conservative
WARM_UP_END_S = 30.0
WARM_UP_NEES_FLOOR = 1.5
# self-calibrated after 60 s: position RMS within this factor of the perfectly calibrated filter's
SELF_CALIBRATED_RMS_FACTOR = 1.3


def test_experiment_windows_are_the_simulated_thesis_sensor_s():
    config = sensor_config_of("thesis_hardware")
    assert np.allclose(THESIS_EXPERIMENT_WINDOWS_RAD, config.hardware.window_range_rad, rtol=1e-4)


@pytest.mark.parametrize("calibrated", [False, True], ids=["uncalibrated", "calibrated"])
@pytest.mark.parametrize("pose", STILL_POSES)
def test_still_robot_spread_matches_the_default_published_variance(pose, calibrated):
    """Calibrated: the demo's perfect calibration file; the bearings corrected at their noisy decoded window
    and their variance with what that adds, as driver_node publishes them (`corrected_variance_of`)."""
    config = sensor_config_of("thesis_hardware")
    model = variance_model_of(SENSOR_PARAMETERS.defaults(), config.codes, config)
    correction = calibration_of(config)
    variance = corrected_variance_of(model, correction) if calibrated else model
    trajectory = EurobotTrajectory.static(pose, 30.0)
    match = simulate_match(30.0, 5, trajectory=trajectory, sensor_config=config, variance_model=variance)
    by_beacon: dict[int, tuple[list[float], list[float]]] = {}
    for revolution in (match.corrected(correction) if calibrated else match).revolutions:
        for b in revolution.bearings:
            by_beacon.setdefault(b.beacon_id, ([], []))
            by_beacon[b.beacon_id][0].append(b.bearing)
            by_beacon[b.beacon_id][1].append(b.variance)
    assert sorted(by_beacon) == [1, 2, 3]
    for beacon_id, (bearings, variances) in by_beacon.items():
        ratio = np.var(bearings) / np.mean(variances)
        assert SPREAD_BAND[0] <= ratio <= SPREAD_BAND[1], (beacon_id, ratio)


def _period(result, start_s: float, end_s: float) -> tuple[float, float]:
    """(position RMS, mean NEES) over [start_s, end_s) of the match."""
    t = result.times_s - result.times_s[0]
    keep = (t >= start_s) & (t < end_s)
    errors = result.errors()[keep]
    return float(np.sqrt(np.mean(errors[:, 0] ** 2 + errors[:, 1] ** 2))), float(result.nees()[keep].mean())


SEEDS = (0, 1, 2)
PERIODS_S = ((1.0, 30.0), (30.0, 60.0), (60.0, 90.0))


def _pooled(results, start_s: float, end_s: float) -> tuple[float, float]:
    """(position RMS, mean NEES) over [start_s, end_s) of each match, pooled over the matches."""
    errors, values = [], []
    for result in results:
        t = result.times_s - result.times_s[0]
        keep = (t >= start_s) & (t < end_s)
        errors.append(result.errors()[keep])
        values.append(result.nees()[keep])
    errors = np.concatenate(errors)
    return float(np.sqrt(np.mean(errors[:, 0] ** 2 + errors[:, 1] ** 2))), float(
        np.concatenate(values).mean()
    )


@pytest.fixture(scope="module")
def replays():
    """Per seed: the default filter on the uncalibrated match (self-calibrating) with its localiser, on
    the perfectly calibrated match, and with the bias as white noise (the filter before issue 19)."""
    runs = {"learning": [], "perfect": [], "white": [], "localisers": [], "matches": []}
    for seed in SEEDS:
        matches = default_driver_matches(90.0, seed)
        uncalibrated = matches[False]
        learning, localiser = run(uncalibrated, PowerBiasStates(), calibrated=False)
        runs["learning"].append(learning)
        runs["localisers"].append(localiser)
        runs["matches"].append(uncalibrated)
        runs["perfect"].append(run(matches[True], PowerBiasStates(), True)[0])
        runs["white"].append(run(uncalibrated, None, calibrated=False)[0])
    return runs


@pytest.mark.parametrize("period", PERIODS_S)
def test_default_filter_is_consistent_uncalibrated_and_calibrated(replays, period):
    learning_nees = _pooled(replays["learning"], *period)[1]
    if period[0] < WARM_UP_END_S:
        # the warm-up: uncalibrated bearings update the pose alone until the window fit is ready, so the
        # filter errs on the safe side there (pooled 1.96 on these seeds since the decoder reports each
        # beacon once per revolution; docs/self_calibration.md), never overconfident
        assert WARM_UP_NEES_FLOOR <= learning_nees <= NEES_BAND[1]
    else:
        assert NEES_BAND[0] <= learning_nees <= NEES_BAND[1]
    assert NEES_BAND[0] <= _pooled(replays["perfect"], *period)[1] <= NEES_BAND[1]
    # the bias as white noise: overconfident (issue 19 measured 37-42)
    assert _pooled(replays["white"], *period)[1] > 10.0


def test_every_30_s_window_is_within_the_consistent_band(replays):
    """Each seed's mean NEES over each 30 s window against the band a consistent filter's would fall in,
    the band from the NEES's autocorrelation pooled over the seeds (beams_thesis.nees_band, Gaussian
    Monte-Carlo: tau 3.0 s, N_eff 11 per window), not from the window itself. All 9 windows at once: each
    band holds 1 - 0.05 / 9 (Bonferroni), so that a consistent filter passes with 95 % probability (each at
    95 %, one would fail 1 - 0.95^9 = 37 % of the time).

    No window is above its band (never overconfident). Below: from 60 s on; in the first minute seed 0 is
    more conservative than a consistent filter (1.69 and 1.62 under 1.74, the self-calibration's warm-up
    and first fits erring on the safe side; docs/self_calibration.md). The bias as white noise (the
    filter before issue 19) is far above its own band (window means 23-49 against at most 5.4)."""
    windows = len(SEEDS) * len(PERIODS_S)
    probability = 1.0 - 0.05 / windows
    learning = [nees_series(r) for r in replays["learning"]]
    _, means, bands = windows_against_band(learning, PERIODS_S[-1][1], probability)
    assert means.shape == (len(SEEDS), len(PERIODS_S))
    assert np.all(means <= bands[:, 1]), (means, bands)
    after_a_minute = [i for i, (start_s, _) in enumerate(PERIODS_S) if start_s >= 60.0]
    assert np.all(means[:, after_a_minute] >= bands[after_a_minute, 0]), (means, bands)
    white = [nees_series(r) for r in replays["white"]]
    _, white_means, white_bands = windows_against_band(white, PERIODS_S[-1][1], probability)
    assert np.all(white_means > white_bands[:, 1]), (white_means, white_bands)


def test_self_calibrated_after_60_s_is_as_accurate_as_the_perfect_calibration(replays):
    learnt = _pooled(replays["learning"], 60.0, 90.0)[0]
    assert learnt <= SELF_CALIBRATED_RMS_FACTOR * _pooled(replays["perfect"], 60.0, 90.0)[0]
    assert _pooled(replays["white"], 60.0, 90.0)[0] > 2.0 * learnt
    for localiser, match in zip(replays["localisers"], replays["matches"], strict=True):
        # within 0.03 deg of the simulated curve over the table's windows (it spans 0.23 deg)
        assert bias_curve_error_rad(localiser, match) < math.radians(0.03)


def test_the_learnt_curve_as_a_calibration_file_corrects_the_bias(replays, tmp_path):
    path = tmp_path / "self_calibration.yaml"
    save_self_calibration(replays["localisers"][0].ekf, EUROBOT_BEACON_MAP, (0.0, 0.0), path)
    correction = load_calibration(path).bearing_correction
    config = sensor_config_of("thesis_hardware")
    windows = config.window_rad(np.linspace(0.3, 3.5, 50))
    residual = config.hardware.power_bias_rad(windows) - np.asarray(correction.power_bias(windows))
    before = config.hardware.power_bias_rad(windows)
    # the constant is the heading's (docs/self_calibration.md): compared without it
    assert np.std(residual) < math.radians(0.03) < np.std(before)


def test_the_turret_offset_is_learnt_while_driving(tmp_path):
    """A turret 2.2 cm off its configured place (configured at the centre): with its states
    (turret_offset_sigma_m 3 cm) the filter learns it within 1 mm and stays consistent after 30 s;
    without them it is overconfident by more than an order of magnitude. The calibration file carries it."""
    from dataclasses import replace

    from beams_driver.parameters import SENSOR_PARAMETERS, variance_model_of
    from beams_ekf.localiser import FilterSettings, build_localiser
    from beams_ekf.turret_offset_states import TurretOffsetStates
    from beams_thesis.match_replay import replay_match

    config = sensor_config_of("thesis_hardware")
    model = variance_model_of(SENSOR_PARAMETERS.defaults(), config.codes, config)
    true_offset = (0.02, 0.01)
    match = simulate_match(90.0, 0, sensor_config=config, variance_model=model, turret_offset_m=true_offset)
    start = (match.initial_pose[0] + 0.01, match.initial_pose[1] - 0.01, match.initial_pose[2] + 0.017)
    covariance = np.diag([1e-4, 1e-4, 0.017**2])
    results = {}
    for states in (None, TurretOffsetStates(0.03)):
        settings = replace(FilterSettings(), turret_offset=states)
        localiser = build_localiser(EUROBOT_BEACON_MAP.as_dict(), (0.0, 0.0), settings)
        results[states] = (replay_match(localiser, match, start, covariance, (), calibrated=False), localiser)
    learnt, localiser = results[TurretOffsetStates(0.03)]
    estimate, offset_covariance = localiser.ekf.estimate(TurretOffsetStates)
    assert np.hypot(*(estimate - true_offset)) < 1e-3
    assert np.all(np.sqrt(np.diag(offset_covariance)) < 1e-3)
    rms, mean_nees = _pooled([learnt], 30.0, 90.0)
    assert rms < 1.5e-3 and NEES_BAND[0] <= mean_nees <= NEES_BAND[1]
    # without them: a mean NEES an order of magnitude beyond 3 (the figure swings with the stream: 1362
    # while the decoder reported 20 beacons twice in one revolution, 82 since it reports each once)
    assert _pooled([results[None][0]], 30.0, 90.0)[1] > 30.0
    path = tmp_path / "offset.yaml"
    save_self_calibration(localiser.ekf, EUROBOT_BEACON_MAP, (0.0, 0.0), path)
    assert np.allclose(load_calibration(path).turret_offset_m, true_offset, atol=1e-3)
