"""A second publisher claiming the recorded publisher's stamps never changes what a bag says.

Core tests feed ``recorder.Recorder`` the sample bag's messages, each tagged like DDS tags
it (the writer's publication sequence number), with an intruder's messages of the same
stamps and NaN/inf/1e308 values delivered *before* the real ones, and off-grid stamps
in between. The live test does the same over DDS: a probe node reacts to each ``/clock``
of a replay by publishing the next ticks' ``/blade/force`` before the player does.
"""
from __future__ import annotations

import json
import math
import shutil
import signal
from dataclasses import replace

import numpy as np
import pytest
import yaml

from soil_bag_tools import bag_io, journal, recorder
from soil_msgs_py import messages as M
from soil_msgs_py.topics import EPISODE_TOPICS, ESTIMATE_FIELDS
from tests.soil_bag_tools.test_bag_tools import (  # noqa: F401 - listener is a fixture
    SAMPLE, TICK_NS, ListLog, _events, assert_same_episode, finish, listener, next_domain_id, reap, start,
)

pytestmark = [pytest.mark.live, pytest.mark.timeout(180)]

BAD_VALUES = (math.nan, math.inf, 1e308, -math.inf)
SPOOFED = ("/blade/force", "/soil/known_params", "/chassis/twist")


def spoof(topic: str, stamp: int, k: int) -> bytes:
    """A message of ``topic`` claiming ``stamp`` with hostile values."""
    width = M.FIELDS[topic].width
    values = [BAD_VALUES[(k + i) % len(BAD_VALUES)] for i in range(width)]
    msg = M.build_message(M.TYPESTORE, topic, stamp, values)
    return bytes(M.TYPESTORE.serialize_cdr(msg, M.FIELDS[topic].topic.msgtype))


def recorder_info(bag) -> dict:
    custom = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["custom_data"]
    return json.loads(custom[journal.RECORDER_INFO_KEY])


class Feed:
    """Hands messages to a Recorder the way record_node does: one sequence counter per writer
    and topic (the intruder's has published before, as any writer's counter may have)."""

    FIRST_SEQ = {"sim": 1, "estimator": 1, "intruder": 1000, "restarted": 1, "controller": 1}

    def __init__(self, rec: recorder.Recorder, with_sequence: bool = True):
        self.rec, self.with_sequence, self.seq = rec, with_sequence, {}

    def send(self, writer: str, topic: str, raw: bytes) -> None:
        n = self.seq[(writer, topic)] = self.seq.get((writer, topic), self.FIRST_SEQ[writer] - 1) + 1
        self.rec.on_message(topic, raw, 0, publication_seq=n if self.with_sequence else None)


def record_with_intruder(tmp_path, *, with_sequence: bool, n_ticks: int = 60, every: int = 3):
    """The sample's first ``n_ticks`` with an intruder claiming every ``every``-th tick first."""
    loaded, start_ev, end_ev = _events(SAMPLE)
    msgs = loaded.messages[: 10 * n_ticks]
    end_ev = replace(end_ev, last_stamp_ns=msgs[-1][0], ticks=n_ticks)
    log = ListLog()
    rec = recorder.Recorder(tmp_path, loaded.topics, log=log, clock=lambda: 0.0)
    feed = Feed(rec, with_sequence)
    rec.on_status(start_ev.to_json())
    spoofs = 0
    for t, topic, raw in msgs:
        tick = (t - msgs[0][0]) // TICK_NS
        if topic in SPOOFED and tick % every == 0:
            feed.send("intruder", topic, spoof(topic, t, tick))  # same stamp, before the real one
            spoofs += 1
        if topic == "/clock" and tick % 7 == 1:
            off = t + TICK_NS // 2  # inside the episode's range, between two ticks
            feed.send("intruder", "/blade/force", spoof("/blade/force", off, tick))
            feed.send("intruder", "/clock", bytes(M.TYPESTORE.serialize_cdr(
                M.build_message(M.TYPESTORE, "/clock", t + 3), loaded.topics["/clock"])))
        feed.send("sim", topic, raw)
    rec.on_status(end_ev.to_json())
    (result,) = rec.finished
    return rec, result, log, spoofs, n_ticks


def test_intruder_claiming_real_stamps_first_is_not_recorded(tmp_path):
    rec, result, log, spoofs, n = record_with_intruder(tmp_path, with_sequence=True)
    assert_same_episode(bag_io.read_episode(result.path), bag_io.read_episode(SAMPLE), n)
    info = recorder_info(result.path)
    assert sum(info["conflicts"].values()) == spoofs
    assert set(info["conflicts"]) == set(SPOOFED)
    assert info["off_grid"] == {"/blade/force": 9, "/clock": 9}
    warnings = [m for lvl, m in log.lines if lvl == "warning"]
    assert any(all(t in m for t in SPOOFED) for m in warnings), warnings  # one warning names every topic
    assert any("off the 60 Hz grid" in m and "/clock" in m for m in warnings), warnings


def test_the_claims_of_an_hour_long_episode_take_a_byte_per_tick_and_topic():
    """A mapping entry per message grew a recorder by 7 MB per minute of episode (an outside soak
    test: +450 MB over an hour); the claims on the tick grid now take one byte each, and stamps off
    it or past the longest episode (a foreign writer's) are still counted."""
    from soil_msgs_py.params import tick_stamp_ns

    claims, ticks = recorder.StampClaims(), int(3600 * 60)
    topics = [t.name for t in EPISODE_TOPICS]
    for k in range(0, ticks, 7):  # (every 7th tick: the arrays reach their full length all the same)
        for topic in topics:
            assert claims.add(topic, tick_stamp_ns(k), k) == 1
    assert claims.add(topics[0], tick_stamp_ns(7), 7) == 2  # a second message for a stamp: counted
    assert max(len(a) for a in claims.per_tick.values()) <= recorder.StampClaims.MAX_TICKS and not claims.other
    assert claims.add("/x", 123, None) == 1 and claims.add("/x", 123, None) == 2  # off the grid
    assert claims.add(topics[0], 10**18, 10**13) == 1 and max(len(a) for a in claims.per_tick.values()) <= ticks + 1


def test_a_recorder_keeps_the_newest_results_only_and_every_bag(tmp_path, monkeypatch):
    """Three passes of a replay started over, a bag each: the recorder keeps the newest
    ``FINISHED_KEPT`` results for its caller (it kept every one: a shift's worth grew without end,
    an outside tester's long run), and every bag is on disk."""
    monkeypatch.setattr(recorder, "FINISHED_KEPT", 2)
    loaded, start_ev, end_ev = _events(SAMPLE)
    n_ticks = 10
    msgs = loaded.messages[: 10 * n_ticks]
    end_ev = replace(end_ev, last_stamp_ns=msgs[-1][0], ticks=n_ticks)
    rec = recorder.Recorder(tmp_path, loaded.topics, log=ListLog(), clock=lambda: 0.0)
    feed = Feed(rec)
    for _ in range(3):
        rec.on_status(start_ev.to_json())
        for _, topic, raw in msgs:
            feed.send("sim", topic, raw)
        rec.on_status(end_ev.to_json())
    bags = sorted(p for p in tmp_path.iterdir() if p.is_dir())
    names = [start_ev.name, f"{start_ev.name}_2", f"{start_ev.name}_3"]
    assert [b.name for b in bags] == names
    assert [r.path.name for r in rec.finished] == names[1:]
    for bag in bags:
        assert len(bag_io.read_episode(bag).stamps_ns) == n_ticks


def test_a_recorder_of_one_launch_records_no_episode_of_another_graph_on_its_topics(tmp_path):
    """Two launches in one namespace of one domain: the one refused had recorded the other's episode
    into its directory (an outside tester's, 2 of 2). Each launch gives its simulator and recorder an
    id; given one, the recorder takes episodes of that id only (a stray start without one, between
    episodes, had opened a bag of its own: the hostile test's)."""
    loaded, start_ev, end_ev = _events(SAMPLE)
    msgs = loaded.messages[: 10 * 30]
    end_ev = replace(end_ev, last_stamp_ns=msgs[-1][0], ticks=30)
    for graph, recorded in (("launch-other", False), ("launch-mine", True), ("", False)):
        log = ListLog()
        rec = recorder.Recorder(tmp_path / (graph or "none"), loaded.topics, log=log, clock=lambda: 0.0,
                                graph_id="launch-mine")
        feed = Feed(rec)
        rec.on_status(replace(start_ev, graph=graph).to_json())
        for _, topic, raw in msgs:
            feed.send("sim", topic, raw)
        rec.on_status(replace(end_ev, graph=graph).to_json())
        rec.close()
        assert bool(rec.finished) == recorded and bool(list((tmp_path / (graph or "none")).iterdir())) == recorded
        said = [m for lvl, m in log.lines if lvl == "warning" and "from another graph (" in m
                and "none of its episodes is recorded" in m]
        assert len(said) == (0 if recorded else 1), log.lines  # said once per episode, not per event


def test_a_stray_episode_event_mid_episode_neither_cuts_nor_ends_the_bag(tmp_path):
    """One foreign episode_start mid-episode had closed the launch's bag cut short and recorded the
    rest under the stranger's name, losing a third of its ticks as off its grid (an outside
    tester's); another episode's episode_end must not end it either. Given the launch's graph id the
    recorder ignores both, saying so; given none (started by hand) it holds the start (only ticks
    stamped back at its start would open it: the launch's simulator started again by hand) and
    ignores the end. Then that restart: the first run's bag cut short, the new one beside it."""
    loaded, start_ev, end_ev = _events(SAMPLE)
    n = 60
    msgs = loaded.messages[: 10 * n]
    start_ev, end_ev = replace(start_ev, graph="launch-mine"), replace(end_ev, graph="launch-mine")
    end_ev = replace(end_ev, last_stamp_ns=msgs[-1][0], ticks=n)
    stray_start = replace(start_ev, name="foreign_episode", episode=7, graph="",
                          meta=replace(start_ev.meta, target_speed_m_s=2.0, target_depth_m=0.6))
    stray_end = replace(end_ev, name="other_graph_episode", episode=7, graph="")
    for graph_id, held in (("launch-mine", "none of its episodes is recorded"),
                           ("", "held until its ticks show a simulator started over")):
        log = ListLog()
        rec = recorder.Recorder(tmp_path / (graph_id or "none"), loaded.topics, log=log, clock=lambda: 0.0,
                                graph_id=graph_id)
        feed = Feed(rec)
        rec.on_status(start_ev.to_json())
        for i, (_, topic, raw) in enumerate(msgs):
            if i == len(msgs) // 2:
                rec.on_status(stray_start.to_json())
                rec.on_status(stray_end.to_json())
            feed.send("sim", topic, raw)
        rec.on_status(end_ev.to_json())
        rec.close()
        (result,) = rec.finished
        assert result.path.name == start_ev.name and [p.name for p in result.path.parent.iterdir()] == [start_ev.name]
        assert_same_episode(bag_io.read_episode(result.path), bag_io.read_episode(SAMPLE), n)
        said = [m for lvl, m in log.lines if lvl == "warning"]
        assert any("foreign_episode" in m and held in m for m in said), said
        assert any("other_graph_episode" in m and ("ignored" in m or "not recorded" in m or "none of its" in m)
                   for m in said), said

    # the launch's simulator killed at half its episode and started again by hand (no graph id): its
    # ticks from the episode's start again open its bag
    log = ListLog()
    rec = recorder.Recorder(tmp_path / "restart", loaded.topics, log=log, clock=lambda: 0.0)  # (by hand: no id)
    feed = Feed(rec)
    rec.on_status(start_ev.to_json())
    for _, topic, raw in msgs[: len(msgs) // 2]:
        feed.send("sim", topic, raw)
    rec.on_status(replace(start_ev, graph="").to_json())
    for _, topic, raw in msgs:
        feed.send("restarted", topic, raw)
    rec.on_status(replace(end_ev, graph="").to_json())
    rec.close()
    first, second = sorted(rec.finished, key=lambda r: r.path.name)
    assert (first.ticks, second.ticks) == (n // 2, n), (first, second)
    assert recorder_info(first.path)["end"] == "cut_short"
    assert_same_episode(bag_io.read_episode(second.path), bag_io.read_episode(SAMPLE), n)


def test_a_long_conversion_says_it_is_at_work():
    """What a stopping recorder says while it makes a big bag: soil_launch waits for it while it
    reports (tests/soil_bringup/test_launch.py), where it had killed it mid-bag."""
    import time

    said: list[float] = []
    with recorder.reporting(said.append, every_s=0.05):
        time.sleep(0.6)
    heard = len(said)
    time.sleep(0.2)
    assert heard >= 3 and len(said) == heard and said == sorted(said)  # while at work, and not after


@pytest.mark.parametrize("values", [None, (1e30, -1e30), (5e9, 0.0), (5e-324, 0.0)],
                         ids=["non-finite", "finite-absurd", "one-absurd", "subnormal"])
def test_an_intruder_whose_counter_meets_the_players_is_refused_by_its_values(tmp_path, values):
    """At one tick the intruder's message carries the very sequence number the simulator's
    carries there and arrives first: by sequence either could continue the simulator's
    counter, so the values decide and the bag keeps the simulator's message. Finite garbage
    (1e30 N) is as implausible as a NaN: no graph value comes near 1e9 in SI, nor near a
    subnormal (5e-324 N)."""
    loaded, start_ev, end_ev = _events(SAMPLE)
    n = 30
    msgs = loaded.messages[: 10 * n]
    rec = recorder.Recorder(tmp_path, loaded.topics, log=ListLog(), clock=lambda: 0.0)
    feed = Feed(rec)
    rec.on_status(start_ev.to_json())
    for t, topic, raw in msgs:
        tick = (t - msgs[0][0]) // TICK_NS
        if topic == "/blade/force" and tick == 12:
            fake = spoof(topic, t, tick) if values is None else bytes(M.TYPESTORE.serialize_cdr(
                M.build_message(M.TYPESTORE, topic, t, values), M.FIELDS[topic].topic.msgtype))
            rec.on_message(topic, fake, 0, publication_seq=feed.seq[("sim", topic)] + 1)
        feed.send("sim", topic, raw)
    rec.on_status(replace(end_ev, last_stamp_ns=msgs[-1][0], ticks=n).to_json())
    (result,) = rec.finished
    assert_same_episode(bag_io.read_episode(result.path), bag_io.read_episode(SAMPLE), n)
    assert recorder_info(result.path)["conflicts"] == {"/blade/force": 1}


def test_without_sequence_numbers_the_plausible_claim_wins(tmp_path):
    """An rmw that gives no publication sequence number: nothing tells the writers apart, so
    the claim with plausible values (finite, below 1e9) is kept, then the first to arrive."""
    rec, result, log, spoofs, n = record_with_intruder(tmp_path, with_sequence=False, every=4)
    got, want = bag_io.read_episode(result.path), bag_io.read_episode(SAMPLE)
    assert len(got) == n and np.array_equal(got.stamps_ns, want.stamps_ns[:n])
    assert_same_episode(got, want, n)  # every spoof carries NaN, inf or 1e308 somewhere
    assert sum(recorder_info(result.path)["conflicts"].values()) == spoofs


def test_a_killed_recorder_journal_is_repaired_without_the_intruder(tmp_path):
    """The choice is made when the journal becomes a bag, so soil_bag_repair makes it too."""
    loaded, start_ev, _ = _events(SAMPLE)
    msgs = loaded.messages[: 10 * 30]
    rec = recorder.Recorder(tmp_path / "rec", loaded.topics, log=ListLog(), clock=lambda: 0.0)
    feed = Feed(rec)
    rec.on_status(start_ev.to_json())
    for t, topic, raw in msgs:
        if topic == "/blade/force":
            feed.send("intruder", topic, spoof(topic, t, 1))
        feed.send("sim", topic, raw)
    (session,) = rec.sessions
    session.journal.flush()  # what a SIGKILL leaves: flushed chunks, no footer
    partial = tmp_path / "killed" / (SAMPLE.name + bag_io.PARTIAL_SUFFIX)
    shutil.copytree(journal.partial_dir(tmp_path / "rec", session.name), partial)
    result = journal.journal_to_bag(partial)
    assert_same_episode(bag_io.read_episode(result.path), bag_io.read_episode(SAMPLE), 30)
    assert result.conflicts == {"/blade/force": 30}
    rec.close()


def test_recorded_replay_holds_only_the_players_data_with_an_intruder(listener, tmp_path):
    """Over DDS: for each /clock of a replay a probe publishes /blade/force for the next two
    ticks (before the player does) with hostile values, plus an off-grid one. The bag equals
    the sample and says how many claims it refused. (A probe whose counter matched the
    player's at a tick would be told apart there only by its non-finite values.)"""
    from rosgraph_msgs.msg import Clock

    from soil_msgs_py.ros_adapter import message_class, topic_qos

    domain = next_domain_id()
    lst = listener(domain, topics=(), status_sub=False)
    pub = lst.node.create_publisher(message_class("geometry_msgs/msg/WrenchStamped"), "/blade/force",
                                    topic_qos("/blade/force"))
    sent: set[int] = set()
    stamps = [int(s) for s in bag_io.read_episode(SAMPLE).stamps_ns]
    tick_of = {s: k for k, s in enumerate(stamps)}

    def on_clock(msg) -> None:
        k = tick_of.get(M.stamp_ns(msg.clock))
        if k is None or k + 2 >= len(stamps):
            return
        for stamp in (stamps[k + 1], stamps[k + 2], stamps[k] + TICK_NS // 2):  # two real ticks ahead, one off-grid
            if stamp not in sent:
                sent.add(stamp)
                k = len(sent)
                pub.publish(M.build_message(M.ros_message_classes(), "/blade/force", int(stamp),
                                            [BAD_VALUES[k % 4], BAD_VALUES[(k + 1) % 4]]))

    lst.node.create_subscription(Clock, "/clock", on_clock, topic_qos("/clock"))
    rec = start("soil_bag_record", "--out", tmp_path, domain=domain)
    player = None
    try:
        assert lst.wait_for(lambda: lst.status_pub.get_subscription_count() >= 1
                            and pub.get_subscription_count() >= 1, 20), "recorder never subscribed"
        for _ in range(50):  # the probe's writer has published before, as any writer may have
            pub.publish(M.build_message(M.ros_message_classes(), "/blade/force", 1, [0.0, 0.0]))
        # (--allow-other-publishers: the probe is the intruder the recorder must refuse, on purpose)
        player = start("soil_bag_play", SAMPLE, "--wait-for-subscribers", 1, "--allow-other-publishers", domain=domain)
        out = finish(player, timeout=60)
        assert player.returncode == 0, out
        bag = tmp_path / SAMPLE.name
        assert lst.wait_for(lambda: bag_io.is_bag(bag), 10), out
        rec.send_signal(signal.SIGINT)
        log = finish(rec)
    finally:
        reap(rec, player)
    assert rec.returncode == 0, log
    assert_same_episode(bag_io.read_episode(bag), bag_io.read_episode(SAMPLE))
    info = recorder_info(bag)
    assert info["conflicts"].get("/blade/force", 0) > 0, info
    assert info["off_grid"].get("/blade/force", 0) > 0, info
    assert "/blade/force" in log


def _estimate(stamp: int, value: float, *, broken: bool = False) -> bytes:
    from soil_msgs_py import topics as T

    msg = M.make_labelled(M.TYPESTORE, stamp, T.ESTIMATE_FIELDS, [value] * len(T.ESTIMATE_FIELDS))
    if broken:  # a layout no reader can index
        msg.layout.dim[0].size, msg.layout.dim[0].stride, msg.layout.data_offset = 4294967295, 0, 3
    return bytes(M.TYPESTORE.serialize_cdr(msg, "std_msgs/msg/Float64MultiArray"))


def _record_estimates(tmp_path, n: int, intrude):
    """The sample's first ``n`` ticks with the estimator's estimates (value: the tick) after each
    tick's /clock; ``intrude(feed, stamp, tick)`` acts first and returns True where the estimator
    skips the tick. Returns (bag, {stamp: value} the estimator published)."""
    from soil_msgs_py import topics as T

    loaded, start_ev, end_ev = _events(SAMPLE)
    msgs = loaded.messages[: 10 * n]
    end_ev = replace(end_ev, last_stamp_ns=msgs[-1][0], ticks=n)
    rec = recorder.Recorder(tmp_path, {**loaded.topics, T.ESTIMATE.name: T.ESTIMATE.msgtype},
                            log=ListLog(), clock=lambda: 0.0)
    feed = Feed(rec)
    rec.on_status(start_ev.to_json())
    published = {}
    for t, topic, raw in msgs:
        feed.send("sim", topic, raw)
        if topic != "/clock":
            continue
        tick = (t - msgs[0][0]) // TICK_NS
        if not intrude(feed, t, tick):
            published[t] = float(tick)
            feed.send("estimator", T.ESTIMATE.name, _estimate(t, float(tick)))
    rec.on_status(end_ev.to_json())
    rec.poll()
    (result,) = rec.finished
    return result.path, published


def test_labelled_extras_hold_only_the_estimators_messages(tmp_path):
    """/soil/estimate, filed by stamp: an intruder's estimates at stamps the estimator also
    sends, at stamps it skipped, off the grid and with a broken layout never enter the bag."""
    from soil_msgs_py import topics as T

    def intrude(feed, t, tick) -> bool:
        if tick % 5 == 2:  # ahead of the estimator, or at a tick it skips
            feed.send("intruder", T.ESTIMATE.name, _estimate(t, 1e308))
            feed.send("intruder", T.ESTIMATE.name, _estimate(t + TICK_NS // 2, 7.0))
            feed.send("intruder", T.ESTIMATE.name, _estimate(t, 3.0, broken=True))
        return tick % 10 == 7

    n = 40
    bag, published = _record_estimates(tmp_path, n, intrude)
    stamps, values = bag_io.read_labelled_topic(bag, T.ESTIMATE.name, T.ESTIMATE_FIELDS)
    assert dict(zip(stamps.tolist(), values[:, 0].tolist())) == published
    assert len(stamps) == len(published)
    info = recorder_info(bag)
    assert info["off_grid"].get(T.ESTIMATE.name) == n // 5
    assert info["conflicts"].get(T.ESTIMATE.name) == n // 5


def test_an_intruder_filling_a_skipped_tick_with_a_fitting_counter_is_refused(tmp_path):
    """The estimator skips ticks (a loaded machine); at each skipped tick an intruder's garbage
    estimate arrives carrying the very sequence number the estimator's next message will carry.
    By sequence alone it continues the estimator's counter (one number across two ticks), and
    judged in arrival order it would take the estimator's place and push the estimator's next
    message out as a stranger's. Judged as a whole, a writer's counter grows by exactly one per
    message, so the intruder's claim displaces the estimator's next one: the chain keeping the
    estimator's finite messages wins, and the bag holds every estimate the estimator sent (the
    last tick too, where nothing follows the intruder's claim: its values give it away)."""
    from soil_msgs_py import topics as T

    intrusions = []

    def intrude(feed, t, tick) -> bool:
        if tick % 6 != 3:
            return False
        fitting = feed.seq.get(("estimator", T.ESTIMATE.name), 0) + 1
        feed.rec.on_message(T.ESTIMATE.name, _estimate(t, BAD_VALUES[tick % 4]), 0, publication_seq=fitting)
        intrusions.append(t)
        return True

    bag, published = _record_estimates(tmp_path, 40, intrude)
    stamps, values = bag_io.read_labelled_topic(bag, T.ESTIMATE.name, T.ESTIMATE_FIELDS)
    assert dict(zip(stamps.tolist(), values[:, 0].tolist())) == published
    assert recorder_info(bag)["conflicts"].get(T.ESTIMATE.name) == len(intrusions)


def test_a_restarted_estimator_is_recorded_after_its_predecessor_but_an_intruder_among_it_is_not(tmp_path):
    """The estimator dies after tick 39 and a new one (a new counter from 1) publishes from
    tick 130, 1.5 s later: the bag keeps both. Judged as one chain the restarted counter, once
    past 40, continues the dead one's, and the heaviest chain took the old estimator's
    estimates with the new one's tail, refusing the rest of the new one's (or, cut there, the
    old one's, tied with the new one's first 40). An intruder's plausible estimates at ticks the
    restarted estimator skips are still refused."""
    from soil_msgs_py import topics as T

    intrusions, restarted = [], {}

    def intrude(feed, t, tick) -> bool:
        if tick >= 130:
            if tick % 7 == 3:  # the restarted estimator skips it; the intruder claims it
                feed.send("intruder", T.ESTIMATE.name, _estimate(t, 5.0))
                intrusions.append(t)
            else:
                feed.send("restarted", T.ESTIMATE.name, _estimate(t, float(tick)))
                restarted[t] = float(tick)
            return True
        return tick >= 40  # dead from tick 40

    bag, published = _record_estimates(tmp_path, 400, intrude)
    stamps, values = bag_io.read_labelled_topic(bag, T.ESTIMATE.name, T.ESTIMATE_FIELDS)
    assert len(published) == 40 and len(restarted) > 200 and intrusions
    assert dict(zip(stamps.tolist(), values[:, 0].tolist())) == {**published, **restarted}
    assert recorder_info(bag)["conflicts"] == {T.ESTIMATE.name: len(intrusions)}


class EndedEpisode:
    """The sample's first ``n`` ticks recorded with /soil/estimate as an extra topic on a fake
    clock (``now``), the episode ended; ``early`` estimates (of its first ticks) came before its
    end. ``estimate(k)`` sends tick k's estimate, ``stamps`` are the ticks' stamps."""

    def __init__(self, tmp_path, n: int, early: int = 0):
        from soil_msgs_py import topics as T

        loaded, start_ev, end_ev = _events(SAMPLE)
        msgs = loaded.messages[: 10 * n]
        self.now, self.log, self.topic = [0.0], ListLog(), T.ESTIMATE.name
        self.rec = recorder.Recorder(tmp_path, {**loaded.topics, self.topic: T.ESTIMATE.msgtype}, log=self.log,
                                     end_grace_s=4.0, clock=lambda: self.now[0])
        self.feed = Feed(self.rec)
        self.stamps = [t for t, topic, _ in msgs if topic == "/clock"]
        self.rec.on_status(start_ev.to_json())
        for _, topic, raw in msgs:
            self.feed.send("sim", topic, raw)
        for k in range(early):
            self.estimate(k)
        self.rec.on_status(replace(end_ev, last_stamp_ns=msgs[-1][0], ticks=n).to_json())

    def estimate(self, k: int) -> None:
        self.feed.send("estimator", self.topic, _estimate(self.stamps[k], float(k)))

    def recorded(self) -> list[int]:
        (result,) = self.rec.finished
        return bag_io.read_labelled_topic(result.path, self.topic, ESTIMATE_FIELDS)[0].tolist()


def test_a_lagging_estimator_still_streaming_is_not_cut_off(tmp_path):
    """The episode's ticks are complete; the estimator's estimates keep coming (a loaded
    machine), for longer than the end grace (5.8 s): the bag waits while they flow and closes
    once they were quiet for the grace."""
    ep = EndedEpisode(tmp_path, 30)
    for k in range(29):  # every tick but the last, each 0.2 s after the previous
        ep.now[0] += 0.2
        ep.estimate(k)
        assert ep.rec.poll() == [], f"closed while estimates still came, at tick {k}"
    ep.now[0] += recorder.EXTRA_TOPIC_GRACE_S + 0.01  # the last tick's estimate never comes
    ep.rec.poll()
    assert ep.recorded() == ep.stamps[:-1]


def test_a_lagging_estimator_that_pauses_between_bursts_is_not_cut_off(tmp_path):
    """An estimator seconds behind on a loaded machine sends its estimates in bursts: a pause of
    more than the short quiet grace while it is still far behind the last tick does not end the
    bag; once it is near the end, the short grace does."""
    n = 180
    ep = EndedEpisode(tmp_path, n, early=10)  # its first estimates came during the episode
    for k in range(10, n - 1):
        ep.now[0] += 1.5 if k in (10, 60, 100) else 0.01  # 1.5 s pauses while more than 1 s behind the last tick
        ep.rec.poll()
        assert not ep.rec.finished, f"closed at tick {k} while the estimator was {(n - k) / 60:.1f} s behind"
        ep.estimate(k)
    ep.now[0] += recorder.EXTRA_TOPIC_GRACE_S + 0.01  # near the end: the short grace
    ep.rec.poll()
    assert ep.recorded() == ep.stamps[:-1]


def test_extras_that_never_stop_are_cut_at_the_lag_limit_with_a_warning(tmp_path):
    """An estimator so far behind that its estimates keep coming, each within the quiet grace of
    the last, cannot hold the bag open for ever: it is finished at the lag limit, with what came
    by then and a warning naming the short topic."""
    n = 150  # more ticks than arrive within the lag limit, one per 0.9 of the quiet grace
    ep = EndedEpisode(tmp_path, n)
    sent = 0
    for k in range(n):
        ep.now[0] += recorder.EXTRA_TOPIC_GRACE_S * 0.9
        ep.estimate(k)
        ep.rec.poll()
        if ep.rec.finished:
            break
        sent += 1
    assert ep.rec.finished and recorder.EXTRA_TOPIC_LAG_LIMIT_S <= ep.now[0] < recorder.EXTRA_TOPIC_LAG_LIMIT_S + 1.0
    assert sent < n - 1
    got = ep.recorded()
    assert got == ep.stamps[:len(got)] and len(got) >= sent
    assert any("still arriving" in m and ep.topic in m for lvl, m in ep.log.lines if lvl == "warning"), ep.log.lines


def _replayed_with_estimates(tmp_path, n: int = 30):
    """A recorder of the sample's topics and /soil/estimate on a fake clock (``now``), the sample's
    first ``n`` ticks to replay (``msgs``, their /clock ``stamps``) and its events ended at tick n."""
    from soil_msgs_py import topics as T

    loaded, start_ev, end_ev = _events(SAMPLE)
    msgs = loaded.messages[: 10 * n]
    end_ev = replace(end_ev, last_stamp_ns=msgs[-1][0], ticks=n)
    now = [0.0]
    rec = recorder.Recorder(tmp_path, {**loaded.topics, T.ESTIMATE.name: T.ESTIMATE.msgtype}, log=ListLog(),
                            end_grace_s=4.0, clock=lambda: now[0])
    stamps = [t for t, topic, _ in msgs if topic == "/clock"]
    return rec, Feed(rec), now, msgs, stamps, start_ev, end_ev


def test_a_sparse_topic_of_the_next_replayed_bag_goes_to_its_own_bag(tmp_path):
    """Two bags played in a row (stamps restart at 0) with an extra topic that never reaches an
    episode's last stamp (the planner's targets, the map): the first bag waits out its end grace
    for it, and an outside tester found every message of the second episode filed into the first
    bag, the second's own bag empty of it. A stamp going back is the newer episode's."""
    from soil_msgs_py import topics as T

    rec, feed, now, msgs, stamps, start_ev, end_ev = _replayed_with_estimates(tmp_path)
    sparse = stamps[:-3:4]  # every 4th tick, never the last ones
    for episode, value in ((0, 1.0), (1, 2.0)):
        rec.on_status(replace(start_ev, episode=episode).to_json())
        for t, topic, raw in msgs:
            feed.send("sim", topic, raw)
            if topic == "/clock" and t in sparse:
                feed.send("estimator", T.ESTIMATE.name, _estimate(t, value))
        rec.on_status(replace(end_ev, episode=episode).to_json())
        now[0] += 1.0  # within the first bag's grace: it still waits for its extra topic
    now[0] += recorder.END_GRACE_S + recorder.EXTRA_TOPIC_GRACE_S
    rec.poll(), rec.poll(), rec.poll()
    assert len(rec.finished) == 2
    for result, value in zip(sorted(rec.finished, key=lambda r: r.path.name), (1.0, 2.0)):
        got, values = bag_io.read_labelled_topic(result.path, T.ESTIMATE.name, ESTIMATE_FIELDS)
        assert got.tolist() == sparse and set(values[:, 0].tolist()) == {value}, (result.path.name, values[:, 0])


def test_an_estimator_more_than_an_episode_behind_has_every_episodes_estimates_recorded(tmp_path):
    """A fast replay (or a lockstep simulator) runs two episodes while the estimator is still on
    the first: the second's ticks are complete before its first estimate. Its bag was finished
    0.3 s later, said "completed", and every estimate of it was dropped as outside any episode (an
    outside tester's: 4 of 6 bags without an estimate). It now waits while the estimator streams
    the older episode's estimates, then takes its own."""
    from soil_msgs_py import topics as T

    rec, feed, now, msgs, stamps, start_ev, end_ev = _replayed_with_estimates(tmp_path)
    for episode in (0, 1):  # the replay's stamps start again with each bag
        rec.on_status(replace(start_ev, episode=episode).to_json())
        for t, topic, raw in msgs:
            feed.send("sim", topic, raw)
            if episode == 0 and topic == "/clock" and t in stamps[:3]:
                feed.send("estimator", T.ESTIMATE.name, _estimate(t, 1.0))  # its first estimates came in time
        rec.on_status(replace(end_ev, episode=episode).to_json())
        rec.poll()
    for episode, late in ((0, stamps[3:]), (1, stamps)):
        for t in late:  # the estimator catching up, an estimate every 0.2 s
            now[0] += 0.2
            rec.poll()
            assert len(rec.finished) <= episode, f"episode {episode + 1} finished before its estimates came"
            feed.send("estimator", T.ESTIMATE.name, _estimate(t, float(episode + 1)))
    now[0] += recorder.EXTRA_TOPIC_GRACE_S + 0.01
    rec.poll(), rec.poll()
    assert len(rec.finished) == 2 and rec.dropped["outside_episode"] == 0
    for result, value in zip(sorted(rec.finished, key=lambda r: r.path.name), (1.0, 2.0)):
        got, values = bag_io.read_labelled_topic(result.path, T.ESTIMATE.name, ESTIMATE_FIELDS)
        assert got.tolist() == stamps and set(values[:, 0].tolist()) == {value}, (result.path.name, values[:, 0])


def test_a_bag_without_a_topic_its_writer_sent_before_it_began_is_not_held_open_for_it(tmp_path):
    """A replay (stamps start again with each bag) whose middle bag has no estimate: its bag waited
    the end grace for the estimates an older bag had had, and the next bag's, arriving meanwhile,
    were filed into it (a reviewer's). It finishes after the short grace, the next bag keeps its own."""
    from soil_msgs_py import topics as T

    rec, feed, now, msgs, _, start_ev, end_ev = _replayed_with_estimates(tmp_path)
    for episode, value in ((0, 1.0), (1, None), (2, 3.0)):
        rec.on_status(replace(start_ev, episode=episode).to_json())
        for t, topic, raw in msgs:
            feed.send("sim", topic, raw)
            if value is not None and topic == "/clock":
                feed.send("estimator", T.ESTIMATE.name, _estimate(t, value))
            now[0] += 0.001
        rec.on_status(replace(end_ev, episode=episode).to_json())
        ended = now[0]
        while len(rec.finished) <= episode and now[0] - ended < 10.0:
            now[0] += 0.05
            rec.poll()
        assert now[0] - ended < recorder.EXTRA_TOPIC_GRACE_S + 0.2, f"bag {episode} held {now[0] - ended:.2f} s"
    named = sorted(rec.finished, key=lambda r: r.path.name)
    assert [bag_io.read_labelled_topic(r.path, T.ESTIMATE.name, ESTIMATE_FIELDS)[1][:, 0].tolist()[:1]
            for r in named] == [[1.0], [], [3.0]]


def test_a_bag_cut_short_by_another_episode_start_says_so(tmp_path):
    """A second graph's episode_start (or a restarted simulator's) before this episode's end
    closes its bag where its ticks stop: it was marked "completed", as if the episode had run its
    course (an outside tester: 173 of 600 ticks)."""
    loaded, start_ev, end_ev = _events(SAMPLE)
    msgs = loaded.messages[: 10 * 20]
    rec = recorder.Recorder(tmp_path, loaded.topics, log=(log := ListLog()), clock=lambda: 0.0)
    feed = Feed(rec)
    rec.on_status(start_ev.to_json())
    for _, topic, raw in msgs:
        feed.send("sim", topic, raw)
    other = replace(start_ev, episode=7, name="default_sand_id060_v0.50_d0.200_s5")
    rec.on_status(other.to_json())
    rec.poll()
    cut = next(r for r in rec.finished if r.path.name == SAMPLE.name)
    info = recorder_info(cut.path)
    assert info["end"] == "cut_short" and info["cut_by"] == other.name, info
    assert any("cut short (a restarted simulator, or a second graph" in m for _, m in log.lines), log.lines


def test_a_planner_started_late_has_its_messages_counted_and_said(tmp_path, monkeypatch):
    """A topic whose first message comes more than the online horizon into the episode (a planner
    started 12 s late) was never judged on arrival: the bag held 1173 of its messages and said it
    had none (an outside tester's). Its first message is judged against the episode's progress:
    counted, its first tick recorded, nothing said. (The horizon scaled to the sample's 10 s.)"""
    from soil_msgs_py import topics as T

    monkeypatch.setattr(recorder, "ONLINE_HORIZON_TICKS", 60)
    loaded, start_ev, end_ev = _events(SAMPLE)
    n, late = 400, 300
    msgs = loaded.messages[: 10 * n]
    rec = recorder.Recorder(tmp_path, {**loaded.topics, T.ESTIMATE.name: T.ESTIMATE.msgtype},
                            log=(log := ListLog()), clock=lambda: 0.0)
    feed = Feed(rec)
    rec.on_status(start_ev.to_json())
    for t, topic, raw in msgs:
        feed.send("sim", topic, raw)
        if topic == "/clock" and (tick := (t - msgs[0][0]) // TICK_NS) >= late:
            feed.send("estimator", T.ESTIMATE.name, _estimate(t, float(tick)))
    rec.on_status(replace(end_ev, last_stamp_ns=msgs[-1][0], ticks=n).to_json())
    (result,) = rec.finished
    assert recorder_info(result.path)["first_tick"][T.ESTIMATE.name] == late
    assert not [m for lvl, m in log.lines if lvl == "warning"], log.lines


@pytest.mark.parametrize("dies, back, horizon", [(400, 550, None), (100, 450, 300)])
def test_a_controller_restarted_with_fewer_commands_left_than_it_sent_completes_the_episode(tmp_path, monkeypatch,
                                                                                          dies, back, horizon):
    """The controller dies and a new one (a new counter) answers from ``back`` to the end: fewer
    commands than its predecessor sent. On arrival the dead writer led the topic until the new one had
    sent more, so the episode never looked complete and waited out its end grace, the recorder saying
    the commands had stopped at the old one's last (an outside tester's). A writer silent for 2 s is
    gone: the restarted one leads at once, and the bag is completed at its end. Also when it comes back
    later than the online horizon after the dead one's last command (a horizon of 300 ticks standing
    for 10 s): judged against its own topic's newest stamp, it was never judged at all."""
    if horizon:
        monkeypatch.setattr(recorder, "ONLINE_HORIZON_TICKS", horizon)
    loaded, start_ev, end_ev = _events(SAMPLE)
    msgs = loaded.messages[: 10 * 600]
    rec = recorder.Recorder(tmp_path, loaded.topics, log=(log := ListLog()), clock=lambda: 0.0)
    feed = Feed(rec)
    rec.on_status(start_ev.to_json())
    sent = {"sim": 0, "restarted": 0}
    for t, topic, raw in msgs:
        tick = (t - msgs[0][0]) // TICK_NS
        writer = "sim"
        if topic == "/chassis/cmd_vel":
            if dies <= tick < back:
                continue
            writer = "restarted" if tick >= back else "sim"
            sent[writer] += 1
        feed.send(writer, topic, raw)
    rec.on_status(replace(end_ev, last_stamp_ns=msgs[-1][0], ticks=600).to_json())
    assert sent == {"sim": dies, "restarted": 600 - back}
    (result,) = rec.finished  # completed at the episode_end, not after the grace
    info = recorder_info(result.path)
    assert info["end"] == "completed" and info["received"]["/chassis/cmd_vel"] == 600 - (back - dies), info
    # and the bag says which ticks it lacks (it reported "0 dropped" and nothing else)
    (warning,) = [m for lvl, m in log.lines if lvl == "warning"]
    assert f"the bag lacks ticks of /chassis/cmd_vel ({back - dies} of 600)" in warning, log.lines


def test_a_message_stamped_seconds_ahead_makes_no_writer_look_silent(tmp_path):
    """Another publisher's one command per topic, stamped at the episode's last tick, sent at tick
    450 (2.5 s ahead, inside the online horizon): judged against its stamp, the controller looked
    silent for 2 s and was forgotten, the stranger led, and the episode looked complete before the
    controller's last commands (3 ticks behind the state) came in: the bag lost its last ticks
    without a word (a reviewer's). Silences are judged against the episode's progress."""
    commands = ("/chassis/cmd_vel", "/blade/cmd")
    loaded, start_ev, end_ev = _events(SAMPLE)
    msgs = loaded.messages[: 10 * 600]
    last = msgs[-1][0]
    final = {topic: raw for t, topic, raw in msgs if t == last and topic in commands}
    rec = recorder.Recorder(tmp_path, loaded.topics, log=ListLog(), clock=lambda: 0.0)
    feed = Feed(rec)
    rec.on_status(start_ev.to_json())
    lagging = []
    for t, topic, raw in msgs:
        tick = (t - msgs[0][0]) // TICK_NS
        if topic in commands:
            lagging.append((tick, topic, raw))
            continue
        feed.send("sim", topic, raw)
        while lagging and lagging[0][0] <= tick - 3:
            feed.send("sim", *lagging.pop(0)[1:])
        if tick == 450 and topic == "/clock":
            for c in commands:
                feed.send("intruder", c, final[c])
    rec.on_status(replace(end_ev, last_stamp_ns=last, ticks=600).to_json())
    assert not rec.finished, "complete before the controller's last commands came"
    for _, topic, raw in lagging:
        feed.send("sim", topic, raw)
    (result,) = rec.finished
    assert result.ticks == 600 and set(result.messages.values()) == {600}, result.summary()
    assert recorder_info(result.path)["conflicts"] == {c: 1 for c in commands}


@pytest.mark.parametrize("restarted", [True, False])
def test_a_simulator_started_again_on_the_same_episode_gets_a_bag_of_its_own(tmp_path, restarted):
    """The simulator is killed at tick 300 and started again with the same episode: its episode_start is
    the first one's to the letter, and was taken for the same event twice; its ticks, stamped from the
    start again with new counters, were refused as another writer's claims on the first run's stamps
    (3000 of them, a reviewer's). The ticks decide: stamped back at the episode's start, the first run's
    bag is closed, cut short, and the new run recorded whole beside it, the controller's commands (one
    writer through both runs, 3 ticks behind the state) each in its run's bag (its next commands had
    gone into the first run's, a reviewer's). The same event heard again while the episode's ticks go
    on changes nothing."""
    loaded, start_ev, end_ev = _events(SAMPLE)
    msgs = loaded.messages[: 10 * 600]
    commands = ("/chassis/cmd_vel", "/blade/cmd")
    rec = recorder.Recorder(tmp_path, loaded.topics, log=(log := ListLog()), clock=lambda: 0.0)
    feed = Feed(rec)

    def run(writer, part, lagging=()) -> list:
        lagging = list(lagging)  # commands not sent yet, in tick order
        for t, topic, raw in part:
            tick = (t - msgs[0][0]) // TICK_NS
            if topic in commands:
                lagging.append((tick, topic, raw))
                continue
            feed.send(writer, topic, raw)
            while lagging and lagging[0][0] <= tick - 3:
                feed.send("controller", *lagging.pop(0)[1:])
        return lagging

    rec.on_status(start_ev.to_json())
    lagging = run("sim", msgs[: 10 * 300])  # the killed simulator's last three ticks are never answered
    rec.on_status(start_ev.to_json())  # the restarted simulator's, or the same event again
    if restarted:
        lagging = run("restarted", msgs)
    else:
        lagging = run("sim", msgs[10 * 300:], lagging)
    rec.on_status(replace(end_ev, last_stamp_ns=msgs[-1][0], ticks=600).to_json())
    for _, topic, raw in lagging:
        feed.send("controller", topic, raw)
    rec.poll(), rec.close()
    results = {r.path.name: r for r in rec.finished}
    name = start_ev.name
    if restarted:
        assert sorted(results) == [name, f"{name}_2"]
        assert (results[name].ticks, results[f"{name}_2"].ticks) == (297, 600)
        assert recorder_info(results[name].path)["end"] == "cut_short"
        assert not results[f"{name}_2"].conflicts and not results[name].conflicts
        assert_same_episode(bag_io.read_episode(results[f"{name}_2"].path), bag_io.read_episode(SAMPLE), 600)
        assert_same_episode(bag_io.read_episode(results[name].path), bag_io.read_episode(SAMPLE), 297)
    else:
        assert list(results) == [name] and results[name].ticks == 600 and not results[name].conflicts
        assert not [m for lvl, m in log.lines if lvl == "warning"], log.lines


def record_120_ticks(out, keep, writer: str, joined_without: set[str]):
    """The sample's first 120 ticks of the topics ``keep`` takes, sent by ``writer`` to a recorder
    whose joined_without is given, as one episode; (recorder, log)."""
    loaded, start_ev, end_ev = _events(SAMPLE)
    msgs = [m for m in loaded.messages[: 10 * 120] if keep(m[1])]
    rec = recorder.Recorder(out, loaded.topics, log=(log := ListLog()), clock=lambda: 0.0, end_grace_s=0.0)
    rec.joined_without = joined_without
    feed = Feed(rec)
    rec.on_status(start_ev.to_json())
    for t, topic, raw in msgs:
        feed.send(writer, topic, raw)
    rec.on_status(replace(end_ev, last_stamp_ns=msgs[-1][0], ticks=120).to_json())
    rec.poll(), rec.poll(), rec.close()
    return rec, log


COMMANDS = ("/chassis/cmd_vel", "/blade/cmd")


def test_a_recorded_topic_whose_writer_sent_nothing_is_said_as_lacking_every_tick(tmp_path):
    """The controller's writers had matched, but it died before the episode: no command at all. Counted
    only among topics with messages, the bag said nothing of it (a reviewer's); a topic no writer had
    matched is said as such instead (``joined_without``), not twice."""
    _, log = record_120_ticks(tmp_path, lambda topic: topic not in COMMANDS, "sim", {"/blade/cmd"})
    warnings = [m for lvl, m in log.lines if lvl == "warning"]
    assert any("no message of /chassis/cmd_vel reached the recorder in this episode (120 ticks)" in m
               for m in warnings), warnings  # (none at all: no writer matched late, said apart)
    assert not any("lacks ticks of" in m and "/blade/cmd" in m for m in warnings), warnings
    assert any("/blade/cmd has no message" in m for m in warnings), warnings


def test_a_bag_of_commands_alone_counts_as_no_bag_and_one_missing_state_topic_does_not(tmp_path):
    """A launch's recorder that joined the state topics after the episode's ticks (an outside
    recorder had met the simulator's wait for it) wrote bags of commands alone, which no reader
    takes as an episode, and exited 0 (an outside tester's). Such an episode counts among those
    without a bag (exit code 5). One state topic missing (a replay that leaves out the ground
    truth, a machine's graph without one) stays a warning, as before."""
    rec, log = record_120_ticks(tmp_path, lambda topic: topic in COMMANDS, "controller", set())
    assert len(rec.unwritten) == 1
    errors = [m for lvl, m in log.lines if lvl == "error"]
    assert any("no message of the simulator's state (/clock, /blade/pose" in m and "only commands" in m
               for m in errors), log.lines
    # (the same with no state writer matched when the recorder joined, which was a warning: said so)
    loaded, _, _ = _events(SAMPLE)
    rec, log = record_120_ticks(tmp_path / "unmatched", lambda topic: topic in COMMANDS, "controller",
                                {t for t in loaded.topics if t not in COMMANDS})
    assert len(rec.unwritten) == 1 and any("no writer of them had matched" in m for lvl, m in log.lines), log.lines
    rec, log = record_120_ticks(tmp_path / "no_truth", lambda topic: topic != "/soil/ground_truth", "sim", set())
    assert rec.unwritten == [] and not [m for lvl, m in log.lines if lvl == "error"]
    assert any("no message of /soil/ground_truth reached the recorder in this episode (120 ticks)" in m
               for lvl, m in log.lines), log.lines
