"""Parameter specs: one check per parameter, the same for the nodes and the offline tools."""

import math

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_common.config.geometry_parameters import GEOMETRY_CHECKS, GEOMETRY_SPECS, geometry_of
from beams_common.config.parameters import (
    ParameterError,
    ParameterSpec,
    ParameterTable,
    is_topic_name,
    load_parameter_file,
    node_section,
)

GAIN = ParameterSpec("gain", 1.0, "A gain.", minimum=0.0, maximum=10.0, runtime=True)
POSE = ParameterSpec("pose", [0.0, 0.0, 0.0], "A pose.", minimum=-5.0, maximum=5.0, length=3)
MODE = ParameterSpec("mode", "exact", "A mode.", choices=("exact", "bound"))
COUNT = ParameterSpec("count", 5, "A count.", minimum=1, maximum=9)
TABLE = ParameterTable("test_node", (GAIN, POSE, MODE, COUNT))
GEOMETRY = ParameterTable("geometry_node", GEOMETRY_SPECS, GEOMETRY_CHECKS)


def test_defaults_are_valid_and_every_refusal_names_the_parameter():
    assert TABLE.validate({}) == {"gain": 1.0, "pose": [0.0, 0.0, 0.0], "mode": "exact", "count": 5}
    cases = {
        "gain": [-0.1, 10.5, math.nan, math.inf, "1.0", True],
        "pose": [[0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [math.nan, 0.0, 0.0], [0.0, 6.0, 0.0], 1.0],
        "mode": ["Exact", "", 3],
        "count": [0, 10, 2.5, False],
    }
    for name, values in cases.items():
        for value in values:
            with pytest.raises(ParameterError, match=name):
                TABLE.validate({name: value})


def test_an_unknown_name_is_refused_unless_ignored():
    with pytest.raises(ParameterError, match="test_node has no parameter gian"):
        TABLE.validate({"gian": 2.0})
    assert TABLE.validate({"use_sim_time": True}, ignore=("use_sim_time",))["gain"] == 1.0


def test_description_says_range_choices_and_whether_runtime():
    assert (
        "Range [0.0, 10.0]" in GAIN.full_description() and "Changeable at runtime" in GAIN.full_description()
    )
    assert "One of ['exact', 'bound']" in MODE.full_description() and "Read-only" in MODE.full_description()


@settings(max_examples=500, deadline=None)
@given(
    st.dictionaries(
        st.sampled_from(["gain", "pose", "mode", "count"]),
        st.one_of(
            st.floats(allow_nan=True, allow_infinity=True),
            st.integers(-100, 100),
            st.text(max_size=5),
            st.booleans(),
            st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=5),
        ),
    )
)
def test_validation_either_accepts_a_valid_set_or_refuses_with_a_parameter_error(values):
    """Random values: never another exception, and what is accepted satisfies every spec."""
    try:
        accepted = TABLE.validate(values)
    except ParameterError:
        return
    assert 0.0 <= accepted["gain"] <= 10.0 and math.isfinite(accepted["gain"])
    assert len(accepted["pose"]) == 3 and all(-5.0 <= v <= 5.0 for v in accepted["pose"])
    assert accepted["mode"] in ("exact", "bound") and 1 <= accepted["count"] <= 9


@settings(max_examples=300, deadline=None)
@given(
    ids=st.lists(st.integers(-5, 300), max_size=6),
    xs=st.lists(st.one_of(st.floats(-200, 200), st.just(math.nan)), max_size=6),
    ys=st.lists(st.one_of(st.floats(-200, 200), st.just(math.nan)), max_size=6),
    offset=st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=3),
)
def test_geometry_parameters_give_a_usable_map_or_a_reason(ids, xs, ys, offset):
    """Beacon lists of any length and content: the geometry built from an accepted set is a valid map
    (>= 3 distinct beacons not on one line, finite) and a finite offset."""
    values = {"beacon_ids": ids, "beacon_x": xs, "beacon_y": ys, "turret_offset_m": offset}
    try:
        accepted = GEOMETRY.validate(values)
    except ParameterError:
        return
    geometry = geometry_of(accepted)
    assert len(geometry.beacon_map.ids) >= 3 and len(set(geometry.beacon_map.ids)) == len(
        geometry.beacon_map.ids
    )
    assert all(math.isfinite(v) for v in geometry.turret_offset_m)


def test_parameter_file_sections_merge_as_rcl_applies_them(tmp_path):
    document = {
        "/**": {"ros__parameters": {"gain": 2.0, "count": 3}},
        "/**/test_node": {"ros__parameters": {"gain": 3.0}},
        "other_node": {"ros__parameters": {"gain": 9.0}},
    }
    assert node_section(document, "test_node") == {"gain": 3.0, "count": 3}
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(document))
    assert load_parameter_file(path, TABLE)["gain"] == 3.0
    path.write_text("/**: [unclosed")
    with pytest.raises(ParameterError, match="not valid YAML"):
        load_parameter_file(path, TABLE)


@pytest.mark.parametrize(
    ("name", "valid"),
    [
        ("/robot_b/beams/sim/ground_truth", True),
        ("odom", True),
        ("~/x", True),
        ("not a topic!", False),
        ("", False),
        ("a//b", False),
        ("1abc", False),
        ("a/", False),
    ],
)
def test_topic_names(name, valid):
    assert is_topic_name(name) is valid


def test_a_runtime_change_reads_the_calibration_file_only_when_the_geometry_changes(tmp_path):
    """A gate or frame change keeps the geometry in use (the file is not read again); a geometry change
    reads it; the map cannot change under a calibration file."""
    from beams_common.calibration.calibration_file import SensorCalibration, save_calibration
    from beams_common.config.geometry_parameters import runtime_geometry
    from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP

    path = tmp_path / "calibration.yaml"
    save_calibration(SensorCalibration(beacon_map=EUROBOT_BEACON_MAP), path)
    values = GEOMETRY.validate({"calibration_file": str(path)})
    current = geometry_of(values)
    path.unlink()  # an unrelated change must not touch the file
    assert runtime_geometry(values, {"max_position_std_m"}, current) is current
    with pytest.raises(OSError):
        runtime_geometry(values, {"calibration_file"}, current)
    with pytest.raises(ValueError, match="cannot change while calibration_file"):
        runtime_geometry(values, {"beacon_x"}, current)
    plain = GEOMETRY.validate({"turret_offset_m": [0.01, 0.0]})
    assert runtime_geometry(plain, {"turret_offset_m"}, current).turret_offset_m == (0.01, 0.0)
