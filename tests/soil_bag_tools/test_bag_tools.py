"""soil_bag_play / soil_bag_record / soil_bag_repair: real processes, real DDS, real MCAP files.

The tools run as the venv's console scripts; this process hosts its own rclpy node (own
context) to listen and to publish ``/sim/status``. DDS stays on loopback
(ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) with one ROS_DOMAIN_ID per test. The unit tests
at the top need no DDS: stamp routing, whole-tick trimming, journal -> bag conversion and
repair of truncated journals.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader

from soil_bringup.launch import loopback_env
from soil_bag_tools import bag_io, bag_writer, journal, playback, recorder
from soil_msgs_py import graph
from soil_msgs_py.graph import EXIT_BAG_NOT_WRITTEN
from soil_msgs_py import topics as T
from soil_msgs_py.topics import EPISODE_TOPICS

from tests.ros_domains import next_domain_id

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "bags" / "samples"
SAMPLE = SAMPLES / "default_loam_id060_v0.50_d0.200_s7"
BIN = Path(sys.executable).parent
TOPICS = [t.name for t in EPISODE_TOPICS]
TICK_NS = 1_000_000_000 // 60
ARRAYS = ("stamps_ns", "observations", "forces", "known", "truth", "extras")

pytestmark = [pytest.mark.live, pytest.mark.timeout(180)]  # a hang guard: process start-up and DDS discovery crawl on a loaded machine


def sample_messages(bag: Path = SAMPLE) -> list[tuple[int, str, bytes]]:
    return playback.load_bag(bag).messages


def assert_same_episode(got: bag_io.Episode, want: bag_io.Episode, n: int | None = None) -> None:
    n = len(want) if n is None else n
    assert len(got) == n
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name)[:n], err_msg=name)
    assert got.meta == want.meta


# --- unit tests (no DDS) ------------------------------------------------------------------

class ListLog:
    def __init__(self):
        self.lines: list[tuple[str, str]] = []

    def __getattr__(self, level):
        return lambda msg: self.lines.append((level, msg))


def _events(bag: Path, episode: int = 0):
    loaded = playback.load_bag(bag)
    start, end = playback.episode_events(loaded, episode)
    return loaded, start, end


def test_recorder_routes_by_stamp_across_overlapping_replays(tmp_path):
    """Two replays of one bag (stamps restart at 0): the first episode's late backlog still goes
    to it, the second's messages to the second; duplicates and strays are dropped."""
    loaded, start, end = _events(SAMPLE)
    msgs = loaded.messages[: 10 * 30]  # 30 ticks
    end = replace(end, last_stamp_ns=msgs[-1][0], ticks=30)
    start2 = replace(start, episode=1)
    end2 = replace(end, episode=1)
    now = [0.0]
    log = ListLog()
    rec = recorder.Recorder(tmp_path, {t: loaded.topics[t] for t in TOPICS}, end_grace_s=1.0, log=log,
                            clock=lambda: now[0])
    rec.on_message("/clock", msgs[0][2], 0)  # before its episode_start: held, then routed
    rec.on_status(start.to_json())
    late = [m for m in msgs[1:] if m[1] == "/blade/cmd"]  # this topic lags behind
    for t, topic, raw in msgs[1:]:
        if topic != "/blade/cmd":
            rec.on_message(topic, raw, 0)
    rec.on_status(end.to_json())
    rec.on_status(start2.to_json())
    rec.on_message("/clock", msgs[0][2], 0)  # episode 2 starts at stamp 0 again
    for t, topic, raw in late:
        rec.on_message(topic, raw, 0)
    assert [r.path.name for r in rec.finished] == [SAMPLE.name]  # episode 1 complete
    rec.on_message("/clock", msgs[0][2], 0)  # duplicate in episode 2
    for t, topic, raw in msgs[1:]:
        rec.on_message(topic, raw, 0)
    rec.on_status(end2.to_json())
    assert [r.path.name for r in rec.finished] == [SAMPLE.name, SAMPLE.name + "_2"]
    want = bag_io.read_episode(SAMPLE)
    for r in rec.finished:
        assert_same_episode(bag_io.read_episode(r.path), want, 30)
    assert any("duplicate /clock" in m for lvl, m in log.lines if lvl == "warning")
    assert any("exists; recording to" in m for lvl, m in log.lines)
    info = json.loads(yaml.safe_load((rec.finished[1].path / "metadata.yaml").read_text())
                      ["rosbag2_bagfile_information"]["custom_data"][journal.RECORDER_INFO_KEY])
    assert info["duplicates"] == 1 and info["end"] == "completed" and info["written_messages"] == 300
    rec.on_status("{not json")  # a bad status is logged, not fatal
    assert any("not JSON" in m for lvl, m in log.lines if lvl == "warning")
    rec.on_message("/clock", msgs[0][2], 0)  # outside any episode: held, then expired
    now[0] = 5.0
    rec.poll()
    assert rec.dropped["outside_episode"] == 1
    assert rec.close() == [] and not list(tmp_path.glob("*.partial"))


def test_an_episode_whose_bag_cannot_be_made_is_not_recorded_and_the_recorder_goes_on(tmp_path):
    """A name the file system refuses (longer than its 255 bytes) once killed the recorder, and with
    it a whole launch: that episode is not recorded, said with the reason, and the next one is."""
    loaded, start, end = _events(SAMPLE)
    msgs = loaded.messages[: 10 * 5]
    end = replace(end, last_stamp_ns=msgs[-1][0], ticks=5)
    log = ListLog()
    rec = recorder.Recorder(tmp_path, loaded.topics, end_grace_s=0.5, log=log, clock=lambda: 0.0)
    rec.on_status(replace(start, name="x" * 300).to_json())
    assert any(lvl == "error" and "cannot open its bag" in m and "not recorded" in m for lvl, m in log.lines), log.lines
    assert rec.unwritten == ["x" * 300]  # the recorder's exit code then says so (EXIT_BAG_NOT_WRITTEN)
    rec.on_status(replace(start, episode=1).to_json())
    for _, topic, raw in msgs:
        rec.on_message(topic, raw, 0)
    rec.on_status(replace(end, episode=1).to_json())
    assert [r.path.name for r in rec.finished] == [SAMPLE.name]
    assert_same_episode(bag_io.read_episode(rec.finished[0].path), bag_io.read_episode(SAMPLE), 5)
    # an episode a Ctrl-C ended is recorded whole ("completed") and says how the episode ended
    rec.on_status(replace(start, episode=2).to_json())
    for _, topic, raw in msgs:
        rec.on_message(topic, raw, 0)
    rec.on_status(replace(end, episode=2, reason="shutdown").to_json())
    done = [m for lvl, m in log.lines if m.startswith("finished (")]
    assert done[1].endswith("; the episode ended: shutdown"), done
    completed = recorder.Recorder(tmp_path / "c", loaded.topics, end_grace_s=0.5, log=ListLog(), clock=lambda: 0.0)
    completed.on_status(start.to_json())
    for _, topic, raw in msgs:
        completed.on_message(topic, raw, 0)
    completed.on_status(replace(end, reason="completed").to_json())
    assert [m for _, m in completed.log.lines if m.startswith("finished (completed)") and "ended" not in m], completed.log.lines


def test_an_episode_recorded_but_not_written_is_counted_for_the_exit_code(tmp_path):
    """Its journal gone before the episode ended (deleted, a disk that failed): no bag, said as an
    error, and the episode listed in ``unwritten``, which record_node's exit code reads
    (EXIT_BAG_NOT_WRITTEN: soil_launch then fails); the next episode records as before."""
    loaded, start, end = _events(SAMPLE)
    msgs = loaded.messages[: 10 * 5]
    end = replace(end, last_stamp_ns=msgs[-1][0], ticks=5)
    log = ListLog()
    rec = recorder.Recorder(tmp_path, loaded.topics, end_grace_s=0.5, log=log, clock=lambda: 0.0)
    rec.on_status(start.to_json())
    for _, topic, raw in msgs:
        rec.on_message(topic, raw, 0)
    shutil.rmtree(journal.partial_dir(tmp_path, SAMPLE.name))
    rec.on_status(end.to_json())
    assert not rec.finished and rec.unwritten == [SAMPLE.name]
    assert any(lvl == "error" and f"{SAMPLE.name}: no bag written" in m for lvl, m in log.lines), log.lines
    rec.on_status(replace(start, episode=1).to_json())
    for _, topic, raw in msgs:
        rec.on_message(topic, raw, 0)
    rec.on_status(replace(end, episode=1).to_json())
    assert [r.path.name for r in rec.finished] == [SAMPLE.name] and rec.unwritten == [SAMPLE.name]


def test_a_bag_says_where_each_topic_starts_and_warns_of_a_head_lost_to_a_late_writer(tmp_path):
    """A recorder that joined before a writer had matched (its --inputs-wait ran out) may miss that
    topic's first ticks: the bag's recorder info gives every topic's first tick, and the log says
    which topics of those start late."""
    loaded, start, end = _events(SAMPLE)
    msgs = loaded.messages[: 10 * 6]
    end = replace(end, last_stamp_ns=msgs[-1][0], ticks=6)
    log = ListLog()
    # the estimator's force starts with its first valid estimate by design (a window later): its
    # first tick says nothing of a late writer (an outside tester's false alarm)
    estimated = T.ESTIMATED_FORCE.name
    rec = recorder.Recorder(tmp_path, {**loaded.topics, estimated: T.ESTIMATED_FORCE.msgtype}, end_grace_s=0.5,
                            log=log, clock=lambda: 0.0)
    rec.joined_without.update({"/blade/cmd", "/chassis/cmd_vel", estimated})
    rec.on_status(start.to_json())
    first = msgs[0][0]
    for stamp, topic, raw in msgs:
        if topic != "/blade/cmd" or stamp >= first + 3 * 10**9 // 60:  # its first 3 ticks never came
            rec.on_message(topic, raw, 0)
        if topic == "/blade/force" and stamp >= first + 4 * 10**9 // 60:  # a WrenchStamped from tick 4 on
            rec.on_message(estimated, raw, 0)
    rec.on_status(end.to_json())
    (r,) = rec.finished
    info = json.loads(yaml.safe_load((r.path / "metadata.yaml").read_text())
                      ["rosbag2_bagfile_information"]["custom_data"][journal.RECORDER_INFO_KEY])
    assert info["first_tick"]["/blade/cmd"] == 3 and info["first_tick"]["/clock"] == 0
    late = [m for lvl, m in log.lines if lvl == "warning" and "starts at tick" in m]
    assert len(late) == 1 and "/blade/cmd starts at tick 3" in late[0] and "/chassis/cmd_vel" not in late[0], log.lines
    assert info["first_tick"][estimated] == 4 and estimated not in late[0]
    # one bag of the whole run (--no-split): said in seconds after the first message (an outside tester's
    # run lost a whole first episode's commands there without a word)
    log = ListLog()
    rec = recorder.Recorder(tmp_path / "whole", loaded.topics, split=False, log=log, clock=lambda: 0.0)
    rec.joined_without.update({"/blade/cmd", "/chassis/cmd_vel"})
    for stamp, topic, raw in msgs:
        if topic != "/blade/cmd" or stamp >= first + 3 * 10**9 // 60:
            rec.on_message(topic, raw, 0)
    (r,) = rec.close()
    info = json.loads(yaml.safe_load((r.path / "metadata.yaml").read_text())
                      ["rosbag2_bagfile_information"]["custom_data"][journal.RECORDER_INFO_KEY])
    assert info["first_stamp_s"]["/blade/cmd"] == pytest.approx(0.05) and info["first_stamp_s"]["/clock"] == 0.0
    late = [m for lvl, m in log.lines if lvl == "warning" and "after the first recorded message" in m]
    assert len(late) == 1 and "/blade/cmd starts 0.050 s after" in late[0] and "/chassis/cmd_vel" not in late[0], log.lines


def test_recorder_grace_timeout_trims_to_whole_ticks(tmp_path):
    loaded, start, end = _events(SAMPLE)
    msgs = loaded.messages[: 10 * 20]
    end = replace(end, last_stamp_ns=msgs[-1][0], ticks=20)
    now = [0.0]
    log = ListLog()
    rec = recorder.Recorder(tmp_path, loaded.topics, end_grace_s=0.5, log=log, clock=lambda: now[0])
    rec.on_status(start.to_json())
    for t, topic, raw in msgs[:-3]:  # the last tick lacks 3 topics
        rec.on_message(topic, raw, 0)
    rec.on_status(end.to_json())
    assert rec.poll() == []
    now[0] = 0.6
    (r,) = rec.poll()
    assert r.ticks == 19 and r.dropped == 7
    assert any("short topics" in m for lvl, m in log.lines if lvl == "warning")
    assert_same_episode(bag_io.read_episode(r.path), bag_io.read_episode(SAMPLE), 19)


def test_whole_tick_cutoff():
    assert journal.whole_tick_cutoff({"a": [1, 2, 3], "b": [1, 2]}) == 2
    assert journal.whole_tick_cutoff({"a": [1, 2, 3], "b": [1, 3], "c": []}) == 3  # middle gap kept
    assert journal.whole_tick_cutoff({"a": [2], "b": [1]}) is None
    assert journal.whole_tick_cutoff({"a": []}) is None


def _journal_from_sample(tmp_path: Path, n_msgs: int, flush_every: int):
    """A journal holding the sample's first ``n_msgs`` messages, flushed every ``flush_every``."""
    loaded = playback.load_bag(SAMPLE)
    partial = journal.partial_dir(tmp_path, journal.claim_name(tmp_path, SAMPLE.name))
    w = journal.JournalWriter(journal.journal_path(partial), {bag_io.META_KEY: loaded.meta.to_json()})
    for topic, msgtype in loaded.topics.items():
        w.add_channel(topic, msgtype, [bag_writer.rosbags_qos(graph.DATA_QOS)])
    for i, (t, topic, raw) in enumerate(loaded.messages[:n_msgs]):
        w.write(topic, t, raw)
        if (i + 1) % flush_every == 0:
            w.flush()
    return partial, w


def _killed(w: journal.JournalWriter) -> None:
    """What a SIGKILL does to a writer: the kernel closes its file (dropping the journal's lock);
    nothing is finished."""
    w._file.close()


def test_truncated_journal_repairs_to_last_flushed_chunk(tmp_path):
    partial, w = _journal_from_sample(tmp_path, n_msgs=900, flush_every=150)  # 6 chunks, 90 ticks
    jpath = journal.journal_path(partial)
    flushed = jpath.stat().st_size
    for t, topic, raw in sample_messages()[900:1005]:
        w.write(topic, t, raw)
    w.flush()  # a 7th chunk; then the writer dies (no close) while the chunk is half on disk
    _killed(w)
    with open(jpath, "r+b") as f:
        f.truncate((flushed + jpath.stat().st_size) // 2)
    r = journal.journal_to_bag(partial, info_key=journal.REPAIR_INFO_KEY)
    assert r.recovered == 900 and r.ticks == 90 and r.dropped == 0 and not r.journal_complete
    assert "the file ends inside the record that starts there" in r.stop
    assert_same_episode(bag_io.read_episode(r.path), bag_io.read_episode(SAMPLE), 90)
    assert not partial.exists()
    info = json.loads(yaml.safe_load((r.path / "metadata.yaml").read_text())
                      ["rosbag2_bagfile_information"]["custom_data"][journal.REPAIR_INFO_KEY])
    assert info["recovered_messages"] == 900 and info["last_stamp_ns"] == sample_messages()[899][0]


def test_repair_cli_keep_partial_ticks_and_nothing_recoverable(tmp_path):
    partial, w = _journal_from_sample(tmp_path, n_msgs=205, flush_every=205)
    _killed(w)
    out = subprocess.run([BIN / "soil_bag_repair", str(tmp_path), "--keep-partial-ticks"],
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    assert "repaired" in out.stdout and "205 messages" in out.stdout
    with AnyReader([tmp_path / SAMPLE.name]) as reader:
        assert reader.message_count == 205
    empty = tmp_path / "empty.partial"
    empty.mkdir()
    (empty / "empty.mcap").write_bytes(b"\x89MCAP0\r\n\x01")  # killed right after the magic
    out = subprocess.run([BIN / "soil_bag_repair", str(empty), str(tmp_path / "nope")],
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 2  # a path that does not exist is a bad argument; the other one is still tried
    assert "nothing recoverable" in out.stderr and "no complete chunk" in out.stderr
    assert "nope does not exist" in out.stderr
    assert empty.exists()  # kept for a later attempt


def test_pacer_deadlines_do_not_drift():
    """Fake clock: sleep overshoots by 0.1 ms, each clock read costs 1 us; no error accumulates."""
    clock = [0.0]

    def now():
        clock[0] += 1e-6
        return clock[0]

    pacer = playback.Pacer(2.0, now=now, sleep=lambda s: clock.__setitem__(0, clock[0] + s + 1e-4))
    pacer.begin(1_000_000_000, start=10.0)
    for k in range(1, 100):
        assert pacer.wait(1_000_000_000 + k * TICK_NS) < 1e-5
        assert clock[0] == pytest.approx(10.0 + k * TICK_NS * 1e-9 / 2, abs=1e-5)


@pytest.mark.parametrize("rate", [0.0, -1.0, float("inf"), float("nan"), 1e-300, 1e6, 0.005])
def test_a_pacer_refuses_a_rate_that_is_no_timing(rate):
    with pytest.raises(ValueError, match=r"rate .* must be a finite number in \[0.01, 1000\]"):
        playback.Pacer(rate)


def test_with_clock_replaces_bag_clock():
    from soil_msgs_py.writer_identity import tick_index

    msgs = sample_messages()[:60]  # 6 ticks
    out = list(playback.with_clock(msgs, 120.0))
    clocks = [t for t, topic, _ in out if topic == "/clock"]
    assert clocks == [k * 10**9 // 120 for k in range(len(clocks))] and len(clocks) == 11
    assert [m for m in out if m[1] != "/clock"] == [m for m in msgs if m[1] != "/clock"]
    assert all(a[0] <= b[0] for a, b in zip(out, out[1:]))
    # at 60 Hz on the ticks' own stamps, first + floor(k·1e9/60), also for an episode that starts off
    # the absolute grid (after one of 100 ticks: 1666666667 ns); rounded, a third of them were off
    # the tick grid, and a recorder of the replay dropped them
    ticks = sorted({t for t, topic, _ in sample_messages() if topic == "/clock"})
    assert [t for t, topic, _ in playback.with_clock(msgs, 60.0) if topic == "/clock"] == ticks[:6]
    first = 1666666667
    later = [(t + first, topic, raw) for t, topic, raw in sample_messages()[:300]]
    clocks = [t for t, topic, _ in playback.with_clock(later, 60.0) if topic == "/clock"]
    assert clocks == [first + t for t in ticks[:30]]
    assert [tick_index(t, first) for t in clocks] == list(range(30))  # as the recorder files them


# --- processes on the loopback DDS ---------------------------------------------------------

def ros_env(domain: int) -> dict[str, str]:
    return loopback_env(domain)


def start(tool: str, *args, domain: int) -> subprocess.Popen:
    return subprocess.Popen([str(BIN / tool), *map(str, args)], env=ros_env(domain),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def finish(proc: subprocess.Popen, timeout: float = 30) -> str:
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate(timeout=5)
        raise AssertionError(f"{proc.args[0]} did not end within {timeout} s:\n{out}") from None
    return out


def reap(*procs: subprocess.Popen | None) -> None:
    """Kill whatever a failed test left running."""
    for proc in procs:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=5)


class Listener:
    """An rclpy node in this process (own context): raw subscriber to every episode topic, in
    ``namespace`` as a namespaced graph's node (the topics by their relative names)."""

    def __init__(self, domain: int, topics=TOPICS, status_sub: bool = True, namespace: str = ""):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from std_msgs.msg import String

        from soil_msgs_py.ros_adapter import init_context, message_class, qos_profile

        self.rclpy = rclpy
        self.context = init_context(domain)
        self.node = rclpy.create_node("test_listener", namespace=namespace, context=self.context)
        self.received: list[tuple[int, str, bytes]] = []  # (perf_counter_ns, topic, raw)
        self.status: list[dict] = []
        self.episode: list[dict] = []  # /sim/episode, latched
        qos = qos_profile(graph.RECORDER_QOS)
        for topic in topics:
            mt = next(t.msgtype for t in EPISODE_TOPICS if t.name == topic)
            self.node.create_subscription(
                message_class(mt), topic.lstrip("/"),
                lambda raw, topic=topic: self.received.append((time.perf_counter_ns(), topic, raw)), qos, raw=True)
        if status_sub:
            self.node.create_subscription(String, graph.SIM_STATUS_TOPIC.lstrip("/"),
                                          lambda m: self.status.append(json.loads(m.data)),
                                          qos_profile(graph.CONTROL_QOS))
            self.node.create_subscription(String, graph.SIM_EPISODE_TOPIC.lstrip("/"),
                                          lambda m: self.episode.append(json.loads(m.data)),
                                          qos_profile(graph.TOPIC_QOS[graph.SIM_EPISODE_TOPIC]))
        self.status_pub = self.node.create_publisher(String, graph.SIM_STATUS_TOPIC.lstrip("/"), qos_profile(graph.CONTROL_QOS))
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        while self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: BLE001 - context shut down under us
                return

    def count(self, topic: str) -> int:
        return sum(1 for _, t, _ in list(self.received) if t == topic)

    def publish_status(self, text: str) -> None:
        from std_msgs.msg import String

        self.status_pub.publish(String(data=text))

    def wait_for(self, cond, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if cond():
                return True
            time.sleep(0.02)
        return cond()

    def close(self):
        self.executor.shutdown(timeout_sec=1.0)
        self.rclpy.shutdown(context=self.context)
        self.thread.join(timeout=2)
        self.node.destroy_node()


@pytest.fixture
def listener(monkeypatch):
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")  # read when the participant is made
    monkeypatch.delenv("ROS_LOCALHOST_ONLY", raising=False)
    made = []

    def make(domain: int, **kw) -> Listener:
        made.append(Listener(domain, **kw))
        return made[-1]

    yield make
    for lst in made:
        lst.close()


def assert_paced(received, bag_msgs, rate: float) -> None:
    """The replay follows the bag's clock instead of dumping the bag: the arrivals span at
    least 90 % of the bag's span / rate. A busy machine only makes a replay later, so this
    holds under load; how close to the schedule it runs is a benchmark figure
    (benchmarks/bench_bag_tools.py)."""
    bag_span_s = (bag_msgs[-1][0] - bag_msgs[0][0]) * 1e-9 / rate
    arrival_span_s = (received[-1][0] - received[0][0]) * 1e-9
    assert arrival_span_s >= 0.9 * bag_span_s, f"{arrival_span_s:.3f} s of arrivals for {bag_span_s:.3f} s of bag"


def test_a_replay_into_a_domain_where_another_node_publishes_its_topics_is_stopped(listener):
    """A replay into a live graph (a simulator on the domain) had a recorder cut the live bag short
    and write one holding both robots' state; the player exits 6 naming the topic and the node,
    before it published anything (or, found while playing, closing the episode it framed)."""
    from soil_msgs_py.ros_adapter import message_class, topic_qos

    domain = next_domain_id()
    lst = listener(domain, topics=())
    lst.node.create_publisher(message_class("geometry_msgs/msg/WrenchStamped"), "/blade/force", topic_qos("/blade/force"))
    player = start("soil_bag_play", SAMPLE, domain=domain)
    out = finish(player)
    assert player.returncode == graph.EXIT_ANOTHER_GRAPH, out
    # (by its name, or, the name not discovered yet on a loaded machine, saying so)
    assert re.search(r"other nodes publish topics this replay plays \(/blade/force by (/|a node not discovered by "
                     r"name yet)", out), out
    # found before anything went out (it looks while DDS discovers the domain), or, on a machine too
    # loaded for that, while playing: then the episode it framed is ended
    time.sleep(1.0)
    if any(e["event"] == "episode_start" for e in lst.status):
        assert lst.wait_for(lambda: lst.status[-1]["event"] == "episode_end", 5), lst.status
        assert lst.status[-1]["reason"] == "shutdown"
    else:
        assert "played " not in out, out


def test_replay_delivers_every_message_in_order_paced(listener):
    domain = next_domain_id()
    lst = listener(domain)
    bag_msgs = sample_messages()
    player = start("soil_bag_play", SAMPLE, "--wait-for-subscribers", 1, domain=domain)
    out = finish(player)
    assert player.returncode == 0, out
    assert lst.wait_for(lambda: len(lst.received) >= len(bag_msgs), 5), f"{len(lst.received)} received\n{out}"
    assert len(lst.received) == len(bag_msgs), f"{len(lst.received)} received\n{out}"  # none lost, none doubled
    for topic in TOPICS:  # every message, byte for byte, in order
        assert [bytes(r) for _, t, r in lst.received if t == topic] == [r for _, t, r in bag_msgs if t == topic]
    assert_paced(lst.received, bag_msgs, 1.0)
    assert [s["event"] for s in lst.status] == ["episode_start", "episode_end"]
    assert lst.status[0]["name"] == SAMPLE.name and lst.status[1]["reason"] == "end_of_bag"
    assert lst.status[1]["last_stamp_ns"] == bag_msgs[-1][0] and lst.status[1]["ticks"] == 600
    # the same events latched on /sim/episode (a reader that matched late gets the newest alone)
    assert lst.wait_for(lambda: lst.episode and lst.episode[-1] == lst.status[-1], 5), (lst.episode, out)
    assert all(e in lst.status for e in lst.episode)


def test_a_bag_holding_sim_episode_plays_it_through_the_players_own_latched_writer(listener, tmp_path):
    """A bag of everything on a live graph (``ros2 bag record -a``) holds /sim/episode: its replay
    met its own second writer there and stopped as if another graph published it (exit 6)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from soil_msgs_py.messages import TYPESTORE

    bag, played = playback.load_bag(SAMPLE), tmp_path / "everything"
    event = playback.episode_events(bag, 0)[0].to_json()
    String = TYPESTORE.types["std_msgs/msg/String"]
    with Writer(played, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        w.set_custom_data(bag_io.META_KEY, bag_io.bag_custom_data(SAMPLE)[bag_io.META_KEY])
        conns = {t: w.add_connection(t, mt, typestore=TYPESTORE) for t, mt in bag.topics.items()}
        latched = w.add_connection(graph.SIM_EPISODE_TOPIC, graph.STRING_MSGTYPE, typestore=TYPESTORE)
        w.write(latched, bag.messages[0][0], TYPESTORE.serialize_cdr(String(data=event), graph.STRING_MSGTYPE))
        for t, topic, raw in bag.messages:
            w.write(conns[topic], t, raw)
    domain = next_domain_id()
    lst = listener(domain, topics=("/blade/force",))
    player = start("soil_bag_play", played, "--rate", 4, "--wait-for-subscribers", 1, domain=domain)
    out = finish(player)
    assert player.returncode == 0 and "other nodes publish" not in out, out
    assert lst.wait_for(lambda: lst.episode and lst.episode[-1]["event"] == "episode_end", 5), (lst.episode, out)


def test_replay_rate_2_topic_selection(listener):
    """... into a machine's namespace (``--ros-args -r __ns:=/dozer1``): the graph there hears it."""
    domain = next_domain_id()
    lst = listener(domain, namespace="/dozer1")
    bag_msgs = [m for m in sample_messages() if m[1] in ("/blade/force", "/clock")]
    player = start("soil_bag_play", SAMPLE, "--rate", 2, "--topics", "/blade/force", "/clock",
                   "--wait-for-subscribers", 1, "--ros-args", "-r", "__ns:=/dozer1", domain=domain)
    out = finish(player)
    assert player.returncode == 0, out
    assert lst.wait_for(lambda: len(lst.received) >= len(bag_msgs), 5), out
    assert sorted({t for _, t, _ in lst.received}) == ["/blade/force", "/clock"]
    assert len(lst.received) == len(bag_msgs) == 1200
    for topic in ("/blade/force", "/clock"):  # every selected message, byte for byte, in order
        assert [bytes(r) for _, t, r in lst.received if t == topic] == [r for _, t, r in bag_msgs if t == topic]
    assert_paced(lst.received, bag_msgs, 2.0)  # the rate itself: test_pacer_deadlines_do_not_drift
    assert [s["event"] for s in lst.status] == ["episode_start", "episode_end"]


def test_record_a_replay_equals_the_sample_and_survives_bad_status(listener, tmp_path):
    domain = next_domain_id()
    lst = listener(domain, topics=(), status_sub=False)  # only publishes /sim/status
    # every episode topic, and one more whose name is misspelt: nothing publishes it
    rec = start("soil_bag_record", "--out", tmp_path, "--all-episode-topics", "--topics", "/soil/estimat", domain=domain)
    player = None
    try:
        assert lst.wait_for(lambda: lst.status_pub.get_subscription_count() >= 1, 10), "recorder never subscribed"
        lst.publish_status("{this is not json")
        lst.publish_status(json.dumps({"event": "episode_start"}))
        player = start("soil_bag_play", SAMPLE, "--wait-for-subscribers", 1, domain=domain)
        out = finish(player)
        assert player.returncode == 0, out
        bag = tmp_path / SAMPLE.name
        assert lst.wait_for(lambda: bag_io.is_bag(bag), 5)
        rec.send_signal(signal.SIGINT)
        log = finish(rec)
    finally:
        reap(rec, player)
    assert rec.returncode == 0, log
    assert "ignoring bad /sim/status message: /sim/status: not JSON" in log
    assert "ignoring bad /sim/status message: /sim/status: episode=None must be a non-negative integer" in log
    assert f"finished (completed) {bag}: 600 ticks, 6000 messages (600 on each of 10 topics), 0 dropped" in log
    # said while recording (the replay lasts 10 s) and again at the end, with the name it was meant as
    assert "no publisher of /soil/estimat (did you mean /soil/estimate?) after 5 s: not recorded until one appears" in log, log
    assert "never recorded (no publisher seen): /soil/estimat (did you mean /soil/estimate?)" in log, log
    assert_same_episode(bag_io.read_episode(bag), bag_io.read_episode(SAMPLE))
    assert sorted(p.name for p in tmp_path.iterdir()) == [SAMPLE.name]  # no journal left


def test_sigint_finishes_and_sigkill_is_repaired(listener, tmp_path):
    """Three recorders on one replay: SIGINT -> a trimmed, valid bag; SIGKILL -> .partial -> repair;
    SIGINT to one whose journal was deleted meanwhile -> no bag, said, and exit code
    EXIT_BAG_NOT_WRITTEN (soil_launch then fails, where it exited 0)."""
    domain = next_domain_id()
    lst = listener(domain, topics=("/blade/cmd",))  # the last topic of each tick
    a, b, c = tmp_path / "sigint", tmp_path / "sigkill", tmp_path / "lost"
    rec_int = start("soil_bag_record", "--out", a, domain=domain)
    rec_kill = start("soil_bag_record", "--out", b, domain=domain)
    rec_lost = start("soil_bag_record", "--out", c, domain=domain)
    player = start("soil_bag_play", SAMPLE, "--wait-for-subscribers", 3, domain=domain)
    try:
        assert lst.wait_for(lambda: lst.count("/blade/cmd") >= 240, 60), "replay did not reach 4 s"
        rec_kill.send_signal(signal.SIGKILL)
        rec_int.send_signal(signal.SIGINT)
        seen = lst.count("/blade/cmd")  # whole ticks this process had received by then
        shutil.rmtree(journal.partial_dir(c, SAMPLE.name))
        rec_lost.send_signal(signal.SIGINT)
        log = finish(rec_int)  # the player is still playing: the recorder stops mid-episode
        lost_log = finish(rec_lost)
        player.send_signal(signal.SIGINT)
        play_log = finish(player)
    finally:
        reap(rec_kill, rec_int, rec_lost, player)
    # an interrupted replay says so and exits 128 + SIGINT (it exited 0 with no word, as a finished one does);
    # a loaded machine may let it finish the 10 s bag first
    finished = "played " in play_log
    assert player.returncode == (0 if finished else 130) and ("stopping: SIGINT received" in play_log) != finished, play_log
    assert rec_int.returncode == 0, log
    assert rec_lost.returncode == EXIT_BAG_NOT_WRITTEN, lost_log
    assert f"{SAMPLE.name}: no bag written" in lost_log and "1 episode(s) without a bag" in lost_log, lost_log
    assert not bag_io.find_episode_bags(c)
    want = bag_io.read_episode(SAMPLE)

    (bag,) = bag_io.find_episode_bags(a)
    with AnyReader([bag]) as reader:  # a complete, valid rosbag2 bag
        assert reader.message_count % 10 == 0 and reader.message_count > 0
    got = bag_io.read_episode(bag)  # trimmed to whole ticks: a prefix of the episode (how long depends on load)
    assert_same_episode(got, want, len(got))
    assert f"finished (stopped) {bag}: {len(got)} ticks, " in log, log  # the bag holds what the recorder counted

    assert rec_kill.returncode == -signal.SIGKILL
    assert not bag_io.find_episode_bags(b) and [p.name for p in b.iterdir()] == [SAMPLE.name + ".partial"]
    out = subprocess.run([BIN / "soil_bag_repair", b], capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    repaired = bag_io.read_episode(b / SAMPLE.name)
    assert_same_episode(repaired, want, len(repaired))
    loss = seen - len(repaired)
    print(f"\nSIGKILL at {seen} ticks: {len(repaired)} recovered, loss {loss} ticks; SIGINT bag {len(got)} ticks")
    assert loss < 60, out.stdout


def test_bad_inputs(tmp_path):
    out = subprocess.run([BIN / "soil_bag_play", tmp_path / "missing"], env=ros_env(105),
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 2 and "no such bag or directory" in out.stderr
    (tmp_path / "file.txt").write_text("x")
    out = subprocess.run([BIN / "soil_bag_play", tmp_path / "file.txt"], env=ros_env(105),
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 2 and "not a rosbag2 bag directory" in out.stderr
    out = subprocess.run([BIN / "soil_bag_play", tmp_path], env=ros_env(105),
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 2 and "contains no bags" in out.stderr
    # a killed recorder's journal: named with the repair, whether given itself, alone in a directory or beside bags
    from soil_bag_tools.playback import expand_bag_args
    journal = tmp_path / "run" / "ep.partial"
    journal.mkdir(parents=True)
    (journal / "ep.mcap").write_bytes(b"")
    out = subprocess.run([BIN / "soil_bag_play", journal], env=ros_env(105), capture_output=True, text=True, timeout=30)
    assert out.returncode == 2 and "a recorder journal, not a bag" in out.stderr and f"soil_bag_repair {journal}" in out.stderr
    out = subprocess.run([BIN / "soil_bag_play", journal.parent], env=ros_env(105), capture_output=True, text=True,
                         timeout=30)
    assert out.returncode == 2 and "contains no bags; not read: 1 recorder journal(s)" in out.stderr, out.stderr
    shutil.copytree(SAMPLE, journal.parent / SAMPLE.name)
    notes: list[str] = []
    assert expand_bag_args([journal.parent], notes) == [journal.parent / SAMPLE.name]
    assert len(notes) == 1 and str(journal) in notes[0] and f"soil_bag_repair {journal.parent}" in notes[0]
    shutil.rmtree(journal.parent)
    out = subprocess.run([BIN / "soil_bag_repair", tmp_path], capture_output=True, text=True, timeout=30)
    assert out.returncode == 1 and "no *.partial journal directory inside" in out.stderr
    shutil.copytree(SAMPLE, tmp_path / "bags" / SAMPLE.name)  # finished bags, which it repairs one by one
    out = subprocess.run([BIN / "soil_bag_repair", tmp_path / "bags"], capture_output=True, text=True, timeout=30)
    assert out.returncode == 1 and "of its 1 finished bag(s) give each damaged one as PATH" in out.stderr, out.stderr
    # an --out it cannot make (under /proc): refused at start naming it, no traceback
    out = subprocess.run([BIN / "soil_bag_record", "--out", "/proc/nope"], env=ros_env(105),
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "--out: '/proc/nope' cannot be written" in out.stdout + out.stderr  # refused when parsed
    assert "Traceback" not in out.stdout + out.stderr


def test_play_refuses_a_corrupt_bag_naming_it(tmp_path):
    """The player's side of test_corrupt_bags.py (the offline tools'): exit 2, the bag named, no traceback."""
    from .test_corrupt_bags import assert_refused, copy_bag, corrupt

    bad = corrupt(copy_bag(SAMPLE, tmp_path / f"{SAMPLE.name}_broken"))
    out = subprocess.run([BIN / "soil_bag_play", bad], env=ros_env(next_domain_id()), capture_output=True, text=True,
                         timeout=60)
    assert_refused(out, bad)


def test_play_checks_every_bag_of_a_directory_before_playing_the_first(tmp_path):
    """A directory whose later bags are damaged had its readable bags played and stopped, exit 2, at
    the first damaged one: every bag is now checked first, each bad one named with its repair, and
    nothing is played."""
    from .test_corrupt_bags import copy_bag, truncate

    good = copy_bag(SAMPLE, tmp_path / "a_good")
    cut = truncate(copy_bag(SAMPLE, tmp_path / "b_truncated"))
    short = copy_bag(SAMPLE, tmp_path / "c_metadata_cut")
    (short / "metadata.yaml").write_bytes((SAMPLE / "metadata.yaml").read_bytes()[:3000])
    assert playback.unreadable_bags([good]) == []
    out = subprocess.run([BIN / "soil_bag_play", tmp_path, "--rate", "50"], env=ros_env(next_domain_id()),
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out.stdout + out.stderr
    assert "2 of the 3 bag(s) cannot be read; nothing played" in out.stderr, out.stderr
    assert f"bag {cut}: " in out.stderr and f"soil_bag_repair {cut} --out NEW_BAG" in out.stderr, out.stderr
    assert f"bag {short}: unreadable metadata.yaml" in out.stderr and f"soil_bag_repair {short}" in out.stderr
    assert f"bag {good}" not in out.stderr and "played" not in out.stdout + out.stderr.replace("nothing played", "")
    assert "Traceback" not in out.stdout + out.stderr


@pytest.mark.parametrize("option, value", [("--wait-timeout", "nan"), ("--wait-timeout", "-5"),
                                           ("--wait-timeout", "inf"), ("--clock", "inf"), ("--clock", "1e12"),
                                           ("--rate", "inf"), ("--rate", "nan"), ("--rate", "1e-300"),
                                           ("--rate", "0"), ("--rate", "1e6")])
def test_play_refuses_a_non_finite_or_negative_bound(option, value):
    """--wait-timeout nan waited forever (a deadline of nan is never passed), -5 was taken for 0,
    --clock inf published /clock at the first stamp without end, and 1e12 Hz made 10^13 messages;
    --rate inf played every message at once, unpaced, and 1e-300 scheduled the second one past any
    wait."""
    out = subprocess.run([BIN / "soil_bag_play", SAMPLE, "--wait-for-subscribers", "1", option, value],
                         env=ros_env(105), capture_output=True, text=True, timeout=30)
    assert out.returncode == 2, out.stdout + out.stderr
    assert f"error: {option} {float(value)} " in out.stderr and "must be a finite number" in out.stderr, out.stderr
    assert "Traceback" not in out.stderr


def test_play_refuses_a_selection_that_leaves_nothing_to_play():
    """--topics naming no topic of any bag exited 0 having published nothing, and with --loop spun
    at 100 % CPU; so did --exclude of every topic. A requested topic some bags lack stays a warning."""
    held = sorted(playback.load_bag(SAMPLE).held)
    for args in (["--loop", "--topics", "/nope"], ["--loop", "--exclude", *held]):
        out = subprocess.run([BIN / "soil_bag_play", SAMPLES, *args], env=ros_env(105),
                             capture_output=True, text=True, timeout=30)
        assert out.returncode == 2, out.stderr
        assert f"{' '.join(args[1:])}: no message to play in the 3 bag(s); their topics: {', '.join(held)}" \
            in out.stderr
        assert "published 0 messages" in out.stderr and "Traceback" not in out.stderr
    out = subprocess.run([BIN / "soil_bag_play", SAMPLES, "--topics", "/nope", "/soil/known_params", "--rate", "50"],
                         env=ros_env(next_domain_id()), capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert f"{SAMPLE}: no topic(s) /nope, named by --topics: not played" in out.stderr, out.stderr
    assert "published 1800 messages" in out.stderr


def test_play_says_an_excluded_topic_no_bag_holds_as_it_says_a_selected_one():
    """--exclude /soil/estimat (a typo) played everything and exited 0 without a word, where --topics
    of an unknown name warns: both go through playback.absent_topics, with the name meant."""
    notes: list[str] = []
    bag = playback.load_bag(SAMPLE, exclude=["/soil/estimat", "/blade/forc"], log=notes.append)
    assert notes == [f"{SAMPLE}: no topic(s) /blade/forc (did you mean /blade/force?), /soil/estimat (did you mean "
                     "/soil/estimate?), named by --exclude: nothing excluded for it"], notes
    assert bag.topics.keys() == bag.held  # (nothing excluded)
    notes.clear()
    playback.load_bag(SAMPLE, exclude=["/blade/force"], drop=["/clock"], log=notes.append)
    assert notes == []  # a topic the bag holds, and the player's own drop, are no news
    # nor the graph's own topics a bag lacks (the README excludes the estimator's outputs on any bag),
    # and a --topics name that is the contract's own gets no guess of another (a reviewer's:
    # "/planner/max_cut_depth (did you mean /planner/target_depth?)")
    absent = [t for t in ("/soil/estimate", "/soil/map", "/planner/max_cut_depth") if t not in bag.held]
    assert absent
    playback.load_bag(SAMPLE, exclude=absent, log=notes.append)
    assert notes == [], notes
    playback.load_bag(SAMPLE, topics=["/blade/force", *absent], log=notes.append)
    assert len(notes) == 1 and "did you mean" not in notes[0] and all(t in notes[0] for t in absent), notes
    out = subprocess.run([BIN / "soil_bag_play", SAMPLE, "--exclude", "/soil/estimat", "--rate", "50"],
                         env=ros_env(next_domain_id()), capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "no topic(s) /soil/estimat (did you mean /soil/estimate?), named by --exclude" in out.stderr, out.stderr


def test_a_robots_bag_plays_without_topics_of_types_not_installed_and_a_contract_topic_of_another_type_is_refused(
        listener, tmp_path):
    """A real robot's bag holds topics of its own message packages (its /tf: tf2_msgs, which this
    project's PyPI set-up lacks): the player had refused the whole bag (exit 2, naming neither topic
    nor way out); now it plays the rest and names what it leaves out (here a made-up package, so the
    test holds on a full ROS install too). A topic of the contract's name but another type
    (/blade/force recorded as a Wrench) had been played where no node of the graph hears it, with only
    "fewer than 1 subscribers" said: now refused, naming the topic, both types and --exclude, before
    any bag of a directory is played (an outside tester's; a reviewer's)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg("float64 cutting_edge_wear_mm", "made_up_robot_msgs/msg/BladeWear"))
    bag = playback.load_bag(SAMPLE)

    def robot_bag(path, force_type):
        with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
            w.set_custom_data(bag_io.META_KEY, bag_io.bag_custom_data(SAMPLE)[bag_io.META_KEY])
            conns = {t: w.add_connection(t, mt if t != "/blade/force" else force_type, typestore=store)
                     for t, mt in bag.topics.items()}
            wear = w.add_connection("/blade/wear", "made_up_robot_msgs/msg/BladeWear", typestore=store)
            worn = store.serialize_cdr(store.types["made_up_robot_msgs/msg/BladeWear"](cutting_edge_wear_mm=2.0),
                                       "made_up_robot_msgs/msg/BladeWear")
            Wrench, Vector3 = store.types["geometry_msgs/msg/Wrench"], store.types["geometry_msgs/msg/Vector3"]
            for t, topic, raw in bag.messages:
                if topic == "/blade/force" and force_type != T.BLADE_FORCE.msgtype:
                    raw = store.serialize_cdr(Wrench(force=Vector3(x=1.0, y=0.0, z=2.0), torque=Vector3(x=0.0, y=0.0, z=0.0)),
                                              force_type)
                w.write(conns[topic], t, raw)
                if topic == "/clock":
                    w.write(wear, t, worn)
        return path

    robots = robot_bag(tmp_path / "robots", T.BLADE_FORCE.msgtype)
    domain = next_domain_id()
    lst = listener(domain, topics=("/blade/force",))
    player = start("soil_bag_play", robots, "--rate", 4, "--wait-for-subscribers", 1, domain=domain)
    out = finish(player)
    assert player.returncode == 0, out
    assert ("not played, their message types not installed here: /blade/wear (made_up_robot_msgs/msg/BladeWear) "
            "(--exclude /blade/wear") in out, out
    assert lst.wait_for(lambda: len([m for m in lst.received if m[1] == "/blade/force"]) == 600, 5), out
    wrench = robot_bag(tmp_path / "two" / "b_wrench", "geometry_msgs/msg/Wrench")
    with pytest.raises(playback.BagPathError, match="topic /blade/force is geometry_msgs/msg/Wrench in it, but the "
                       "graph's contract is geometry_msgs/msg/WrenchStamped: .* --exclude /blade/force plays the rest"):
        playback.load_bag(wrench)
    shutil.copytree(SAMPLE, tmp_path / "two" / "a_sample")  # played first, had the check come only as each bag loads
    out = subprocess.run([BIN / "soil_bag_play", tmp_path / "two", "--rate", "50"], env=ros_env(next_domain_id()),
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "nothing played" in out.stderr, out.stderr
    assert "--exclude /blade/force plays the rest" in out.stderr and "Traceback" not in out.stderr, out.stderr
    assert not playback.unreadable_bags([wrench], exclude=["/blade/force"])
    assert not playback.unreadable_bags([wrench], topics=["/clock"])


def test_replay_of_a_dataset_is_split_into_its_episodes(listener, tmp_path):
    """Three bags whose stamps all start at 0, played back to back at rate 2: the episode
    recorder writes the same three bags; a --no-split recorder writes one bag of everything.
    (Rate 2, not faster: two recorders and a listener share the machine with the player, and
    what is checked is the split, not how fast a recorder keeps up; bench_bag_tools times replays.)"""
    domain = next_domain_id()
    lst = listener(domain, topics=(), status_sub=False)
    split, whole = tmp_path / "split", tmp_path / "whole"
    rec = start("soil_bag_record", "--out", split, domain=domain)
    rec_all = start("soil_bag_record", "--out", whole, "--no-split", domain=domain)
    player = None
    try:
        player = start("soil_bag_play", SAMPLES, "--rate", 2, "--wait-for-subscribers", 2, domain=domain)
        play_log = finish(player)
        assert player.returncode == 0, play_log
        assert lst.wait_for(lambda: len(bag_io.find_episode_bags(split)) == 3, 5), play_log
        for proc in (rec, rec_all):
            proc.send_signal(signal.SIGINT)
        log, log_all = finish(rec), finish(rec_all)
    finally:
        reap(rec, rec_all, player)
    assert rec.returncode == 0 and rec_all.returncode == 0, log + log_all
    samples = bag_io.find_episode_bags(SAMPLES)
    assert [b.name for b in bag_io.find_episode_bags(split)] == [b.name for b in samples]
    for bag in samples:
        assert_same_episode(bag_io.read_episode(split / bag.name), bag_io.read_episode(bag))
    (bag,) = bag_io.find_episode_bags(whole)
    assert bag.name.startswith("record_")
    with AnyReader([bag]) as reader:
        assert reader.message_count == 3 * 6000
    assert bag_io.META_KEY not in yaml.safe_load((bag / "metadata.yaml").read_text())[
        "rosbag2_bagfile_information"]["custom_data"]


def test_a_journal_still_being_written_is_skipped_by_repair_and_repaired_once_its_writer_is_gone(tmp_path):
    """soil_bag_repair on a recorder's output directory mid-episode turned the live journal into
    a bag of its first seconds and deleted it under the recorder (the rest of the episode lost),
    or crashed reading a journal that grew between its two passes. A writer holds the journal's
    lock until it closes (the kernel drops it when the writer dies): the repair skips it, says
    why and exits 1, touching nothing; once the writer is gone it repairs the journal."""
    partial, w = _journal_from_sample(tmp_path, n_msgs=300, flush_every=100)
    before = journal.journal_path(partial).read_bytes()
    out = subprocess.run([BIN / "soil_bag_repair", str(tmp_path)], capture_output=True, text=True, timeout=30)
    assert out.returncode == 1 and "Traceback" not in out.stderr, out.stderr
    assert f"skipped {partial}" in out.stderr and "another process is writing" in out.stderr, out.stderr
    assert journal.journal_path(partial).read_bytes() == before and not (tmp_path / SAMPLE.name).exists()
    with pytest.raises(journal.JournalInUse):
        journal.journal_to_bag(partial)
    w.write(*[sample_messages()[300][k] for k in (1, 0, 2)])  # the writer goes on undisturbed
    held = w.close(keep_lock=True)  # the recorder's hand-over: closed, its lock kept until it converts
    try:
        with pytest.raises(journal.JournalInUse):  # a repair between the close and the conversion
            journal.journal_to_bag(partial)
        r = journal.journal_to_bag(partial, locked=True)
    finally:
        os.close(held)
    assert not partial.exists() and r.ticks == 30 and len(bag_io.read_episode(r.path)) == 30
    partial, w = _journal_from_sample(tmp_path / "again", n_msgs=300, flush_every=100)
    w.close()
    out = subprocess.run([BIN / "soil_bag_repair", str(tmp_path / "again")], capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    assert not partial.exists() and len(bag_io.read_episode(tmp_path / "again" / SAMPLE.name)) == 30


def test_a_file_system_without_flock_records_and_repairs_unlocked_and_says_so_once(tmp_path, monkeypatch, caplog):
    """Some shared file systems refuse flock (ENOSYS; NFS for a file open only for reading): the
    recorder must still record and the repair still convert, unlocked, with one warning."""
    import errno

    def no_flock(fd, op):
        raise OSError(errno.ENOSYS, "Function not implemented")

    monkeypatch.setattr(journal.fcntl, "flock", no_flock)
    monkeypatch.setattr(journal, "_unlocked_warned", set())
    with caplog.at_level("WARNING", logger=journal.__name__):
        partial, w = _journal_from_sample(tmp_path, n_msgs=300, flush_every=100)
        _killed(w)
        r = journal.journal_to_bag(partial)
    assert r.ticks == 30 and not partial.exists()
    said = [rec.getMessage() for rec in caplog.records if "refuses a lock" in rec.getMessage()]
    assert len(said) == 1 and "Function not implemented" in said[0], said
