"""Live fuzzing: a hostile node publishes malformed messages into a running graph.

The whole graph (simulator, controller, estimator, recorder) runs under ``soil_launch`` on its
own loopback domain while ``tests.hostile.HostileNode`` publishes a bounded, seeded stream of
bad messages on every topic the graph uses. A bad message must never stop a node, make a node
publish something non-finite, silence the controller or change what the bag says. Lockstep
pacing makes the last point exact: a lockstep run equals ``soil_sim_batch``'s run of the same
seed bit for bit, so any intruder value or missing tick in the bag shows as a difference,
however loaded the machine is.
"""
from __future__ import annotations


import numpy as np
import pytest

from soil_bag_tools.bag_io import find_episode_bags, read_episode, read_labelled_topic
from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_sim_node.rollout import run_episodes
from soil_sim_node.simulator import EpisodeSpec, SimConfig

from tests.hostile import GraphObserver, HostileNode, grid_stamp, non_finite_fields
from tests.ros_probe import next_domain_id, run_launch

pytestmark = pytest.mark.live

SEED = 5
BUDGET = 600  # malformed messages at most
SPEC = EpisodeSpec("Clay", 80.0, 0.5, 0.15, seed=21, duration_s=4.0)
TICKS = 240
OBSERVED = (*G.SIM_STATE_TOPICS, *G.COMMAND_TOPICS, G.SIM_STATUS_TOPIC, *G.ESTIMATOR_OUTPUTS)


def _launch_args(bags) -> list[str]:
    sim = {"world_mode": "default", "soil": SPEC.soil, "relative_density_pct": SPEC.relative_density_pct,
           "target_depth_m": SPEC.target_depth_m, "seed": SPEC.seed, "duration_s": SPEC.duration_s}
    args = ["--pacing", "lockstep", "--estimator", "--record", str(bags), "--timeout", "90",
            "--sim-param", "wait_timeout_s:=60.0"]  # (the observer's own wait is bounded by 60 s too)
    for name, value in sim.items():
        args += ["--sim-param", f"{name}:={value}"]
    # The observer and the hostile node subscribe to every state topic and the hostile node
    # publishes commands: the simulator waits for them too, so tick 0 already meets them. The
    # observer subscribes to the state topics only once it hears the controller's commands and
    # the estimator's outputs (``GraphObserver`` held topics), so it misses none of them either.
    for topic in G.SIM_STATE_TOPICS:
        args += ["--wait-for", f"{topic}:2"]
    for topic in G.COMMAND_TOPICS:
        args += ["--wait-for", f"{topic}:1"]
    return args + ["--wait-for", f"{G.SIM_STATUS_TOPIC}:1"]


def _stamps(messages, topic: str) -> list[int]:
    out = []
    for msg in messages:
        try:
            out.append(M.parse_message(topic, msg)[0])
        except ValueError:
            out.append(-1)
    return out


@pytest.mark.timeout(180)
def test_a_hostile_node_cannot_stop_the_graph_silence_the_controller_or_change_the_bag(tmp_path):
    domain = next_domain_id()
    bags = tmp_path / "bags"
    held = {t: 2 for t in (*G.COMMAND_TOPICS, *G.ESTIMATOR_OUTPUTS)}  # the graph's publisher and the hostile one
    with GraphObserver(domain, OBSERVED, held=G.SIM_STATE_TOPICS, until_matched=held) as observer, \
            HostileNode(domain, SEED, BUDGET) as hostile:
        rc = run_launch(_launch_args(bags), domain, tmp_path / "launch.log", 120)
        log = (tmp_path / "launch.log").read_text(errors="replace")
        observer.settle()  # what is still in flight reaches the observer
        graph = {topic: observer.graph_messages(topic, hostile) for topic in OBSERVED}
        sent, sent_by_tick, spoofed = hostile.sent, dict(hostile.sent_by_tick), set(hostile.spoofed_stamps)
        matched_s = observer.matched_s

    problems: list[str] = []
    if matched_s is None:  # a harness fault, said as such: the observer may have missed the first ticks
        problems.append(f"the observer did not hear the graph's publishers of {sorted(held)} within 60 s")
    # 1. No node died: the launch ends with the simulator's last episode and exits 0.
    died = [line for line in log.splitlines() if " died " in line or "exited with code" in line or "Traceback" in line]
    if rc != 0 or died:
        problems.append(f"launch exit code {rc}; {died[:6]}")

    # 2. The simulator ran the whole episode.
    ends = [G.EpisodeEvent.from_json(m.data) for m in graph[G.SIM_STATUS_TOPIC]]
    ends = [e for e in ends if e.event == G.EVENT_EPISODE_END]
    if [(e.reason, e.ticks) for e in ends] != [("completed", TICKS)]:
        problems.append(f"episode ends {[(e.reason, e.ticks) for e in ends]}, expected one completed with {TICKS} ticks")

    # 3. Nothing non-finite (and no impossible stamp) left any node.
    for topic in OBSERVED:
        for msg in graph[topic]:
            if bad := non_finite_fields(msg):
                problems.append(f"a node published {topic} with {bad[:3]}")
                break

    # 4. The controller answered every tick the simulator published.
    ticks = sorted(set(_stamps(graph[T.CHASSIS_POSE.name], T.CHASSIS_POSE.name)))
    first = ticks[0] if ticks else 0
    grid = [grid_stamp(first, k) for k in range(TICKS)]
    if ticks != grid:
        problems.append(f"the simulator's /chassis/pose stamps are not the {TICKS}-tick grid: {len(ticks)} stamps")
    for topic in G.COMMAND_TOPICS:
        unanswered = sorted(set(grid) - set(_stamps(graph[topic], topic)))
        if unanswered:
            problems.append(f"the controller left {len(unanswered)} ticks without {topic}, from {unanswered[0]} ns")

    # 5. The bag holds the simulator's run and nothing else: equal to the batch run bit for bit.
    found = find_episode_bags(bags) if bags.is_dir() else []
    if len(found) != 1:
        problems.append(f"{len(found)} bags recorded, expected 1: {found}")
    else:
        try:
            live = read_episode(found[0])
        except ValueError as err:
            problems.append(f"the bag does not read as an episode: {err}")
        else:
            (ref,) = run_episodes(SimConfig(world_mode="default"), [SPEC])
            if len(live) != len(ref) or not np.array_equal(live.stamps_ns - live.stamps_ns[0], ref.stamps_ns):
                missing = sorted(set(grid) - set(live.stamps_ns.tolist()))
                copied = sorted({t for t, s in spoofed if s in set(missing)})
                problems.append(f"the bag has {len(live)} ticks, not the {len(ref)}-tick grid: {len(missing)} missing "
                                f"from {missing[:1]} ns; the hostile node sent copies stamped like them on {copied}")
            else:
                for name in ("observations", "forces", "known", "truth", "extras"):
                    diff = np.flatnonzero((getattr(live, name) != getattr(ref, name)).any(axis=1))
                    if diff.size:
                        k = int(diff[0])
                        problems.append(f"bag {name} differs from the simulator's run at {diff.size} ticks, "
                                        f"first tick {k}: {getattr(live, name)[k].tolist()} in the bag, "
                                        f"{getattr(ref, name)[k].tolist()} simulated")
        # Estimates in the bag: only ones the estimator published.
        try:
            stamps, values = read_labelled_topic(found[0], T.ESTIMATE.name, T.ESTIMATE_FIELDS)
        except ValueError as err:
            problems.append(f"the bag's {T.ESTIMATE.name} does not read: {err}")
        else:
            published = {M.parse_labelled(m, T.ESTIMATE_FIELDS)[0]: np.asarray(M.parse_labelled(
                m, T.ESTIMATE_FIELDS)[1]) for m in graph[T.ESTIMATE.name] if M.labelled_stamp(m) is not None}
            # The observer matches the estimator's publisher by discovery, which a fast lockstep
            # graph may outrun: judge from the first estimate it saw on.
            seen_from = min(published, default=0)
            foreign = [s for s, v in zip(stamps.tolist(), values) if s >= seen_from and (
                       s not in published or not np.array_equal(published[s], v))]
            if foreign or len(set(stamps.tolist())) != len(stamps):
                spoofs = sum((T.ESTIMATE.name, s) in spoofed for s in foreign)
                problems.append(f"the bag's {T.ESTIMATE.name} holds {len(foreign)} messages the estimator did not "
                                f"publish (of {len(stamps)}; {spoofs} stamped like a hostile copy, "
                                f"{len(set(foreign) - set(grid))} off the tick grid), "
                                f"first at {foreign[:1]} ns")

    # The attack really happened, inside the episode.
    during = sent_by_tick.get(grid[-1], sent) if grid else 0
    print(f"\nhostile node: {sent} messages ({during} before the last tick), {len(spoofed)} same-stamp copies; "
          f"graph messages observed: { {t: len(m) for t, m in graph.items()} }")
    if during < 150 or len(spoofed) < 30:
        problems.append(f"the hostile stream missed the episode: {during} sent before its last tick, {len(spoofed)} spoofs")
    assert not problems, "\n".join(problems) + f"\n--- launch log (tail) ---\n{log[-6000:]}"
