"""The edge-level sensor simulation against section 2.4 and the receiver departures of section 5.6."""

import numpy as np
import pytest

from beams_driver.codes import code_family
from beams_driver.edges import STEPS_PER_TURN, TURRET_PERIOD_S, RevolutionEdges
from beams_driver.receiver import THESIS_WINDOW_RANGE_RAD, HardwareNoise
from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator, SimulatedBeacon, beacons_from_map

CODES = code_family()
PHI0_RAD = CODES[0].bit_time_s * 2.0 * np.pi / TURRET_PERIOD_S


def _one_beacon(config, beacon_id=1, distance_m=2.0, seed=0, **kwargs):
    return SensorSimulator(
        config, [SimulatedBeacon(beacon_id, distance_m, 0.0)], np.random.default_rng(seed), **kwargs
    )


def _outer_edges(edges: RevolutionEdges) -> tuple[float, float, np.ndarray]:
    """First rising angle, last falling angle and burst lengths (rad) of a one-window revolution."""
    angles = edges.edge_angles_rad
    return angles[0], angles[-1], angles[1::2] - angles[0::2]


def test_turret_timing_of_section_2_4_2():
    config = SensorSimConfig()
    assert config.period_s == pytest.approx(0.09984)
    assert 1.0 / config.period_s == pytest.approx(10.016, abs=1e-3)
    assert 2.0 * np.pi / STEPS_PER_TURN == pytest.approx(1.007e-4, rel=1e-3)  # 0.1 mrad per step


def test_window_shrinks_with_distance_as_eq_2_7_says():
    config = SensorSimConfig()
    distances = np.array([0.3, 1.0, 2.0, 3.6, 6.0, 6.9, 8.0])
    windows = config.window_rad(distances)
    assert np.all(np.diff(windows) <= 0.0)
    # About 20 bits (~2 codes) at the 6 m working range (section 2.5.1), nothing beyond 6.9 m.
    assert 18.0 < windows[4] / PHI0_RAD < 22.0
    assert windows[-1] == 0.0
    assert _one_beacon(config, distance_m=8.0).revolution(lambda t: (0.0, 0.0, 0.0), 0.0).n_edges == 0
    # Four times the power reaches twice as far with the same window (d ~ sqrt(S Pe)).
    assert config.window_rad(4.0, power_scale=4.0) == pytest.approx(config.window_rad(2.0))


def test_edges_are_timer_captures_inside_the_revolution():
    config = SensorSimConfig(spurious_rate_hz=200.0)
    beacons = [
        SimulatedBeacon(1, -0.062, -0.062),
        SimulatedBeacon(2, -0.062, 2.062),
        SimulatedBeacon(3, 3.062, 1.0),
    ]
    simulator = SensorSimulator(config, beacons, np.random.default_rng(3))
    tick_rad = 2.0 * np.pi / STEPS_PER_TURN
    for k in range(50):
        start = 1.0 + k * config.period_s
        edges = simulator.revolution(lambda t: (1.5 + 0.1 * t, 1.0, 3.0 * t), start)
        assert edges.revolution == k
        assert np.all(np.diff(edges.edge_times_s) >= 0.0)
        assert np.all((edges.edge_angles_rad >= 0.0) & (edges.edge_angles_rad < 2.0 * np.pi))
        assert np.all((edges.edge_times_s >= start) & (edges.edge_times_s < start + config.period_s))
        assert edges.edge_angles_rad == pytest.approx(
            (edges.edge_times_s - start) * config.turret_speed_rad_s
        )
        steps = edges.edge_angles_rad / tick_rad
        assert np.abs(steps - np.round(steps)).max() < 1e-6
        assert edges.edge_rising.sum() == pytest.approx(edges.n_edges / 2, abs=1)


def test_ideal_receiver_is_code_and_window():
    config = SensorSimConfig.ideal()
    simulator = _one_beacon(config, beacon_id=5, distance_m=1.5)
    window = float(config.window_rad(1.5))
    for k in range(30):
        edges = simulator.revolution(lambda t: (0.0, 0.0, 1.0), k * config.period_s)
        rising, falling, bursts = _outer_edges(edges)
        # Each outer edge lies at most phi0 inside the true window (section 3.2), up to a capture tick.
        assert window - 2 * PHI0_RAD - 2e-4 < falling - rising <= window + 2e-4
        assert 0.5 * (rising + falling) == pytest.approx(2.0 * np.pi - 1.0, abs=PHI0_RAD)
        inner = bursts[1:-1] / PHI0_RAD
        assert np.allclose(inner, 5.0, atol=0.1)  # code 5: bursts of 5 bits


def test_and_hypothesis_drops_short_leading_and_trailing_bursts():
    shortest = {}
    for fraction in (0.0, 0.56):
        config = SensorSimConfig.ideal(min_burst_fraction=fraction)
        simulator = _one_beacon(config, beacon_id=3, seed=4)
        outer = []
        for k in range(400):
            edges = simulator.revolution(lambda t: (0.0, 0.0, 1.0), k * config.period_s)
            bursts = _outer_edges(edges)[2]
            outer += [bursts[0], bursts[-1]]
        shortest[fraction] = min(outer) / PHI0_RAD
    assert shortest[0.0] < 0.2
    assert shortest[0.56] >= 0.56 - 0.06  # within a capture tick


def test_rising_edges_are_noisier_than_falling_edges():
    config = SensorSimConfig(edge_jitter_s=0.0, min_burst_fraction=0.0)
    reference = _one_beacon(SensorSimConfig.ideal(), seed=5)
    noisy = _one_beacon(config, seed=5)
    offsets_r, offsets_f = [], []
    for k in range(600):
        ideal = _outer_edges(reference.revolution(lambda t: (0.0, 0.0, 1.0), k * config.period_s))
        real = _outer_edges(noisy.revolution(lambda t: (0.0, 0.0, 1.0), k * config.period_s))
        offsets_r.append(real[0] - ideal[0])
        offsets_f.append(real[1] - ideal[1])
    assert np.std(offsets_r) == pytest.approx(config.rising_noise_rad, rel=0.15)
    assert np.std(offsets_f) == pytest.approx(config.falling_noise_rad, rel=0.15)
    assert np.std(offsets_r) > 2.0 * np.std(offsets_f)


def test_same_seed_same_edges_and_beacons_from_a_map():
    class Map:
        ids = (1, 2, 3)
        xy = np.array([[-0.062, -0.062], [-0.062, 2.062], [3.062, 1.0]])

    beacons = beacons_from_map(Map())
    assert [b.beacon_id for b in beacons] == [1, 2, 3]
    runs = []
    for _ in range(2):
        simulator = SensorSimulator(SensorSimConfig(spurious_rate_hz=100.0), Map(), np.random.default_rng(42))
        runs.append([simulator.revolution(lambda t: (1.0, 1.0, 0.5), 0.1 * k) for k in range(5)])
    for a, b in zip(*runs, strict=True):
        assert np.array_equal(a.edge_times_s, b.edge_times_s)
        assert np.array_equal(a.edge_rising, b.edge_rising)


def test_invalid_configuration_and_unknown_beacon_are_refused():
    with pytest.raises(ValueError, match="spurious rate"):
        SensorSimConfig(spurious_rate_hz=-1.0)
    with pytest.raises(ValueError, match="period_s"):
        SensorSimConfig(period_s=0.0)
    with pytest.raises(KeyError, match="beacon 7 has no code"):
        _one_beacon(SensorSimConfig(), beacon_id=7)
    with pytest.raises(ValueError, match="must match"):
        RevolutionEdges(0, 0.0, 0.1, np.zeros(2), np.zeros(3), np.zeros(2, dtype=bool))


def test_the_thesis_hardware_noise_is_the_drivers_over_the_default_beams_windows():
    """The simulator emulates the receiver the driver assumes by default (beams_driver.receiver): fig.
    5.3's windows are those of the default beam at 6 m and 1 m, exactly."""
    assert (SensorSimConfig().window_rad(6.0), SensorSimConfig().window_rad(1.0)) == THESIS_WINDOW_RANGE_RAD
    assert SensorSimConfig.thesis_hardware().hardware == HardwareNoise.thesis_hardware()
