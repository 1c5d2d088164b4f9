"""The state blocks (beams_ekf.state_blocks, docs/state_blocks.md): a new block is one module and its one
line in FilterSettings. The worked example of the docs, a constant bearing offset, registered here, runs
with every other block: the state's layout, its parameters, the Jacobian of every block against central
differences of the predicted bearing, and the offset learnt and kept across a re-initialisation."""

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pytest

from beams_common.config.parameters import ParameterSpec, ParameterTable
from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_ekf.beacon_states import BeaconStates
from beams_ekf.bearing_ekf import BearingEkf, bearing_measurement, turret_pose
from beams_ekf.odometry_errors import OdometryErrorStates
from beams_ekf.power_bias_states import PowerBiasStates
from beams_ekf.settings import FilterSettings
from beams_ekf.state_blocks import BearingPart, Sighting, StateBlock, block_field, registered_blocks
from beams_ekf.turret_offset_states import TurretOffsetStates

# the docs' worked example: a module with its specs, its block and the block of their values
BEARING_OFFSET_SPECS = ParameterTable(
    "ekf_node",
    (
        ParameterSpec(
            "bearing_offset_sigma_rad",
            0.0,
            "Prior standard deviation (rad) of a constant offset of every bearing; 0: none.",
            minimum=0.0,
            maximum=0.1,
        ),
    ),
)


@dataclass(frozen=True)
class BearingOffsetStates(StateBlock):
    """A constant offset b (rad) of every bearing (the turret's zero misaligned): h(x) + b."""

    prior_sigma_rad: float = 0.01
    size = 1

    @property
    def prior_covariance(self) -> np.ndarray:
        return self.prior_sigma_rad**2 * np.eye(self.size)

    def bearing(self, mean: np.ndarray, sighting: Sighting, memory: Any) -> BearingPart:
        return BearingPart(np.ones(self.size), float(mean[0]))


def bearing_offset_states_of(values: dict) -> BearingOffsetStates | None:
    sigma = float(values["bearing_offset_sigma_rad"])
    return BearingOffsetStates(sigma) if sigma > 0.0 else None


@dataclass(frozen=True)
class Settings(FilterSettings):
    """FilterSettings with the example's one line."""

    bearing_offset: BearingOffsetStates | None = field(
        **block_field(BEARING_OFFSET_SPECS, bearing_offset_states_of)
    )


MAP = {**EUROBOT_BEACON_MAP.as_dict(), 4: (1.5, -0.062)}
OFFSET = (0.03, -0.01)
POSE = (1.2, 0.7, 0.4)


def _every_block() -> Settings:
    return replace(
        Settings(),
        turret_offset=TurretOffsetStates(),
        beacon_states=BeaconStates((3,)),
        bearing_offset=BearingOffsetStates(0.02),
    )


def _filter(settings: Settings) -> BearingEkf:
    return BearingEkf(MAP, OFFSET, settings.process_noise, settings.gate_probability, settings.blocks)


def test_the_registered_block_takes_its_place_and_its_parameters():
    assert [name for name, _, _ in registered_blocks(Settings)][-1] == "bearing_offset"
    assert Settings().bearing_offset is None  # its spec's default: off
    settings = _every_block()
    assert [type(b) for b in settings.blocks] == [
        OdometryErrorStates,
        PowerBiasStates,
        TurretOffsetStates,
        BeaconStates,
        BearingOffsetStates,
    ]
    ekf = _filter(settings)
    assert ekf.dim == 3 + 3 + 4 + 2 + 2 + 1
    ekf.initialise(POSE, np.eye(3) * 1e-4)
    mean, covariance = ekf.estimate(BearingOffsetStates)
    assert mean.tolist() == [0.0] and covariance.tolist() == [[0.02**2]]
    assert ekf.block(BearingOffsetStates) == BearingOffsetStates(0.02)


def test_every_blocks_jacobian_matches_finite_differences_of_the_predicted_bearing():
    """h(x) of a bearing with every block (the observed beacon's coordinates estimated, a fourth beacon
    fixed): its analytic Jacobian against central differences of h, at a random state and a turned
    lever."""
    ekf = _filter(_every_block())
    ekf.initialise(POSE, np.eye(3) * 1e-4)
    rng = np.random.default_rng(5)
    x, p = ekf.state()
    x[3:, 0] += rng.normal(0.0, 2e-3, ekf.dim - 3)
    ekf.restore((x, p))
    lever = (0.05, 0.02, 0.3)
    # a window the fit never saw: the bias is evaluated at the measured window (no fit yet)
    _, jacobian = ekf.predicted_bearing(3, lever, 0.09)
    numeric = np.zeros(ekf.dim)
    for k in range(ekf.dim):
        values = []
        for step in (1e-6, -1e-6):
            moved = x.copy()
            moved[k, 0] += step
            ekf.restore((moved, p))
            values.append(ekf.predicted_bearing(3, lever, 0.09)[0])
        numeric[k] = wrap_to_pi(values[0] - values[1]) / 2e-6
    ekf.restore((x, p))
    assert np.allclose(jacobian[0], numeric, atol=1e-6), (jacobian[0], numeric)
    assert np.all(numeric[3:6] == 0.0)  # the odometry error states enter the prediction only
    assert np.all(numeric[-3:-1] != 0.0)  # the beacon's coordinates enter its bearing
    assert abs(numeric[-1] - 1.0) < 1e-6  # the offset adds to h


def test_the_example_block_learns_a_constant_offset_and_a_reinitialisation_keeps_it():
    """A still robot whose heading is known: bearings all turned by 0.01 rad teach the offset (a
    heading error would turn them alike: the offset is observable through the heading's prior)."""
    settings = replace(Settings(), power_bias=None, bearing_offset=BearingOffsetStates(0.02))
    ekf = BearingEkf(EUROBOT_BEACON_MAP.as_dict(), OFFSET, blocks=settings.blocks)
    sigma = np.diag([1e-6, 1e-6, 1e-10])
    ekf.initialise(POSE, sigma)
    lever = turret_pose((0.0, 0.0, 0.0), OFFSET)
    for _ in range(30):
        for beacon_id, xy in EUROBOT_BEACON_MAP.as_dict().items():
            bearing, _ = bearing_measurement(POSE, xy, lever)
            assert ekf.update_bearing(beacon_id, wrap_to_pi(bearing + 0.01), 1e-6).accepted
    learnt, covariance = ekf.estimate(BearingOffsetStates)
    assert abs(learnt[0] - 0.01) < 1e-4 and covariance[0, 0] < 1e-7
    ekf.reset()
    ekf.initialise(POSE, sigma)
    assert ekf.estimate(BearingOffsetStates)[0] == learnt  # learnt: kept
    ekf.reset(forget_learnt=True)
    ekf.initialise(POSE, sigma)
    assert ekf.estimate(BearingOffsetStates)[0] == 0.0  # forgotten: the prior again


def test_a_bearing_whose_bias_is_not_modelled_yet_teaches_no_learnt_block():
    """An uncalibrated bearing before the window fit is ready updates the pose alone (power_bias_states):
    the odometry errors, registered before the power bias, are frozen too; a calibrated one teaches them
    through their cross-covariance with the pose."""
    ekf = BearingEkf(EUROBOT_BEACON_MAP.as_dict(), OFFSET, blocks=(OdometryErrorStates(), PowerBiasStates()))
    ekf.initialise(POSE, np.eye(3) * 1e-4)
    ekf.predict((0.3, 0.0, 0.5))  # correlates the pose with the odometry errors
    before = [ekf.estimate(kind)[0] for kind in (OdometryErrorStates, PowerBiasStates)]
    pose = ekf.pose
    assert ekf.update_bearing(
        1, ekf.predicted_bearing(1)[0] + 2e-3, 1e-6, uncorrected_window_rad=0.09
    ).accepted
    assert ekf.pose != pose
    for kind, mean in zip((OdometryErrorStates, PowerBiasStates), before, strict=True):
        np.testing.assert_array_equal(ekf.estimate(kind)[0], mean)
    assert ekf.update_bearing(1, ekf.predicted_bearing(1)[0] + 2e-3, 1e-6).accepted
    assert np.any(ekf.estimate(OdometryErrorStates)[0] != before[0])
    np.testing.assert_array_equal(ekf.estimate(PowerBiasStates)[0], before[1])  # calibrated: no bias


def test_a_new_map_resets_a_moved_beacons_states_and_keeps_every_other_learnt_state():
    """A calibration reload on a filter that learnt: every block is asked which of its states the new map
    makes stale (the pose block has none); the moved beacon's go back to their prior, the rest stay."""
    ekf = _filter(_every_block())
    ekf.initialise(POSE, np.eye(3) * 1e-4)
    ekf.reset()
    ekf.initialise(POSE, np.eye(3) * 1e-4)  # from now on the blocks' states are learnt ones
    x, p = ekf.state()
    x[3:, 0] = 1e-3
    ekf.restore((x, p))
    moved = {**MAP, 3: (MAP[3][0] + 0.01, MAP[3][1])}
    settings = _every_block()
    ekf.configure(moved, OFFSET, settings.process_noise, settings.gate_probability)
    beacon, covariance = ekf.estimate(BeaconStates)
    assert beacon.tolist() == [0.0, 0.0] and np.all(np.diag(covariance) > 0.0)
    assert np.all(ekf.estimate(TurretOffsetStates)[0] == 1e-3)
    assert np.all(ekf.estimate(BearingOffsetStates)[0] == 1e-3)
    assert ekf.pose == pytest.approx(POSE)
    ekf.configure(moved, OFFSET, settings.process_noise, settings.gate_probability)  # the same map: no change
    assert np.all(ekf.estimate(TurretOffsetStates)[0] == 1e-3)
