"""ekf_node's checkpoint (beams_ekf.checkpoint): the learnt states and their covariance come back exactly and
are kept by the first initialisation; a file learnt against another geometry, by other blocks, or of
another format is refused with the reason and the filter starts from its priors; runtime changes come back
only over the start-up value they replaced."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from beams_common.calibration.bearing_correction import BearingCorrection
from beams_common.calibration.calibration_file import SensorCalibration
from beams_common.config.geometry_parameters import BeaconGeometry
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP, BeaconMap
from beams_ekf.checkpoint import (
    RuntimeChanges,
    checkpoint_path,
    checkpoint_text,
    parameters_to_restore,
    resume_from,
    save_checkpoint,
)
from beams_ekf.localiser import build_localiser
from beams_ekf.parameters import EKF_PARAMETERS, filter_settings

GEOMETRY = BeaconGeometry(EUROBOT_BEACON_MAP, (0.01, -0.02))
# a calibration of the same beacons and offset: its bearing correction is part of what was learnt against
CALIBRATION = SensorCalibration(
    EUROBOT_BEACON_MAP, BearingCorrection((-90.46, 35.83, -4.59, 0.19)), (0.01, -0.02)
)
STARTUP = EKF_PARAMETERS.defaults()


def filter_of(geometry: BeaconGeometry = GEOMETRY, **parameters):
    settings = filter_settings({**STARTUP, **parameters})
    return build_localiser(geometry.beacon_map.as_dict(), geometry.turret_offset_m, settings).ekf


def learnt(ekf, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Learnt states of the filter's size: a mean and a correlated covariance, taken by the filter."""
    size = len(ekf._kept)
    rng = np.random.default_rng(seed)
    root = rng.normal(scale=1e-3, size=(size, size))
    mean, covariance = rng.normal(scale=1e-2, size=size), root @ root.T
    ekf.resume_learnt([repr(b) for b, _ in ekf._parts if b.learnt], mean, covariance)
    return mean, covariance


def saved(tmp_path: Path, ekf, geometry=GEOMETRY, changes: RuntimeChanges | None = None) -> Path:
    path = tmp_path / "beams" / "ekf_node_checkpoint.yaml"
    changes = changes or RuntimeChanges(STARTUP)
    assert save_checkpoint(path, ekf, geometry, changes) == ""
    return path


def resumed(path: Path, ekf, geometry=GEOMETRY, startup=STARTUP, set_parameter=lambda _n, _v: ""):
    return resume_from(path, ekf, startup, set_parameter, lambda: geometry)


def test_the_learnt_states_come_back_exactly_and_the_first_initialisation_keeps_them(tmp_path):
    before = filter_of()
    mean, covariance = learnt(before)
    path = saved(tmp_path, before)
    after = filter_of()
    assert after.learnt_states() is None
    said, complete = resumed(path, after)
    assert complete and "resumed the learnt states of OdometryErrorStates, PowerBiasStates" in said, said
    _, mean_back, covariance_back = after.learnt_states()
    assert np.array_equal(mean_back, mean) and np.array_equal(covariance_back, covariance)
    after.initialise((0.5, 1.0, 0.2), np.diag([0.01, 0.01, 0.001]))
    _, mean_kept, covariance_kept = after.learnt_states()
    assert np.array_equal(mean_kept, mean) and np.array_equal(covariance_kept, covariance)
    assert np.allclose(after.covariance, np.diag([0.01, 0.01, 0.001]))


@pytest.mark.parametrize(
    ("geometry", "parameters", "reason"),
    [
        (
            BeaconGeometry(BeaconMap.from_lists([1, 2, 3], [0.0, 3.0, 0.0], [0.0, 0.0, 2.0]), (0.01, -0.02)),
            {},
            "beacons",
        ),
        (BeaconGeometry(EUROBOT_BEACON_MAP, (0.0, 0.0)), {}, "turret offset"),
        (BeaconGeometry(EUROBOT_BEACON_MAP, (0.01, -0.02), CALIBRATION), {}, "bearing correction"),
        (GEOMETRY, {"power_bias_states": "off"}, "learnt by other state blocks"),
    ],
)
def test_states_learnt_against_another_geometry_or_by_other_blocks_are_refused(
    tmp_path, geometry, parameters, reason
):
    before = filter_of()
    learnt(before)
    path = saved(tmp_path, before)
    after = filter_of(geometry, **parameters)
    said, complete = resumed(path, after, geometry)
    assert not complete and "learnt states refused" in said and reason in said, said
    assert after.learnt_states() is None


@pytest.mark.parametrize(
    ("edit", "reason"),
    [
        (lambda d: d.update(version=2), "version 2 is not supported"),
        (lambda d: d.update(format="beams-calibration"), "format is"),
        (lambda d: d["states"].update(mean=["x"]), "states.mean: expected a number"),
        (lambda d: d["states"]["covariance"][0].__setitem__(1, 1.0), "not symmetric positive semi-definite"),
    ],
)
def test_a_malformed_checkpoint_is_refused_with_its_reason(tmp_path, edit, reason):
    before = filter_of()
    learnt(before)
    path = saved(tmp_path, before)
    document = yaml.safe_load(path.read_text())
    edit(document)
    path.write_text(yaml.safe_dump(document))
    after = filter_of()
    said, complete = resumed(path, after)
    assert not complete and reason in said, said
    assert after.learnt_states() is None


def test_runtime_changes_come_back_over_the_start_up_value_they_replaced(tmp_path):
    changes = RuntimeChanges(STARTUP)
    changes.record({**STARTUP, "gate_probability": 0.99}, {"gate_probability"})
    changes.record({**STARTUP, "max_stamp_age_s": 2.0}, {"max_stamp_age_s"})
    changes.record({**STARTUP, "gate_probability": STARTUP["gate_probability"]}, set())
    assert list(changes.changes) == ["gate_probability", "max_stamp_age_s"]
    changes.record(dict(STARTUP), {"max_stamp_age_s"})  # set back to its start-up value: nothing to keep
    assert list(changes.changes) == ["gate_probability"]
    document = yaml.safe_load(checkpoint_text(filter_of(), GEOMETRY, changes, "now"))
    assert document["states"] is None
    assert parameters_to_restore(document, STARTUP) == ({"gate_probability": 0.99}, [])
    edited = {**STARTUP, "gate_probability": 0.9}  # the parameter file changed since: it wins
    assert parameters_to_restore(document, edited)[1] == [
        f"gate_probability: its start-up value is 0.9 now, not {STARTUP['gate_probability']!r}"
    ]
    path = saved(tmp_path, filter_of(), changes=changes)
    set_back = {}
    said, complete = resumed(path, filter_of(), set_parameter=lambda n, v: set_back.update({n: v}) or "")
    assert complete and set_back == {"gate_probability": 0.99} and "['gate_probability']" in said, said
    said, complete = resumed(path, filter_of(), set_parameter=lambda _n, _v: "out of range")
    assert not complete and "not taken back: gate_probability: out of range" in said, said


def test_the_checkpoint_file_is_per_node_under_the_ros_home_and_off_when_empty(monkeypatch):
    template = EKF_PARAMETERS.default("checkpoint_file")
    home = Path.home()
    assert (
        checkpoint_path(template, "/robot1/ekf_node", {})
        == home / ".ros/beams/robot1/ekf_node_checkpoint.yaml"
    )
    assert checkpoint_path(template, "/ekf_node", {"ROS_HOME": "/var/ros"}) == Path(
        "/var/ros/beams/ekf_node_checkpoint.yaml"
    )
    assert checkpoint_path("", "/ekf_node", {}) is None
    assert resumed(None, filter_of()) == ("checkpoint off", True)
    assert resumed(Path("/nonexistent/ekf.yaml"), filter_of())[1]


def test_an_untouched_filter_leaves_an_older_checkpoint_be_and_a_failed_write_says_why(tmp_path):
    untouched = filter_of()
    assert save_checkpoint(tmp_path / "c.yaml", untouched, GEOMETRY, RuntimeChanges(STARTUP)) == ""
    assert not (tmp_path / "c.yaml").exists()
    learnt(untouched)
    (tmp_path / "file").write_text("")
    problem = save_checkpoint(tmp_path / "file" / "c.yaml", untouched, GEOMETRY, RuntimeChanges(STARTUP))
    assert problem.startswith(f"{tmp_path / 'file' / 'c.yaml'}: ")
