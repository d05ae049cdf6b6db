"""soil_bringup.launch as a library: stopping a previous launch's nodes, the interrupt hook."""
from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from soil_bringup import launch as L
from soil_msgs_py import graph as G


def started(proc: subprocess.Popen, limit_s: float = 10.0) -> subprocess.Popen:
    """Wait until the kernel shows the child's own command line. Popen returns once the exec's
    close-on-exec step ran, but the new argument area is set up after it: a loaded machine can
    show an empty /proc/<pid>/cmdline for a while, which is what a node that is no longer the
    logged command looks like."""
    deadline = time.monotonic() + limit_s
    while not Path(f"/proc/{proc.pid}/cmdline").read_bytes() and time.monotonic() < deadline:
        time.sleep(0.01)
    return proc


def test_only_nodes_still_running_their_logged_command_are_killed(tmp_path):
    mine = started(subprocess.Popen(["sleep", "60"]))
    other = started(subprocess.Popen(["sleep", "61"]))
    try:
        log = tmp_path / "launch.log"
        log.write_text(f"[launch] started sim (pid {mine.pid}): sleep 60\n"
                       f"[launch] started recorder (pid {other.pid}): sleep 99\n"  # not what runs under that pid
                       f"[launch] started controller (pid 999999999): sleep 60\n")
        assert L.stop_logged_nodes(log) == [f"sim ({mine.pid})"]
        assert mine.wait(timeout=5) == -9 and other.poll() is None
    finally:
        for p in (mine, other):
            p.kill()
            p.wait(timeout=5)


def test_the_first_interrupt_is_announced_once_and_the_launch_builds_from_its_arguments(tmp_path):
    said = []
    launch = L.launch_for(L.parse_args(["--record", str(tmp_path / "bags"), "--estimator", "--timeout", "7"]),
                          on_interrupt=lambda: said.append("stopping"))
    assert [n.name for n in launch.nodes] == ["recorder", "estimator", "controller", "sim"]
    assert launch.timeout_s == 7.0 and launch.env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    launch._on_signal(signal.SIGINT, None)
    launch._on_signal(signal.SIGTERM, None)
    assert launch.interrupted and said == ["stopping"] and launch.signal == signal.SIGINT


@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_an_interrupted_launch_exits_128_plus_the_signal_not_0(tmp_path, signum, code):
    """A cut stopped by Ctrl-C or SIGTERM midway exited 0 like one whose episodes were done: a
    script could not tell them apart (soil_sim_batch and pinn_train give 130 / 143)."""
    log = tmp_path / "launch.log"
    with log.open("w") as out:
        launch = L.Launch([L.NodeProcess("sleeper", ["sleep", "60"], stop_order=0)], L.loopback_env(0), out=out)
        threading.Timer(0.5, launch._on_signal, (signum, None)).start()
        assert launch.run() == code
    text = log.read_text()
    assert "interrupted; stopping all nodes" in text and f"done, exit code {code}" in text, text
    # --keep-running: the simulator stays up after its episodes until Ctrl-C, which is then the run's end
    # (a node that stops cleanly on SIGINT, as the graph's do, signalled once it said it is up)
    node = [sys.executable, "-c", "import signal, sys, time; signal.signal(signal.SIGINT, lambda *_: sys.exit(0)); "
            "print('up', flush=True); time.sleep(60)"]
    with log.open("w") as out:
        launch = L.Launch([L.NodeProcess("node", node, stop_order=0)], L.loopback_env(0), out=out,
                          interrupt_ends_run=True)

        def signal_once_up():
            deadline = time.monotonic() + 60
            while "[node] up" not in log.read_text() and time.monotonic() < deadline:
                time.sleep(0.05)
            launch._on_signal(signum, None)

        threading.Thread(target=signal_once_up, daemon=True).start()
        assert launch.run() == 0, log.read_text()
    # ... but not mid-episode: that is a cut stopped short, as without --keep-running (it had been 0)
    sim = [sys.executable, "-c", "import signal, sys, time; signal.signal(signal.SIGINT, lambda *_: sys.exit(0)); "
           f"print('[INFO] [0.0] [soil_sim_node]: {G.episode_log(0, 'start')}: x (600 ticks)', flush=True); "
           "print('up', flush=True); "
           "time.sleep(60)"]
    with log.open("w") as out:
        launch = L.Launch([L.NodeProcess("node", sim, stop_order=0, ends_launch=True)], L.loopback_env(0), out=out,
                          interrupt_ends_run=True)
        threading.Thread(target=signal_once_up, daemon=True).start()
        assert launch.run() == code, log.read_text()
    assert L.launch_for(L.parse_args(["--keep-running"])).interrupt_ends_run


def test_after_another_graph_the_recorder_is_stopped_first(tmp_path):
    """A simulator that found another graph in its namespace ran nothing; stopped last, as after a
    run, the recorder had recorded the other graph's next episode into this launch's directory
    (an outside tester's: a "completed" bag of the other machine's). Now it is stopped first."""
    stops = tmp_path / "stops"

    def node(name):  # says it is up, writes its name when asked to stop
        return [sys.executable, "-c", "import signal, sys, time, pathlib\n"
                f"def stop(*_):\n    pathlib.Path({str(stops)!r}).open('a').write('{name}\\n'); sys.exit(0)\n"
                "signal.signal(signal.SIGINT, stop); print('up', flush=True); time.sleep(60)"]

    sim = [sys.executable, "-c", f"import time; print('up', flush=True); time.sleep(1.0); raise SystemExit({G.EXIT_ANOTHER_GRAPH})"]
    nodes = [L.NodeProcess("recorder", node("recorder"), stop_order=3), L.NodeProcess("controller", node("controller"), stop_order=1),
             L.NodeProcess("sim", sim, stop_order=0, ends_launch=True)]
    with (tmp_path / "launch.log").open("w") as out:
        assert L.Launch(nodes, L.loopback_env(0), out=out).run() == L.EXIT_NODE_DIED
    assert stops.read_text().split() == ["recorder", "controller"], (tmp_path / "launch.log").read_text()


def test_a_stopping_node_that_keeps_reporting_is_waited_for_and_a_silent_one_is_not(tmp_path):
    """A recorder making an hour-long episode's bag at its stop (~30 s, saying how far it is) was
    killed --stop-timeout + 5 s after the stop, its bag half written (an outside soak test)."""
    busy = [sys.executable, "-c", "import signal, sys, time\n"
            "def stop(*_):\n    for k in range(8):\n        print('making its bag', k, flush=True); time.sleep(0.25)\n"
            "    sys.exit(0)\n"
            "signal.signal(signal.SIGINT, stop); print('up', flush=True); time.sleep(60)"]
    silent = [sys.executable, "-c", "import signal, time\n"
              "signal.signal(signal.SIGINT, lambda *_: None); print('up', flush=True); time.sleep(60)"]
    for argv, code in ((busy, 0), (silent, -signal.SIGTERM)):
        node = L.NodeProcess("recorder", argv, stop_order=0)
        with (tmp_path / "launch.log").open("w") as out:
            launch = L.Launch([node], L.loopback_env(0), out=out, stop_timeout_s=0.6)
            launch.start()
            deadline = time.monotonic() + 30
            while not node.spoke.is_set() and time.monotonic() < deadline:
                time.sleep(0.02)
            launch.stop()
        assert node.returncode == code, (tmp_path / "launch.log").read_text()


def test_a_launch_log_names_the_nodes_it_started_so_they_can_be_stopped_later(tmp_path):
    log = tmp_path / "launch.log"
    with log.open("w") as out:
        launch = L.Launch([L.NodeProcess("sleeper", ["sleep", "60"], stop_order=0)], L.loopback_env(0), out=out)
        launch.start()
    try:
        pid = started(launch.nodes[0].proc).pid
        assert L.started_nodes(log) == {pid: ("sleeper", "sleep 60")}
        assert L.stop_logged_nodes(log) == [f"sleeper ({pid})"]
        assert launch.nodes[0].proc.wait(timeout=5) == -9
    finally:
        launch.stop()


def test_the_planner_option_closes_the_loop_and_yields_the_cpu_to_the_60_hz_nodes(tmp_path):
    nodes = {n.name: n for n in L.build_nodes(L.parse_args(["--planner", "--record", str(tmp_path / "b"),
                                                             "--controller-param", "k_v_m_s:=0.4"]))}
    assert set(nodes) == {"recorder", "estimator", "planner", "controller", "sim"}  # the planner needs the estimator
    ctl = nodes["controller"].argv
    assert ctl.index("depth_source:=planner") < ctl.index("k_v_m_s:=0.4")  # the user's -p come later and win
    assert nodes["planner"].niceness > 0 and nodes["controller"].niceness == nodes["sim"].niceness == 0
    rec = nodes["recorder"].argv
    assert "/planner/target_depth" in rec and "/planner/max_cut_depth" in rec
    sim = " ".join(nodes["sim"].argv)
    assert "'/soil/known_params:3'" in sim  # recorder, estimator and planner before tick 0
    # the run (simulator, controller, recorder) is required; the advice (estimator, planner) is not
    assert {n for n, node in nodes.items() if node.required} == {"sim", "controller", "recorder"}
    assert all(nodes[n].without for n in ("estimator", "planner"))
    required = L.build_nodes(L.parse_args(["--planner", "--require", "estimator"]))
    assert {n.name for n in required if n.required} == {"sim", "controller", "estimator"}  # the demo's estimator


def test_a_namespace_moves_every_node_and_reads_its_params_file_sections(tmp_path, capsys):
    """``--namespace /dozer1`` puts each node of the graph, the recorder too, into the machine's
    namespace (its topics follow: tests/graph/test_planner_loop.py runs one beside another graph);
    the launcher's own reading of a params file takes that node's sections there."""
    nodes = L.build_nodes(L.parse_args(["--planner", "--namespace", "/site_a/dozer1", "--record", str(tmp_path / "b")]))
    for node in nodes:
        args = node.argv[node.argv.index("--ros-args"):]
        assert args[1:3] == ["-r", "__ns:=/site_a/dozer1"], (node.name, node.argv)
    assert all("__ns:=" not in " ".join(n.argv) for n in L.build_nodes(L.parse_args(["--planner", "--namespace", "/"])))
    # the launch's own graph id, the same for its simulator and its recorder, another for the next launch
    by_name = {n.name: n.argv for n in nodes}
    graph = by_name["recorder"][by_name["recorder"].index("--graph-id") + 1]
    assert f"graph_id:={graph}" in by_name["sim"] and graph.startswith("launch-")
    again = {n.name: n.argv for n in L.build_nodes(L.parse_args(["--record", str(tmp_path / "b")]))}
    assert f"graph_id:={graph}" not in again["sim"]
    mine = {n.name: n.argv for n in L.build_nodes(L.parse_args(["--record", str(tmp_path / "b"),
                                                                 "--sim-param", "graph_id:=mine"]))}
    assert mine["recorder"][mine["recorder"].index("--graph-id") + 1] == "mine"  # one id for both, the user's
    # a params file whose sections rcl would not apply in the namespace is refused, as is a second recorder id
    f = tmp_path / "p.yaml"
    f.write_text("soil_sim_node:\n  ros__parameters:\n    world_mode: fee\n")
    for argv, needle in ((["--namespace", "/dozer1", "--sim-params-file", str(f)], "its sections are for /soil_sim_node"),
                         (["--record", str(tmp_path / "b"), "--recorder-arg=--graph-id=x"], "--recorder-arg --graph-id")):
        with pytest.raises(SystemExit):
            L.parse_args(argv)
        assert needle in capsys.readouterr().err, argv
    f.write_text("/**/soil_sim_node:\n  ros__parameters:\n    world_mode: fee\n")
    assert L.parse_args(["--namespace", "/dozer1", "--sim-params-file", str(f)]).namespace == "/dozer1"
    f.write_text("site_a:\n  dozer1:\n    soil_sim_node:\n      ros__parameters:\n        world_mode: fee\n")
    assert L.given_params("soil_sim_node", f, [], ("world_mode",), "/site_a/dozer1") == {"world_mode": "fee"}
    assert L.given_params("soil_sim_node", f, [], ("world_mode",)) == {"world_mode": None}


def test_what_the_user_gives_a_node_is_never_overridden_by_the_launchers_own_value(tmp_path):
    """rcl drops a later -p of another type than an earlier one without a word: a mistyped
    exit_when_done:=maybe ran with the launcher's value (an outside tester found). Now the
    launcher leaves out its own value of every name the user gives, so the node reads the
    user's (and refuses it if it is bad)."""
    def argv(node, *args):
        return {n.name: n for n in L.build_nodes(L.parse_args(["--planner", *args]))}[node].argv

    # the planner's physics is the estimator's, heard from it (tests/soil_planner/test_estimator_physics.py):
    # the launcher gives none, and a user's bound_law goes through as given
    assert not any(a.startswith(("bound_law:=", "terms:=")) for a in argv("planner"))
    bad = "bound_law:=['a', 'b', 'c', 'd']"
    assert [a for a in argv("planner", "--planner-param", bad) if a.startswith("bound_law:=")] == [bad]
    sim = argv("sim", "--sim-param", "exit_when_done:=maybe")
    assert [a for a in sim if a.startswith("exit_when_done:=")] == ["exit_when_done:=maybe"]
    assert any(a.startswith("wait_for:=") for a in sim)
    ctl = argv("controller", "--controller-param", "depth_source:=parameter")
    assert [a for a in ctl if a.startswith("depth_source:=")] == ["depth_source:=parameter"]
    # the shipped params files list every parameter at its default (wait_for: [], depth_source:
    # parameter): given as they are, the launcher's wiring stays
    config = Path(L.__file__).parents[2]
    shipped = {flag: config / pkg / "config" / f"{pkg}.yaml" for flag, pkg in (
        ("--sim-params-file", "soil_sim_node"), ("--controller-params-file", "anti_stall_controller"),
        ("--planner-params-file", "soil_planner"))}
    assert all(f.is_file() for f in shipped.values())
    files = [a for flag, f in shipped.items() for a in (flag, str(f))]
    nodes = {n.name: n.argv for n in L.build_nodes(L.parse_args(["--planner", "--record", str(tmp_path / "b"), *files]))}
    for node, names in (("controller", ("depth_source",)), ("sim", ("wait_for", "exit_when_done"))):
        for name in names:
            assert any(a.startswith(f"{name}:=") for a in nodes[node]), (node, name, nodes[node])


def test_the_launchs_own_nodes_wait_for_each_other_half_as_long_as_its_simulator_waits_for_them(tmp_path):
    """On a loaded 2-core machine the estimator's start (torch's import) took over 5 s, the nodes'
    own inputs_wait_s: the planner joined without its writer, missed the first estimates, and a
    lockstep controller waited planner_wait_s for the first targets. The launch's nodes are coming:
    its simulator waits for them G.LAUNCH_START_WAIT_S, and they for each other half of it, or half
    of what the user gives the simulator (0, for ever: half the launch's own); a node's or the
    recorder's own value given stays, and a wait the simulator would refuse leaves the nodes theirs."""
    def argvs(*args):
        return {n.name: n.argv for n in L.build_nodes(L.parse_args(["--planner", "--record", str(tmp_path / "b"), *args]))}

    def waits(nodes):
        said = {name: [a for a in argv if a.startswith(("inputs_wait_s:=", "wait_timeout_s:="))] for name, argv in nodes.items()}
        rec = nodes["recorder"]
        said["recorder"] = [rec[i + 1] for i, a in enumerate(rec) if a == "--inputs-wait"]
        return said

    half = G.LAUNCH_START_WAIT_S / 2
    assert waits(argvs()) == {"recorder": [str(half)], "estimator": [f"inputs_wait_s:={half}"],
                              "planner": [f"inputs_wait_s:={half}"], "controller": [f"inputs_wait_s:={half}"],
                              "sim": [f"wait_timeout_s:={G.LAUNCH_START_WAIT_S}"]}
    assert G.INPUTS_WAIT_S < half  # longer than a node started by hand waits
    given = waits(argvs("--sim-param", "wait_timeout_s:=8", "--planner-param", "inputs_wait_s:=1.0",
                        "--recorder-arg=--inputs-wait=2"))
    assert given == {"recorder": [], "estimator": ["inputs_wait_s:=4.0"], "planner": ["inputs_wait_s:=1.0"],
                     "controller": ["inputs_wait_s:=4.0"], "sim": ["wait_timeout_s:=8"]}
    # the simulator waiting for ever: the nodes half the launch's own (an input whose writer never comes held a node an hour)
    forever = waits(argvs("--sim-param", "wait_timeout_s:=0"))
    assert forever["planner"] == [f"inputs_wait_s:={half}"] and forever["sim"] == ["wait_timeout_s:=0"]
    refused = waits(argvs("--sim-param", "wait_timeout_s:=-1"))  # the simulator refuses it, and the launch stops
    assert refused == {"recorder": [], "estimator": [], "planner": [], "controller": [], "sim": ["wait_timeout_s:=-1"]}
    # a params file's wait is the user's too, unless it is the hand-started default the shipped files list
    sim_file, planner_file = tmp_path / "sim.yaml", tmp_path / "planner.yaml"
    sim_file.write_text("soil_sim_node:\n  ros__parameters:\n    wait_timeout_s: 120.0\n")
    planner_file.write_text("soil_planner:\n  ros__parameters:\n    inputs_wait_s: 2.5\n")
    from_files = waits(argvs("--sim-params-file", str(sim_file), "--planner-params-file", str(planner_file)))
    assert from_files == {"recorder": ["60.0"], "estimator": ["inputs_wait_s:=60.0"], "planner": [],
                          "controller": ["inputs_wait_s:=60.0"], "sim": []}, from_files
    config = Path(L.__file__).parents[2]
    shipped = waits(argvs("--sim-params-file", str(config / "soil_sim_node" / "config" / "soil_sim_node.yaml"),
                          "--planner-params-file", str(config / "soil_planner" / "config" / "soil_planner.yaml")))
    assert shipped == waits(argvs())


def test_the_launchs_planner_follows_the_episodes_speed_only_where_its_controller_follows_their_targets(tmp_path):
    """A controller told not to follow the episodes (follow_episode_targets false) cuts at its own
    target speed: its planner then keeps its cut_speed_m_s, not the episode's."""
    def planner(*args):
        return {n.name: n.argv for n in L.build_nodes(L.parse_args(["--planner", *args]))}["planner"]

    assert not any(a.startswith("follow_episode_speed:=") for a in planner())
    assert "follow_episode_speed:=false" in planner("--controller-param", "follow_episode_targets:=false")
    ctl = tmp_path / "ctl.yaml"
    ctl.write_text("anti_stall_controller:\n  ros__parameters:\n    follow_episode_targets: false\n")
    assert "follow_episode_speed:=false" in planner("--controller-params-file", str(ctl))
    given = planner("--controller-param", "follow_episode_targets:=false", "--planner-param", "follow_episode_speed:=true")
    assert [a for a in given if a.startswith("follow_episode_speed:=")] == ["follow_episode_speed:=true"]


def test_the_simulator_waits_for_the_launchs_own_nodes_by_name_its_recorder_by_a_name_of_its_own(tmp_path, capsys):
    """Readers outside the launch met the simulator's counts before its recorder listened (its
    first episodes went unrecorded, exit 0), and a recorder started by hand is named
    soil_bag_record too: the launch's recorder gets a name of its own, and the simulator waits
    for each of the launch's nodes by name on every topic it reads (or, the controller, writes)."""
    def wait_for(*args):
        nodes = {n.name: n for n in L.build_nodes(L.parse_args(["--record", str(tmp_path / "b"), *args]))}
        (given,) = [a for a in nodes["sim"].argv if a.startswith("wait_for:=")]
        return nodes["recorder"].argv, yaml.safe_load(given.split(":=", 1)[1])

    argv, entries = wait_for("--estimator", "--planner", "--namespace", "/dozer1")
    name = own_name(argv).removeprefix("__node:=")
    assert name.startswith("soil_bag_record_") and "-" not in name
    assert argv[-4:] == ["-r", "__ns:=/dozer1", "-r", f"__node:={name}"]
    named = {}
    for entry in entries:
        if "@" in entry:
            topic, node = entry.split("@")
            named.setdefault(node, set()).add(topic)
    assert named == {f"/dozer1/{name}": set(L.RECORDER_ENDPOINTS),
                     "/dozer1/pinn_estimator": set(L.ESTIMATOR_ENDPOINTS),
                     "/dozer1/soil_planner": set(L.PLANNER_ENDPOINTS),
                     "/dozer1/anti_stall_controller": set(L.CONTROLLER_ENDPOINTS)}
    assert own_name(wait_for()[0]) != own_name(wait_for()[0])  # each launch its own
    # a name the user gives the recorder is the one waited for (for every node, or for the recorder alone)
    for remap in ("__node:=rec2", "soil_bag_record:__node:=rec2"):
        argv, entries = wait_for("--recorder-arg=--ros-args", "--recorder-arg=-r", f"--recorder-arg={remap}")
        assert argv.count(remap) == 1 and not any(a.startswith("__node:=soil_bag_record") for a in argv)
        assert "/sim/status@/rec2" in entries
    # a remap for another node is not the recorder's name
    argv, entries = wait_for("--recorder-arg=--ros-args", "--recorder-arg=-r", "--recorder-arg=pinn_estimator:__node:=x")
    assert own_name(argv).startswith("__node:=soil_bag_record_") and not any("@/x" in e for e in entries)
    # a user's whole list replaces the launch's (as any -p they give): said, with the way to add to it
    capsys.readouterr()
    argv, entries = wait_for("--sim-param", "wait_for:=['/blade/force:1']")
    assert entries == ["/blade/force:1"]
    said = capsys.readouterr().err
    assert "replaces the launch's own wait" in said and f"/sim/status@/{own_name(argv).removeprefix('__node:=')}" in said
    wait_for("--wait-for", "/blade/force:1")
    assert "replaces" not in capsys.readouterr().err
    # beside --wait-for, whose entries it would drop too: refused, naming both
    with pytest.raises(ValueError, match="replaces the whole list .*--wait-for /blade/force:2 with it"):
        wait_for("--wait-for", "/blade/force:2", "--sim-param", "wait_for:=['/x:1']")
    # a namespace of its own would be waited for elsewhere: refused, --namespace is the way
    with pytest.raises(SystemExit):
        L.parse_args(["--record", str(tmp_path / "b"), "--recorder-arg=--ros-args", "--recorder-arg=-r",
                      "--recorder-arg=__ns:=/x"])


def test_the_planner_in_lockstep_with_an_estimator_stride_above_1_is_refused_before_the_graph_starts(capsys):
    """The controller keeps step with a plan per tick and the planner plans from estimates: at
    stride 3 most ticks waited the controller's planner_wait_s (42 s for a 1 s episode)."""
    for args in (["--pacing", "lockstep", "--estimator-param", "stride:=3"],
                 ["--sim-param", "pacing:=lockstep", "--estimator-param", "stride:=2"]):
        with pytest.raises(SystemExit) as exit_:
            L.parse_args(["--planner", *args])
        assert exit_.value.code == 2
        assert "stride" in (err := capsys.readouterr().err) and "lockstep" in err, err
    for args in (["--pacing", "realtime", "--estimator-param", "stride:=3"],
                 ["--pacing", "lockstep", "--estimator-param", "stride:=1"], ["--pacing", "lockstep"]):
        L.parse_args(["--planner", *args])


def own_name(argv: list[str]) -> str:
    return next(a for a in argv if a.startswith("__node:="))


def test_a_run_whose_episode_ended_in_error_exits_non_zero_and_says_so(tmp_path):
    """The simulator finishes its queue but says an episode failed (its exit code): the launch
    stops the others and exits with that code, not 0 (a script tells that run from a good one),
    and does not call the simulator dead."""
    import sys

    log = tmp_path / "launch.log"
    with log.open("w") as out:
        ready = tmp_path / "other.ready"  # the other node is up (has said so) and stops cleanly on SIGINT
        node = ("import pathlib, signal, sys, time; signal.signal(signal.SIGINT, lambda *_: sys.exit(0)); "
                f"print('up', flush=True); time.sleep(0.5); pathlib.Path({str(ready)!r}).touch(); time.sleep(60)")
        sim = (f"import pathlib, time; t = time.monotonic()\nwhile not pathlib.Path({str(ready)!r}).exists() "
               f"and time.monotonic() - t < 60: time.sleep(0.02)\nraise SystemExit({G.EXIT_EPISODE_FAILED})")
        launch = L.Launch([L.NodeProcess("other", [sys.executable, "-c", node], stop_order=1),
                           L.NodeProcess("sim", [sys.executable, "-c", sim], stop_order=0, ends_launch=True)],
                          L.loopback_env(0), out=out, stop_timeout_s=5)
        assert launch.run() == G.EXIT_EPISODE_FAILED
    text = log.read_text()
    assert "an episode ended in error" in text and "died" not in text, text


def test_a_recorder_that_wrote_no_bag_of_an_episode_fails_the_launch_and_says_why(tmp_path):
    """The episodes ran to their end, but the recorder left one without its bag (it exits
    EXIT_BAG_NOT_WRITTEN when stopped): the launch exits 1 (was 0: the bag silently missing), naming
    the recorder, its code and what the code means."""
    import sys

    log = tmp_path / "launch.log"
    with log.open("w") as out:
        ready = tmp_path / "recorder.ready"
        recorder = ("import pathlib, signal, sys, time; "
                    f"signal.signal(signal.SIGINT, lambda *_: sys.exit({G.EXIT_BAG_NOT_WRITTEN})); "
                    f"print('up', flush=True); time.sleep(0.5); pathlib.Path({str(ready)!r}).touch(); time.sleep(60)")
        sim = (f"import pathlib, time; t = time.monotonic()\nwhile not pathlib.Path({str(ready)!r}).exists() "
               "and time.monotonic() - t < 60: time.sleep(0.02)")
        launch = L.Launch([L.NodeProcess("recorder", [sys.executable, "-c", recorder], stop_order=2),
                           L.NodeProcess("sim", [sys.executable, "-c", sim], stop_order=0, ends_launch=True)],
                          L.loopback_env(0), out=out, stop_timeout_s=5, drain_s=0.0)
        assert launch.run() == L.EXIT_NODE_DIED
    text = log.read_text()
    assert f"recorder exited with code {G.EXIT_BAG_NOT_WRITTEN} (an episode's bag was not written" in text, text


def test_a_recorder_killed_mid_run_is_said_with_where_its_journals_are(tmp_path):
    """A SIGKILLed recorder leaves *.partial journals; the launch said only "recorder died (exit
    code -9)" (an outside tester found). It now says where they are and the command that repairs them."""
    args = L.parse_args(["--record", str(tmp_path / "bags")])
    (recorder,) = [n for n in L.build_nodes(args) if n.name == "recorder"]
    log = tmp_path / "launch.log"
    with log.open("w") as out:
        dying = "import os, signal, time; time.sleep(0.3); os.kill(os.getpid(), signal.SIGKILL)"
        launch = L.Launch([L.NodeProcess("recorder", [sys.executable, "-c", dying], stop_order=2,
                                         after_death=recorder.after_death),
                           L.NodeProcess("sim", ["sleep", "60"], stop_order=0, ends_launch=True)],
                          L.loopback_env(0), out=out, stop_timeout_s=5, drain_s=0.0)
        assert launch.run() == L.EXIT_NODE_DIED
    text = log.read_text()
    assert "recorder died (exit code -9); stopping the others (what it had flushed is in the *.partial journals " \
           f"under {tmp_path / 'bags'}: `soil_bag_repair {tmp_path / 'bags'}` makes bags of them)" in text, text


def test_a_node_stopped_before_it_said_anything_gets_sigterm_not_a_traceback(tmp_path):
    """A node refusing its parameters stops the others while they may still be importing: a
    SIGINT there is a KeyboardInterrupt traceback (35 lines burying the refusal). One that has
    said nothing is sent SIGTERM, which ends it quietly; one that is up still gets SIGINT."""
    import sys

    log = tmp_path / "launch.log"
    importing = "import time; time.sleep(60)"  # still silent: as if importing rclpy and torch
    up = ("import signal, sys, time; signal.signal(signal.SIGINT, lambda *_: (print('got SIGINT', flush=True), "
          "sys.exit(0))); print('up', flush=True); time.sleep(60)")
    refusing = "import time, sys; time.sleep(1.5); print('cannot start: k=nan', flush=True); sys.exit(2)"
    with log.open("w") as out:
        launch = L.Launch([L.NodeProcess("controller", [sys.executable, "-c", refusing], stop_order=1),
                           L.NodeProcess("sim", [sys.executable, "-c", importing], stop_order=0),
                           L.NodeProcess("recorder", [sys.executable, "-c", up], stop_order=2)],
                          L.loopback_env(0), out=out, stop_timeout_s=5)
        assert launch.run() == L.EXIT_NODE_DIED
    text = log.read_text()
    assert "controller refused its parameters" in text and "Traceback" not in text, text
    assert "[recorder] got SIGINT" in text and "needed" not in text, text
    assert {n.name: n.returncode for n in launch.nodes} == {"controller": 2, "sim": -signal.SIGTERM, "recorder": 0}


def test_options_that_would_be_ignored_or_misread_are_refused(capsys):
    """An option for a node the launch does not start, a negative or NaN timeout, a parameter
    without a value: refused up front with the option named (before, some were dropped without a
    word and a run went on without the planner the user had configured)."""
    import pytest

    for argv, needle in ((["--planner-param", "margin:=0.9"], "--planner-param given, but this launch starts no planner"),
                         (["--require", "planner"], "--require planner given, but this launch starts no planner"),
                         (["--estimator-param", "stride:=2"], "starts no estimator"),
                         (["--no-controller", "--controller-param", "k_v_m_s:=1.0"], "starts no controller"),
                         (["--timeout", "-5"], "--timeout -5.0 must be a finite number"),
                         (["--timeout", "nan"], "--timeout nan must be a finite number"),
                         (["--stop-timeout", "0"], "--stop-timeout 0.0 must be a finite number of seconds, > 0"),
                         (["--namespace", "dozer1"], "--namespace 'dozer1' is not a ROS namespace"),
                         (["--namespace", "/dozer 1"], "is not a ROS namespace"),
                         (["--namespace", "/1dozer"], "is not a ROS namespace"),
                         (["--namespace", "/dozer1/"], "is not a ROS namespace"),
                         (["--namespace", "/" + "a" * 199], "--namespace of 200 characters: at most 199")):
        with pytest.raises(SystemExit):
            L.parse_args(argv)
        assert needle in capsys.readouterr().err, argv
    assert L.parse_args(["--planner", "--estimator-param", "stride:=2", "--require", "estimator"]).estimator
    with pytest.raises(ValueError, match="parameter 'duration_s:=' is not of the form name:=value"):
        L.build_nodes(L.parse_args(["--sim-param", "duration_s:="]))
    # a topic the simulator does not own: its node refused it only once every node was up (exit 1)
    with pytest.raises(ValueError, match="'/soil/estimate:1': the simulator waits only for endpoints of its own "
                                         "topics, one of /clock, .*/sim/status"):
        L.build_nodes(L.parse_args(["--estimator", "--wait-for", "/soil/estimate:1"]))
    assert "'/blade/force:2'" in " ".join(L.build_nodes(L.parse_args(["--wait-for", "/blade/force:1"]))[-1].argv)


def test_a_fee_world_launch_estimates_with_the_fee_worlds_model_unless_told_otherwise(tmp_path, capsys):
    """A launch in the fee world ran the default world's model (F̂_x ~40 % off there, an outside
    tester found) and its calibration, and gave the planner that world's term: now the estimator
    gets the world's shipped model, and with it the world's calibration and terms (none, which it
    says to the planner), unless a checkpoint is given on the command line or in a params file."""
    from pinn_estimator.shipped import MODELS_DIR

    def argv(*args):
        nodes = {n.name: n for n in L.build_nodes(L.parse_args(["--planner", *args]))}
        return nodes["estimator"].argv, nodes["planner"].argv

    fee = f"checkpoint:={MODELS_DIR / 'pinn_fee.pt'}"
    est, plan = argv("--sim-param", "world_mode:=fee")
    assert fee in est, est
    assert "the fee world: the estimator runs its shipped model" in capsys.readouterr().err
    sim_file = tmp_path / "sim.yaml"
    sim_file.write_text("soil_sim_node:\n  ros__parameters:\n    world_mode: fee\n")
    assert fee in argv("--sim-params-file", str(sim_file))[0]
    for given in (["--sim-param", "world_mode:=default"], [],
                  ["--sim-param", "world_mode:=fee", "--estimator-param", "checkpoint:=mine.pt"]):
        est, plan = argv(*given)
        assert not any(a.startswith("checkpoint:=") and "pinn_fee" in a for a in est), (given, est)
    est_file = tmp_path / "est.yaml"
    est_file.write_text("pinn_estimator:\n  ros__parameters:\n    checkpoint: mine.pt\n")
    assert fee not in argv("--sim-param", "world_mode:=fee", "--estimator-params-file", str(est_file))[0]
    # an empty checkpoint given is the user's choice (the node's "shipped default"), not "none given"
    assert fee not in argv("--sim-param", "world_mode:=fee", "--estimator-param", "checkpoint:=''")[0]


def test_a_nodes_parameters_are_read_from_the_sections_of_a_params_file_that_apply_to_it(tmp_path):
    """A section of another node named world_mode: default after the simulator's fee, and the
    launch gave the estimator the default world's model. The sections are rcl's (the node reads
    them so): its name, a wildcard, not another namespace's node of the same name."""
    from soil_msgs_py.params_files import node_parameters

    f = tmp_path / "p.yaml"
    f.write_text("soil_sim_node:\n  ros__parameters:\n    world_mode: fee\n"
                 "other_node:\n  ros__parameters:\n    world_mode: default\n")
    assert L.given_params("soil_sim_node", f, [], ("world_mode",)) == {"world_mode": "fee"}
    f.write_text("ns:\n  soil_sim_node:\n    ros__parameters:\n      world_mode: fee\n"
                 "/**:\n  ros__parameters:\n    seed: 3\n")
    # the launched simulator is /soil_sim_node: /ns/soil_sim_node's section is not its own
    assert L.given_params("soil_sim_node", f, [], ("world_mode", "seed", "soil")) == \
        {"world_mode": None, "seed": "3", "soil": None}
    sections = yaml.safe_load(f.read_text())
    assert node_parameters(sections, "/ns/soil_sim_node") == [{"world_mode": "fee"}, {"seed": 3}]  # nested maps
    f.write_text("/soil_sim_node:\n  ros__parameters:\n    world_mode: fee\n")
    assert L.given_params("soil_sim_node", f, [], ("world_mode",)) == {"world_mode": "fee"}
    assert L.given_params("soil_sim_node", f, ["world_mode:=default"], ("world_mode",)) == {"world_mode": "default"}
    assert L.given_params("pinn_estimator", f, [], ("world_mode",)) == {"world_mode": None}


@pytest.mark.parametrize("episodes, finished, drains", [(1, 1, False), (1, 0, True), (2, 1, True), (0, 0, True)])
def test_the_recorder_is_stopped_at_once_when_it_finished_a_bag_of_every_episode_else_after_the_drain(
        tmp_path, monkeypatch, episodes, finished, drains):
    """The drain before the recorder's stop gives it the messages in flight. A recorder that said it
    finished a bag for every episode the simulator said it started has none in flight: it is stopped
    at once (1.5 s saved in every launch that records). One that has not (an episode it did not
    finish, a simulator that started none, a bag of the whole run) still gets the drain. The real
    nodes' lines: rclpy's "[INFO] [stamp] [name]: " before each head (``G.episode_log``,
    ``G.bag_finished_log``)."""
    slept: list[float] = []

    class Clock:  # launch.py's clock, its sleeps noted (the drain is the one of DRAIN_S)
        monotonic = staticmethod(time.monotonic)

        @staticmethod
        def sleep(seconds: float) -> None:
            slept.append(seconds)
            time.sleep(min(seconds, 0.05))

    monkeypatch.setattr(L, "time", Clock)
    drain_s = 7.25
    ready = tmp_path / "recorder.ready"
    lines = [f"[INFO] [1] [rec]: {G.bag_finished_log('completed')} /bags/ep{k}" for k in range(finished)]
    recorder = (f"import pathlib, signal, sys, time\nsignal.signal(signal.SIGINT, lambda *_: sys.exit(0))\n"
                f"print('up', flush=True)\nfor line in {lines!r}: print(line, flush=True)\n"
                f"time.sleep(0.3); pathlib.Path({str(ready)!r}).touch(); time.sleep(60)")
    said = [f"[INFO] [1] [sim]: {G.episode_log(k, what)}: ep{k}" for k in range(episodes) for what in ("start", "end")]
    sim = (f"import pathlib, time\nfor line in {said!r}: print(line, flush=True)\nt = time.monotonic()\n"
           f"while not pathlib.Path({str(ready)!r}).exists() and time.monotonic() - t < 60: time.sleep(0.02)")
    controller = "import signal, sys, time; signal.signal(signal.SIGINT, lambda *_: sys.exit(0)); print('up', flush=True); time.sleep(60)"
    with (tmp_path / "launch.log").open("w") as out:
        launch = L.Launch([L.NodeProcess("recorder", [sys.executable, "-c", recorder], stop_order=3, records=True),
                           L.NodeProcess("controller", [sys.executable, "-c", controller], stop_order=1),
                           L.NodeProcess("sim", [sys.executable, "-c", sim], stop_order=0, ends_launch=True)],
                          L.loopback_env(0), out=out, stop_timeout_s=5, drain_s=drain_s)
        assert launch.run() == 0
    assert (launch.episodes_started, launch.bags_finished) == (episodes, finished)
    assert (drain_s in slept) == drains, slept
