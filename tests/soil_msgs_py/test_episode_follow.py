"""Which /sim/status events a node takes (``soil_msgs_py.episode_follow``), no ROS: given its graph's
id, none of another graph or of none and, mid-episode, only the episode's own end; given none, any
start and only the episode's own end; any start once its source is gone."""
from __future__ import annotations

from dataclasses import replace

import pytest

from soil_msgs_py import graph as G
from soil_msgs_py.episode import EpisodeMeta
from soil_msgs_py.episode_follow import EpisodeFollower, same_episode

META = EpisodeMeta(soil="Clay", relative_density_pct=50.0, world_mode="default", seed=3, target_speed_m_s=0.5,
                   target_depth_m=0.15, duration_s=10.0)
START = G.EpisodeEvent(G.EVENT_EPISODE_START, 0, META.name, META, 10**9, planned_ticks=600, graph="launch-a")
END = replace(START, event=G.EVENT_EPISODE_END, last_stamp_ns=10**9 + 599 * 16_666_666, ticks=600, reason="completed")
STRAY = G.EpisodeEvent(G.EVENT_EPISODE_START, 7, "foreign_episode",
                       replace(META, target_speed_m_s=2.0, target_depth_m=0.6), 5 * 10**9, planned_ticks=60)


def test_a_launched_node_refuses_strays_and_other_graphs_and_follows_its_own_episodes():
    follower = EpisodeFollower("launch-a")
    other = replace(STRAY, graph="launch-b")
    why = follower.refusal(other)  # before any episode: a stray start had taken the nodes over (the hostile test)
    assert "foreign_episode (graph launch-b; this node follows graph launch-a): not this graph's event" in why, why
    assert "foreign_episode (no graph id; this node follows graph launch-a)" in follower.refusal(STRAY)
    assert follower.under_way is None and follower.refusal(START) == ""
    assert "foreign_episode (no graph id" in follower.refusal(STRAY)  # mid-episode
    assert "not its end" in follower.refusal(replace(END, name="other_graph_episode", episode=7))
    assert "not this graph's" in follower.refusal(replace(END, graph=""))  # its name, no id
    assert follower.under_way == START  # still following the episode
    assert follower.refusal(START) == ""  # the same start again (a late or repeated delivery)
    restarted = replace(START, first_stamp_ns=0)  # its simulator started over, stamps from 0 again
    assert follower.refusal(restarted) == "" and follower.under_way == restarted
    assert follower.refusal(replace(END, first_stamp_ns=0)) == "" and follower.under_way is None
    assert follower.refusal(STRAY) != "" and follower.refusal(STRAY, source_silent=True) != ""  # never its graph's
    # its own graph's next episode whose start was lost: its end is taken once the first's source is gone
    follower.refusal(START)
    next_end = replace(END, name="next", episode=1, first_stamp_ns=2 * 10**10)
    assert "not its end" in follower.refusal(next_end)
    assert follower.refusal(next_end, source_silent=True) == "" and follower.under_way is None


def test_a_node_given_no_graph_id_takes_any_start_and_only_the_episodes_own_end():
    """Started by hand: a simulator started again by hand (no id) after a launched one looks like a
    stray, so every start is taken, as always; an end that is not the episode under way's is not."""
    follower = EpisodeFollower()
    assert follower.refusal(START) == ""
    assert follower.refusal(STRAY) == "" and follower.under_way == STRAY
    assert "not its end" in follower.refusal(END)
    assert follower.refusal(replace(STRAY, event=G.EVENT_EPISODE_END, last_stamp_ns=6 * 10**9, ticks=60,
                                    reason="completed")) == ""
    assert follower.under_way is None and follower.refusal(END) == ""  # (nothing under way: taken)


def test_a_bad_graph_id_is_refused_naming_the_parameter():
    with pytest.raises(ValueError, match="parameter graph_id='a b' must be a string of at most 64 letters"):
        EpisodeFollower("a b")


def test_an_episode_is_its_start_and_end_alike():
    assert same_episode(START, END)
    for changed in ({"name": "x"}, {"episode": 1}, {"first_stamp_ns": 0}, {"graph": "launch-b"}):
        assert not same_episode(START, replace(END, **changed)), changed
