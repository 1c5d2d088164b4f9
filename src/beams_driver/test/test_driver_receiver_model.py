"""The driver describes the receiver its edges come through with `ReceiverModel`, not with the
simulator's configuration: the thesis hardware's (sections 5.5-5.7) for a real sensor, the simulated
sensor's own for `source: sim`, and the two agree where the simulator emulates the thesis hardware."""

import pytest

from beams_driver.codes import code_family, codes_from_strings
from beams_driver.edge_source import source_kind
from beams_driver.receiver import THESIS_MIN_BURST_FRACTION, ReceiverModel
from beams_sim.sensor_sim import SensorSimConfig


def test_the_thesis_receiver_is_the_one_the_simulator_emulates():
    assert ReceiverModel.thesis_hardware() == SensorSimConfig.thesis_hardware().receiver
    assert ReceiverModel.thesis_hardware(0.2) == SensorSimConfig.thesis_hardware(period_s=0.2).receiver
    assert ReceiverModel.thesis_hardware().min_burst_fraction == THESIS_MIN_BURST_FRACTION


def test_a_real_sensor_is_described_by_the_thesis_receiver():
    codes = tuple(code_family())
    receiver = source_kind("serial").receiver({}, codes)
    assert isinstance(receiver, ReceiverModel)
    assert receiver == ReceiverModel.thesis_hardware()


@pytest.mark.parametrize("noise_model", ["thesis_hardware", "ideal"])
def test_the_simulated_source_describes_its_own_receiver(noise_model):
    codes = tuple(codes_from_strings(["111110111110", "11111001111100"]))
    kind = source_kind("sim")
    values = {spec.name: spec.default for spec in kind.parameters} | {"sim_noise_model": noise_model}
    receiver = kind.receiver(values, codes)
    config = SensorSimConfig.thesis_hardware() if noise_model == "thesis_hardware" else SensorSimConfig()
    assert isinstance(receiver, ReceiverModel)
    assert receiver == config.receiver
