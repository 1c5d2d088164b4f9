"""ekf_node's checkpoint: what the filter learnt past the pose, kept across a restart (docs/integrity.md).

The file (YAML, `format: beams-ekf-checkpoint`, `version: 1`, replaced atomically) holds the learnt
blocks' states and their joint covariance, the geometry they were learnt against and the runtime-set
parameters, each with the start-up value it replaced. A (re)started node sets the parameters back first
(a calibration_file among them changes the geometry), then takes the states when the filter's blocks and
geometry are the file's; what it does not take back, it says why.
"""

import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from beams_common.calibration import file_schema
from beams_common.calibration.calibration_file import SensorCalibration, atomic_write_text
from beams_common.config.geometry_parameters import BeaconGeometry
from beams_common.intake.validation import bounded
from beams_ekf.bearing_ekf import BearingEkf

FILE_FORMAT = "beams-ekf-checkpoint"
FILE_VERSION = 1


def checkpoint_path(template: str, node_name: str, environ: Mapping[str, str]) -> Path | None:
    """The file `checkpoint_file` names: `{node}` the node's fully qualified name (no leading slash),
    `~/.ros` the ROS home ($ROS_HOME when set, as the ROS tools read it), `~` the user's home; None when
    empty (off)."""
    if not template:
        return None
    path = template.replace("{node}", node_name.strip("/"))
    if environ.get("ROS_HOME") and path.startswith("~/.ros/"):
        path = environ["ROS_HOME"] + path[len("~/.ros") :]
    return Path(os.path.expanduser(path))


def learnt_against(geometry: BeaconGeometry) -> dict[str, Any]:
    """The geometry the learnt states are corrections of or were learnt with, as the file holds it."""
    calibration = geometry.calibration
    return {
        "beacons": [[i, *map(float, xy)] for i, xy in geometry.beacon_map.as_dict().items()],
        "turret_offset_m": list(map(float, geometry.turret_offset_m)),
        "bearing_correction": repr(calibration.bearing_correction) if calibration else None,
    }


class RuntimeChanges:
    """The parameters set at runtime that differ from the node's start-up values, each as {value, the
    start-up value it replaced}, in the order they were last set (the order they are set back in)."""

    def __init__(self, startup: Mapping[str, Any]) -> None:
        self.startup = dict(startup)
        self.changes: dict[str, dict[str, Any]] = {}
        self.recorded = False  # any change since the start (one set back to its start-up value too)

    def record(self, values: Mapping[str, Any], changed: set[str]) -> None:
        self.recorded = True
        for name in sorted(changed):
            self.changes.pop(name, None)
            if values[name] != self.startup[name]:
                self.changes[name] = {"value": values[name], "replaced": self.startup[name]}


def checkpoint_text(
    ekf: BearingEkf, geometry: BeaconGeometry, changes: RuntimeChanges, saved_utc: str
) -> str:
    """The checkpoint's YAML: the learnt states when the filter learnt something (else none)."""
    learnt = ekf.learnt_states()
    states = (
        None
        if learnt is None
        else {"blocks": learnt[0], "mean": learnt[1].tolist(), "covariance": learnt[2].tolist()}
    )
    document = {
        "format": FILE_FORMAT,
        "version": FILE_VERSION,
        "saved_utc": saved_utc,
        "learnt_against": learnt_against(geometry),
        "states": states,
        "runtime_parameters": changes.changes,
    }
    return yaml.safe_dump(document, sort_keys=False, default_flow_style=None)


def save_checkpoint(
    path: Path | None, ekf: BearingEkf, geometry: BeaconGeometry, changes: RuntimeChanges
) -> str:
    """Replace the file atomically (a crash leaves the old one or the new one, never a part) once there is
    something to keep (an untouched node leaves an older file be); why it could not, or ''."""
    if path is None or (ekf.learnt_states() is None and not changes.recorded):
        return ""
    try:
        atomic_write_text(
            path, checkpoint_text(ekf, geometry, changes, SensorCalibration.now_utc()), keep_backup=False
        )
    except OSError as error:
        return f"{path}: {error}"
    return ""


def read_checkpoint(path: Path) -> Mapping[str, Any] | None:
    """The checkpoint's document (its header checked), None when there is no file; ValueError or OSError
    with the reason when it cannot be read."""
    if not path.exists():
        return None
    top = file_schema.header(file_schema.read_yaml(path), FILE_FORMAT, FILE_VERSION)
    parameters = file_schema.mapping(top.get("runtime_parameters") or {}, "runtime_parameters")
    for name, change in parameters.items():
        file_schema.mapping(change, f"runtime_parameters.{name}", ("value", "replaced"))
    return top


def parameters_to_restore(document: Mapping[str, Any], startup: Mapping[str, Any]) -> tuple[dict, list[str]]:
    """The runtime changes to set back ({name: value}) and why the others are not (`name: reason`): a
    change is set back only over the start-up value it replaced (a parameter file edited since wins)."""
    restore, skipped = {}, []
    for name, change in (document.get("runtime_parameters") or {}).items():
        if name not in startup:
            skipped.append(f"{name}: no such parameter")
        elif startup[name] != change["replaced"]:
            skipped.append(f"{name}: its start-up value is {startup[name]!r} now, not {change['replaced']!r}")
        else:
            restore[name] = change["value"]
    return restore, skipped


def resume(ekf: BearingEkf, document: Mapping[str, Any], geometry: BeaconGeometry) -> str:
    """Put the file's learnt states back into the (not yet initialised) filter; what was resumed, or
    ValueError with why not (learnt against another geometry, by other blocks, malformed)."""
    states = document.get("states")
    if states is None:
        return "no learnt states in it"
    now = learnt_against(geometry)
    then = file_schema.mapping(document.get("learnt_against"), "learnt_against")
    differ = [key.replace("_", " ") for key in now if then.get(key) != now[key]]
    if differ:
        raise ValueError(f"learnt against different {', '.join(differ)}")
    states = file_schema.mapping(states, "states", ("blocks", "mean", "covariance"))
    mean = _numbers(states["mean"], "states.mean")
    rows = file_schema.items(states["covariance"], "states.covariance", len(mean))
    covariance = np.array([_numbers(row, "states.covariance", len(mean)) for row in rows])
    blocks = [file_schema.text(b, "states.blocks") for b in file_schema.items(states["blocks"], "states")]
    ekf.resume_learnt(blocks, np.array(mean), covariance)
    return f"resumed the learnt states of {bounded(', '.join(b.split('(')[0] for b in blocks), 200)}"


def resume_from(
    path: Path | None,
    ekf: BearingEkf,
    startup: Mapping[str, Any],
    set_parameter: Callable[[str, Any], str],
    geometry: Callable[[], BeaconGeometry],
) -> tuple[str, bool]:
    """Resume from the file: its runtime changes set back (`set_parameter` answers '' or why it refused),
    then its learnt states against the geometry then in use. What it says, and whether it took all back."""
    try:
        document = read_checkpoint(path) if path is not None else None
    except (ValueError, OSError) as error:
        return f"checkpoint {path} refused, starting from the priors: {error}", False
    if document is None:
        return (f"no checkpoint at {path}: starting from the priors" if path else "checkpoint off"), True
    restore, skipped = parameters_to_restore(document, startup)
    for name, value in restore.items():
        reason = set_parameter(name, value)
        if reason:
            skipped.append(f"{name}: {reason}")
    restored = sorted(set(restore) - {s.split(":")[0] for s in skipped})
    try:
        states = resume(ekf, document, geometry())
    except ValueError as error:
        states, skipped = "learnt states refused", [*skipped, f"learnt states: {error}"]
    said = f"checkpoint {path} (saved {document.get('saved_utc')}): {states}; parameters set back: {restored}"
    return said + (f"; not taken back: {'; '.join(skipped)}" if skipped else ""), not skipped


def _numbers(value: Any, path: str, length: int | None = None) -> list[float]:
    return [file_schema.number(v, path) for v in file_schema.items(value, path, length)]
