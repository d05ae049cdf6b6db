"""Property-based tests of the contract's parsers and gates: whatever arrives, the answer is
either a value in range or the documented ValueError, never another exception.

Derandomized and without an example database, so a run is reproducible; examples are few
(the suite runs on two shared cores) and no deadline (the machine is noisy)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.episode import EpisodeMeta
from soil_msgs_py.stamp_join import DUPLICATE_POLICIES, StampJoiner, Verdict, Why

FUZZ = settings(max_examples=150, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])
META = EpisodeMeta("Clay", 40.0, "fee", 3, 0.5, 0.1, 2.0, source="soil_sim_node")
MAX_SEC = M.MAX_STAMP_NS // M.NS_PER_S

any_float = st.floats(allow_nan=True, allow_infinity=True)
stamp_like = st.one_of(any_float, st.integers(min_value=-(2**70), max_value=2**70),
                       st.sampled_from([2.0**31, 2.0**31 - 1, 2.0**63, 1e308, -1e308, 1e9, 1e9 - 1, -0.0]))
valid_ns = st.integers(min_value=0, max_value=M.MAX_STAMP_NS)


def _in_range(ns: int) -> bool:
    return isinstance(ns, int) and 0 <= ns <= M.MAX_STAMP_NS


# --- stamps ----------------------------------------------------------------------------

@FUZZ
@given(valid_ns)
def test_split_and_join_round_trip_every_valid_stamp(ns):
    sec, nanosec = M.split_ns(ns)
    assert 0 <= nanosec < M.NS_PER_S and 0 <= sec <= MAX_SEC
    assert M.checked_stamp(sec, nanosec) == ns
    assert M.checked_stamp(float(sec), float(nanosec)) == ns  # the labelled arrays' float fields


@FUZZ
@given(stamp_like, stamp_like)
def test_any_sec_nanosec_is_a_stamp_in_range_or_a_value_error(sec, nanosec):
    try:
        ns = M.checked_stamp(sec, nanosec, "/t", "stamp.")
    except ValueError as err:
        assert "/t" in str(err) and "stamp." in str(err)
        return
    assert _in_range(ns)
    assert sec == int(sec) and nanosec == int(nanosec) and 0 <= nanosec < M.NS_PER_S


@FUZZ
@given(stamp_like, stamp_like)
def test_header_stamps_of_any_value_parse_in_range_or_raise_value_error(sec, nanosec):
    msg = M.build_message(M.TYPESTORE, T.CHASSIS_POSE.name, 0, [1.0, 2.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    try:
        ns, values = M.parse_message(T.CHASSIS_POSE.name, msg)
    except ValueError as err:
        assert T.CHASSIS_POSE.name in str(err)
        return
    assert _in_range(ns) and values.tolist() == [1.0, 2.0]


# --- labelled arrays -----------------------------------------------------------------------

labels = st.lists(st.text(min_size=1, max_size=6), min_size=0, max_size=4).map(tuple)


@FUZZ
@given(labels, labels, st.lists(any_float, max_size=8), stamp_like, stamp_like, st.integers(-2, 12), st.booleans())
def test_parse_labelled_of_anything_is_values_or_a_value_error(want, have, data, sec, nanosec, size, resize):
    msg = M.make_labelled(M.TYPESTORE, 0, have, np.zeros(len(have)))
    msg.data = np.array([sec, nanosec, *data], dtype=np.float64)
    if resize:
        msg.layout.dim[0].size = size
    try:
        ns, values = M.parse_labelled(msg, want, "/x")
    except ValueError as err:
        assert str(err).startswith("/x: ")
        return
    assert _in_range(ns) and len(values) == len(want)
    assert M.labelled_stamp(msg) == (ns if want else None)  # (it files arrays that carry a payload)


@FUZZ
@given(valid_ns, st.lists(st.floats(allow_nan=False), min_size=1, max_size=5))
def test_make_and_parse_labelled_round_trip(ns, values):
    names = tuple(f"f{i}" for i in range(len(values)))
    got_ns, got = M.parse_labelled(M.make_labelled(M.TYPESTORE, ns, names, values), names)
    assert got_ns == ns and got.tolist() == values


# --- JSON commands and status --------------------------------------------------------------

# huge integers too: JSON has no bound on them, and one of 400 digits has no float (OverflowError)
json_leaf = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=8),
                      st.integers(min_value=10**300, max_value=10**400), st.integers(max_value=-10**300))
json_value = st.recursive(json_leaf, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)), max_leaves=20)
command_like = st.fixed_dictionaries(
    {"action": st.one_of(st.sampled_from(G.ACTIONS), json_value)},
    optional={k: json_value for k in G.START_FIELDS})


def _nested(depth: int, opener: str) -> str:
    """Arrays or objects ``depth`` deep."""
    return "[" * depth + "]" * depth if opener == "[" else '{"a":' * depth + "1" + "}" * depth


def _parsed_or_refused(parse, text: str, topic: str):
    """``parse(text)``, or None when it refused the text with a ValueError naming ``topic``."""
    try:
        return parse(text)
    except ValueError as err:
        assert str(err).startswith(topic), str(err)
        return None


def _texts(structured):
    return st.one_of(st.text(max_size=200), json_value.map(json.dumps), structured.map(json.dumps),
                     st.builds(_nested, st.integers(0, 50_000), st.sampled_from("[{")))


@FUZZ
@given(_texts(command_like))
def test_sim_command_of_any_text_is_a_command_or_a_value_error(text):
    cmd = _parsed_or_refused(G.SimCommand.from_json, text, G.SIM_COMMAND_TOPIC)
    if cmd is not None:
        assert cmd.action in G.ACTIONS and set(cmd.overrides) <= set(G.START_FIELDS)
        assert G.SimCommand.from_json(cmd.to_json()) == cmd


_END = json.loads(G.EpisodeEvent(G.EVENT_EPISODE_END, 0, META.name, META, 0, 120, 1, 120, "completed").to_json())
event_like = st.builds(lambda changes: {**_END, **changes}, st.dictionaries(
    st.sampled_from(sorted(_END)), json_value, max_size=3)) | st.builds(
    lambda meta_changes: {**_END, "meta": {**_END["meta"], **meta_changes}},
    st.dictionaries(st.sampled_from(sorted(_END["meta"]) + [""]), json_value, max_size=2))


@FUZZ
@given(_texts(event_like))
def test_status_event_of_any_text_is_an_event_or_a_value_error(text):
    ev = _parsed_or_refused(G.EpisodeEvent.from_json, text, G.SIM_STATUS_TOPIC)
    if ev is not None:
        assert ev.event in G.EVENTS and _in_range(ev.first_stamp_ns)
        assert ev.last_stamp_ns == -1 or _in_range(ev.last_stamp_ns)


def test_json_bounds_let_every_real_message_through():
    end = G.EpisodeEvent(G.EVENT_EPISODE_END, 0, META.name, META, 0, 120, 1, 120, "completed",
                         stats={"period": {"n": 119, "p50_ms": 16.7}, "late_commands": 0})
    assert G.EpisodeEvent.from_json(end.to_json()) == end
    assert G.MAX_JSON_DEPTH >= 4 and G.MAX_JSON_CHARS >= 10 * len(end.to_json())


# --- the stamp joiner -----------------------------------------------------------------------

TOPICS = ("/a", "/b", "/c")
offers = st.lists(st.tuples(st.sampled_from(TOPICS), st.integers(-5, 60), st.booleans()), max_size=80)
joiner_settings = st.fixed_dictionaries({
    "max_pending": st.integers(1, 6),
    "reorder_ns": st.integers(0, 5),
    "duplicates": st.sampled_from(DUPLICATE_POLICIES),
    "restart_back_ns": st.one_of(st.none(), st.integers(0, 20)),
    "max_ahead_ns": st.one_of(st.none(), st.integers(0, 10)),
    "restart_after_refused": st.integers(0, 6),
})


@FUZZ
@given(joiner_settings, st.one_of(st.none(), st.integers(0, 20)), offers)
def test_joiner_never_raises_releases_in_order_and_bounds_memory(kw, first, seq):
    j = StampJoiner(TOPICS, **kw)
    j.reset(first)
    last_in_order = j.last_ns
    for topic, stamp, bad in seq:
        before = j.last_ns
        verdict, out = j.offer(topic, stamp, (topic, stamp), bad="bad" if bad else "")
        assert len(j) <= kw["max_pending"]
        if verdict in (Verdict.STALE, Verdict.FUTURE):
            assert out == [] and j.last_ns == before  # a refused message changes nothing
        if verdict is Verdict.RESTART:
            last_in_order = stamp - 1
        for joined in out:
            assert set(joined.parts) <= set(TOPICS)
            assert all(p == (t, joined.stamp_ns) for t, p in joined.parts.items())
            assert joined.complete == (joined.why is Why.COMPLETE) or joined.why is Why.EVICTED
            if joined.why is not Why.EVICTED:
                assert joined.stamp_ns > last_in_order
                last_in_order = joined.stamp_ns
    drained = j.drain()
    assert [d.stamp_ns for d in drained] == sorted(d.stamp_ns for d in drained) and len(j) == 0


@FUZZ
@given(st.integers(0, 10**6), st.lists(st.integers(2 * 10**6, M.MAX_STAMP_NS), max_size=2), st.integers(1, 40))
def test_with_max_ahead_stray_future_stamps_never_stop_a_steady_stream(first, strays, ticks):
    """A stream one unit apart with a stray far pair or two in between: every tick still leaves."""
    j = StampJoiner(("/a", "/b"), max_pending=8, max_ahead_ns=5, restart_after_refused=6)
    j.reset(first)
    left = []
    for k in range(ticks):
        for s in strays if k == 1 else ():
            j.offer("/a", s)
            j.offer("/b", s)
        left += [x.stamp_ns for x in j.offer("/a", first + k).out + j.offer("/b", first + k).out if x.complete]
    assert left == list(range(first, first + ticks))


def test_restart_after_refused_follows_a_stream_only_once_it_kept_being_refused():
    j = StampJoiner(("/a",), max_pending=4, max_ahead_ns=10, restart_after_refused=3)
    j.reset(100)
    assert [x.stamp_ns for x in j.offer("/a", 100).out] == [100]
    assert [j.offer("/a", s).verdict for s in (5000, 50)] == [Verdict.FUTURE, Verdict.STALE]
    assert j.offer("/a", 101).verdict is Verdict.TAKEN  # taken: the count starts again
    assert [j.offer("/a", s).verdict for s in (7000, 7001)] == [Verdict.FUTURE, Verdict.FUTURE]
    verdict, out = j.offer("/a", 7002)
    assert verdict is Verdict.RESTART and [x.stamp_ns for x in out] == [7002] and j.last_ns == 7002


@pytest.mark.parametrize("count", [-1, 1.5, True])
def test_bad_restart_after_refused_is_named(count):
    with pytest.raises(ValueError, match=f"restart_after_refused={count!r}"):
        StampJoiner(TOPICS, max_pending=2, max_ahead_ns=1, restart_after_refused=count)



def test_a_number_too_large_for_a_float_in_a_command_is_refused_naming_the_field():
    """A 400-digit integer has no float: checked as one it raised OverflowError, which a node does
    not catch as a bad message (the simulator died, and the launch with it)."""
    import pytest

    huge = "9" * 400
    for text, needle in ((f'{{"action": "start", "seed": {huge}}}', "seed=9999"),
                         (f'{{"action": "start", "target_depth_m": {huge}}}', "target_depth_m=9999"),
                         (f'{{"action": "start", "patches": [{{"x_start_m": {huge}, "soil": "Clay", '
                          '"relative_density_pct": 50}]}', "patches[0].x_start_m=")):
        with pytest.raises(ValueError, match=needle.replace("[", r"\[").replace("]", r"\]")):
            G.SimCommand.from_json(text)
    with pytest.raises(ValueError, match=r"seed=9223372036854775808 must be at most 2\*\*63 - 1"):
        G.SimCommand.from_json('{"action": "start", "seed": 9223372036854775808}')
    with pytest.raises(ValueError, match=r"seed=-1 must be an integer in \[0, 2\*\*63 - 1\]"):
        G.SimCommand.from_json('{"action": "start", "seed": -1}')
