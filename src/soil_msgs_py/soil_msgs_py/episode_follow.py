"""Which ``/sim/status`` events a node takes: its graph's, and of them the episode under way's end.

Why: a node that took every well-formed event let any other writer of /sim/status steer it. In
an outside tester's live runs one foreign ``episode_start`` (no graph id, 2 m/s, 0.6 m)
retargeted the controller mid-episode at four times the set speed and split the recorder's bag,
and one foreign ``episode_end`` (another episode's name) stopped the controller answering for
the rest of its episode.

A node given its graph's id (``graph_id``, which ``soil_launch`` gives the controller, the
estimator and the planner, as it gives its simulator and recorder) takes no event of another
graph id or of none: its launch's simulator says its id in every event, refuses to run beside
another graph's, and takes the launch down when it dies, so any other event is a stray's. Of its
own graph's, while an episode is under way (its start taken, its end not) it takes only that
episode's ``episode_end`` (same name, episode index, first stamp and graph id), and any start.
A node given no id (started by hand) takes any start whenever it comes, as it always did (a
simulator started again by hand looks like a stray), and refuses only an end that is not the
episode under way's. The episode under way is given up once the node's inputs have been silent
for ``graph.INPUT_SILENCE_S`` (its source is gone). A writer that copies the graph's id (random
per launch, but said in every event) is taken for the graph's own: rclpy's message info names no
writer. No rclpy here.
"""
from __future__ import annotations

from .graph import EVENT_EPISODE_START, EpisodeEvent, graph_id_problem
from .values import short_repr


def graph_said(graph: str) -> str:
    """An event's graph id in words ("graph launch-…", or "no graph id")."""
    return f"graph {graph}" if graph else "no graph id"


def same_episode(a: EpisodeEvent, b: EpisodeEvent) -> bool:
    """Whether two events are of one episode (its start and end carry the same identity)."""
    return (a.name, a.episode, a.first_stamp_ns, a.graph) == (b.name, b.episode, b.first_stamp_ns, b.graph)


class EpisodeFollower:
    """The episode a node follows (module doc); ``refusal`` judges each event in arrival order.
    ``graph_id``: the node's graph ("": none given)."""

    def __init__(self, graph_id: str = "") -> None:
        if problem := graph_id_problem(graph_id):
            raise ValueError(f"parameter graph_id={short_repr(graph_id)} {problem}")
        self.graph_id = graph_id
        self.under_way: EpisodeEvent | None = None

    def refusal(self, ev: EpisodeEvent, source_silent: bool = False) -> str:
        """"" if the node takes ``ev`` (the follower then follows it), else why not, for a warning.
        ``source_silent``: the node's inputs have been silent for ``INPUT_SILENCE_S``: the episode
        under way is given up first."""
        if source_silent:
            self.under_way = None
        if self.graph_id and ev.graph != self.graph_id:
            return (f"{ev.event} of {ev.name} ({graph_said(ev.graph)}; this node follows graph {self.graph_id}): not "
                    "this graph's event (another graph or a stray writer on /sim/status); ignored")
        cur = self.under_way
        if ev.event == EVENT_EPISODE_START:
            self.under_way = ev
            return ""
        if cur is not None and not same_episode(ev, cur):
            return (f"episode_end of {ev.name} (episode {ev.episode}) while {cur.name} (episode {cur.episode}) is "
                    "under way: not its end; ignored")
        self.under_way = None
        return ""
