"""The live monitor (soil_bringup.monitor) fed one episode's messages by hand, no simulator:
how it pairs estimates with their tick's truth and force, and what it prints and counts."""
from __future__ import annotations

import io

import pytest

from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.params import DEG, GROUND_TRUTH_PARAMS

from soil_bringup.monitor import LiveMonitor
from tests.soil_bringup.estimate_bags import estimate

pytestmark = pytest.mark.live


def _status(event: str, ep, **kw):
    from std_msgs.msg import String

    first = int(ep.stamps_ns[0])
    return String(data=G.EpisodeEvent(event, 0, ep.meta.name, ep.meta, first, **kw).to_json())


def test_each_second_prints_its_estimate_with_its_ticks_truth_and_force_and_the_end_closes_the_episode(episode):
    from tests.ros_probe import next_domain_id

    ep, out = episode, io.StringIO()
    classes = M.ros_message_classes()
    monitor = LiveMonitor(next_domain_id(), 1, out=out)
    try:
        monitor._on_status(_status(G.EVENT_EPISODE_START, ep, planned_ticks=len(ep)))
        for k, stamp in enumerate(int(s) for s in ep.stamps_ns):
            if k != 60:  # the truth of the tick that starts second 1 is lost: the one before stands in
                monitor._on_truth(M.make_labelled(classes, stamp, GROUND_TRUTH_PARAMS, ep.truth[k]))
            monitor._on_force(M.build_message(classes, T.BLADE_FORCE.name, stamp, ep.forces[k]))
            monitor._on_estimate(M.make_labelled(classes, stamp, T.ESTIMATE_FIELDS,
                                                 estimate(ep, k, k >= 59, min(k + 1, 60))))
        monitor._on_status(_status(G.EVENT_EPISODE_END, ep, ticks=len(ep), reason="completed"))
        late = int(ep.stamps_ns[-1])  # an estimate after the end is not counted
        monitor._on_estimate(M.make_labelled(classes, late, T.ESTIMATE_FIELDS, estimate(ep, len(ep) - 1, True, 60)))
    finally:
        monitor.close()

    lines = out.getvalue().splitlines()
    live = [line for line in lines if line.startswith("Clay    20%")]
    assert [line[12:17] for line in live] == [" 0.0s", " 1.0s"], lines
    assert "filling window  1/60" in live[0]
    assert "--/" not in live[1] and f"{ep.forces[60, 0] / 1e3:.2f}" in live[1]
    assert f"/{ep.truth[59, GROUND_TRUTH_PARAMS.index('phi')] / DEG:<5.1f}" in live[1]
    seen = monitor.episodes[0]
    assert seen.reason == "completed" and seen.ticks == len(ep)
    assert seen.estimates == len(ep) and seen.valid == len(ep) - 59 == len(seen.latencies_s)
    assert lines[-1].startswith("--- end (completed): 120 ticks") and "61 valid estimates seen live" in lines[-1]
