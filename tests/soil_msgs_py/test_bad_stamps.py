"""Stamps the graph cannot mean, and JSON nobody should have to decode, are refused where
messages are parsed: a ValueError naming topic, field and value, never a crash further on
(a bag's log time, a log line, a recursion while decoding)."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.episode import EpisodeMeta
from soil_msgs_py.params import KNOWN_PARAMS
from soil_bag_tools.recorder import decode_stamp

META = EpisodeMeta("Clay", 40.0, "fee", 3, 0.5, 0.1, 2.0, source="soil_sim_node")
HUGE_SECONDS = (1e308, 2.0**63, 2.0**31, -1.0)


def _labelled_known(sec: float, nanosec: float = 0.0):
    msg = M.build_message(M.TYPESTORE, T.KNOWN.name, 0, [0.1] * len(KNOWN_PARAMS))
    msg.data[0], msg.data[1] = sec, nanosec
    return msg


@pytest.mark.parametrize("sec", HUGE_SECONDS)
def test_labelled_stamp_seconds_beyond_the_graphs_range_are_refused(sec):
    msg = _labelled_known(sec)
    with pytest.raises(ValueError, match=rf"{T.KNOWN.name}: .*stamp_sec={re.escape(repr(sec))}"):
        M.parse_message(T.KNOWN.name, msg)
    assert M.labelled_stamp(msg) is None


def test_labelled_nanosec_of_a_whole_second_or_more_is_refused():
    with pytest.raises(ValueError, match=r"stamp_nanosec=1000000000.0"):
        M.parse_message(T.KNOWN.name, _labelled_known(5.0, 1e9))


def test_the_largest_stamp_the_graph_can_mean_still_parses():
    sec = 2**31 - 1
    stamp, _ = M.parse_message(T.KNOWN.name, _labelled_known(float(sec), 999_999_999.0))
    assert stamp == sec * M.NS_PER_S + 999_999_999 == M.MAX_STAMP_NS


@pytest.mark.parametrize("sec, nanosec, field", [
    (0, 1_000_000_000, "nanosec=1000000000"),
    (0, 2**32 - 1, "nanosec=4294967295"),
    (-1, 0, "sec=-1"),
])
def test_header_stamps_out_of_range_are_refused_naming_topic_and_field(sec, nanosec, field):
    msg = M.build_message(M.TYPESTORE, T.CHASSIS_POSE.name, 0, [1.0, 2.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    with pytest.raises(ValueError, match=rf"{T.CHASSIS_POSE.name}: .*header.stamp.{field}"):
        M.parse_message(T.CHASSIS_POSE.name, msg)


@pytest.mark.parametrize("sec", (1e308, 2.0**63))
def test_the_recorder_never_gets_a_stamp_mcap_cannot_hold(sec):
    """The recorder files a labelled array by its stamp; one beyond 64 bits crashed the bag writer."""
    raw = M.TYPESTORE.serialize_cdr(_labelled_known(sec), T.KNOWN.msgtype)
    assert decode_stamp(T.KNOWN.name, T.KNOWN.msgtype, raw) is None
    assert decode_stamp(T.ESTIMATE.name, T.ESTIMATE.msgtype, raw) is None  # any labelled array


@pytest.mark.parametrize("depth", (5_000, 100_000))  # within the size bound (the decoder recursed), beyond it
def test_deeply_nested_json_command_is_a_value_error_naming_the_topic(depth):
    text = '{"action": "start", "soil": ' + "[" * depth + "]" * depth + "}"
    with pytest.raises(ValueError, match=G.SIM_COMMAND_TOPIC):
        G.SimCommand.from_json(text)
    with pytest.raises(ValueError, match=G.SIM_STATUS_TOPIC):
        G.EpisodeEvent.from_json("[" * depth)


def test_nesting_is_measured_outside_strings():
    assert G._nesting_depth('{"a": "[[[\\"{{", "b": [[1]]}') == 3
    assert G.SimCommand.from_json(json.dumps({"action": "start", "soil": "[" * 1000})).overrides["soil"] == "[" * 1000
    with pytest.raises(ValueError, match=rf"nested {G.MAX_JSON_DEPTH + 1} deep"):
        G.SimCommand.from_json('{"action": "start", "soil": ' + "[" * G.MAX_JSON_DEPTH + "]" * G.MAX_JSON_DEPTH + "}")


def test_oversized_json_is_refused_before_decoding():
    text = json.dumps({"action": "start", "soil": "x" * (G.MAX_JSON_CHARS + 1)})
    with pytest.raises(ValueError, match=rf"{G.SIM_COMMAND_TOPIC}: .*{len(text)} characters"):
        G.SimCommand.from_json(text)


def test_json_that_is_not_text_is_a_value_error():
    with pytest.raises(ValueError, match=G.SIM_COMMAND_TOPIC):
        G.SimCommand.from_json(None)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=G.SIM_COMMAND_TOPIC):
        G.SimCommand.from_json('{"action": "start", "seed": ' + "9" * 5000 + "}")  # past int digit limit


@pytest.mark.parametrize("key", ("first_stamp_ns", "last_stamp_ns"))
def test_status_event_stamps_beyond_the_graphs_range_are_refused(key):
    end = G.EpisodeEvent(G.EVENT_EPISODE_END, 0, META.name, META, 0, 120, 1, 120, "completed")
    data = {**json.loads(end.to_json()), key: 2**63}
    with pytest.raises(ValueError, match=f"{key}={2**63}"):
        G.EpisodeEvent.from_json(json.dumps(data))


def test_valid_stamps_round_trip_unchanged():
    for ns in (0, 1, M.NS_PER_S - 1, 16_666_666, M.MAX_STAMP_NS):
        msg = M.build_message(M.TYPESTORE, T.CHASSIS_TWIST.name, ns, [0.5, 0.0])
        assert M.parse_message(T.CHASSIS_TWIST.name, msg)[0] == ns
        labelled = M.make_labelled(M.TYPESTORE, ns, ("a",), np.array([1.0]))
        assert M.parse_labelled(labelled, ("a",))[0] == ns
