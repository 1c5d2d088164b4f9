"""The bearing intake: each rule once, what was kept and what was refused with its kind and reason."""

import math
from types import SimpleNamespace

from hypothesis import given, settings
from hypothesis import strategies as st

from beams_common.geometry.bearing import Bearing
from beams_common.intake.bearing_intake import (
    BearingRefusal,
    bearings_message_intake,
    revolution_intake,
)
from beams_common.intake.validation import (
    MAX_BEARINGS_PER_REVOLUTION,
    MIN_BEARING_VARIANCE_RAD2,
    bearing_problem,
)

KNOWN = (1, 2, 3)
VARIANCE = 3.0e-6


def _revolution(*items: tuple[float, int, float, float]) -> list[Bearing]:
    return [Bearing(*item) for item in items]


def test_a_clean_revolution_is_kept_whole_in_order():
    bearings = _revolution((0.00, 3, 0.1, VARIANCE), (0.03, 1, 1.0, VARIANCE), (0.06, 2, 2.0, VARIANCE))
    intake = revolution_intake(bearings, KNOWN)
    assert intake.kept == bearings and intake.refused == [] and intake.too_many == ""
    assert intake.revolution_refusals() == [] and sum(intake.counts().values()) == 0


def test_each_refusal_has_its_kind_count_and_revolution_reason():
    """A sequence of well-formed but wrong revolutions: each refused bearing once, with its kind."""
    cases = [
        # (bearings, kept ids, counts, revolution-level keys)
        (
            _revolution((0.0, 1, 0.1, VARIANCE), (0.03, 9, 0.2, VARIANCE), (0.06, 2, 0.3, VARIANCE)),
            [1, 2],
            {"bearings_unknown_beacon": 1},
            [],  # another team's beacon: counted, not a refusal of the revolution (issue 18)
        ),
        (
            _revolution((0.0, 1, math.nan, VARIANCE), (0.03, 2, 0.2, 0.0), (0.06, 3, 0.3, VARIANCE)),
            [3],
            {"bearings_invalid_measurement": 2},
            ["revolutions_with_invalid_bearings"],
        ),
        (  # beacon 1 again later: the sighting nearest the middle (0.05 s) kept, the other set aside
            _revolution((0.0, 1, 0.1, VARIANCE), (0.05, 2, 0.2, VARIANCE), (0.06, 1, 0.3, VARIANCE)),
            [1, 2],  # the beacon's place is its first sighting's
            {"bearings_repeated_beacon": 1},
            [],
        ),
        (  # beacon 2 twice at one instant: both refused, the unknown one too
            _revolution((0.0, 2, 0.1, VARIANCE), (0.0, 2, 0.2, VARIANCE), (0.05, 7, 0.3, VARIANCE)),
            [],
            {"bearings_conflicting_beacon": 2, "bearings_unknown_beacon": 1},
            ["revolutions_conflicting_beacon"],
        ),
    ]
    for bearings, kept_ids, counts, keys in cases:
        intake = revolution_intake(bearings, KNOWN)
        assert [b.beacon_id for b in intake.kept] == kept_ids
        assert dict(intake.counts()) == counts
        assert {r.refusal for r in intake.refused} == {
            BearingRefusal(k.removeprefix("bearings_")) for k in counts
        }
        assert [key for key, _ in intake.revolution_refusals()] == keys
        assert all(r.reason for r in intake.refused)
    assert revolution_intake(cases[2][0], KNOWN).kept[0].stamp_s == 0.06


def test_an_oversized_message_is_refused_before_its_bearings_are_read():
    class Unreadable(list):
        def __iter__(self):
            raise AssertionError("the bearings were read")

    message = SimpleNamespace(bearings=Unreadable([None] * (MAX_BEARINGS_PER_REVOLUTION + 1)), header=None)
    intake = bearings_message_intake(message, lambda stamp: 0.0, KNOWN)
    assert f"more than the limit {MAX_BEARINGS_PER_REVOLUTION}" in intake.too_many
    assert intake.kept == [] and intake.refused == []
    assert intake.revolution_refusals() == [("revolutions_too_many_bearings", intake.too_many)]


BEARINGS = st.builds(
    Bearing,
    st.sampled_from([0.0, 0.01, 0.02, 0.05, math.nan]),
    st.integers(0, 5),
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.sampled_from([VARIANCE, MIN_BEARING_VARIANCE_RAD2, 0.0, -1.0, math.inf, math.nan]),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(BEARINGS, max_size=12))
def test_every_bearing_is_kept_or_refused_once_and_the_kept_are_valid(bearings):
    intake = revolution_intake(bearings, KNOWN)
    assert len(intake.kept) + len(intake.refused) == len(bearings)
    assert sorted(map(id, [*intake.kept, *(r.bearing for r in intake.refused)])) == sorted(map(id, bearings))
    kept_ids = [b.beacon_id for b in intake.kept]
    assert len(set(kept_ids)) == len(kept_ids)
    for b in intake.kept:
        assert bearing_problem(b.beacon_id, b.bearing_rad, b.variance_rad2, b.stamp_s, KNOWN) == ""
    conflicting = set(intake.conflicting_ids)
    assert not conflicting & set(kept_ids)
    assert sum(intake.counts().values()) == len(intake.refused)
