"""What ekf_node and the offline replay share between their inputs and the filter: bad bearings refused
before they reach the history, the pose covariance fallback, the operator pose stamp rule, and the
parameters -> settings mapping."""

import math
import pathlib
from itertools import groupby

import numpy as np
import pytest
import yaml

from beams_common.config.parameters import node_section
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.intake.pose_intake import PoseSource, planar_pose_intake
from beams_ekf.bearing_ekf import BEARING_EKF_SPECS, ProcessNoise
from beams_ekf.localiser import (
    Bearing,
    FilterSettings,
    Localiser,
    LocaliserConfig,
    build_localiser,
    operator_pose_stamp_s,
    revolution_of,
)
from beams_ekf.odometry_errors import ODOMETRY_ERROR_SPECS
from beams_ekf.parameters import EKF_PARAMETERS, filter_settings
from beams_ekf.settings import SETTINGS_SPECS
from beams_thesis.synthetic import SyntheticMatch, synthetic_match

EUROBOT_BEACONS = EUROBOT_BEACON_MAP.as_dict()

OFFSET = (0.03, -0.01)
# the shipped parameter file (beams_bringup), this node's section
CONFIG = pathlib.Path(__file__).resolve().parents[2] / "beams_bringup" / "config" / "beams_params.yaml"
DEFAULT = np.diag([0.05**2, 0.05**2, 0.1**2])


@pytest.fixture(scope="module")
def match() -> SyntheticMatch:
    return synthetic_match(6.0, seed=8, sensor_offset_m=OFFSET)


# odometry reaches the filter this late (s): the last bearings of a revolution are applied with
# extrapolated odometry, and filtering them again later (with interpolated odometry) would change them
ODOMETRY_LAG_S = 0.03


def _run(match: SyntheticMatch, spoil: bool) -> tuple[Localiser, list[tuple]]:
    """Odometry (late by ODOMETRY_LAG_S) and revolutions in arrival order; with spoil, every third
    revolution comes with bad bearings stamped just before the previous revolution's last bearing (which
    was applied with extrapolated odometry). Returns the localiser and its estimate (stamp, pose,
    covariance) after every revolution."""
    localiser = build_localiser(EUROBOT_BEACONS, OFFSET, FilterSettings())
    localiser.on_pose(planar_pose_intake(PoseSource.OPERATOR, 0.0, match.truth[0], np.diag([1e-6] * 3)))
    trace, k, previous_s = [], 0, None
    for n, (arrival_s, group) in enumerate(groupby(match.bearings, key=lambda b: b.arrival_s)):
        while k < len(match.times_s) and match.times_s[k] <= arrival_s - ODOMETRY_LAG_S:
            localiser.on_odometry(float(match.times_s[k]), tuple(match.odometry[k]))
            k += 1
        revolution = [Bearing(b.stamp_s, b.beacon_id, b.bearing_rad, b.variance_rad2) for b in group]
        if spoil and n % 3 == 1:  # a message of bad bearings just before the revolution's
            localiser.on_bearings(revolution_of(localiser, _bad_bearings(previous_s - 0.001)))
        localiser.on_bearings(revolution_of(localiser, revolution))
        previous_s = revolution[-1].stamp_s
        estimate = localiser.estimate()
        trace.append((estimate.stamp_s, estimate.pose, estimate.covariance.tobytes()))
    return localiser, trace


def _bad_bearings(stamp_s: float) -> list[Bearing]:
    """Unknown id, NaN bearing, NaN stamp, zero variance."""
    return [
        Bearing(stamp_s, 9, 0.3, 1e-6),
        Bearing(stamp_s, 1, math.nan, 1e-6),
        Bearing(math.nan, 2, 0.3, 1e-6),
        Bearing(stamp_s, 3, 0.3, 0.0),
    ]


def test_bad_bearings_change_nothing_bit_for_bit(match):
    """Refused by the intake, a bad bearing does not make the filter go back and filter again from its
    stamp (which re-applied the later bearings with newer odometry: up to 0.46 mm off in a replay)."""
    clean, clean_trace = _run(match, spoil=False)
    spoilt, spoilt_trace = _run(match, spoil=True)
    assert spoilt_trace == clean_trace
    revolutions = len(clean_trace)
    counts = spoilt.stats.counts
    assert counts["bearings_unknown_beacon"] == len(range(1, revolutions, 3))
    assert counts["bearings_invalid_measurement"] == 3 * len(range(1, revolutions, 3))
    assert counts["bearings_accepted"] == clean.stats.counts["bearings_accepted"] > 0


@pytest.mark.parametrize(
    ("stamp_s", "newest_s", "expected"),
    [
        (0.0, 12.5, 12.5),  # unstamped (RViz, the service): now
        (13.0, 12.5, 12.5),  # ahead of the odometry: now
        (12.2, 12.5, 12.2),  # in the odometry's past: kept
        (7.0, None, 7.0),  # no odometry yet: kept
    ],
)
def test_operator_pose_stamp_rule(stamp_s, newest_s, expected):
    assert operator_pose_stamp_s(stamp_s, newest_s) == expected


def test_the_pose_door_counts_the_intake_s_refusals_and_applies_both_rules():
    """A sequence of poses through the pose intake: the refused ones counted under their keys and never
    reaching the filter; an unstamped operator pose with a zero covariance initialises at the newest
    odometry instant with the default covariance; ToTal's pose keeps its stamp (refused here: older than
    the history)."""
    localiser = build_localiser(EUROBOT_BEACONS, OFFSET, FilterSettings())
    for k in range(10):
        localiser.on_odometry(5.0 + 0.02 * k, (0.01 * k, 0.0, 0.0))
    refused = [
        planar_pose_intake(PoseSource.TOTAL, 5.1, (1.0, math.nan, 0.0), np.eye(3) * 1e-4),
        planar_pose_intake(PoseSource.TOTAL, 5.1, (1.0, 1.0, 0.0), np.diag([1e-4, -1e-4, 1e-4])),
        planar_pose_intake(PoseSource.OPERATOR, 0.0, (1.0, 1.0, 0.0), np.diag([1e12, 1e12, 0.01])),
        planar_pose_intake(PoseSource.TOTAL, 5.1, (1.0, 1.0, 0.0), np.diag([1e-4, 1e-4, 1e300])),
    ]
    assert [localiser.on_pose(intake) for intake in refused] == ["invalid"] * 4
    assert not localiser.ekf.initialised
    counts = localiser.stats.counts
    assert (counts["total_poses_invalid"], counts["total_poses_covariance"]) == (1, 2)
    assert counts["operator_poses_covariance"] == 1
    total = planar_pose_intake(PoseSource.TOTAL, 4.0, (1.0, 1.0, 0.0), np.eye(3))
    assert localiser.on_pose(total) == "outside_history"
    operator = planar_pose_intake(PoseSource.OPERATOR, 0.0, (1.0, 1.0, 0.0), np.zeros((3, 3)))
    assert operator.covariance is None  # no information: the default replaces it
    assert localiser.on_pose(operator) == "initialisations"
    estimate = localiser.estimate()
    assert estimate.stamp_s == 5.18
    np.testing.assert_array_equal(estimate.covariance, DEFAULT)
    assert sum(v for k, v in counts.items() if "_poses_" in k) == 4


def test_settings_from_the_node_parameter_file():
    """Every value of the ekf_node section of beams_params.yaml reaches the settings; a missing one
    takes its default."""
    parameters = node_section(yaml.safe_load(CONFIG.read_text()), "ekf_node")
    settings = filter_settings(
        {**parameters, "odometry_history_s": 1.5, "default_pose_sigma": [0.1, 0.2, 0.3]}
    )
    assert settings.process_noise == ProcessNoise(
        parameters["translation_variance_m2_per_m"],
        parameters["rotation_variance_rad2_per_rad"],
        parameters["rotation_variance_rad2_per_m"],
        cross_track_m2_per_m=parameters["cross_track_variance_m2_per_m"],
    )
    assert (
        settings.odometry_errors.heading_drift_sigma_rad_per_m
        == parameters["odometry_heading_drift_sigma_rad_per_m"]
    )
    assert settings.localiser.lost_nis_window_bearings == parameters["lost_nis_window_bearings"]
    assert settings.gate_probability == parameters["gate_probability"]
    assert settings.localiser.odometry_history_s == 1.5
    assert settings.localiser.kidnap_heading_rad == parameters["kidnap_heading_rad"]
    assert settings.use_total_pose is parameters["use_total_pose"]
    np.testing.assert_allclose(settings.default_pose_covariance, np.diag([0.01, 0.04, 0.09]))
    assert filter_settings({}) == FilterSettings()
    assert FilterSettings().localiser == LocaliserConfig()


def test_declared_defaults_are_the_settings_and_the_documented_ones():
    """ekf_node declares its parameters with the specs' defaults: they map back to the default settings,
    and the documented YAML file gives the same values."""
    defaults = {
        spec.name: spec.default
        for spec in (*BEARING_EKF_SPECS.specs, *SETTINGS_SPECS.specs, *ODOMETRY_ERROR_SPECS.specs)
    }
    assert filter_settings(defaults) == FilterSettings()
    assert {name: EKF_PARAMETERS[name].default for name in defaults} == defaults
    documented = node_section(yaml.safe_load(CONFIG.read_text()), "ekf_node")
    shared = set(defaults) & set(documented)
    assert len(shared) == 27
    assert {name: defaults[name] for name in shared} == {name: documented[name] for name in shared}


@pytest.mark.parametrize(
    "parameters",
    [
        {"default_pose_sigma": [0.1, 0.1]},
        {"kidnap_gated_bearings": 13, "kidnap_window_bearings": 12},
        {"translation_variance_m2_per_m": -1.0},
        {"kidnap_probability": 0.9999999},  # the spec's range: [0.5, 0.999999]
    ],
)
def test_settings_refuse_inconsistent_values(parameters):
    with pytest.raises(ValueError):
        filter_settings(parameters)
