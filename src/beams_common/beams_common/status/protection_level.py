"""Protection levels: bounds on an estimate's horizontal (m) and heading (rad) errors that the true error
exceeds with probability at most the integrity risk, one undetected faulty bearing or beacon included
(solution separation, as ARAIM does for satellites; docs/protection_level.md has the formulas and the
faults they cannot cover), and the alert limits beyond which the estimate is unavailable for navigation.

Fault-free, the error e ~ N(0, P) of a 2x2 position covariance P satisfies |e|^2 <= lambda_max(P)
e' P^-1 e, and e' P^-1 e is chi-square with 2 degrees of freedom, whose tail is exp(-k^2 / 2): so
|e| <= k sigma_major with k = sqrt(-2 ln risk) (the Rayleigh quantile), and the heading's two-sided
Gaussian quantile bounds |e_theta|. Under the hypothesis that measurement (or beacon) i is faulty, the
solution without it is fault-free, so |e| <= |x0 - x_i| + k sigma_major(P_i): the observed separation
plus the separated solution's bound. Each hypothesis is bounded at the whole risk, so the risk holds
whatever the prior probability of each fault (their sum is at most one); the protection level is the
largest of the bounds. Pure numpy, closed forms: computed with every estimate.
"""

import math
from collections.abc import Mapping
from dataclasses import dataclass
from statistics import NormalDist
from typing import Any

import numpy as np

from beams_common.config.parameters import ParameterSpec

INTEGRITY_SPECS = (
    ParameterSpec(
        "integrity_risk",
        1.0e-5,
        "Probability per estimate that the error exceeds its protection level (docs/protection_level.md).",
        minimum=1.0e-15,
        maximum=0.1,
        runtime=True,
    ),
    ParameterSpec(
        "horizontal_alert_limit_m",
        0.05,
        "Largest horizontal protection level (m) for the status to be tracking; beyond it the status is "
        "degraded (unavailable for navigation).",
        minimum=1.0e-6,
        maximum=100.0,
        runtime=True,
    ),
    ParameterSpec(
        "heading_alert_limit_rad",
        math.radians(3.0),
        "Largest heading protection level (rad) for the status to be tracking; beyond it the status is "
        "degraded (unavailable for navigation).",
        minimum=1.0e-9,
        maximum=math.pi,
        runtime=True,
    ),
)


@dataclass(frozen=True)
class ProtectionLevel:
    """The bounds of one estimate; `faults_covered` False: a solution without redundancy (ToTal's three
    bearings), whose bound is the fault-free one alone."""

    horizontal_m: float
    heading_rad: float
    faults_covered: bool = True


def major_sigma_m(covariance: np.ndarray) -> np.ndarray:
    """sqrt of the largest eigenvalue of the 2x2 position blocks of (n, 3, 3) covariances."""
    a, b, c = covariance[:, 0, 0], covariance[:, 0, 1], covariance[:, 1, 1]
    return np.sqrt(np.maximum(0.5 * (a + c) + np.hypot(0.5 * (a - c), b), 0.0))


class Integrity:
    """The integrity risk and the alert limits of validated parameter values (INTEGRITY_SPECS), with the
    quantiles of the risk."""

    def __init__(self, values: Mapping[str, Any]) -> None:
        self.risk = float(values["integrity_risk"])
        self.horizontal_limit_m = float(values["horizontal_alert_limit_m"])
        self.heading_limit_rad = float(values["heading_alert_limit_rad"])
        self.k_horizontal = math.sqrt(-2.0 * math.log(self.risk))
        self.k_heading = -NormalDist().inv_cdf(0.5 * self.risk)

    @classmethod
    def default(cls) -> "Integrity":
        """The defaults of INTEGRITY_SPECS (the offline replays')."""
        return cls({spec.name: spec.default for spec in INTEGRITY_SPECS})

    def level(
        self,
        covariance: np.ndarray,
        shifts: np.ndarray | None = None,
        separated: np.ndarray | None = None,
    ) -> ProtectionLevel:
        """The protection level of an estimate of 3x3 `covariance` (x, y, theta); with the fault
        hypotheses' `shifts` (n, 3: the estimate minus the solution without measurement or beacon i) and
        the `separated` solutions' covariances (n, 3, 3). None: no redundancy, the fault-free bound."""
        (a, b, _), (_, c, _), (_, _, theta) = covariance.tolist()  # scalars: numpy's cost is per call
        horizontal = self.k_horizontal * math.sqrt(max(0.5 * (a + c) + math.hypot(0.5 * (a - c), b), 0.0))
        heading = self.k_heading * math.sqrt(max(theta, 0.0))
        if shifts is None or separated is None:
            return ProtectionLevel(horizontal, heading, faults_covered=False)
        if len(shifts):
            h_faults = np.hypot(shifts[:, 0], shifts[:, 1]) + self.k_horizontal * major_sigma_m(separated)
            theta_sigma = np.sqrt(np.maximum(separated[:, 2, 2], 0.0))
            theta_faults = np.abs(shifts[:, 2]) + self.k_heading * theta_sigma
            horizontal = max(horizontal, float(h_faults.max()))
            heading = max(heading, float(theta_faults.max()))
        return ProtectionLevel(horizontal, heading)

    def within(self, level: ProtectionLevel) -> bool:
        """True when both bounds are within their alert limits."""
        return level.horizontal_m <= self.horizontal_limit_m and level.heading_rad <= self.heading_limit_rad

    def problem(self, level: ProtectionLevel | None) -> str:
        """Why the estimate is unavailable for navigation (a bound above its alert limit), or ''."""
        if level is None or self.within(level):
            return ""
        return (
            f"protection level {1e3 * level.horizontal_m:.0f} mm / {math.degrees(level.heading_rad):.2f} deg "
            f"above the alert limits {1e3 * self.horizontal_limit_m:.0f} mm / "
            f"{math.degrees(self.heading_limit_rad):.2f} deg: unavailable for navigation"
        )
