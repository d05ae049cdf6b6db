"""The stamp joiner (soil_msgs_py.stamp_join): sets by stamp, released in stamp order, and each
policy for stale, duplicate, out-of-order, far-back and far-future stamps and bounded memory."""
from __future__ import annotations

import pytest

from soil_msgs_py.stamp_join import StampJoiner, Verdict, Why

A, B, C = "/a", "/b", "/c"
P = 100  # a tick [ns] in these tests


def stamps(out):
    return [(j.stamp_ns, j.why) for j in out]


def test_a_set_leaves_once_every_topic_came_whatever_the_arrival_order():
    j = StampJoiner((A, B, C), max_pending=10)
    assert j.offer(B, 0, "b0") == (Verdict.TAKEN, [])
    assert j.offer(C, 0, "c0").out == []
    verdict, out = j.offer(A, 0, "a0")
    (joined,) = out
    assert verdict is Verdict.TAKEN and joined.usable and joined.why is Why.COMPLETE
    assert joined.parts == {B: "b0", C: "c0", A: "a0"} and joined.missing == () and joined.previous_ns == -1
    assert len(j) == 0 and j.last_ns == 0


def test_sets_leave_in_stamp_order_a_newer_complete_one_waits_for_the_older():
    j = StampJoiner((A, B), max_pending=10, reorder_ns=3 * P)
    j.offer(A, 0)
    j.offer(A, P)
    assert j.offer(B, P).out == []  # complete, but tick 0 may still come
    out = j.offer(B, 0).out
    assert stamps(out) == [(0, Why.COMPLETE), (P, Why.COMPLETE)] and out[1].previous_ns == 0


def test_an_incomplete_set_is_given_up_once_a_complete_one_reorder_ns_newer_exists():
    j = StampJoiner((A, B), max_pending=10, reorder_ns=2 * P)
    j.offer(A, 0)  # B of tick 0 never comes
    for k in (1, 2):
        j.offer(A, k * P)
        out = j.offer(B, k * P).out
        if k == 1:
            assert out == [], "1 tick newer: still within the horizon"
    assert stamps(out) == [(0, Why.OVERTAKEN), (P, Why.COMPLETE), (2 * P, Why.COMPLETE)]
    assert out[0].missing == (B,) and not out[0].usable and out[0].parts == {A: None}


def test_reorder_zero_gives_up_older_sets_as_soon_as_a_newer_one_is_complete():
    j = StampJoiner((A, B), max_pending=10)
    j.offer(A, 0)
    j.offer(B, P)
    j.offer(A, 3 * P)  # newer than the set that completes: it stays
    out = j.offer(A, P).out
    assert stamps(out) == [(0, Why.OVERTAKEN), (P, Why.COMPLETE)] and len(j) == 1


def test_stale_stamps_are_refused_and_reset_sets_the_first_expected_stamp():
    j = StampJoiner((A,), max_pending=10)
    j.offer(A, 5 * P)
    assert j.offer(A, 5 * P) == (Verdict.STALE, []) and j.offer(A, 2 * P).verdict is Verdict.STALE
    j.reset(first_stamp_ns=10 * P)
    assert j.offer(A, 10 * P - 1).verdict is Verdict.STALE and j.last_ns == 10 * P - 1
    assert j.offer(A, 10 * P).out[0].previous_ns == 10 * P - 1
    j.reset()
    assert j.offer(A, 0).verdict is Verdict.TAKEN, "reset without a first stamp: anything goes"


def test_far_back_restarts_the_stream_near_back_is_stale():
    j = StampJoiner((A, B), max_pending=10, restart_back_ns=10 * P)
    for k in range(20):
        j.offer(A, k * P)
        j.offer(B, k * P)
    j.offer(A, 25 * P)  # pending, forgotten by the restart
    assert j.offer(A, 10 * P).verdict is Verdict.STALE, "exactly the horizon back: stale"
    verdict, out = j.offer(A, 0, "again")
    assert verdict is Verdict.RESTART and out == [] and len(j) == 1 and j.last_ns == -1
    assert j.offer(B, 0).out[0].parts == {A: "again", B: None}


def test_max_ahead_zero_takes_only_the_expected_stamp():
    j = StampJoiner((A, B), max_pending=1, max_ahead_ns=0)
    assert j.offer(A, 7 * P).verdict is Verdict.TAKEN, "no stamp expected yet: no future limit"
    j.reset(first_stamp_ns=P)
    assert j.offer(A, P + 1).verdict is Verdict.FUTURE and j.offer(A, P - 1).verdict is Verdict.STALE
    j.offer(A, P)
    assert stamps(j.offer(B, P).out) == [(P, Why.COMPLETE)]
    assert j.offer(A, P + 1).verdict is Verdict.TAKEN, "after P the next expected stamp is P + 1 ns"


@pytest.mark.parametrize("policy, part, bad", [("replace", "second", ""), ("keep_first", "first", ""),
                                               ("spoil", "second", f"{A} twice")])
def test_duplicate_policies(policy, part, bad):
    j = StampJoiner((A, B), max_pending=10, duplicates=policy)
    j.offer(A, 0, "first")
    assert j.offer(A, 0, "second").verdict is Verdict.DUPLICATE
    (joined,) = j.offer(B, 0, "b").out
    assert joined.parts[A] == part and joined.bad == bad and joined.complete and joined.usable == (not bad)


def test_a_bad_message_spoils_its_set_which_still_leaves_in_order():
    j = StampJoiner((A, B), max_pending=10)
    assert j.bad(0) == ""
    j.offer(A, 0, bad="a: x=nan")
    j.offer(B, 0, bad="b: y=inf")  # the first reason is kept
    j.offer(A, P)
    assert j.bad(P) == ""
    (joined,) = j.offer(B, P).out
    assert joined.stamp_ns == P and joined.previous_ns == 0  # tick 0 left, marked bad
    j2 = StampJoiner((A, B), max_pending=10)
    j2.offer(A, 0, bad="a: x=nan")
    assert j2.bad(0) == "a: x=nan"
    (spoiled,) = j2.offer(B, 0).out
    assert spoiled.complete and not spoiled.usable and spoiled.bad == "a: x=nan"


def test_memory_is_bounded_and_the_longest_waiting_set_goes_first():
    """Bogus far-future stamps fill the pending sets; they age out, real ticks keep flowing."""
    j = StampJoiner((A, B), max_pending=4)
    released, evicted = [], []
    for k in range(20):
        for joined in j.offer(A, 10**18 + k).out + j.offer(A, k * P).out + j.offer(B, k * P).out:
            (released if joined.why is Why.COMPLETE else evicted).append(joined)
    assert [x.stamp_ns for x in released] == [k * P for k in range(20)]
    assert len(j) <= 4 and all(x.why is Why.EVICTED and x.missing == (B,) for x in evicted)
    assert [x.stamp_ns for x in evicted] == [10**18 + k for k in range(len(evicted))] and len(evicted) >= 15


def test_eviction_does_not_move_the_order_on():
    j = StampJoiner((A, B), max_pending=1)
    j.offer(A, 5 * P)
    (gone,) = j.offer(A, 9 * P).out
    assert gone.stamp_ns == 5 * P and gone.why is Why.EVICTED and j.last_ns == -1
    assert j.offer(A, 5 * P).verdict is Verdict.TAKEN, "an evicted stamp is not stale"


def test_drain_gives_up_everything_oldest_first():
    j = StampJoiner((A, B), max_pending=10)
    j.offer(A, 3 * P)
    j.offer(B, P)
    out = j.drain()
    assert stamps(out) == [(P, Why.DRAINED), (3 * P, Why.DRAINED)] and len(j) == 0 and j.last_ns == 3 * P
    assert out[0].missing == (A,) and out[1].missing == (B,)


@pytest.mark.parametrize("kwargs, needle", [
    ({"topics": ()}, "topics=()"),
    ({"topics": (A, A)}, "distinct"),
    ({"max_pending": 0}, "max_pending=0"),
    ({"duplicates": "merge"}, "duplicates='merge'"),
    ({"reorder_ns": -1}, "reorder_ns=-1"),
    ({"max_ahead_ns": float("nan")}, "max_ahead_ns=nan"),
    ({"slot_ns": -1}, "slot_ns=-1"),
])
def test_bad_settings_are_named(kwargs, needle):
    args = {"topics": (A, B), "max_pending": 10, **kwargs}
    with pytest.raises(ValueError, match=needle.replace("(", r"\(").replace(")", r"\)")):
        StampJoiner(args.pop("topics"), **args)
    with pytest.raises(ValueError, match="'/z' is not one of"):
        StampJoiner((A,), max_pending=1).offer("/z", 0)


def test_a_second_stamp_of_a_tick_is_a_stray_whichever_comes_first_and_the_tick_leaves_once():
    """A writer stamping 1 ns off a tick (the grid check lets ±12 ns through) made a set of its own:
    it held the real tick back, left incomplete beside it, and a consumer gave out two results in
    one tick. With ``slot_ns`` it leaves as STRAY, never delaying or replacing the real tick."""
    # ahead of the real tick (another writer's, sent early): the real one leaves at once, complete
    j = StampJoiner((A, B, C), max_pending=10, reorder_ns=3 * P, slot_ns=P / 2)
    j.offer(A, P - 1, "stray")
    j.offer(B, P - 1, "stray")
    j.offer(A, P)
    j.offer(B, P)
    out = j.offer(C, P).out
    assert stamps(out) == [(P - 1, Why.STRAY), (P, Why.COMPLETE)]
    assert out[0].twin_ns == P and out[0].parts == {A: "stray", B: "stray"} and out[1].previous_ns == -1
    assert j.last_ns == P
    # after the real tick's first message: it waits for its own, then the stray goes
    j.offer(A, 2 * P)
    j.offer(B, 2 * P + 1, "stray")
    j.offer(B, 2 * P)
    out = j.offer(C, 2 * P).out
    assert stamps(out) == [(2 * P, Why.COMPLETE), (2 * P + 1, Why.STRAY)] and out[1].twin_ns == 2 * P
    # a whole tick's stray beside a tick that left: each message a stray of it, no tick given out
    for t in (A, B):
        j.offer(t, 3 * P)
    j.offer(C, 3 * P)
    out = [x for t in (A, B, C) for x in j.offer(t, 3 * P + 2).out]
    assert stamps(out) == [(3 * P + 2, Why.STRAY)] * 3 and len(j) == 0
    # both incomplete, one message each: given up once, the tick said missing by the older
    j.offer(A, 4 * P - 1)
    j.offer(B, 4 * P)
    out = [x for k in (5, 6, 7) for t in (A, B, C) for x in j.offer(t, k * P).out]
    assert stamps(out)[:2] == [(4 * P, Why.STRAY), (4 * P - 1, Why.OVERTAKEN)]
    assert [s for s, why in stamps(out) if why is not Why.STRAY] == [4 * P - 1, 5 * P, 6 * P, 7 * P]


def test_without_a_slot_two_stamps_of_a_tick_are_two_ticks():
    j = StampJoiner((A, B), max_pending=10, reorder_ns=P)
    j.offer(A, P - 1)
    j.offer(A, P)
    out = j.offer(B, P).out
    assert stamps(out) == []  # the incomplete older one holds the real tick for the reorder horizon
    out = [x for t in (A, B) for x in j.offer(t, 2 * P).out]
    assert stamps(out) == [(P - 1, Why.OVERTAKEN), (P, Why.COMPLETE), (2 * P, Why.COMPLETE)]


def test_a_stray_rule_never_takes_a_new_phase_a_restart_or_a_drained_tick_for_a_stray():
    """The slot's edges (an outside reviewer's): a new phase (``new_phase``: a machine's next episode
    a few ms after the last one's end) and a stream started again (``start_at``) begin with a tick,
    not a stray of what left before; of two incomplete sets of one tick the one with more messages
    speaks for it; ``drain`` gives a tick out once."""
    j = StampJoiner((A, B), max_pending=10, reorder_ns=P, slot_ns=P / 4)
    for t in (A, B):
        j.offer(t, 0)
    j.new_phase(10)
    out = [x for t in (A, B) for x in j.offer(t, 10).out]
    assert stamps(out) == [(10, Why.COMPLETE)]
    j.start_at(15)
    out = [x for t in (A, B) for x in j.offer(t, 15).out]
    assert stamps(out) == [(15, Why.COMPLETE)]
    # the real tick lost one message, a stray 1 ns on carries one: the real tick is the one said missing
    j = StampJoiner((A, B, C), max_pending=10, reorder_ns=P, slot_ns=P / 4)
    j.offer(A, P)
    j.offer(B, P)
    j.offer(C, P + 1, "stray")
    out = [x for t in (A, B, C) for x in j.offer(t, 2 * P).out]
    assert stamps(out) == [(P + 1, Why.STRAY), (P, Why.OVERTAKEN), (2 * P, Why.COMPLETE)]
    assert out[1].missing == (C,) and out[0].twin_ns == P
    # drained: one set per tick, the fuller one
    j.offer(A, 3 * P)
    j.offer(B, 3 * P)
    j.offer(A, 3 * P - 1, "stray")
    assert stamps(j.drain()) == [(3 * P - 1, Why.STRAY), (3 * P, Why.DRAINED)]
