"""Lost detection (issue 13): the NIS monitor declares a confidently wrong filter lost and ToTal's next
fix restarts it, within 2 s of a 5 cm wrong start; no false alarm over ten seeds of the simulated match."""

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from beams_ekf.consistency import NisMonitor
from beams_ekf.localiser import FilterSettings, Localiser, build_localiser
from beams_sim.simulated_match import simulate_match
from beams_thesis.match_replay import match_fixes, replay_match

GATE = float(chi2.ppf(0.999, df=1))
CONFIDENT = np.diag([1e-6, 1e-6, 1e-6])  # 1 mm, 0.06 deg: a fix believed far better than it is


def _localiser(match, settings: FilterSettings | None = None) -> Localiser:
    settings = settings or FilterSettings()
    beacons = dict(zip(match.beacon_map.ids, map(tuple, match.beacon_map.xy), strict=True))
    return build_localiser(beacons, match.turret_offset_m, settings)


def test_consistent_innovations_raise_no_alarm_and_inconsistent_ones_do():
    rng = np.random.default_rng(11)
    monitor = NisMonitor(30, 1 - 1e-6, GATE)
    alarms = sum(monitor.add(float(v)) for v in rng.chisquare(1, 100_000))
    assert alarms == 0
    # innovations twice as large as the filter believes (NIS x 4): caught within a window
    monitor.clear()
    assert any(monitor.add(4 * float(v)) for v in rng.chisquare(1, 30))


def test_one_wild_bearing_is_not_lost_but_three_at_the_gate_are():
    monitor = NisMonitor(30, 1 - 1e-6, GATE)
    assert not monitor.add(1e9)  # a reflection: counted as the gate, 10.8 < chi-square(1) quantile 23.9
    assert not monitor.add(1e9)  # 21.7 < 28.4 (2 dof)
    assert monitor.add(1e9)  # 32.5 > 30.7 (3 dof)
    assert monitor.lost and monitor.window_sum == pytest.approx(3 * GATE)
    monitor.clear()
    assert not monitor.lost
    assert not NisMonitor(0, 1 - 1e-6, GATE).add(1e9)  # switched off


@pytest.fixture(scope="module")
def short_matches():
    return {seed: simulate_match(4.0, seed) for seed in (0, 1)}


def _wrong_starts(match):
    x, y, theta = match.initial_pose
    for angle in np.linspace(0.0, 2 * math.pi, 8, endpoint=False):
        for heading_deg in (-1.0, 0.0, 1.0):
            yield (x + 0.05 * math.cos(angle), y + 0.05 * math.sin(angle), theta + math.radians(heading_deg))


def _recovered_by_s(result, start_s: float) -> float:
    """Instant (s from the start) from which the position error stays under 1 cm (inf: never)."""
    off = np.flatnonzero(np.hypot(*result.errors()[:, :2].T) > 0.01)
    if len(off) and off[-1] == len(result.times_s) - 1:
        return math.inf
    return float(result.times_s[off[-1] + 1 if len(off) else 0] - start_s)


@pytest.mark.parametrize("seed", [0, 1])
def test_recovery_within_2_s_from_a_5_cm_wrong_start(short_matches, seed):
    match = short_matches[seed]
    fixes = match_fixes(match)
    start_s = float(match.odometry.stamp_s[0])
    for start in _wrong_starts(match):
        localiser = _localiser(match)
        result = replay_match(localiser, match, start, CONFIDENT, fixes)
        assert _recovered_by_s(result, start_s) <= 2.0, start
        counts = localiser.stats.counts
        assert counts["lost_reinitialisations"] + counts["kidnap_reinitialisations"] >= 1


def test_without_the_monitor_some_wrong_starts_stay_off(short_matches):
    """The monitor is what recovers them: switched off, the kidnap test alone misses some."""
    settings = FilterSettings()
    off = replace(settings, localiser=replace(settings.localiser, lost_nis_window_bearings=0))
    missed = 0
    for match in short_matches.values():
        fixes = match_fixes(match)
        for start in _wrong_starts(match):
            result = replay_match(_localiser(match, off), match, start, CONFIDENT, fixes)
            missed += _recovered_by_s(result, float(match.odometry.stamp_s[0])) > 2.0
    assert missed >= 3


def test_no_false_alarm_over_ten_seeds():
    for seed in range(10):
        match = simulate_match(20.0, seed)
        x, y, theta = match.initial_pose
        start = (x + 0.01, y - 0.01, theta + math.radians(1.0))
        localiser = _localiser(match)
        replay_match(
            localiser, match, start, np.diag([1e-4, 1e-4, math.radians(1.0) ** 2]), match_fixes(match)
        )
        counts = localiser.stats.counts
        assert counts["lost_detections"] == 0 and counts["lost_reinitialisations"] == 0, seed
        assert counts["kidnap_reinitialisations"] == 0, seed
