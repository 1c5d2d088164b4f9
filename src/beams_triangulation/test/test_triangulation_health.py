"""triangulation_node's status model (issue 18): waiting, tracking while poses are accepted at the rate
of the turret, degraded on implausible inputs or rates, lost without an accepted pose for a second."""

import numpy as np

from beams_common.status.health import BEARING_RATE_SPECS, ODOMETRY_RATE_SPEC, Status
from beams_common.status.protection_level import INTEGRITY_SPECS
from beams_triangulation.triangulation_health import TriangulationHealth

# a ToTal pose's covariance: 1 cm, 0.2 deg (protection level 48 mm, 0.88 deg: within the default limits)
ONE_CM = np.diag([1e-4, 1e-4, np.radians(0.2) ** 2])
VALUES = {spec.name: spec.default for spec in (*BEARING_RATE_SPECS, ODOMETRY_RATE_SPEC, *INTEGRITY_SPECS)}


def _run(health: TriangulationHealth, start_s: float, end_s: float, *, accepted=True, odometry=True) -> None:
    for k in range(round((end_s - start_s) * 50)):
        now = start_s + k * 0.02
        if odometry:
            health.on_odometry(now)
        if k % 5 == 0:
            health.on_bearings(now)
            health.on_pose(now, accepted, ONE_CM)


def test_statuses_follow_the_accepted_poses_rates_and_faults():
    health = TriangulationHealth(VALUES, 0.0, use_odometry=True)
    assert health.verdict(0.5).status is Status.WAITING
    _run(health, 0.0, 3.0)
    assert health.verdict(3.0).status is Status.TRACKING
    _run(health, 3.0, 4.5, accepted=False)
    verdict = health.verdict(4.5)
    assert (
        verdict.status is Status.LOST and "no accepted pose for 1.6 s"
    )  # the last at 2.9 s in verdict.message
    _run(health, 4.5, 7.0)
    health.fault("odometry_jump", 7.0, "odometry moved 100.000 m in 0.020 s")
    assert "100.000 m" in health.verdict(7.1).message and health.verdict(7.1).status is Status.DEGRADED
    _run(health, 7.0, 10.0, odometry=False)
    assert "odometry at 0.0 Hz" in health.verdict(10.0).message


def test_without_odometry_in_use_its_rate_is_not_judged():
    health = TriangulationHealth(VALUES, 0.0, use_odometry=False)
    _run(health, 0.0, 3.0, odometry=False)
    assert health.verdict(3.0).status is Status.TRACKING
