"""Which /sim/status events a node takes (``soil_msgs_py.episode_follow``), no ROS: the episode
under way's own end, starts of its graph, anything between episodes or once its source is gone."""
from __future__ import annotations

from dataclasses import replace

from soil_msgs_py import graph as G
from soil_msgs_py.episode import EpisodeMeta
from soil_msgs_py.episode_follow import EpisodeFollower, same_episode

META = EpisodeMeta(soil="Clay", relative_density_pct=50.0, world_mode="default", seed=3, target_speed_m_s=0.5,
                   target_depth_m=0.15, duration_s=10.0)
START = G.EpisodeEvent(G.EVENT_EPISODE_START, 0, META.name, META, 10**9, planned_ticks=600, graph="launch-a")
END = replace(START, event=G.EVENT_EPISODE_END, last_stamp_ns=10**9 + 599 * 16_666_666, ticks=600, reason="completed")
STRAY_META = replace(META, target_speed_m_s=2.0, target_depth_m=0.6)


def test_mid_episode_a_stray_start_or_another_episodes_end_is_refused_and_the_episode_goes_on():
    follower = EpisodeFollower()
    assert follower.refusal(START) == ""
    stray_start = G.EpisodeEvent(G.EVENT_EPISODE_START, 7, "foreign_episode", STRAY_META, 5 * 10**9, planned_ticks=60)
    why = follower.refusal(stray_start)
    assert "foreign_episode (no graph id)" in why and "(graph launch-a) is under way" in why and "ignored" in why
    other_graph = replace(stray_start, graph="launch-b")
    assert "graph launch-b" in follower.refusal(other_graph)
    stray_end = replace(END, name="other_graph_episode", episode=7)
    assert "not its end" in follower.refusal(stray_end)
    assert "not this graph's" in follower.refusal(replace(END, graph=""))  # its name, another graph
    assert follower.under_way == START  # still following the episode
    assert follower.refusal(START) == ""  # the same start again (a late or repeated delivery)
    assert follower.refusal(END) == "" and follower.under_way is None
    # between episodes any start is taken, of any graph
    assert follower.refusal(other_graph) == "" and follower.under_way == other_graph


def test_a_restart_of_the_same_graph_is_followed_and_a_gone_source_frees_the_follower():
    follower = EpisodeFollower()
    follower.refusal(START)
    restarted = replace(START, episode=0, first_stamp_ns=0)  # its simulator started over (stamps from 0 again)
    assert follower.refusal(restarted) == "" and follower.under_way == restarted
    stray = G.EpisodeEvent(G.EVENT_EPISODE_START, 0, "replayed", META, 0, planned_ticks=60)  # a player's (no id)
    assert follower.refusal(stray) != ""
    assert follower.refusal(stray, source_silent=True) == "" and follower.under_way == stray
    # an episode without a graph id (a replay, a simulator by hand) yields to any start; its end
    # is still its own
    assert "not its end" in follower.refusal(replace(END, graph=""))
    assert follower.refusal(START) == "" and follower.under_way == START


def test_an_episode_is_its_start_and_end_alike():
    assert same_episode(START, END)
    for changed in ({"name": "x"}, {"episode": 1}, {"first_stamp_ns": 0}, {"graph": "launch-b"}):
        assert not same_episode(START, replace(END, **changed)), changed
