"""The raw output of the BeAMS sensor for one turret revolution: timed receiver edges (section 2.4.1). The
timer that latches each edge also drives the turret, so each capture is both an instant and a turret angle
(eq. 2.1)."""

from dataclasses import dataclass, field

import numpy as np

# The common timer drives the turret: 62400 virtual steps per turn at 625 kHz (section 2.4.2).
TIMER_HZ = 625000.0
STEPS_PER_TURN = 62400
TURRET_PERIOD_S = STEPS_PER_TURN / TIMER_HZ
TURRET_SPEED_RAD_S = 2.0 * np.pi / TURRET_PERIOD_S


@dataclass(frozen=True)
class RevolutionEdges:
    """Edges captured during one revolution: instants (increasing), turret angles in [0, 2 pi) from the zero
    reference (CCW), rising or not; lost_angles_rad (m, 2): intervals where frames were lost (the decoder
    rejects the windows they touch)."""

    revolution: int
    start_time_s: float
    period_s: float
    edge_times_s: np.ndarray
    edge_angles_rad: np.ndarray
    edge_rising: np.ndarray
    lost_angles_rad: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))

    def __post_init__(self) -> None:
        times = np.asarray(self.edge_times_s, dtype=float).reshape(-1)
        angles = np.asarray(self.edge_angles_rad, dtype=float).reshape(-1)
        rising = np.asarray(self.edge_rising, dtype=bool).reshape(-1)
        if not times.shape == angles.shape == rising.shape:
            raise ValueError(
                f"revolution {self.revolution}: {times.size} times, {angles.size} angles, "
                f"{rising.size} polarities; they must match"
            )
        if not self.period_s > 0.0:
            raise ValueError(f"revolution {self.revolution}: period must be positive, got {self.period_s}")
        if times.size and np.any(np.diff(times) < 0.0):
            raise ValueError(f"revolution {self.revolution}: edge times must be increasing")
        lost = np.asarray(self.lost_angles_rad, dtype=float).reshape(-1, 2)
        for name, array in (
            ("edge_times_s", times),
            ("edge_angles_rad", angles),
            ("edge_rising", rising),
            ("lost_angles_rad", lost),
        ):
            array.setflags(write=False)
            object.__setattr__(self, name, array)

    @property
    def n_edges(self) -> int:
        """Number of edges captured in the revolution."""
        return int(self.edge_times_s.size)

    @property
    def turret_speed_rad_s(self) -> float:
        """omega = 2 pi / period (eq. 2.1)."""
        return 2.0 * np.pi / self.period_s
