"""Noise estimation on the thesis-hardware simulator: a still robot at four poses, 60 s each,
recorded by a driver with its default natural variance (3.05e-7 rad^2); `estimate_noise`'s fit against
the injected natural variance (fig. 5.3's edge noise, linear in the window), and the published / actual
variance ratio per beacon before the fit and, on new recordings, from a driver configured with it.
"""

import math
import sys

import numpy as np
from rows_table import Row, bench_main

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_driver.estimate_noise import estimate
from beams_driver.noise_estimation import beacon_spread, recordings_from_bearings
from beams_driver.parameters import DRIVER_PARAMETERS, codes_of, variance_model_of
from beams_sim.sensor_sim import SensorSimConfig, beacons_from_map
from beams_sim.simulated_match import simulated_bearings

HARDWARE = SensorSimConfig.thesis_hardware()
POSES = [(1.5, 1.0, 0.0), (0.9, 1.2, 1.0), (2.0, 0.5, -2.0), (2.0, 1.6, 2.5)]
REVOLUTIONS = 600
LIMITS = {"max_std_rad": math.radians(0.3), "max_drift_rad": math.radians(0.1), "slope_z_threshold": 3.0}


def _recordings(values: dict, seed0: int) -> list:
    codes = codes_of(values)
    model = variance_model_of(values, codes, HARDWARE)
    beacons = beacons_from_map(EUROBOT_BEACON_MAP)
    return [
        recording
        for k, pose in enumerate(POSES)
        for recording in recordings_from_bearings(
            str(pose),
            simulated_bearings(HARDWARE, model, beacons, lambda _t, p=pose: p, REVOLUTIONS, seed0 + k),
        )
    ]


def _injected_rad2(window_rad: float) -> float:
    return float(HARDWARE.hardware.natural_variance_rad2(window_rad, None))


def rows() -> list[Row]:
    """(figure, value, unit, compared with) for the table of BENCHMARKS.md."""
    defaults = DRIVER_PARAMETERS.defaults()
    report = estimate(_recordings(defaults, 0), defaults, **LIMITS)
    fit = report.fit
    windows = np.array([s.mean_window_rad for s in report.spreads])
    errors = [fit.at(w) / _injected_rad2(w) - 1.0 for w in windows]
    injected_slope = HARDWARE.hardware.natural_variance_line()[1]
    result = [
        (
            "noise estimation: natural variance at the mean window",
            fit.natural_variance_rad2,
            "rad²",
            f"injected {_injected_rad2(fit.reference_window_rad):.3e} at "
            f"{math.degrees(fit.reference_window_rad):.2f} deg (4 poses x 60 s, thesis hardware; driver "
            "default 3.05e-7)",
        ),
        (
            "noise estimation: natural variance slope in the window",
            fit.slope_rad2_per_rad,
            "rad²/rad",
            f"injected {injected_slope:.3e} (fig. 5.3); {fit.slope_z:.1f} sigma, selected: "
            f"{fit.window_dependent}",
        ),
        (
            "noise estimation: worst error of the fitted natural variance",
            100.0 * float(np.max(np.abs(errors))),
            "%",
            f"at the {len(windows)} recorded windows ({math.degrees(windows.min()):.1f}-"
            f"{math.degrees(windows.max()):.1f} deg); test band 15%",
        ),
    ]
    after_values = {**defaults, **fit.parameters()}
    after = [beacon_spread(r) for r in _recordings(after_values, 100)]
    for beacon_id in sorted({s.beacon_id for s in report.spreads}):
        before_ratios = [
            c.ratio for s, c in zip(report.spreads, report.published, strict=True) if s.beacon_id == beacon_id
        ]
        after_ratios = [
            s.observed_variance_rad2 / s.mean_published_variance_rad2
            for s in after
            if s.beacon_id == beacon_id
        ]
        for name, ratios in (("before", before_ratios), ("after", after_ratios)):
            result.append(
                (
                    f"noise estimation: beacon {beacon_id} actual / published variance, {name} the fit",
                    float(np.mean(ratios)),
                    "",
                    f"range {min(ratios):.2f}-{max(ratios):.2f} over {len(ratios)} poses; goal 0.8-1.25",
                )
            )
    return result


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
