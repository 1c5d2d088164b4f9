"""The simulated source following a ground-truth stream that stops: revolutions the truth covers are
simulated, the later ones skipped; a pass straddling the end of the truth's reach never crashes it
(the stream stopped, e.g. a rehearsal's publisher exited)."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_driver.edge_source import ENTRY_POINT_GROUP, source_kind
from beams_driver.edges import TURRET_PERIOD_S
from beams_driver.parameters import DRIVER_PARAMETERS, codes_of
from beams_sim import sim_source
from beams_sim.sim_source import PARAMETERS, SimulatedSource


class Host:
    def __init__(self) -> None:
        self.callbacks = {}

    def subscribe_poses(self, topic, callback) -> None:
        self.callbacks[topic] = callback

    def resolve_topic(self, topic: str) -> str:
        return "/" + topic

    def log_info(self, message: str) -> None:
        pass

    def log_warning(self, message: str) -> None:
        pass

    def now_s(self) -> float:
        return 0.0


@settings(max_examples=40, deadline=None)
@given(st.floats(0.0, TURRET_PERIOD_S), st.floats(-math.pi, math.pi))
def test_a_truth_stream_that_stops_never_crashes_the_simulation(stop_phase_s, heading):
    values = {**DRIVER_PARAMETERS.defaults(), **{spec.name: spec.default for spec in PARAMETERS}}
    values.update(
        sim_beacon_ids=[1, 2, 3],
        sim_beacon_x=[1.1504, 0.6045, 0.0452],
        sim_beacon_y=[0.0449, 0.9068, 0.0515],
        sim_noise_model="ideal",
    )
    host = Host()
    source = SimulatedSource(values, codes_of(values), host)
    truth = host.callbacks["beams/sim/ground_truth"]
    stop_s = 2.0 + stop_phase_s
    stamps = [k * 0.05 for k in range(int(stop_s / 0.05) + 1)]
    for stamp in stamps:
        truth(stamp, (0.6, 0.36, heading), (0.0, 0.0))
    revolutions = 0
    for step in range(1, 80):  # the source polled every 50 ms, on to well past the truth's end
        revolutions += len(source.poll(step * 0.05).revolutions)
    # every revolution the truth covers was simulated (from the first poll's start), none long after
    assert 10 <= revolutions <= math.ceil((stamps[-1] + 0.25) / TURRET_PERIOD_S)
    assert source.health().level == "warn" and "waiting for" in source.health().message
    assert source.counts["revolutions_skipped_no_pose"] > 0


def test_past_the_truths_reach_the_pose_holds_at_the_reach():
    """The truth's reach: TRUTH_MAX_EXTRAPOLATION_S past the newest sample, clamped there."""
    values = {**DRIVER_PARAMETERS.defaults(), **{spec.name: spec.default for spec in PARAMETERS}}
    values.update(sim_beacon_ids=[1, 2, 3], sim_beacon_x=[1.0, 0.5, 0.0], sim_beacon_y=[0.0, 1.0, 0.0])
    host = Host()
    source = SimulatedSource(values, codes_of(values), host)
    host.callbacks["beams/sim/ground_truth"](1.0, (0.2, 0.3, 0.4), (0.1, 0.0))
    assert source.ground_truth.pose_at(1.5) is None
    assert source._pose_at(1.5) == pytest.approx(source.ground_truth.pose_at(1.25))


def test_the_driver_finds_the_simulated_source_by_the_entry_point_this_package_declares():
    """`source: sim` is beams_sim's declaration in the driver's group (setup.py, installed by colcon), the
    driver naming nothing of beams_sim."""
    from importlib.metadata import entry_points

    (point,) = [p for p in entry_points(group=ENTRY_POINT_GROUP) if p.name == "sim"]
    assert point.load() is sim_source.EDGE_SOURCE
    assert source_kind("sim") is sim_source.EDGE_SOURCE
    assert source_kind("beams_sim.sim_source:EDGE_SOURCE") is sim_source.EDGE_SOURCE
