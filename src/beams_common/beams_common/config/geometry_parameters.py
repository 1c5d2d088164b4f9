"""The beacon geometry parameters shared by the triangulation and the EKF (and the replay of both).

`calibration_file`, `beacon_ids`, `beacon_x`, `beacon_y` and `turret_offset_m`: a calibration file, when
given, replaces the beacon coordinates and the turret offset (thesis ch. 7 calibrates both). One place
declares them, validates them and turns them into a BeaconMap and an offset, for the nodes and the
offline tools alike.
"""

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from beams_common.calibration.calibration_checks import calibration_nominal_problem
from beams_common.calibration.calibration_file import SensorCalibration, load_calibration
from beams_common.config.parameters import ParameterSpec
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP, BeaconMap

CALIBRATION_FILE = ParameterSpec(
    "calibration_file",
    "",
    "Calibration file written by beams_calibration (YAML); empty for none. Setting it at runtime loads "
    "and applies the file (refused with the reason when it cannot be read).",
    runtime=True,
)


def beacon_map_specs(
    prefix: str = "beacon_", what: str = "Beacon", runtime: bool = True
) -> tuple[ParameterSpec, ...]:
    """The parameters <prefix>ids, <prefix>x, <prefix>y (map frame, m; the Eurobot table by default)."""
    ids = list(EUROBOT_BEACON_MAP.ids)
    return (
        ParameterSpec(
            f"{prefix}ids", ids, f"{what} ids (their codes).", 0, 255, length=(3, 64), runtime=runtime
        ),
        *(
            ParameterSpec(
                f"{prefix}{axis}",
                EUROBOT_BEACON_MAP.xy[:, column].tolist(),
                f"{what} {axis}, map frame (m).",
                -100.0,
                100.0,
                length=(3, 64),
                runtime=runtime,
            )
            for column, axis in enumerate("xy")
        ),
    )


def beacon_map_of(values: Mapping[str, Any], prefix: str = "beacon_") -> BeaconMap:
    """The BeaconMap of the three parameters; ValueError (naming them) when they do not make one."""
    try:
        return BeaconMap.from_lists(values[f"{prefix}ids"], values[f"{prefix}x"], values[f"{prefix}y"])
    except ValueError as error:
        raise ValueError(f"{prefix}ids/x/y: {error}") from None


def beacon_map_check(prefix: str = "beacon_"):
    """A ParameterTable `together` check: the three lists make a valid map."""

    def check(values: Mapping[str, Any]) -> str | None:
        try:
            beacon_map_of(values, prefix)
        except ValueError as error:
            return str(error)
        return None

    return check


TURRET_OFFSET = ParameterSpec(
    "turret_offset_m",
    [0.0, 0.0],
    "Turret centre (x, y) in base_link (m); a calibration file overrides it.",
    minimum=-1.0,
    maximum=1.0,
    length=2,
    runtime=True,
)
GEOMETRY_SPECS = (CALIBRATION_FILE, *beacon_map_specs(), TURRET_OFFSET)
GEOMETRY_CHECKS = (beacon_map_check(),)
GEOMETRY_NAMES = frozenset(spec.name for spec in GEOMETRY_SPECS)


@dataclass(frozen=True)
class BeaconGeometry:
    """Where the beacons stand and where the turret sits on the robot."""

    beacon_map: BeaconMap
    turret_offset_m: tuple[float, float]
    calibration: SensorCalibration | None = None


def geometry_of_calibration(
    calibration: SensorCalibration, nominal: Mapping[str, Any] | None = None
) -> BeaconGeometry:
    """The geometry a calibration file carries: the calibrated beacon map and turret offset. With the
    nominal parameter values (beacon_ids/x/y, turret_offset_m), ValueError when the calibration is no
    correction of them (`calibration_checks.calibration_nominal_problem`)."""
    offset = calibration.turret_offset_m
    if nominal is not None:
        nominal_offset = nominal.get("turret_offset_m", TURRET_OFFSET.default)
        problem = calibration_nominal_problem(
            calibration.beacon_map, offset, beacon_map_of(nominal), nominal_offset
        )
        if problem:
            raise ValueError(f"calibration refused, implausible against the nominal geometry: {problem}")
    return BeaconGeometry(calibration.beacon_map, (float(offset[0]), float(offset[1])), calibration)


def geometry_of(values: Mapping[str, Any]) -> BeaconGeometry:
    """The geometry the parameters give: the calibration file's when one is named (checked against the
    map and offset parameters, its nominal geometry), else the map and offset parameters. Raises OSError
    or ValueError (with the file's reason) for a bad calibration file."""
    path = values.get("calibration_file", "")
    if path:
        return geometry_of_calibration(load_calibration(path), values)
    offset = values.get("turret_offset_m", TURRET_OFFSET.default)
    return BeaconGeometry(beacon_map_of(values), (float(offset[0]), float(offset[1])))


def runtime_geometry(values: Mapping[str, Any], changed: set[str], current: BeaconGeometry) -> BeaconGeometry:
    """The geometry after a runtime parameter change: `current` when no geometry parameter changed (the
    calibration file is not read again for a gate or a frame: a file rewritten on disk is applied by the
    reload service, not by an unrelated change), else read anew. Raises ValueError when the change sets
    the map or offset under a calibration file (`refuse_overridden_geometry`), OSError or ValueError for
    a calibration file that cannot be read."""
    refuse_overridden_geometry(values, changed)
    return geometry_of(values) if changed & GEOMETRY_NAMES else current


def refuse_overridden_geometry(values: Mapping[str, Any], changed: set[str]) -> None:
    """Raise ValueError when a runtime change sets the beacon map or the turret offset while a calibration
    file overrides them (the change would be accepted and ignored)."""
    overridden = sorted(changed & (GEOMETRY_NAMES - {"calibration_file"}))
    if overridden and values.get("calibration_file"):
        raise ValueError(
            f"{', '.join(overridden)} cannot change while calibration_file "
            f"({values['calibration_file']}) sets the geometry: set calibration_file to '' first"
        )
