"""The calibration file and the dataset file read against their schema (beams_common.calibration.file_schema).

Enumerated, then searched: valid documents with every entry replaced by a value of each YAML kind (or
deleted), then perturbed at random entries by any YAML value, and random documents. Whatever the
document, the parser either returns a calibration (or dataset) of finite numbers or refuses it with a
ValueError naming the entry, never another exception (issue 15: `power_bias: [1, 2, 3, 4]` ended a
running node with an AttributeError).
"""

import copy
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from beams_calibration.dataset import Dataset, DatasetError, dataset_from_dict, dataset_to_dict, load_dataset
from beams_common.calibration.bearing_correction import THESIS_CORRECTION, BearingCorrection
from beams_common.calibration.calibration_file import (
    CalibrationFileError,
    RmsFigures,
    SensorCalibration,
    calibration_from_dict,
    calibration_to_dict,
    load_calibration,
    save_calibration,
)
from beams_common.calibration.file_schema import schema_problem
from beams_common.geometry.beacon_map import BeaconMap
from beams_thesis import thesis_setup

# derandomised (a CI run is reproducible); every entry is walked by the enumeration, the search adds values
SEARCH = settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)

CALIBRATION = SensorCalibration(
    beacon_map=BeaconMap.from_lists((1, 2, 3), (1.1499, 0.6048, 0.0455), (0.0455, 0.9076, 0.0516)),
    bearing_correction=BearingCorrection(
        THESIS_CORRECTION.power_bias_coefficients, THESIS_CORRECTION.rotation_bias_coefficients, (0.08, 0.19)
    ),
    turret_offset_m=(-0.00098, -0.00011),
    rms=(RmsFigures("no calibration", 0.00875, 0.0075), RmsFigures("global", 0.00216, 0.00315)),
    leave_one_out=RmsFigures("leave one position out", 0.0025, 0.0034),
    warnings=("beacon 1 moved by 4.5 mm",),
    created_utc="2026-11-22T03:30:00Z",
)
VALID_CALIBRATION = calibration_to_dict(CALIBRATION)
VALID_DATASET = dataset_to_dict(
    thesis_setup.geometric_dataset(
        thesis_setup.reference_poses(thesis_setup.REFERENCE_POSITIONS[:2]),
        thesis_setup.TRUE_BEACONS,
        prior_map=thesis_setup.PRIOR_BEACONS,
    )
)

# Any value YAML can hold: scalars of every type (non-finite floats included), lists and mappings.
SCALARS = (
    st.none()
    | st.booleans()
    | st.integers()
    | st.integers().map(lambda n: n * 10**400)  # beyond a float's range
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=20)
)
YAML_VALUES = st.recursive(
    SCALARS,
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=8), inner, max_size=5),
    max_leaves=12,
)
DELETE = object()
# one value of each kind YAML holds, for every entry: what a hand edit puts where a number, a list or a
# mapping goes
EVERY_KIND = (DELETE, None, True, 0, -1, 10**400, 1.5, -1e308, math.nan, math.inf, -math.inf, "", "1 cm")
EVERY_KIND += ([], [0.1], [1, 2, 3, 4], ["a", None], {}, {"a": 1}, {"": [math.nan]})


def _paths(document: Any, prefix: tuple = ()) -> list[tuple]:
    """Every entry's path (keys and indices) in a nested document, inner nodes included."""
    paths = [prefix] if prefix else []
    if isinstance(document, dict):
        for key, value in document.items():
            paths += _paths(value, (*prefix, key))
    elif isinstance(document, list):
        for index, value in enumerate(document):
            paths += _paths(value, (*prefix, index))
    return paths


def _perturbed(document: dict, path: tuple, value: Any) -> dict:
    """A copy of the document with the entry at `path` replaced by `value` (or deleted)."""
    copied = copy.deepcopy(document)
    parent = copied
    for key in path[:-1]:
        parent = parent[key]
    if value is DELETE:
        del parent[path[-1]]
    else:
        parent[path[-1]] = value
    return copied


def _perturbations(document: dict):
    return st.tuples(st.sampled_from(_paths(document)), YAML_VALUES | st.just(DELETE))


def _finite(values) -> bool:
    return all(math.isfinite(float(v)) for v in values)


def _assert_calibration_usable(calibration: SensorCalibration) -> None:
    correction = calibration.bearing_correction
    assert np.all(np.isfinite(calibration.beacon_map.xy))
    assert _finite(correction.power_bias_coefficients) and _finite(correction.rotation_bias_coefficients)
    assert _finite(calibration.turret_offset_m)
    # the corrections the driver applies stay finite on any window and angle
    corrected = correction.correct(np.linspace(-np.pi, np.pi, 7), np.full(7, 0.12))
    assert np.all(np.isfinite(corrected))


def _assert_dataset_usable(dataset: Dataset) -> None:
    assert np.all(np.isfinite(dataset.beacon_map.xy))
    for configuration in dataset.configurations:
        assert _finite((configuration.x_m, configuration.y_m, configuration.theta_rad))
        for observation in configuration.observations:
            assert _finite((observation.bearing_rad, observation.window_rad, observation.spread_rad))
            assert observation.window_rad >= 0.0 and observation.revolutions >= 1


def test_the_valid_documents_parse():
    _assert_calibration_usable(calibration_from_dict(VALID_CALIBRATION))
    _assert_dataset_usable(dataset_from_dict(VALID_DATASET))
    assert len(dataset_from_dict(VALID_DATASET).configurations) == 8


DOCUMENTS = {
    "calibration": (VALID_CALIBRATION, calibration_from_dict, _assert_calibration_usable),
    "dataset": (VALID_DATASET, dataset_from_dict, _assert_dataset_usable),
}


@pytest.mark.parametrize("kind", DOCUMENTS)
def test_every_entry_of_every_kind_parses_or_is_refused_with_a_reason(kind):
    valid, parse, assert_usable = DOCUMENTS[kind]
    for path in _paths(valid):
        for value in EVERY_KIND:
            try:
                parsed = parse(_perturbed(valid, path, value))
            except ValueError as error:
                assert str(error), ("a refusal must say why", path, value)
                continue
            assert_usable(parsed)


@pytest.mark.parametrize("kind", DOCUMENTS)
@SEARCH
@given(data=st.data())
def test_a_document_perturbed_anywhere_parses_or_is_refused_with_a_reason(kind, data):
    valid, parse, assert_usable = DOCUMENTS[kind]
    path, value = data.draw(_perturbations(valid))
    try:
        parsed = parse(_perturbed(valid, path, value))
    except ValueError as error:
        assert str(error), "a refusal must say why"
        return
    assert_usable(parsed)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(YAML_VALUES)
def test_random_documents_are_refused_with_a_reason(document):
    for parse in (calibration_from_dict, dataset_from_dict):
        assert schema_problem(parse, document)  # no random value is a calibration or a dataset


@settings(
    max_examples=100,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(_perturbations(VALID_CALIBRATION))
def test_a_perturbed_calibration_file_loads_or_is_refused_as_a_calibration_file_error(tmp_path, perturbation):
    path = tmp_path / "calibration.yaml"
    path.write_text(yaml.safe_dump(_perturbed(VALID_CALIBRATION, *perturbation)))
    try:
        _assert_calibration_usable(load_calibration(path))
    except CalibrationFileError as error:
        assert str(path) in str(error)


# --- the reproductions of issue 15 ---------------------------------------------------------------


def test_power_bias_as_a_list_is_refused_naming_the_entry(tmp_path: Path):
    """Issue 15: `power_bias: [1, 2, 3, 4]` made every node's reload (and start-up) die in an
    AttributeError; the schema refuses it with the entry and what it expected."""
    path = tmp_path / "calibration.yaml"
    save_calibration(CALIBRATION, path)
    document = yaml.safe_load(path.read_text())
    document["power_bias"] = [1, 2, 3, 4]
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(
        CalibrationFileError, match=r"power_bias: expected a mapping with a, b, c, d, got list"
    ):
        load_calibration(path)


@pytest.mark.parametrize(
    ("entry", "value", "reason"),
    [
        (("rotation_bias", "A"), ".nan", r"rotation_bias\.A: expected a finite number"),
        (("turret_offset_m", "x"), "'1 cm'", r"turret_offset_m\.x: expected a number, got str"),
        (("beacons", 0, "id"), "true", r"beacons\[0\]\.id: expected an integer, got bool"),
        (("power_bias", "window_range_rad"), "[0.1]", r"power_bias\.window_range_rad: expected 2 items"),
    ],
)
def test_each_entry_is_checked_for_type_and_finiteness(tmp_path: Path, entry, value, reason):
    document = _perturbed(VALID_CALIBRATION, entry, yaml.safe_load(value))
    path = tmp_path / "calibration.yaml"
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(CalibrationFileError, match=reason):
        load_calibration(path)


def test_a_dataset_with_a_mistyped_window_is_refused_naming_the_configuration(tmp_path: Path):
    document = _perturbed(VALID_DATASET, ("configurations", 3, "beacons", 1, "window_rad"), [0.1])
    path = tmp_path / "dataset.yaml"
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(
        DatasetError, match=r"configurations\[3\]\.beacons\[1\]\.window_rad: expected a number"
    ):
        load_dataset(path)


@pytest.mark.parametrize(
    "content",
    [
        b"[" * sys.getrecursionlimit(),  # nested beyond the parser's recursion limit (frames per level)
        b"\xff\xfe format",  # not UTF-8
        b"power_bias: !!python/object:os.system {}",  # not safe YAML
    ],
)
def test_unreadable_yaml_is_refused_as_such(tmp_path: Path, content: bytes):
    path = tmp_path / "calibration.yaml"
    path.write_bytes(content)
    with pytest.raises(CalibrationFileError, match="not valid YAML"):
        load_calibration(path)
    with pytest.raises(DatasetError, match="not valid YAML"):
        load_dataset(path)
