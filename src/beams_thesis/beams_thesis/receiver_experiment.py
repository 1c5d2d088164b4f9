"""The receiver experiment of section 5.3 on the simulated receiver (thesis fig. 5.3, table 5.1): one
beacon, fixed true windows, the first rising and last falling edges against the window's boundaries.
A reproduction of the thesis's measurement, moved out of beams_sim.sensor_sim (the runtime simulator)."""

import numpy as np
from numpy.typing import ArrayLike

from beams_driver.codes import BeaconCode, first_last_edges
from beams_sim.sensor_sim import SensorSimConfig


def window_experiment(
    config: SensorSimConfig,
    code: BeaconCode | None,
    windows_rad: ArrayLike,
    n_turns: int,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Section 5.3's measurements on the simulated receiver (one free-running beacon, fixed true windows):
    (Phi_r - phi_R, Phi_f - phi_F) (rad, windows x turns) with `SensorSimulator`'s edge effects; code None
    is the carrier C_k; every turn must be detected."""
    windows = np.asarray(windows_rad, dtype=float).reshape(-1, 1)
    omega = config.turret_speed_rad_s
    shape = (windows.size, n_turns)
    opens, closes = np.zeros(shape), np.broadcast_to(windows, shape).copy()
    if config.hardware is not None:
        rising_std, falling_std = config.hardware.edge_std_rad(windows, code)
        opens = opens + rng.normal(0.0, 1.0, shape) * rising_std
        closes = closes + rng.normal(0.0, 1.0, shape) * falling_std
    else:
        # The constant noise on the outer edges (SensorSimulator adds it after the AND).
        opens = opens + rng.normal(0.0, config.rising_noise_rad, shape)
        closes = closes + rng.normal(0.0, config.falling_noise_rad, shape)
    if code is None:
        rising, falling = opens, closes
    else:
        phase_s = rng.uniform(0.0, code.duration_s, shape)
        min_burst_s = config.receiver.min_burst_s(code)
        first, last, detected = first_last_edges(
            code, phase_s + opens / omega, phase_s + closes / omega, min_burst_s
        )
        if not np.all(detected):
            raise ValueError("window_experiment: a window too short for the code left turns undetected")
        shift_rad = 0.5 * config.hardware.modulation_shortening_rad if config.hardware is not None else 0.0
        rising = (first - phase_s) * omega + shift_rad
        falling = (last - phase_s) * omega - shift_rad
    tick_rad = config.tick_s * omega
    captured = np.round(rising / tick_rad) * tick_rad, np.round(falling / tick_rad) * tick_rad
    return captured[0], captured[1] - windows
