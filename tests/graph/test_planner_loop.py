"""The loop closed in the live graph: ``soil_launch --planner`` runs simulator, controller,
estimator, planner and recorder as separate processes on a loopback domain, along a path whose
soil changes. The planner's targets are in the bag and the controller cut to them."""
from __future__ import annotations

import contextlib
import io
import subprocess
from pathlib import Path

import numpy as np
import pytest

from soil_bag_tools.bag_io import find_episode_bags, read_episode, read_labelled_topic
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.params import OBSERVATION_FIELDS

from tests.ros_probe import launched, next_domain_id, run_launch, wait_until

pytestmark = pytest.mark.live

U_ZA = OBSERVATION_FIELDS.index("u_za")
README = Path(__file__).resolve().parents[2] / "README.md"


def run_readme_planner_example(bag) -> dict:
    """The README's "Your own planner from the topics" example, run on ``bag`` (its namespace)."""
    text = README.read_text(encoding="utf-8")
    start = text.index("```python\n", text.index("**Your own planner from the topics.**")) + len("```python\n")
    code = text[start:text.index("```", start)]
    assert code.count('"bags/live/<episode>"') == 1, "the example no longer names its bag as it did"
    namespace: dict = {}
    with contextlib.redirect_stdout(io.StringIO()):
        exec(compile(code.replace("bags/live/<episode>", str(bag)), str(README), "exec"), namespace)
    return namespace


@pytest.mark.timeout(180)
def test_soil_launch_with_the_planner_closes_the_loop_and_records_it(tmp_path):
    domain, bags = next_domain_id(), tmp_path / "bags"
    args = ["--planner", "--pacing", "realtime", "--record", str(bags), "--timeout", "120",
            "--sim-param", "patches:=['0:Sand:20','4.5:Clay:80']", "--sim-param", "duration_s:=8.0",
            "--sim-param", "world_mode:=fee", "--planner-param", "start_depth_m:=0.08"]
    log_path = tmp_path / "launch.log"
    rc = run_launch(args, domain, log_path, 150)
    out = log_path.read_text()
    assert rc == 0, out[-4000:]
    assert "[planner]" in out and "depth_source:=planner" in out and "following the planner's target depth" in out, out[-4000:]

    (bag,) = find_episode_bags(bags)
    ep = read_episode(bag)
    stamps, targets = read_labelled_topic(bag, T.TARGET_DEPTH.name, T.TARGET_DEPTH_FIELDS)
    plan_stamps, plans = read_labelled_topic(bag, T.PLAN.name, T.PLAN_FIELDS)
    assert len(plan_stamps) > 100 and len(stamps) >= 10 and np.isfinite(targets).all()
    assert targets[0, 0] == pytest.approx(0.08) and targets[:, 0].max() > 0.12  # started shallow, then deepened
    # its figure draws the planner's targets, not the episode's 0.2 m the controller never cut to
    from soil_sim_node.plot import planner_targets
    drawn_t, drawn = planner_targets(bag, ep)
    np.testing.assert_array_equal(drawn, targets[:, 0])
    np.testing.assert_allclose(drawn_t, (stamps - ep.stamps_ns[0]) / 1e9)
    # The controller answers a tick before that tick's plan exists: a command follows some target
    # stamped within planner_timeout_s (1 s) before its tick, or the parameter's 0.2 m without
    # one; never deeper than the deepest of them (u_za = −(d̄ − Δd̄) >= −d̄: the anti-stall lift).
    after = ep.stamps_ns >= stamps[0]
    u_za, when = ep.observations[after, U_ZA], ep.stamps_ns[after]
    lo = np.searchsorted(stamps, when - M.NS_PER_S, side="left")
    hi = np.searchsorted(stamps, when, side="right")
    deepest = np.array([targets[a:b, 0].max(initial=0.2) for a, b in zip(lo, hi)])
    assert (u_za >= -deepest - 1e-9).all(), (u_za[u_za < -deepest - 1e-9][:5], deepest[u_za < -deepest - 1e-9][:5])
    exact = np.array([np.isclose(u, -targets[a:b, 0], atol=1e-9).any() for u, a, b in zip(u_za, lo, hi)])
    assert exact.mean() > 0.5, exact.mean()  # mostly cut to a planner target exactly (not lifting, not 0.2 m)


@pytest.mark.timeout(240)
def test_in_lockstep_the_live_loop_keeps_step_with_the_planner_and_equals_the_cut_report_loop(tmp_path):
    """In lockstep the simulator outruns the estimator and planner; the controller waits for the
    planner's target of tick k − 2 before it answers tick k (``plan_wait``), so the live graph, five
    processes over DDS, cuts exactly what ``soil_cut_report``'s in-process loop cuts, whatever the
    load (the episode's target depth, the controller's fallback for the first two ticks, set to the
    planner's start depth as the report's loop starts there). Into dense gravel, where the lift
    holds the edge short of its commanded depth and the plan reads that command (``command_wait``):
    on a loaded machine (two or three CPU-bound processes beside it), planned without waiting for
    it, 103 and 358 of the 480 ticks differed from the report's loop (up to 8 cm).

    The loop runs in a machine's namespace (``--namespace /dozer1``) beside another graph of its
    own in the root namespace of the same domain, cutting clay: with absolute topic names, which
    ignore a namespace, the two had crossed their data (a node that missed its namespace would
    hear the other's ticks, and the cut would differ from the report's loop)."""
    from soil_bringup.cut_trial import Policy, SoilAwareSetup, run_cut
    from soil_msgs_py.params import KNOWN_PARAMS
    from soil_sim_node.simulator import EpisodeSpec

    domain, bags, other_bags = next_domain_id(), tmp_path / "bags", tmp_path / "other"
    patches = ["0:Sand:20", "1.5:Gravel:90"]
    args = ["--namespace", "/dozer1", "--planner", "--pacing", "lockstep", "--record", str(bags), "--timeout", "180",
            "--sim-param", "patches:=[" + ",".join(f"'{p}'" for p in patches) + "]", "--sim-param", "duration_s:=8.0",
            "--sim-param", "target_depth_m:=0.1", "--sim-param", "seed:=5",
            # the waits' bounds are for liveness, not the loop: here generous, so that a machine
            # loaded by other tests does not end a wait that a quiet one never reaches (the
            # simulator waits up to its lockstep_timeout_s, 10 s, for the controller)
            "--controller-param", "planner_wait_s:=8.0", "--planner-param", "command_wait_s:=5.0"]
    log_path, other_log = tmp_path / "launch.log", tmp_path / "other.log"
    with launched(["--pacing", "lockstep", "--record", str(other_bags), "--timeout", "180", "--sim-param", "soil:=Clay",
                   "--sim-param", "duration_s:=4.0"], domain, other_log) as other:
        rc = run_launch(args, domain, log_path, 220)
        other_rc = other.wait(timeout=60)
    out = log_path.read_text()
    assert rc == 0, out[-4000:]
    assert other_rc == 0, other_log.read_text()[-4000:]
    # each simulator waited for its own nodes by name (/dozer1/soil_bag_record_<launch>, /soil_bag_record_<launch>)
    # and met them
    assert "starting without" not in out and "starting without" not in other_log.read_text(), out[-4000:]
    (other_bag,) = find_episode_bags(other_bags)
    other_ep = read_episode(other_bag)  # the root graph's own ticks, each once, its own soil
    assert len(other_ep) == 240 and other_ep.meta.soil == "Clay", (len(other_ep), other_ep.meta)
    assert "[sim]" in out and "dozer1.soil_sim_node" in out and "dozer1.soil_planner" in out, out[-4000:]
    # (a plan that did not come within planner_wait_s on a loaded machine would make the cut differ:
    # said here, by its cause, before the arrays below)
    assert "answered without its planner target" not in out, out[-4000:]
    assert "no planner target" not in out and "estimates unpaired" in out and " 0 estimates unpaired" in out, out[-4000:]
    assert " 0 planned without it" in out, out[-4000:]  # (each tick's own command read, as the report's loop)
    # the posterior read through the estimator's physics, heard from it (the launcher no longer passes it)
    assert "plans read the posterior through FEE + form:-qnq*tanhvx0.1 (k = 0.756) (the estimator's)" in out, out[-4000:]
    (bag,) = find_episode_bags(bags)
    ep = read_episode(bag)
    stamps, _ = read_labelled_topic(bag, T.TARGET_DEPTH.name, T.TARGET_DEPTH_FIELDS)
    assert len(stamps) == len(ep) == 480  # a target for every tick

    spec = EpisodeSpec("Sand", 20.0, 0.5, 0.1, seed=5, duration_s=8.0, patches=patches)
    cut = run_cut("default", spec, Policy("soil-aware"), SoilAwareSetup("default"))
    assert ep.meta.soil_patches() == cut.spec.patches
    np.testing.assert_array_equal(ep.known[:, KNOWN_PARAMS.index("d")], cut.depth)
    assert np.ptp(cut.target) > 0.05  # the plan moved the cut (deeper in the sand, then held in the gravel)

    # The README's example of a planner of one's own, run on this bag, plans what the node planned:
    # its last plan is the node's last, which depends on every tick's estimate, command and force before
    plan_stamps, plans = read_labelled_topic(bag, T.PLAN.name, T.PLAN_FIELDS)
    example = run_readme_planner_example(bag)
    assert example["stamp"] == plan_stamps[-1]
    assert (example["plan"].max_depth_m, example["plan"].f_x_n) == pytest.approx(
        tuple(plans[-1, [T.PLAN_FIELDS.index("max_depth_m"), T.PLAN_FIELDS.index("f_x_n")]]), rel=1e-9)


@pytest.mark.timeout(180)
@pytest.mark.parametrize("role, executable, signal", [("planner", "soil_planner", "-9"),
                                                      ("estimator", "pinn_estimator", "-15")])
def test_an_advisory_node_that_dies_does_not_stop_the_cut(tmp_path, role, executable, signal):
    """The planner and the estimator it plans from are advice: either killed mid-episode (the
    planner as a crash, the estimator stopped, which leaves the graph at once), the planner sends
    no more targets, the controller falls back to its own target depth and the episodes run to
    their end; the launch says what died (and exits 1 at the end if it crashed). The next episode
    waits for the stopped node's endpoints once (wait_timeout_s), the one after that not again
    (before, each later episode waited the whole timeout); a crashed node's endpoints stay
    matched until its DDS lease ends."""
    domain = next_domain_id()
    # the crash is checked over one episode (its lingering readers cost each later one 3 s of acks
    # and each node's stop 5 s), the stop over three (the third must not wait); 2.5 s each: the
    # kill comes at the first episode's first ticks, the fallback after 1 s
    episodes = 1 if signal == "-9" else 3
    args = ["--planner", "--pacing", "realtime", "--timeout", "150",
            "--sim-param", "duration_s:=2.5", "--sim-param", "world_mode:=fee",
            "--sim-param", f"episodes:={episodes}", "--sim-param", "wait_timeout_s:=4.0"]
    log_path = tmp_path / "launch.log"
    with launched(args, domain, log_path) as proc:
        wait_until(lambda: "following the planner's target depth" in log_path.read_text(), 90,
                   "the controller following the planner")
        node = wait_until(lambda: subprocess.run(["pgrep", "-P", str(proc.pid), "-f", executable],
                                                 capture_output=True, text=True).stdout.split(), 10, f"the {role}")
        subprocess.run(["kill", signal, node[0]], check=True)
        rc = proc.wait(timeout=120)
    out = log_path.read_text()
    assert rc == (1 if signal == "-9" else 0), out[-4000:]  # stopped, it exits 0: no failure of the launch
    how = "died (exit code -9)" if signal == "-9" else "exited (exit code 0)"
    assert f"{role} {how}; not required, the others go on" in out, out[-4000:]
    assert "no planner target within" in out, out[-4000:]  # the controller fell back to its own depth
    assert "sim finished; stopping the others" in out and f"episode {episodes - 1} end" in out, out[-4000:]
    if signal == "-15":  # gone from the graph at once: episode 1 waits for it, gives up, episode 2 does not wait
        after = out.split(f"{role} {how}")[1]
        assert "starting without" in after.split("episode 1 start")[0] and "until they match again" in after, out[-4000:]
        assert "starting without" not in after.split("episode 1 start")[1].split("episode 2 start")[0], out[-4000:]


@pytest.mark.timeout(120)
def test_an_advisory_node_refusing_its_parameters_stops_the_launch(tmp_path):
    """Not required is not optional: a planner refusing a parameter at start is the user's
    mistake, and the launch stops everything and says so rather than cut without it."""
    domain = next_domain_id()
    args = ["--planner", "--pacing", "realtime", "--timeout", "90",
            "--sim-param", "duration_s:=6.0", "--planner-param", "margin:=2.0"]
    log_path = tmp_path / "launch.log"
    rc = run_launch(args, domain, log_path, 110)
    out = log_path.read_text()
    assert rc == 1, out[-4000:]
    assert "planner refused its parameters (exit code 2); stopping the others" in out, out[-4000:]
    assert "margin=2.0" in out and "episode 0 end" not in out, out[-4000:]
