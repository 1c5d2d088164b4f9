"""driver_node's parameters: one spec each (the chosen edge source adds its own, edge_source.py). The variance
model, the frame and the calibration file change at runtime; the codes and the source stay read-only.
`autostart` is declared first and alone (LIFECYCLE_PARAMETERS), so that the node knows whether to exit or wait
when another parameter is bad."""

from collections.abc import Mapping
from typing import Any

from beams_common.calibration.bearing_correction import BearingCorrection
from beams_common.config.geometry_parameters import CALIBRATION_FILE
from beams_common.config.parameters import ParameterSpec, ParameterTable
from beams_driver.codes import BIT_TIME_S, BeaconCode, code_family, codes_from_strings, validate_codes
from beams_driver.decoder import MIN_CODES_SEEN
from beams_driver.receiver import HardwareNoise, ReceiverModel
from beams_driver.variance import VARIANCE_MODES, CorrectedVariance, VarianceModel, split_natural_variance

# The defaults describe the receiver the thesis measured (sections 5.5-5.7, what the simulated sensor
# emulates by default), so that the nodes run with no parameter publish honest variances.
_THESIS_NOISE = HardwareNoise.thesis_hardware()
_NATURAL_AT_LOW, _NATURAL_SLOPE, _NATURAL_LOW_WINDOW = _THESIS_NOISE.natural_variance_line()


def codes_of(values: Mapping[str, Any]) -> tuple[BeaconCode, ...]:
    """The code list the parameters give: the custom codes, else the family of code_count (eq. 2.6);
    ValueError when it breaks section 2.4.4's constraints."""
    custom = [code for code in values["custom_codes"] if code]
    bit_time_s = values["bit_time_s"]
    codes = (
        codes_from_strings(custom, bit_time_s) if custom else code_family(values["code_count"], bit_time_s)
    )
    validate_codes(codes)
    return tuple(codes)


def _codes_check(values: Mapping[str, Any]) -> str | None:
    try:
        codes_of(values)
    except ValueError as error:
        return f"codes: {error}"
    return None


# the parameters variance_model_of reads
VARIANCE_PARAMETERS = frozenset(
    {
        "variance_mode",
        "natural_variance_rad2",
        "natural_variance_slope_rad2_per_rad",
        "natural_variance_reference_window_rad",
        "constant_variance_rad2",
    }
)


def variance_model_of(
    values: Mapping[str, Any], codes: tuple[BeaconCode, ...], receiver: ReceiverModel
) -> VarianceModel:
    """The bearing variance model of the parameters (ch. 4 exact, theorem 3.1's bound, or a constant),
    for the receiver the edges come through (its minimum burst, section 5.6)."""
    return VarianceModel(
        codes,
        values["variance_mode"],
        natural_variance_rad2=values["natural_variance_rad2"],
        natural_variance_slope_rad2_per_rad=values["natural_variance_slope_rad2_per_rad"],
        natural_variance_reference_window_rad=values["natural_variance_reference_window_rad"],
        constant_variance_rad2=values["constant_variance_rad2"],
        min_burst_fraction=receiver.min_burst_fraction,
        min_burst_gap_exponent=receiver.min_burst_gap_exponent,
    )


def corrected_variance_of(model: VarianceModel, correction: BearingCorrection) -> CorrectedVariance:
    """The variance the driver publishes for a corrected bearing: `CorrectedVariance` (eq. 7.18-7.19), the
    natural variance split between the edges as the thesis hardware's (fig. 5.3)."""
    return CorrectedVariance(model, correction, split_natural_variance(model, _THESIS_NOISE.rising_share))


AUTOSTART = ParameterSpec(
    "autostart",
    True,
    "Configure and activate the (lifecycle) node at start-up, exiting with the reason when it cannot; "
    "false: wait unconfigured for a lifecycle manager (ros2 lifecycle set).",
)
LIFECYCLE_PARAMETERS = ParameterTable("driver_node", (AUTOSTART,))

SENSOR_PARAMETERS = ParameterTable(
    "driver_node",
    (
        ParameterSpec(
            "source",
            "sim",
            "Edge source: 'sim' (simulated sensor), 'serial' (the sensor's "
            "microcontroller) or 'package.module:ATTRIBUTE' (an EdgeSourceKind of another package).",
        ),
        ParameterSpec("frame_id", "beams_sensor", "Frame of the turret (sensor).", runtime=True),
        ParameterSpec(
            "code_count", 5, "Number of codes of the family C_i (thesis eq. 2.6).", minimum=1, maximum=9
        ),
        ParameterSpec(
            "custom_codes",
            [""],
            "Custom code list as bit strings (e.g. '10111111'), code i+1 = entry i; [''] for the family.",
            length=(1, 64),
        ),
        ParameterSpec("bit_time_s", BIT_TIME_S, "Bit time T0 of the codes (s).", minimum=1e-6, maximum=1e-3),
        ParameterSpec(
            "variance_mode", "exact", "Bearing variance model.", choices=VARIANCE_MODES, runtime=True
        ),
        ParameterSpec(
            "natural_variance_rad2",
            _NATURAL_AT_LOW,
            "Natural (noise) variance added to the code variance (rad^2), at "
            "natural_variance_reference_window_rad when it depends on the window; default: the thesis "
            "hardware's edge noise (fig. 5.3) at the smallest window of section 5.3's experiment (6 m).",
            minimum=0.0,
            maximum=1e-2,
            runtime=True,
        ),
        ParameterSpec(
            "natural_variance_slope_rad2_per_rad",
            _NATURAL_SLOPE,
            "Growth of the natural variance with the angular window (rad^2 per rad; thesis section 5.5), "
            "as estimate_noise fits it; 0: constant natural variance. Default: the thesis hardware's "
            "(fig. 5.3, linear between the windows of 6 m and 1 m).",
            minimum=-1e-2,
            maximum=1e-2,
            runtime=True,
        ),
        ParameterSpec(
            "natural_variance_reference_window_rad",
            _NATURAL_LOW_WINDOW,
            "Angular window (rad) at which natural_variance_rad2 holds when the slope is not 0.",
            minimum=0.0,
            maximum=1.0,
            runtime=True,
        ),
        ParameterSpec(
            "constant_variance_rad2",
            1e-6,
            "Variance of every bearing in variance_mode 'constant' (rad^2).",
            minimum=1e-12,
            maximum=1e-2,
            runtime=True,
        ),
        ParameterSpec(
            "min_complete_codes",
            MIN_CODES_SEEN,
            "Complete codes a window must show to give a "
            "bearing (thesis section 2.5.2: the code seen twice).",
            minimum=1,
            maximum=10,
            runtime=True,
        ),
        CALIBRATION_FILE,
    ),
    (_codes_check,),
)
DRIVER_PARAMETERS = LIFECYCLE_PARAMETERS + SENSOR_PARAMETERS
