"""The planner node and episodes whose estimates come late: an estimator behind (a replay of bags in
a row faster than it) still sends an episode's estimates after the next episodes began. They are
planned and published as that episode's, and each episode's cut starts with its own first estimate.
Real node process, real DDS on loopback, the probe playing the simulator and the estimator."""
from __future__ import annotations

import time

import pytest
from std_msgs.msg import String

from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.episode import EpisodeMeta
from soil_msgs_py.params import TICK_PERIOD_NS
from soil_msgs_py.ros_adapter import publisher_qos
from tests.ros_probe import NodeProc, RosProbe, next_domain_id

pytestmark = pytest.mark.live

FIRST = 100 * M.NS_PER_S
TICKS = 90  # per episode


def stamp(episode: int, k: int) -> int:
    return FIRST + int((episode * TICKS + k) * TICK_PERIOD_NS)


@pytest.mark.timeout(120)
@pytest.mark.parametrize("scenario", ["behind", "stray", "loop"])
def test_estimates_of_an_episode_that_come_after_the_next_ones_began_are_planned_as_its_own(tmp_path, scenario):
    """behind: the estimator an episode and a half behind, late copies of starts taken already among
    the events; stray: one estimate an hour ahead among them (it had started every held cut, a
    reviewer's); loop: a replay of two bags started over (--loop) while the estimator is behind, the
    first bag's start again after the second's (it had been ignored as a copy, and the second pass
    dropped as the previous cut's, a reviewer's)."""
    domain = next_domain_id()
    classes = M.ros_message_classes()
    metas = [EpisodeMeta(soil, 40.0, "default", i, 0.5, 0.1, TICKS / 60.0, source="test")
             for i, soil in enumerate(("Clay", "Sand", "Loam"))]
    with RosProbe(domain) as probe:
        probe.subscribe(T.PLAN.name, T.PLAN.msgtype)
        status = probe.publisher(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        estimate = probe.publisher(T.ESTIMATE.name, T.ESTIMATE.msgtype, publisher_qos(T.ESTIMATE.name))
        planner = NodeProc("soil_planner", ["--ros-args", "-p", "inputs_wait_s:=0.0"], domain, tmp_path)

        def event(kind, i):
            extra = dict(last_stamp_ns=stamp(i, TICKS - 1), ticks=TICKS, reason="completed") if kind == G.EVENT_EPISODE_END else {}
            status.publish(String(data=G.EpisodeEvent(kind, i, metas[i].name, metas[i], stamp(i, 0),
                                                      planned_ticks=TICKS, **extra).to_json()))

        def send(i, ks):  # estimates with nothing to plan from yet (a window filling): each answered at once
            for k in ks:
                estimate.publish(M.make_labelled(classes, stamp(i, k), T.ESTIMATE_FIELDS, [0.0] * len(T.ESTIMATE_FIELDS)))
                time.sleep(0.004)  # (a burst beyond the readers' history is lost on the way, not by the planner)

        def planned():
            return {M.parse_labelled(m, T.PLAN_FIELDS, T.PLAN.name)[0] for m in probe.messages(T.PLAN.name)}

        try:
            probe.wait_for(lambda: status.get_subscription_count() >= 1 and estimate.get_subscription_count() >= 1
                           and probe.matched_publishers(T.PLAN.name) >= 1, 60, "planner endpoints")
            event(G.EVENT_EPISODE_START, 0)
            sent = []

            def first_plans():  # (a reader may match late on a busy core: send until planned)
                send(0, [len(sent)])
                sent.append(len(sent))
                return planned()
            probe.wait_for(first_plans, 20, "the first plans")
            n = len(sent)
            assert n < TICKS // 2, f"{n} estimates before the first plan"
            send(0, range(n, TICKS // 2))
            probe.wait_for(lambda: stamp(0, TICKS // 2 - 1) in planned(), 20, "plans of the first half")
            # the estimator falls behind: A's end, B's start and end and C's start come before A's last estimates
            event(G.EVENT_EPISODE_END, 0)
            event(G.EVENT_EPISODE_START, 1)
            event(G.EVENT_EPISODE_END, 1)
            if scenario == "loop":
                event(G.EVENT_EPISODE_START, 0)  # the first bag again
            else:
                event(G.EVENT_EPISODE_START, 2)
                event(G.EVENT_EPISODE_START, 1)  # late copies of starts taken already change nothing
                event(G.EVENT_EPISODE_START, 0)
            time.sleep(1.0)
            if scenario == "stray":
                estimate.publish(M.make_labelled(classes, stamp(0, 0) + 3600 * M.NS_PER_S, T.ESTIMATE_FIELDS,
                                                 [0.0] * len(T.ESTIMATE_FIELDS)))
            send(0, range(TICKS // 2, TICKS))
            send(1, range(TICKS))
            send(*((0, range(TICKS)) if scenario == "loop" else (2, range(30))))
            want = {stamp(0, k) for k in range(n, TICKS)} | {stamp(1, k) for k in range(TICKS)} | (
                set() if scenario == "loop" else {stamp(2, k) for k in range(30)})
            plans = (lambda: len(probe.messages(T.PLAN.name))) if scenario == "loop" else None
            try:
                probe.wait_for(lambda: want <= planned() and (plans is None or plans() >= 2 * TICKS + TICKS - n), 30,
                               "a plan of every estimate")
            except AssertionError as err:
                missing = sorted((s - FIRST) // int(TICK_PERIOD_NS) for s in want - planned())
                raise AssertionError(f"{err}: ticks {missing} missing; the planner said: {planner.output}") from None
        finally:
            assert planner.stop() == 0, planner.output
    assert "before the episode under way" not in planner.output, planner.output
