"""``use_sim_time``, as a ROS user sets it on every node (a shared params file's ``/**``): the nodes
that follow the simulator take it (their polls, waits and silences run on the steady clock), and
the simulator, the clock's source, says it changes nothing there and paces itself on the wall
clock. Before: a lockstep graph waited 10 s and ended its episode at tick 1, and a simulator given
it started no episode and said nothing (an outside tester's)."""
from __future__ import annotations

import subprocess

import pytest

from soil_bag_tools.bag_io import find_episode_bags, read_episode, read_labelled_topic
from soil_msgs_py import topics as T

from tests.ros_probe import BIN, loopback_env, next_domain_id, run_launch

pytestmark = pytest.mark.live


def test_every_node_given_use_sim_time_keeps_a_lockstep_graph_going(tmp_path):
    domain = next_domain_id()
    bags = tmp_path / "bags"
    shared = tmp_path / "shared.yaml"
    shared.write_text("/**:\n  ros__parameters:\n    use_sim_time: true\n")
    args = ["--pacing", "lockstep", "--estimator", "--record", str(bags), "--sim-param", "duration_s:=2.0",
            "--timeout", "90"]
    for node in ("sim", "controller", "estimator"):
        args += [f"--{node}-params-file", str(shared)]
    rc = run_launch(args, domain, tmp_path / "launch.log", 120)
    log = (tmp_path / "launch.log").read_text(errors="replace")
    assert rc == 0, log[-4000:]
    (bag,) = find_episode_bags(bags)
    ep = read_episode(bag)
    assert len(ep) == 120 and ep.meta.duration_s == 2.0
    stamps, _ = read_labelled_topic(bag, T.ESTIMATE.name, T.ESTIMATE_FIELDS)
    assert len(stamps) > 60, "the estimator followed the episode"
    assert "starting without" not in log and "no complete command" not in log, log[-4000:]
    assert "use_sim_time=True changes nothing here: the simulator is the graph's clock" in log, log[-4000:]

    # the simulator alone, in real time (it had waited for ever in silence)
    sim = subprocess.run([str(BIN / "soil_sim_node"), "--ros-args", "-p", "use_sim_time:=true", "-p", "duration_s:=1.0",
                          "-p", "exit_when_done:=true", "-p", "wait_timeout_s:=0.0"], env=loopback_env(next_domain_id()),
                         capture_output=True, text=True, timeout=60)
    said = sim.stdout + sim.stderr
    assert sim.returncode == 0 and "end (completed): 60 ticks" in said, said
