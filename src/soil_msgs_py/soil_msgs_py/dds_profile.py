"""The graph's Fast DDS profile: a reliable writer's acknowledgements in a tenth of a second, not
three, and a node that starts late matched within about a second, not three.

Fast DDS (rmw_fastrtps, Jazzy's default RMW) sends a reliable writer's heartbeat, which the
readers answer with their acknowledgement, every 3 s by default, and a small sample carries
none: ``Publisher.wait_for_all_acked`` then waits up to 3 s for a sample every reader got at
once. The graph waits for acknowledgements where order matters (an episode's start before its
first tick, every sample before a node exits): the simulator's ``episode_start`` waited its
whole 2 s bound before every episode, its ``episode_end`` 1 s. Newer Fast DDS releases send a
heartbeat from ``wait_for_all_acked`` itself; the 2.14.5 of the Jazzy wheels does not.

A participant announces itself every 3 s by default. Nodes start at different times (the
estimator loads torch and its model for about 2 s after the others are up), and one that came
after the others' first announcements was, measured on loopback, heard by some of them only at
their next periodic announcement: each launch's first episode waited 2–3 s for it (a lockstep
launch with the estimator and the planner: first episode 5.9–6.1 s after the start, 3.5–4.0 s
with announcements every 0.5 s; ``benchmarks/bench_dds_profile.py``). Lease durations, after
which a silent participant is taken as gone, stay Fast DDS's 20 s.

So every process of the graph loads ``fastdds_profile.xml`` (a writer's heartbeat every 0.1 s, a
participant's announcement every 0.5 s; nothing else changed) unless its user chose profiles of
their own. Other RMWs never read the file.
"""
from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path

PROFILE_FILE = Path(__file__).with_name("fastdds_profile.xml")
PROFILES_NAMESPACE = "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"  # of a Fast DDS profiles file
# Fast DDS 2.x (Jazzy's 2.14) reads only the first, 3.x the second.
PROFILE_ENV_VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def use_graph_profile(env: MutableMapping[str, str] | None = None) -> bool:
    """Point Fast DDS at the graph's profile in ``env`` (default: this process's environment,
    which its child processes inherit) unless a profile file is already set there; a file the
    user set under one name is set under the other too, so that either Fast DDS reads theirs.
    Call before the process's first ``rclpy.init``: Fast DDS reads the profiles once, when the
    first participant is created. True if it set the graph's profile."""
    env = os.environ if env is None else env
    mine = next((env[name] for name in PROFILE_ENV_VARS if env.get(name)), None)
    for name in PROFILE_ENV_VARS:
        if not env.get(name):
            env[name] = mine or str(PROFILE_FILE)
    return mine is None
