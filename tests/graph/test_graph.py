"""The live graph: simulator and controller nodes in separate processes over DDS on loopback.

Each test gets its own ROS_DOMAIN_ID; every process is started as its console script and
stopped (or killed) at the end; every wait is bounded.
"""
from __future__ import annotations

import collections

import json
import math
import re
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import String

from soil_bringup.launch import stop_logged_nodes
from tests.ros_probe import call_service, NodeProc, RosProbe, next_domain_id, start_launch, wait_until
from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T

pytestmark = [pytest.mark.live, pytest.mark.timeout(120)]
CLASSES = M.ros_message_classes()


def _events(probe: RosProbe) -> list[G.EpisodeEvent]:
    return [G.EpisodeEvent.from_json(m.data) for m in probe.messages(G.SIM_STATUS_TOPIC)]


def _ended(probe: RosProbe, n: int = 1):
    return lambda: [e for e in _events(probe) if e.event == G.EVENT_EPISODE_END][n - 1:] or None


def _sim_args(*params: str, wait_for: tuple[str, ...] = ()) -> list[str]:
    out = ["--ros-args"]
    for p in params:
        out += ["-p", p]
    if wait_for:
        out += ["-p", "wait_for:=[" + ",".join(f"'{w}'" for w in wait_for) + "]"]
    return out


@pytest.fixture
def domain():
    return next_domain_id()


def test_realtime_graph_publishes_every_tick_and_reports_timing(tmp_path, domain):
    """sim + controller at 60 Hz: every tick of the episode arrives, stats are sane; a misspelt
    parameter is named (rclpy alone would ignore it silently) and the node exits without a
    traceback once its episodes are done."""
    with RosProbe(domain) as probe:
        probe.subscribe(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        probe.subscribe(T.BLADE_FORCE.name, T.BLADE_FORCE.msgtype)
        probe.subscribe(T.CMD_VEL.name, T.CMD_VEL.msgtype)
        ctl = NodeProc("anti_stall_controller", [], domain, tmp_path)
        sim = None
        try:
            # the simulator waits until it sees the controller; the probe must see it too before
            # the first tick, or on a busy machine its discovery lags and the first commands pass it by
            probe.wait_for(lambda: probe.matched_publishers(T.CMD_VEL.name) >= 1, 30, "the controller's commands")
            sim = NodeProc("soil_sim_node", _sim_args(
                "duration_s:=2.0", "exit_when_done:=true", "soil:=Clay", "seeed:=3",
                wait_for=("/chassis/cmd_vel:1", "/blade/cmd:1", "/chassis/twist:1", "/sim/status:2",
                          "/blade/force:1")), domain, tmp_path)
            assert sim.wait(timeout=30) == 0, sim.output
            end = probe.wait_for(_ended(probe), 5, "episode_end")[0]
        finally:
            if sim is not None:
                sim.stop()
            ctl.stop()
        assert end.reason == "completed" and end.ticks == 120 and end.meta.soil == "Clay"
        assert "parameter 'seeed' is not a parameter of this node (did you mean seed?); ignored" in sim.output
        assert "Traceback" not in sim.output and "Exception ignored" not in sim.output, sim.output
        stamps = [M.parse_message(T.BLADE_FORCE.name, m)[0] for m in probe.messages(T.BLADE_FORCE.name)]
        assert stamps == [end.first_stamp_ns + (k * 10**9) // 60 for k in range(120)]
        answered = {M.parse_message(T.CMD_VEL.name, m)[0] for m in probe.messages(T.CMD_VEL.name)}
        assert answered == set(stamps)
        stats = end.stats  # how fast and how steady: benchmarks/bench_graph.py
        print(f"\nrealtime 2 s: period {stats['period']}, jitter {stats['jitter']}, loop {stats['loop_latency']}, "
              f"late {stats['late_commands']}")
        assert stats["nominal_period_ms"] == pytest.approx(1e3 / 60, abs=1e-3)
        assert stats["period"]["n"] == stats["jitter"]["n"] == 119  # one period between each two ticks
        assert stats["loop_latency"]["n"] + stats["late_commands"] == 120  # each tick answered in time or late


def _bad_command_burst(probe: RosProbe, stamp: int, k: int) -> None:
    """One of several kinds of bad command for the tick stamped ``stamp``."""
    vel = probe.publisher(T.CMD_VEL.name, T.CMD_VEL.msgtype)
    blade = probe.publisher(T.BLADE_CMD.name, T.BLADE_CMD.msgtype)
    tick = 10**9 // 60
    kind = k % 6
    if kind == 0:
        vel.publish(M.build_message(CLASSES, T.CMD_VEL.name, stamp, [math.nan]))
        blade.publish(M.build_message(CLASSES, T.BLADE_CMD.name, stamp, [math.inf, -0.1]))
    elif kind == 1:
        vel.publish(M.build_message(CLASSES, T.CMD_VEL.name, stamp, [0.5]))
        blade.publish(M.build_message(CLASSES, T.BLADE_CMD.name, stamp, [5.0, -0.1]))  # beyond the reach
    elif kind == 2:
        vel.publish(M.build_message(CLASSES, T.CMD_VEL.name, stamp - 3 * tick, [0.5]))  # stale
        blade.publish(M.build_message(CLASSES, T.BLADE_CMD.name, stamp + 5 * tick, [0.0, 0.0]))  # future
    elif kind == 3:
        wrong = M.make_labelled(CLASSES, stamp, ("u_zr", "u_zb"), [0.0, 0.0])  # wrong labels
        blade.publish(wrong)
        vel.publish(M.build_message(CLASSES, T.CMD_VEL.name, stamp, [-math.inf]))
    elif kind == 4:
        short = M.make_labelled(CLASSES, stamp, ("u_zr", "u_za"), [0.0, 0.0])
        short.data = short.data[:3]  # wrong shape
        blade.publish(short)
        vel.publish(M.build_message(CLASSES, T.CMD_VEL.name, stamp, [50.0]))  # beyond max speed
    else:
        vel.publish(M.build_message(CLASSES, T.CMD_VEL.name, stamp, [0.5]))
        blade.publish(M.build_message(CLASSES, T.BLADE_CMD.name, stamp, [-0.1, -0.1]))


def test_bad_commands_are_clamped_or_ignored_never_published_as_nan(tmp_path, domain):
    with RosProbe(domain) as probe:
        for t in T.EPISODE_TOPICS[:8]:
            probe.subscribe(t.name, t.msgtype)
        probe.subscribe(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        sim = NodeProc("soil_sim_node", _sim_args(
            "duration_s:=3.0", "exit_when_done:=true", wait_for=("/chassis/pose:1", "/sim/status:1")),
            domain, tmp_path)
        try:
            answered, k = set(), 0
            t_end = time.monotonic() + 30
            while sim.proc.poll() is None and time.monotonic() < t_end:
                poses = probe.messages(T.CHASSIS_POSE.name)
                if poses:
                    stamp = M.parse_message(T.CHASSIS_POSE.name, poses[-1])[0]
                    if stamp not in answered:
                        answered.add(stamp)
                        _bad_command_burst(probe, stamp, k)
                        k += 1
                time.sleep(0.002)
            assert sim.wait(timeout=10) == 0, sim.output
            end = probe.wait_for(_ended(probe), 5, "episode_end")[0]
        finally:
            sim.stop()
        out = sim.output
    assert end.reason == "completed" and end.ticks == 180, out  # kept running through all of it
    assert k > 60
    for t in T.EPISODE_TOPICS[:8]:
        msgs = probe.messages(t.name)
        assert len(msgs) == 180, t.name
        values = np.array([M.parse_message(t.name, m)[1] for m in msgs])
        assert np.isfinite(values).all(), f"{t.name} published a non-finite value"
    for needle in ("field u_x=nan is not finite", "field u_zr=inf is not finite", "field u_zr=5.0 outside",
                   "field u_x=-inf is not finite", "field u_x=50.0 outside", "stale stamp", "future stamp",
                   "label mismatch", "len(data)=3"):
        assert needle in out, f"no warning containing {needle!r} in:\n{out}"
    assert end.stats["commands_sanitised"] > 0 and end.stats["commands_rejected"] > 0


def test_episodes_start_and_reset_over_sim_command(tmp_path, domain):
    with RosProbe(domain) as probe:
        probe.subscribe(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        cmd = probe.publisher(G.SIM_COMMAND_TOPIC, G.STRING_MSGTYPE)
        sim = NodeProc("soil_sim_node", _sim_args("episodes:=0", "rate:=4.0", "duration_s:=1.0"), domain, tmp_path)
        try:
            probe.wait_for(lambda: cmd.get_subscription_count() > 0 and probe.matched_publishers(G.SIM_STATUS_TOPIC),
                           20, "the simulator's /sim/command subscription")
            # every parameter reads back, the empty lists too (declared by type alone, they had no
            # value, and rclpy's get_parameters then answered nothing for a request naming one)
            client = AsyncParameterClient(probe.node, "soil_sim_node")
            assert client.wait_for_services(timeout_sec=20)
            names = call_service(lambda: client.list_parameters()).result.names
            values = call_service(lambda: client.get_parameters(names)).values
            assert {"patches", "plugins", "effects_off", "wait_for"} <= set(names) and len(values) == len(names)
            assert [v.string_array_value for n, v in zip(names, values) if n == "patches"] == [[]]
            time.sleep(0.3)
            cmd.publish(String(data="{not json"))
            cmd.publish(String(data=json.dumps({"action": "start", "soil": "Sand", "seed": 7})))
            cmd.publish(String(data=json.dumps({"action": "start", "relative_density_pct": 250})))  # refused
            first = probe.wait_for(_ended(probe), 10, "first episode end")[0]
            cmd.publish(String(data=json.dumps({"action": "start", "soil": "Gravel", "duration_s": 30.0})))
            starts = probe.wait_for(lambda: [e for e in _events(probe) if e.event == "episode_start"][1:], 10, "start")
            time.sleep(0.5)
            cmd.publish(String(data=json.dumps({"action": "reset"})))
            second = probe.wait_for(_ended(probe, 2), 10, "reset episode end")[0]
            cmd.publish(String(data=json.dumps({"action": "start", "duration_s": 30.0})))
            probe.wait_for(lambda: [e for e in _events(probe) if e.event == "episode_start"][2:], 10, "third start")
            cmd.publish(String(data=json.dumps({"action": "shutdown"})))  # ends the running episode too
            third = probe.wait_for(_ended(probe, 3), 10, "shutdown episode end")[0]
            assert sim.wait(timeout=10) == 0
        finally:
            sim.stop()
    assert first.meta.soil == "Sand" and first.meta.seed == 7 and first.reason == "completed" and first.ticks == 60
    assert starts[0].meta.soil == "Gravel"
    assert second.reason == "reset" and 0 < second.ticks < 1800
    assert second.first_stamp_ns == first.last_stamp_ns + 16_666_667  # simulation time continues
    assert third.reason == "shutdown" and third.ticks < 1800
    out = sim.output
    assert "/sim/command: not JSON" in out and "relative_density_pct=250" in out


def test_with_no_planned_episode_exit_when_done_waits_for_a_commanded_one(tmp_path, domain):
    """episodes:=0 (episodes only via /sim/command) with exit_when_done:=true had exited at once,
    before any command could come (an outside tester's): it exits once a commanded episode ran."""
    with RosProbe(domain) as probe:
        probe.subscribe(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        cmd = probe.publisher(G.SIM_COMMAND_TOPIC, G.STRING_MSGTYPE)
        sim = NodeProc("soil_sim_node", _sim_args("episodes:=0", "exit_when_done:=true", "rate:=4.0", "duration_s:=1.0"),
                       domain, tmp_path)
        try:
            probe.wait_for(lambda: cmd.get_subscription_count() > 0 and probe.matched_publishers(G.SIM_STATUS_TOPIC),
                           20, "the simulator's /sim/command subscription")
            time.sleep(1.0)  # (its timer runs every tick: it had finished within the first)
            assert sim.proc.poll() is None, sim.output
            cmd.publish(String(data=json.dumps({"action": "start", "soil": "Sand", "seed": 7})))
            ended = probe.wait_for(_ended(probe), 20, "the commanded episode's end")[0]
            assert sim.wait(timeout=20) == 0 and ended.reason == "completed"
        finally:
            sim.stop()


def test_controller_parameters_files_overrides_and_runtime_changes(tmp_path, domain):
    params = tmp_path / "ctl.yaml"
    params.write_text("anti_stall_controller:\n  ros__parameters:\n    target_speed_m_s: 0.7\n    c_vx: 0.1\n")
    with RosProbe(domain) as probe:
        probe.subscribe(T.CMD_VEL.name, T.CMD_VEL.msgtype)
        probe.subscribe(T.BLADE_CMD.name, T.BLADE_CMD.msgtype)
        ctl = NodeProc("anti_stall_controller", ["--ros-args", "--params-file", str(params), "-p", "c_vx:=0.3",
                                                 "-p", "follow_episode_targets:=false"], domain, tmp_path)
        try:
            client = AsyncParameterClient(probe.node, "anti_stall_controller")
            assert client.wait_for_services(timeout_sec=20)
            got = call_service(lambda: client.get_parameters(["target_speed_m_s", "c_vx", "target_depth_m"]))
            assert [v.double_value for v in got.values] == [0.7, 0.3, 0.2]  # file, then -p override

            ok = call_service(lambda: client.set_parameters([Parameter("target_speed_m_s", value=0.9),
                                              Parameter("target_depth_m", value=0.1)]))
            assert all(r.successful for r in ok.results)
            bad = call_service(lambda: client.set_parameters([Parameter("target_speed_m_s", value=-1.0)]))
            assert not bad.results[0].successful and "target_speed_m_s" in bad.results[0].reason
            bad = call_service(lambda: client.set_parameters([Parameter("k_v_m_s", value=math.nan)]))
            assert not bad.results[0].successful and "k_v_m_s" in bad.results[0].reason

            twist = probe.publisher(T.CHASSIS_TWIST.name, T.CHASSIS_TWIST.msgtype)
            pose = probe.publisher(T.CHASSIS_POSE.name, T.CHASSIS_POSE.msgtype)
            probe.wait_for(lambda: twist.get_subscription_count() and probe.node.count_subscribers(T.CMD_VEL.name) == 1
                           and pose.get_subscription_count(), 20, "controller subscriptions")
            time.sleep(0.3)
            stamp = 5 * 10**9
            twist.publish(M.build_message(CLASSES, T.CHASSIS_TWIST.name, stamp, [0.9, 0.0]))
            pose.publish(M.build_message(CLASSES, T.CHASSIS_POSE.name, stamp, [1.0, -0.05]))
            probe.wait_for(lambda: probe.messages(T.BLADE_CMD.name), 10, "the controller's answer")
            pose.publish(M.build_message(CLASSES, T.CHASSIS_POSE.name, stamp - 10**7, [1.0, -0.05]))  # stale
            wait_until(lambda: "is not newer than the last answered tick" in ctl.output, 10, "the stale warning")
        finally:
            ctl.stop()
    (vel,) = probe.messages(T.CMD_VEL.name)
    (blade,) = probe.messages(T.BLADE_CMD.name)
    assert M.parse_message(T.CMD_VEL.name, vel) == (stamp, pytest.approx([0.9]))
    b_stamp, (u_zr, u_za) = M.parse_message(T.BLADE_CMD.name, blade)
    assert b_stamp == stamp and u_za == pytest.approx(-0.1) and u_zr == pytest.approx(-0.05)
    assert "is not newer than the last answered tick" in ctl.output


def _launch(args: list[str], domain: int, tmp_path) -> subprocess.Popen:
    """soil_launch as a subprocess; its output goes to ``proc.log_path`` (one file per launch)."""
    return start_launch(args, domain, tmp_path / f"launch_{time.monotonic_ns()}.log")


def _running(pid: str) -> bool:
    """The process exists and is no zombie (an orphan's new parent may be slow to reap it)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _process_report(pid: str) -> str:
    """What a process that should have stopped is doing, from /proc: its command, state, signals
    (pending, blocked, caught, ignored: SIGTERM is bit 15) and where each thread waits in the kernel
    (``wchan``: ``pipe_write`` would be a write to its dead launcher's pipe, ``futex`` a lock)."""
    base = Path(f"/proc/{pid}")
    try:
        cmd = base.joinpath("cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
        status = dict(line.split(":", 1) for line in base.joinpath("status").read_text().splitlines() if ":" in line)
        waits = collections.Counter(t.joinpath("wchan").read_text() or "-" for t in base.joinpath("task").iterdir())
    except OSError as err:
        return f"pid {pid}: gone while reported ({err})"
    fields = ", ".join(f"{k} {status.get(k, '?').strip()}" for k in ("State", "SigPnd", "ShdPnd", "SigBlk", "SigCgt",
                                                                      "SigIgn"))
    return f"pid {pid} ({cmd[:160]}): {fields}; threads waiting in {dict(waits)}"


def _children_gone(pid: int) -> bool:
    res = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True)
    return res.stdout.strip() == ""


def test_a_start_waits_for_the_named_nodes_own_endpoints_not_for_a_reader_outside(tmp_path, domain):
    """wait_for 'topic@/node' (soil_launch names its own nodes so): a reader outside the graph on
    every awaited topic (the probe) meets each count but starts nothing; the recorder named does,
    and its bag holds the whole episode. (With counts alone an outside reader met them before the
    launch's recorder listened: the first episode went unrecorded and the launch exited 0.)"""
    from rosbags.highlevel import AnyReader

    from soil_bag_tools.bag_io import find_episode_bags

    recorder = "/" + G.NODE_NAMES["recorder"]
    with RosProbe(domain) as probe:
        probe.subscribe(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        probe.subscribe(T.BLADE_FORCE.name, T.BLADE_FORCE.msgtype)
        sim = NodeProc("soil_sim_node", _sim_args(
            "duration_s:=1.0", "exit_when_done:=true", "wait_timeout_s:=0", "world_mode:=fee",
            wait_for=("/sim/status:1", "/blade/force:1", f"/sim/status@{recorder}", f"/blade/force@{recorder}")),
            domain, tmp_path)
        rec = None
        try:
            wait_until(lambda: "queued" in sim.output, 60, "the simulator up")
            time.sleep(3.0)  # (a window for a wrong start: the counts are met, the named reader is not there)
            assert not _events(probe) and "episode 0 start" not in sim.output, sim.output
            rec = NodeProc("soil_bag_record", ["--out", str(tmp_path / "bags")], domain, tmp_path)
            assert sim.wait(timeout=60) == 0, sim.output
            wait_until(lambda: find_episode_bags(tmp_path / "bags"), 30, "the recorder's bag")
        finally:
            for proc in (sim, rec):
                if proc is not None:
                    proc.stop()
    (bag,) = find_episode_bags(tmp_path / "bags")
    with AnyReader([bag]) as reader:  # (no controller: the state's ticks, not an episode to train on)
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts[T.BLADE_FORCE.name] == counts[T.CLOCK.name] == 60, (counts, rec.output)  # every tick of the 1 s


def test_a_wait_for_entry_naming_a_node_is_checked():
    from soil_sim_node.pacing import AwaitedEndpoint, parse_wait_for

    known = {"/sim/status", "/blade/force"}
    assert parse_wait_for(["/sim/status:2", "/blade/force@/dozer1/soil_bag_record"], known) == [
        AwaitedEndpoint("/sim/status", 2), AwaitedEndpoint("/blade/force", 1, "/dozer1/soil_bag_record")]
    for bad in ("/blade/force@soil_bag_record", "/blade/force@/1node", "/nowhere@/n", "/sim/status@/a//b",
                "/sim/status@/n:1", "/sim/status:²"):
        with pytest.raises(ValueError, match=f"wait_for entry '{re.escape(bad)}'"):
            parse_wait_for([bad], known)


def test_launch_runs_episodes_in_a_row_and_exits_zero(tmp_path, domain):
    with RosProbe(domain) as probe:
        probe.subscribe(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        # The probe is outside the launch: the simulator must see its subscription before the first
        # (1 s, lockstep) episode starts, or a slow discovery loses that episode's events.
        proc = _launch(["--pacing", "lockstep", "--sim-param", "duration_s:=1.0", "--sim-param", "episodes:=2",
                        "--sim-param", "sequence_soils:=['Clay','Sand']", "--wait-for", f"{G.SIM_STATUS_TOPIC}:1"],
                       domain, tmp_path)
        assert proc.wait(timeout=60) == 0
        probe.wait_for(_ended(probe, 4), 5, "four episode ends")
    ends = [e for e in _events(probe) if e.event == G.EVENT_EPISODE_END]
    names = [e.name for e in ends]
    assert [e.reason for e in ends] == ["completed"] * 4 and [e.ticks for e in ends] == [60] * 4
    assert [n.split("_")[1] for n in names] == ["clay", "clay", "sand", "sand"]
    assert [int(n.rsplit("_s", 1)[1]) for n in names] == [0, 1, 2, 3]


def test_launch_exits_nonzero_when_a_node_dies_and_stops_the_rest(tmp_path, domain):
    proc = _launch(["--sim-param", "duration_s:=60.0", "--timeout", "60"], domain, tmp_path)
    try:
        def controller_pid():
            res = subprocess.run(["pgrep", "-P", str(proc.pid), "-f", "anti_stall_controller"],
                                 capture_output=True, text=True)
            return res.stdout.split()
        pid = wait_until(controller_pid, 20, "the controller process")[0]
        time.sleep(2.0)
        subprocess.run(["kill", "-9", pid], check=True)
        rc = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    log = proc.log_path.read_text()
    assert rc == 1, log
    assert "controller died (exit code -9)" in log
    assert _children_gone(proc.pid)


def test_launch_forwards_ctrl_c_and_exits_as_interrupted(tmp_path, domain):
    proc = _launch(["--sim-param", "duration_s:=60.0", "--timeout", "60"], domain, tmp_path)
    try:
        wait_until(lambda: "episode 0 start" in proc.log_path.read_text(), 30, "the episode to start")
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    log = proc.log_path.read_text()
    assert rc == 130, log  # 128 + SIGINT: interrupted, not done
    assert "interrupted; stopping all nodes" in log and "episode 0 end (shutdown)" in log
    # each node says why it stops (an estimator that ended with code 0 and no word looked like a crash)
    assert all(re.search(rf"\[{name}\].*stopping: SIGINT received", log) for name in ("sim", "controller")), log
    assert _children_gone(proc.pid)


def test_a_launcher_killed_outright_takes_its_nodes_with_it_and_the_bag_is_finished(tmp_path, domain):
    """SIGKILL leaves the launcher no chance to stop its nodes; they used to run on as orphans on
    the domain (a second controller spoils every tick of the next launch). Each node now gets
    SIGTERM from the kernel when the launcher dies, which it takes as an ordinary stop: the
    recorder still finishes the episode's bag."""
    from soil_bag_tools.bag_io import find_episode_bags, read_episode

    # The episode (300 s) outlasts the wait below: a node that stops in it stopped because its
    # launcher died, not because the run ended. The wait bounds a hang, it times nothing (a node's
    # stop is itself bounded by its drain, its readers' acknowledgements and the executor's end,
    # which a machine under load stretches); a node still running after it is reported from /proc.
    proc = _launch(["--record", str(tmp_path / "bags"), "--sim-param", "duration_s:=300.0", "--timeout", "300"],
                   domain, tmp_path)
    try:
        wait_until(lambda: "episode 0 start" in proc.log_path.read_text(), 30, "the episode to start")
        nodes = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True).stdout.split()
        assert len(nodes) == 3, proc.log_path.read_text()  # recorder, controller, simulator
        time.sleep(1.0)
        proc.kill()
        proc.wait(timeout=10)
        try:
            wait_until(lambda: not any(_running(pid) for pid in nodes), 120, "the nodes to stop")
        except AssertionError as err:
            still = "\n".join(_process_report(pid) for pid in nodes if _running(pid))
            raise AssertionError(f"{err}; still running:\n{still}") from None
    finally:
        if proc.poll() is None:
            proc.kill()
        stop_logged_nodes(proc.log_path)  # a failure above leaves no node of it behind
    (bag,) = find_episode_bags(tmp_path / "bags")
    assert len(read_episode(bag)) > 0  # a finished bag: metadata written, ticks readable


# --- recorded runs (soil_launch with the recorder) --------------------------------------

def _recorded_episodes(root):
    from soil_bag_tools.bag_io import find_episode_bags, read_episode
    return [read_episode(b) for b in find_episode_bags(root)]


def test_lockstep_run_records_the_batch_generators_episode_bit_for_bit(tmp_path, domain):
    """Two seeded episodes in a row through DDS in separate processes == soil_sim_batch's arrays."""
    from soil_sim_node.rollout import run_episodes
    from soil_sim_node.simulator import EpisodeSpec, SimConfig

    proc = _launch(["--pacing", "lockstep", "--record", str(tmp_path / "bags"), "--timeout", "90",
                    "--sim-param", "world_mode:=default", "--sim-param", "soil:=Clay",
                    "--sim-param", "relative_density_pct:=80.0", "--sim-param", "target_depth_m:=0.15",
                    "--sim-param", "seed:=21", "--sim-param", "duration_s:=4.0", "--sim-param", "episodes:=2"],
                   domain, tmp_path)
    assert proc.wait(timeout=120) == 0, proc.log_path.read_text()
    recorded = _recorded_episodes(tmp_path / "bags")
    assert len(recorded) == 2, proc.log_path.read_text()
    specs = [EpisodeSpec("Clay", 80.0, 0.5, 0.15, seed=s, duration_s=4.0) for s in (21, 22)]
    batch = run_episodes(SimConfig(world_mode="default"), specs)
    for live, ref in zip(recorded, batch):
        assert live.meta.seed == ref.meta.seed and live.meta.source == "soil_sim_node"
        assert len(live) == len(ref) == 240
        np.testing.assert_array_equal(live.stamps_ns - live.stamps_ns[0], ref.stamps_ns)
        for name in ("observations", "forces", "known", "truth", "extras"):
            np.testing.assert_array_equal(getattr(live, name), getattr(ref, name), err_msg=name)
    assert recorded[1].stamps_ns[0] == recorded[0].stamps_ns[-1] + 16_666_667


def test_lockstep_with_the_force_lift_records_the_batch_generators_episode_bit_for_bit(tmp_path, domain):
    """The controller joining /blade/force by stamp (``force_lift_m_s`` > 0) over DDS gives the
    compiled rollout's episode with the same gains, and the lift acted (dense clay at 0.25 m)."""
    from anti_stall_controller.controller import AntiStallGains
    from soil_sim_node.rollout import run_episodes
    from soil_sim_node.simulator import EpisodeSpec, SimConfig

    proc = _launch(["--pacing", "lockstep", "--record", str(tmp_path / "bags"), "--timeout", "90",
                    "--sim-param", "world_mode:=default", "--sim-param", "soil:=Clay",
                    "--sim-param", "relative_density_pct:=80.0", "--sim-param", "target_depth_m:=0.25",
                    "--sim-param", "seed:=5", "--sim-param", "duration_s:=4.0",
                    "--controller-param", "force_lift_m_s:=1.0"], domain, tmp_path)
    assert proc.wait(timeout=120) == 0, proc.log_path.read_text()
    (live,) = _recorded_episodes(tmp_path / "bags")
    spec = [EpisodeSpec("Clay", 80.0, 0.5, 0.25, seed=5, duration_s=4.0)]
    (ref,) = run_episodes(SimConfig(world_mode="default"), spec, gains=AntiStallGains(force_lift_m_s=1.0))
    for name in ("observations", "forces", "known", "truth", "extras"):
        np.testing.assert_array_equal(getattr(live, name), getattr(ref, name), err_msg=name)
    (plain,) = run_episodes(SimConfig(world_mode="default"), spec)
    assert np.max(np.abs(live.column("u_za") - plain.column("u_za"))) > 0.01


@pytest.mark.timeout(300)
def test_realtime_15s_at_60hz_loses_no_tick(tmp_path, domain):
    """A quarter of a minute of real time (900 ticks): the bag has every tick and the simulator
    accounts for every tick's commands; late commands, jitter and loop latency are benchmark figures
    (benchmarks/bench_graph.py), printed here only. The timeouts only catch a hang: ticks a
    loaded machine misses stretch the simulated time in wall time."""
    with RosProbe(domain) as probe:
        probe.subscribe(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        proc = _launch(["--record", str(tmp_path / "bags"), "--timeout", "200", "--sim-param", "duration_s:=15.0",
                        "--sim-param", "soil:=Gravel", "--wait-for", f"{G.SIM_STATUS_TOPIC}:1"], domain, tmp_path)
        try:
            assert proc.wait(timeout=230) == 0, proc.log_path.read_text()
        finally:
            if proc.poll() is None:
                proc.kill()
        end = probe.wait_for(_ended(probe), 5, "episode_end")[0]
    (ep,) = _recorded_episodes(tmp_path / "bags")
    assert len(ep) == 900 and end.ticks == 900 and end.reason == "completed"
    assert ep.stamps_ns[0] == end.first_stamp_ns and ep.stamps_ns[-1] == end.last_stamp_ns
    assert set(np.diff(ep.stamps_ns).tolist()) <= {16_666_666, 16_666_667}  # no tick missing: the 60 Hz grid
    s = end.stats
    print(f"\nrealtime 15 s @ 60 Hz: publish period {s['period']}, jitter {s['jitter']}, "
          f"sim->controller->sim loop latency {s['loop_latency']}, late commands {s['late_commands']}")
    assert s["period"]["n"] == 899, s  # every tick was published
    assert s["loop_latency"]["n"] + s["late_commands"] == 900, s  # each tick answered in time or late


def test_lockstep_without_a_controller_ends_the_episode_instead_of_hanging(tmp_path, domain):
    with RosProbe(domain) as probe:
        probe.subscribe(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        sim = NodeProc("soil_sim_node", _sim_args("pacing:=lockstep", "lockstep_timeout_s:=1.5", "exit_when_done:=true",
                                                  wait_for=("/sim/status:1",)), domain, tmp_path)
        try:
            assert sim.wait(timeout=30) == G.EXIT_EPISODE_FAILED, sim.output  # an episode failed: not 0
            end = probe.wait_for(_ended(probe), 5, "episode_end")[0]
        finally:
            sim.stop()
    assert end.reason == "error" and end.ticks == 1
    assert "no complete command for stamp 0 ns after 1.5 s" in sim.output


def test_a_force_plugin_that_fails_mid_episode_ends_it_in_error_and_the_node_goes_on(tmp_path, domain):
    """A user's plugin that raises (here: a parameter its formula cannot use) ends its episode with
    reason error, named in the log; the node finishes its queue and exits 4, without a traceback."""
    plugin = "soil_sim_node.plugins_example:side_wall_shear walls=abc"
    with RosProbe(domain) as probe:
        probe.subscribe(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        sim = NodeProc("soil_sim_node", _sim_args(f"plugins:=['{plugin}']", "exit_when_done:=true", "duration_s:=0.5",
                                                  "rate:=5.0", "episodes:=2", wait_for=("/sim/status:1",)),
                       domain, tmp_path)
        try:
            assert sim.wait(timeout=60) == G.EXIT_EPISODE_FAILED, sim.output
            probe.wait_for(_ended(probe, 2), 5, "the second episode_end")
            ends = [e for e in _events(probe) if e.event == G.EVENT_EPISODE_END]
        finally:
            sim.stop()
    assert [e.reason for e in ends] == ["error", "error"]
    # the parameter and its value named, by the loader and by the plugin (not NumPy's words alone)
    assert ("plugin='soil_sim_node.plugins_example:side_wall_shear' with walls='abc' raised ValueError: "
            "walls='abc' must be a finite number >= 0") in sim.output, sim.output[-3000:]
    assert "Traceback" not in sim.output


@pytest.mark.parametrize("param, needle", [
    ("duration_s:=abc", "duration_s"),  # a string for a double parameter (a whole number is taken as the float)
    ("soil:=Mud", "Mud"),
    ("pacing:=sometimes", "pacing='sometimes'"),
    ("wait_for:=['/nowhere:1']", "wait_for entry '/nowhere:1'"),
    ("plugins:=['nope.mod:fn']", "cannot import module 'nope.mod'"),  # at start, not at the first episode
])
def test_bad_simulator_parameters_exit_2_with_the_name(tmp_path, domain, param, needle):
    sim = NodeProc("soil_sim_node", ["--ros-args", "-p", param], domain, tmp_path)
    try:
        assert sim.wait(timeout=30) == 2, sim.output
    finally:
        sim.stop()
    assert "cannot start" in sim.output and needle in sim.output and "Traceback" not in sim.output
