"""The planner node reads the depth the controller commands (−u_za of /blade/cmd) from the
controller's writer only, as the simulator's command gate follows it (no rclpy.init, no DDS:
the node's callback is called with sequence numbers as DDS's message info gives them)."""
from __future__ import annotations

import collections
from types import SimpleNamespace

from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.writer_identity import FORGET_WRITER_AFTER_TICKS, WriterTracks
from soil_planner.command_wait import CommandWait
from soil_planner.node import PlannerNode

CLASSES = M.ros_message_classes()


def stamp(k: int) -> int:
    return k * 10**9 // 60


def node() -> SimpleNamespace:
    warned = []
    return SimpleNamespace(commanded=collections.OrderedDict(), warned=warned,
                           command_writer=WriterTracks(forget_after_ticks=FORGET_WRITER_AFTER_TICKS),
                           command_wait=CommandWait(), _answer=lambda ticks: None,
                           _warn=lambda kind, text: warned.append(kind))


def send(n, k: int, u_za: float, sequence, values=None) -> None:
    msg = M.make_labelled(CLASSES, stamp(k), T.BLADE_CMD.labels, values or [u_za + 0.3, u_za])
    PlannerNode._on_blade_cmd(n, msg, sequence)


def test_the_controllers_commanded_depth_is_kept_and_an_intruders_is_not():
    n = node()
    for k in range(5):
        send(n, k, -0.10 - 0.01 * k, 1 + k)
    assert n.commanded[stamp(4)] == 0.14
    send(n, 5, -0.30, 1)  # another writer's own counter, first for tick 5
    send(n, 5, -0.15, 6)  # the controller's
    assert n.commanded[stamp(5)] == 0.15
    send(n, 6, float("nan"), 7)  # not finite: nothing for that tick
    assert stamp(6) not in n.commanded


def test_without_sequence_numbers_the_first_command_of_a_tick_counts_and_a_bad_layout_is_warned():
    n = node()
    send(n, 0, -0.12, None)
    send(n, 0, -0.25, None)
    assert n.commanded[stamp(0)] == 0.12
    bad = M.make_labelled(CLASSES, stamp(1), ("u_zr",), [0.1])
    PlannerNode._on_blade_cmd(n, bad, 2)
    assert n.warned == ["blade_cmd:layout"] and stamp(1) not in n.commanded


def test_an_intruders_command_releases_no_tick_waiting_for_the_controllers():
    n = node()
    send(n, 0, -0.10, 1)
    n.command_wait.offer(stamp(1), "tick 1", now_s=0.0)
    send(n, 3, -0.30, 1)  # another writer, stamped ahead
    assert [w.item for w in n.command_wait.waiting] == ["tick 1"]
    send(n, 1, -0.12, 2)  # the controller's own: tick 1 is answered
    assert not n.command_wait.waiting and n.command_wait.newest_command_ns == stamp(1)


def test_one_stray_tick_far_from_the_schedule_moves_no_target_and_a_jump_that_stays_starts_a_new_cut():
    """An outside tester's: one invalid estimate stamped 0 (or an hour ahead) restarted the cut, its
    schedule back at the start depth and the evidence forgotten, without a word. A far tick now moves
    no target until the next one follows it there; a stream that really jumped (a replay started
    over) is a new cut from its second tick."""
    from soil_planner.depth_schedule import DepthSchedule

    published, forgotten = [], []
    n = SimpleNamespace(schedule=DepthSchedule(), planner=SimpleNamespace(forget=lambda: forgotten.append(1)),
                        _target_sent=None, _jumped_to=None, _pace_ns=None, commanded=collections.OrderedDict(),
                        measured=collections.OrderedDict(), command_wait=CommandWait(), lockstep=True, classes=CLASSES,
                        target_pub=SimpleNamespace(publish=lambda msg: published.append(M.parse_labelled(
                            msg, T.TARGET_DEPTH_FIELDS, T.TARGET_DEPTH.name))), warned=[], cut_first_ns=None,
                        cut_end_ns=None, starts_ahead=collections.deque(), cut_newest_ns=None)
    n._warn = lambda kind, text: n.warned.append(kind)
    n._new_cut = lambda at_stamp_ns=None: PlannerNode._new_cut(n, at_stamp_ns)
    n._unfollow_episode = lambda: PlannerNode._unfollow_episode(n)

    def target(k, depth):
        PlannerNode._target(n, stamp(k), depth)

    start = 3600 * 60
    for k in range(start, start + 120):  # two seconds of a cut, the plan allowing 0.3 m
        target(k, 0.3)
    deep = published[-1][1][0]
    assert deep > 0.15 and not forgotten
    for stray in (0, start + 3600 * 60):  # stamped 0, an hour ahead
        count = len(published)
        target(stray, None)
        assert len(published) == count and n.warned[-1] == "jump" and not forgotten
    target(start + 120, 0.3)  # the cut goes on where it was
    assert published[-1][0] == stamp(start + 120) and published[-1][1][0] >= deep and not forgotten
    target(0, 0.3)  # the replay started over: its first tick ...
    target(1, 0.3)  # ... and the next, which follows it: a new cut from the start depth
    assert forgotten == [1] and published[-1][0] == stamp(1) and published[-1][1][0] < deep


def test_a_new_cut_follows_the_controllers_writer_afresh_when_the_ticks_start_again():
    """Bags replayed in a row: the second episode's ticks start at 0 again from the same writer
    (the player's counter goes on). The first episode's track led and its commands were dropped
    until they outnumbered it; the planner's plans of the second bag anchored otherwise."""
    from soil_planner.depth_schedule import DepthSchedule, ScheduleSettings

    n = node()
    n.__dict__.update(measured=collections.OrderedDict(), schedule=DepthSchedule(ScheduleSettings()),
                      planner=SimpleNamespace(forget=lambda: None), _target_sent=None, _jumped_to=None, _pace_ns=None)
    for k in range(300):
        send(n, k, -0.10, 1 + k)
    PlannerNode._new_cut(n)  # the next episode_start
    for k in range(5):
        send(n, k, -0.20, 301 + k)
    assert [n.commanded.get(stamp(k)) for k in range(5)] == [0.20] * 5


def _target_node(published: list, forgotten: list, cut_first_ns=None) -> SimpleNamespace:
    from soil_planner.depth_schedule import DepthSchedule

    n = SimpleNamespace(schedule=DepthSchedule(), planner=SimpleNamespace(forget=lambda: forgotten.append(1)),
                        _target_sent=None, _jumped_to=None, _pace_ns=None, commanded=collections.OrderedDict(),
                        measured=collections.OrderedDict(), command_wait=CommandWait(), lockstep=True, classes=CLASSES,
                        target_pub=SimpleNamespace(publish=lambda msg: published.append(M.parse_labelled(
                            msg, T.TARGET_DEPTH_FIELDS, T.TARGET_DEPTH.name))), warned=[], cut_first_ns=cut_first_ns,
                        cut_end_ns=None if cut_first_ns is None else cut_first_ns + stamp(599), previous_cut_ticks=0, starts_ahead=collections.deque(), cut_newest_ns=None)
    n._warn = lambda kind, text: n.warned.append(kind)
    n._new_cut = lambda at_stamp_ns=None: PlannerNode._new_cut(n, at_stamp_ns)
    n._unfollow_episode = lambda: PlannerNode._unfollow_episode(n)
    return n


def test_estimates_lost_mid_episode_are_a_gap_in_the_cut_not_a_new_cut():
    """Within the episode followed, ticks more than a second ahead of the last scheduled are
    estimates lost (a loaded machine's queue), not a new cut: the cut's evidence and stall memory
    stay (a new cut had forgotten them and jumped the target to the start depth, an outside
    reviewer's). Without an episode followed it stays a new cut, as a replay started over is."""
    published, forgotten = [], []
    n = _target_node(published, forgotten, cut_first_ns=stamp(0))
    for k in range(120):
        PlannerNode._target(n, stamp(k), 0.3)
    deep = published[-1][1][0]
    for k in (120 + 90, 120 + 91):  # 1.5 s of estimates lost, then the cut goes on
        PlannerNode._target(n, stamp(k), 0.3)
    assert not forgotten and n.warned == ["jump"]
    assert published[-1][0] == stamp(211) and published[-1][1][0] <= deep  # backed off over the gap, no jump deeper
    unfollowed = _target_node([], forgotten := [])
    for k in (*range(120), 210, 211):
        PlannerNode._target(unfollowed, stamp(k), 0.3)
    assert forgotten == [1]
    ended = _target_node([], forgotten := [], cut_first_ns=stamp(0))  # a stream 40 s after the episode's end
    for k in (*range(600), 600 + 2400, 600 + 2401):
        PlannerNode._target(ended, stamp(k), 0.3)
    assert forgotten == [1] and ended.cut_first_ns is None  # a new cut, no episode of it followed


def test_estimates_seconds_apart_without_an_episode_followed_are_one_cut_and_two_strays_are_no_pace():
    """An estimator at stride 120 and no /sim/status (a replay of its estimates alone): one cut,
    every estimate after the third moving the target (before: none did). The pace never takes
    in two strays, an hour or 30 s apart, nor keeps a second-wide gap once estimates come at 60 Hz
    again; lost estimates at stride 120 within the episode followed are a gap in the cut (a
    reviewer's: every target had stopped for good after them)."""
    published, forgotten = [], []
    n = _target_node(published, forgotten)
    for k in range(0, 7 * 120, 120):
        PlannerNode._target(n, stamp(k), 0.3)
    assert not forgotten and [p[0] for p in published] == [stamp(k) for k in (0, *range(360, 7 * 120, 120))]
    assert published[0][1][0] == 0.1 and all(p[1][0] == 0.3 for p in published[1:])  # deepened (to the reach), never back
    for k in range(7 * 120, 7 * 120 + 60):  # the stride set back to 1: 60 Hz again
        PlannerNode._target(n, stamp(k), 0.3)
    assert n._pace_ns is None
    count = len(published)
    PlannerNode._target(n, stamp(7 * 120 + 60 + 90), 0.3)  # 1.5 s lost: held, as at 60 Hz before
    assert len(published) == count and n.warned[-1] == "jump"
    strays = _target_node([], forgotten := [])
    for k in range(120):
        PlannerNode._target(strays, stamp(k), 0.3)
    for k in (120 + 3600 * 60, 120 + 7200 * 60):  # two stray ticks an hour apart: held both
        PlannerNode._target(strays, stamp(k), None)
    assert not forgotten and strays.warned == ["jump", "jump"] and strays._pace_ns is None
    near = _target_node(published := [], forgotten := [])
    for k in (*range(120), 120 + 30 * 60, 120 + 60 * 60, *range(120, 240)):  # strays 30 s apart, then the stream
        PlannerNode._target(near, stamp(k), 0.3)
    assert not forgotten and near._pace_ns is None and [p[0] for p in published] == [stamp(k) for k in range(240)]
    followed = _target_node(published := [], forgotten := [], cut_first_ns=stamp(0))
    followed.cut_end_ns = stamp(60 * 60)  # a minute's episode
    ks = [k for k in range(0, 30 * 120, 120) if k not in (10 * 120, 11 * 120)]  # two estimates lost
    for k in ks:
        PlannerNode._target(followed, stamp(k), 0.3)
    assert not forgotten and stamp(ks[-1]) == published[-1][0] and len(published) == len(ks) - 3


def test_a_stream_started_over_without_sim_status_is_planned_again():
    """A replay of an earlier bag with --topics (no /sim/status) after an episode was followed: its
    ticks, all before that episode's first, had been dropped as the previous cut's for good (an
    outside reviewer's). Refused a moment, the stream is followed once it stays there."""
    from soil_planner.node import estimate_joiner

    planned = []
    n = SimpleNamespace(joiner=estimate_joiner(), command_wait=CommandWait(), cut_first_ns=stamp(1200),
                        cut_end_ns=stamp(1799), previous_cut_ticks=0, warned=[], dropped=0, lockstep=True,
                        starts_ahead=collections.deque(), cut_newest_ns=None)
    n._warn = lambda kind, text: n.warned.append(kind)
    n._previous_cut = lambda s: PlannerNode._previous_cut(n, s)
    n._unfollow_episode = lambda: PlannerNode._unfollow_episode(n)
    n._answer = lambda ticks: PlannerNode._answer(n, ticks)
    n._plan = lambda s, est, known: planned.append(s)
    n.joiner.start_at(stamp(1200))
    for k in range(600):  # the replay: ticks 0 .. 10 s, Θ_k and estimate each
        PlannerNode._join(n, T.KNOWN.name, stamp(k), {})
        PlannerNode._join(n, T.ESTIMATE.name, stamp(k), {})
    assert n.cut_first_ns is None and "restart" in n.warned
    assert len(planned) >= 600 - 31 and planned == sorted(planned)


def test_late_estimates_of_the_previous_episode_plan_nothing_in_the_next():
    """An estimator seconds behind: the last ticks of episode A come after B began. Planned, they
    had moved B's target (0.10 -> 0.17 m) and filled its evidence before B's first estimate."""
    published, forgotten = [], []
    n = _target_node(published, forgotten, cut_first_ns=stamp(600))
    planned = []
    n._plan = lambda stamp_ns, est, known: planned.append(stamp_ns)
    n._publish = lambda stamp_ns, values: published.append(("plan", stamp_ns))
    n._previous_cut = lambda stamp_ns: PlannerNode._previous_cut(n, stamp_ns)
    tick = collections.namedtuple("tick", "stamp_ns item")
    PlannerNode._answer(n, [tick(stamp(k), ({}, {})) for k in range(555, 600)] + [tick(stamp(555), ({}, None))])
    assert planned == [] and published == [] and n.previous_cut_ticks == 46 and set(n.warned) == {"previous_cut"}
    PlannerNode._answer(n, [tick(stamp(600), ({}, {}))])
    assert planned == [stamp(600)]


def test_one_stray_estimate_of_an_older_tick_drops_no_tick_waiting_for_its_known_params():
    """One estimate stamped a few ticks behind the newest planned (a second publisher's) had
    restarted the planner's join and dropped every Θ_k waiting: 60 ticks of plans lost."""
    from soil_msgs_py.stamp_join import Verdict
    from soil_planner.node import estimate_joiner

    joiner = estimate_joiner()
    for k in range(100):
        joiner.offer(T.KNOWN.name, stamp(k))
    done = sum(j.complete for k in range(40) for j in joiner.offer(T.ESTIMATE.name, stamp(k)).out)
    assert joiner.offer(T.ESTIMATE.name, stamp(35)).verdict is Verdict.STALE
    done += sum(j.complete for k in range(40, 100) for j in joiner.offer(T.ESTIMATE.name, stamp(k)).out)
    assert done == 100
    joiner.start_at(stamp(600))  # the next episode's start: older ticks refused, its own kept
    assert joiner.offer(T.ESTIMATE.name, stamp(599)).verdict is Verdict.STALE
    assert [j.stamp_ns for j in joiner.offer(T.KNOWN.name, stamp(600)).out + joiner.offer(
        T.ESTIMATE.name, stamp(600)).out] == [stamp(600)]


def _held_starts_node(monkeypatch):
    """A stand-in planner node for its held starts: the real ``_on_status``, ``_start_ahead``,
    ``_follow_cut`` and ``_note_estimate``; ``started`` lists each cut started (name, ahead, back)."""
    import soil_planner.node as PN

    n = SimpleNamespace(cut_first_ns=None, cut_end_ns=None, cut_newest_ns=None, timeline_newest_ns=None,
                        cut_known_ns=None, known_jump=None,
                        starts_ahead=collections.deque(), started=[], _warn=None, follower=None,
                        silence=SimpleNamespace(start=lambda name: None, end=lambda: None))

    def start_cut(event, last, ahead, back=False):
        n.started.append((event.name, ahead, back))
        PlannerNode._follow_cut(n, event, last)

    n._start_cut = start_cut
    n._estimates_still_due = lambda first: PlannerNode._estimates_still_due(n, first)
    n._start_ahead = lambda stamp_ns: PlannerNode._start_ahead(n, stamp_ns)
    monkeypatch.setattr(PN, "followed_status_event", lambda event, *args: event)
    n.status = lambda event: PlannerNode._on_status(n, SimpleNamespace(data=event))
    n.estimate = lambda k: PlannerNode._note_estimate(n, stamp(k))
    return n


def _start(first_k, name, ticks=90):
    from soil_msgs_py import graph as G
    from soil_msgs_py.episode import EpisodeMeta

    meta = EpisodeMeta("Clay", 40.0, "default", 0, 0.5, 0.1, 1.5, source="test")
    return G.EpisodeEvent(G.EVENT_EPISODE_START, 0, name, meta, stamp(first_k), planned_ticks=ticks)


def test_an_estimate_starts_only_the_held_episode_that_holds_it_and_drops_those_held_before(monkeypatch):
    """Starts held while the cut under way still had estimates due: an estimate of a held episode
    starts that one; those held before it (a stray start, or an episode none of whose estimates
    came) are dropped, not started: started, a stray had cleared the next cut's commands and forces
    (a reviewer's). An estimate beyond every held episode (a stray) starts none."""
    n = _held_starts_node(monkeypatch)
    n.status(_start(0, "A"))
    for k in range(41):
        n.estimate(k)
    for held in (_start(10**6, "stray"), _start(90, "B"), _start(180, "C")):
        n.status(held)
    assert n.started == [("A", False, False)] and len(n.starts_ahead) == 3
    n.estimate(60)  # the cut under way's own late estimate
    n.estimate(10**7)  # a stray beyond every held episode
    assert n.started == [("A", False, False)] and len(n.starts_ahead) == 3
    n.estimate(180)  # C's first estimate (B's never came)
    assert n.started[1:] == [("C", True, False)] and not n.starts_ahead


def test_a_replay_started_over_starts_once_an_estimate_goes_back_to_it(monkeypatch):
    """A start held at or before the cut under way (a replay started over, behind other held starts)
    starts at an estimate at or before the newest so far: time went back. The late estimates of the
    cut under way, in its range too, start nothing; nor do those owed a cut started early, with none
    of its estimates yet, when more than ``MAX_STARTS_AHEAD`` starts were held (they had started the
    replay's cut and dropped every held start, a reviewer's). A cut of one estimate, at its first
    tick, lets the replay start at that tick's (it had never started). Once time went back, the
    newest is the new pass's."""
    from soil_planner.node import MAX_STARTS_AHEAD

    n = _held_starts_node(monkeypatch)
    n.status(_start(0, "A"))
    for k in range(41):
        n.estimate(k)
    n.status(_start(90, "B"))
    n.status(_start(0, "A again"))  # held behind B
    n.estimate(60)  # A's own late estimate, in the replay's range too
    assert n.started == [("A", False, False)] and len(n.starts_ahead) == 2
    n.estimate(30)  # back: the replay's
    assert n.started[1:] == [("A again", False, True)] and not n.starts_ahead
    for k in range(31, 39):  # the replay's newest (38) is time's newest now, not the first pass's (40)
        n.estimate(k)
    n.status(_start(90, "B again"))
    n.status(_start(0, "A a third time"))
    n.estimate(39)  # the second pass's own late estimate
    assert n.started[2:] == [] and len(n.starts_ahead) == 2

    n = _held_starts_node(monkeypatch)  # one estimate only, at the cut's first tick
    n.status(_start(0, "A"))
    n.estimate(0)
    n.status(_start(90, "B"))
    n.status(_start(0, "A again"))
    n.estimate(0)
    assert n.started[1:] == [("A again", False, True)] and not n.starts_ahead

    n = _held_starts_node(monkeypatch)  # the estimator more than MAX_STARTS_AHEAD episodes behind
    ticks = 30
    n.status(_start(0, "E0", ticks))
    for k in range(5):
        n.estimate(k)
    for e in range(1, MAX_STARTS_AHEAD + 1):
        n.status(_start(e * ticks, f"E{e}", ticks))
    n.status(_start(0, "E0 again", ticks))  # one too many held: E1 starts early
    assert n.started == [("E0", False, False), ("E1", True, False)]
    for k in range(5, 4 * ticks):  # E0's late estimates (none of a replay), then E1's to E3's
        n.estimate(k)
    assert n.started[2:] == [("E2", True, False), ("E3", True, False)]
    assert len(n.starts_ahead) == MAX_STARTS_AHEAD - 2 and n.starts_ahead[-1][0].name == "E0 again"
    n.estimate(0)  # the replay's first estimate: the held episodes before it never came, dropped
    assert n.started[4:] == [("E0 again", False, True)] and not n.starts_ahead
