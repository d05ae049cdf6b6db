"""`soil_launch`: start the graph (sim + controller [+ estimator [+ planner]] [+ recorder]) as separate processes.

There is no ``ros2 launch`` on these machines, so this is ours. It

* starts every node as its own process (its console script, ``--ros-args`` as usual) with
  loopback-only DDS (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) on one ROS_DOMAIN_ID, in one
  namespace (``--namespace /dozer1``: several machines' graphs on one domain, each in its own);
* tells the simulator which endpoints to wait for (the controller's, the estimator's, the
  recorder's) so no tick is published before its consumers have matched;
* prefixes each process's output with its name, like ``ros2 launch``;
* forwards Ctrl-C / SIGTERM, stops the nodes in data-flow order (simulator first, recorder
  last, so the recorder finishes its bags) and escalates to SIGTERM/SIGKILL if one hangs;
* exits 0 when the simulator finished its episodes and everyone stopped cleanly, 130 / 143
  when a Ctrl-C / SIGTERM stopped it first (as ``soil_sim_batch`` and ``pinn_train`` do: a script
  tells an interrupted cut from a finished one; the bags of what ran are finished; with
  ``--keep-running`` an interrupt between episodes is how the run ends: 0), 4
  (``graph.EXIT_EPISODE_FAILED``) when it finished them but one ended in error, and
  non-zero when a node died or exited with an error, e.g. the recorder with 5 when an episode went
  without its bag (its name and exit code are printed; 1), or ``--timeout`` hit (3). The
  simulator, controller and recorder are the run: one dying stops the others. The estimator
  and planner are advice: one dying mid-run is reported and the others go on (the controller
  falls back to its own target depth), and the launch exits 1 at the end (``--require NODE``
  makes one required). A later episode then starts after the simulator's ``wait_timeout_s``
  for the dead node's endpoints. Any node refusing its parameters (exit code 2, which a node
  gives only at start) stops the launch.

    soil_launch --pacing lockstep --record bags/run1 --sim-param soil:=Clay
    soil_launch --estimator --record bags/run2 --estimator-param checkpoint:=my_model.pt
    soil_launch --rate 2 --sim-param episodes:=3 --sim-params-file my_sim.yaml
    soil_launch --planner --record bags/run3 --sim-param "patches:=['0:Sand:20','10:Clay:80']"

``--planner`` starts the soil-aware planner too (and the estimator it plans from, whose posterior
physics and bound law the planner hears from it on /soil/estimator/physics) and sets the controller's
``depth_source:=planner``: the loop is closed, the cut depth follows the soil. A value the
launcher sets itself is left out wherever the user gives that name (``unless_given``).
"""
from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from soil_msgs_py import graph as G
from soil_msgs_py.cli_paths import bags_dir
from soil_msgs_py.interrupts import EXIT_INTERRUPTED, EXIT_TERMINATED
from soil_msgs_py.launcher_death import LAUNCHER_PID_ENV
from soil_msgs_py.params_files import node_parameters, read_params_file

MAX_DOMAIN_ID = 232  # the largest ROS_DOMAIN_ID DDS allows on Linux (its ports above stay below 65536)
# The longest namespace the graph fits under: rmw's longest topic or service name (255 − 8) less the
# graph's longest name below its namespace, the controller's parameter service (a longer one: tracebacks)
MAX_NAMESPACE_LEN = 255 - 8 - len("/anti_stall_controller/set_parameters_atomically")

# A remap of the recorder's node name given through --recorder-arg (rcl's '__node:=NAME', also as
# 'soil_bag_record:__node:=NAME' for that node alone): the launch's simulator waits for that name
RECORDER_NAME_REMAP_RE = re.compile(rf"(?:{re.escape(G.NODE_NAMES['recorder'])}:)?__(?:node|name):=([A-Za-z_][A-Za-z0-9_]*)")

# --NODE-params-file: the node each is for
PARAMS_FILE_NODES = {role: G.NODE_NAMES[role] for role in ("sim", "controller", "estimator", "planner")}
# The longest a stopping node that keeps reporting its progress is waited for (a recorder making its bags)
STOP_REPORTING_LIMIT_S = 600.0

EXIT_NODE_DIED = 1
EXIT_TIMEOUT = 3
EXIT_BAD_ARGS = 2
ADVISORY_NODES = ("estimator", "planner")  # not required unless --require names them

# The simulator's side of each node's endpoints, for its 'wait_for' (topic -> count): the
# topics it publishes that the node reads, and the command topics the node publishes. (The
# recorder's command subscriptions match the controller, not the simulator: 'settle_s'.)
CONTROLLER_ENDPOINTS = {name: 1 for name in G.CONTROLLER_INPUTS + G.COMMAND_TOPICS}
RECORDER_ENDPOINTS = {name: 1 for name in G.RECORDER_INPUTS if name not in G.COMMAND_TOPICS}
ESTIMATOR_ENDPOINTS = {name: 1 for name in G.ESTIMATOR_INPUTS if name not in G.COMMAND_TOPICS}
PLANNER_ENDPOINTS = {name: 1 for name in (*G.PLANNER_STATE_TOPICS, G.SIM_STATUS_TOPIC)}
PLANNER_NICENESS = 10  # the planner's plan may come a tick late; the controller's command may not

# The line the launch logs per node it starts; ``started_nodes`` reads it back from a log.
STARTED_LINE = "started {name} (pid {pid}): {command}"
_STARTED_RE = re.compile(r"^\[launch\] started (\S+) \(pid (\d+)\): (.*)$", re.M)


def executable(name: str) -> str:
    """A console script next to this interpreter (the venv) or on PATH (a colcon install)."""
    here = Path(sys.executable).parent / name
    if here.exists():
        return str(here)
    found = shutil.which(name)
    if found is None:
        raise FileNotFoundError(f"executable {name!r} not found next to {sys.executable} or on PATH")
    return found


def ros_domain_id(text: str) -> int:
    """A ROS domain id for ``--domain-id`` (an argparse ``type``): a whole number in [0, MAX_DOMAIN_ID],
    else an error naming the text, whether it came from the option or from $ROS_DOMAIN_ID (its default)."""
    text = text.strip()
    # decimal digits alone, no leading zero: rcl reads the variable with strtoul(..., 0), "010" as 8
    # and "0x10" as 16, where int() read 10 and refused the second (nodes started by hand would
    # have joined another domain than the launch's)
    value = int(text) if re.fullmatch(r"0|[1-9][0-9]*", text, re.ASCII) else -1
    if not 0 <= value <= MAX_DOMAIN_ID:
        raise argparse.ArgumentTypeError(f"{text!r} is not a ROS domain id, a whole number in [0, {MAX_DOMAIN_ID}] "
                                         "(given by --domain-id, else by $ROS_DOMAIN_ID)")
    return value


def add_domain_id_option(p: argparse.ArgumentParser, fallback: int) -> None:
    """``--domain-id`` of a tool that starts a graph: by default $ROS_DOMAIN_ID, as a node started by
    hand reads it, else ``fallback``. (soil_launch failed with a traceback on a ROS_DOMAIN_ID that is
    no number, soil_demo took its own id without a word, and the benchmarks ignored the variable.)"""
    given = os.environ.get("ROS_DOMAIN_ID", "").strip()
    # (argparse passes a default given as text through ``type``, so a bad variable is said as a bad option)
    p.add_argument("--domain-id", type=ros_domain_id, default=given or str(fallback), metavar="ID",
                   help=f"ROS_DOMAIN_ID for every node, DDS on loopback only (default: $ROS_DOMAIN_ID, else {fallback})")


def loopback_env(domain_id: int) -> dict[str, str]:
    """This environment with DDS confined to loopback on ``domain_id``."""
    env = dict(os.environ)
    env.pop("ROS_LOCALHOST_ONLY", None)  # deprecated; it would override the variable below
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["PYTHONUNBUFFERED"] = "1"
    return env


@dataclass
class NodeProcess:
    """One node of the launch: its name (output prefix), command line and role."""

    name: str
    argv: list[str]
    stop_order: int  # lower stops first
    required: bool = True  # its death (any exit before shutdown) stops the launch (else: the exit code only)
    without: str = ""  # what the graph does without it, said when a node that is not required dies
    ends_launch: bool = False  # its clean exit (code 0) ends the launch successfully
    records: bool = False  # the recorder: its finished bags are counted (``Launch.stop``'s drain)
    after_death: str = ""  # what a user can do after it died (said with its death)
    # Scheduling niceness set at start (setpriority): the nodes that close the 60 Hz loop (the
    # simulator and the controller) keep 0; a node whose answer may come a tick later (the
    # planner) yields the CPU to them on a busy machine.
    niceness: int = 0
    proc: subprocess.Popen | None = None
    pump: threading.Thread | None = None
    returncode: int | None = field(default=None)
    spoke: threading.Event = field(default_factory=threading.Event)  # a first line of output came
    last_line: list[float] = field(default_factory=lambda: [0.0])  # time.monotonic() of its newest line


def _pump(prefix: str, stream, out, spoke: threading.Event | None = None, on_line=None,
          last_line: list[float] | None = None) -> None:
    """Copy a child's output line by line with its name; never dies on a closed terminal
    (a dead pump would leave the child blocked on a full pipe). ``on_line``: also given each line."""
    for line in iter(stream.readline, ""):
        if spoke is not None:
            spoke.set()
        if last_line is not None:
            last_line[0] = time.monotonic()
        if on_line is not None:
            on_line(line)
        try:
            out.write(f"[{prefix}] {line}" if line.endswith("\n") else f"[{prefix}] {line}\n")
            out.flush()
        except (OSError, ValueError):
            pass
    stream.close()


class Launch:
    """Starts, watches and stops a group of node processes.

    ``on_interrupt`` is called once, from the signal handler, at the first Ctrl-C / SIGTERM
    (an embedding program can say at once that it is stopping)."""

    def __init__(self, nodes: list[NodeProcess], env: dict[str, str], *, timeout_s: float = 0.0,
                 stop_timeout_s: float = 10.0, drain_s: float = 1.5, out=sys.stdout,
                 on_interrupt: Callable[[], None] | None = None, interrupt_ends_run: bool = False):
        self.nodes = nodes
        # --keep-running: a simulator kept up after its episodes is ended with Ctrl-C, so an
        # interrupt between episodes is the run's end (exit 0); one mid-episode is a cut stopped
        # short (130 / 143), as without it (it had been 0 too)
        self.interrupt_ends_run = interrupt_ends_run
        self.env = env
        self.timeout_s = timeout_s
        self.stop_timeout_s = stop_timeout_s
        self.drain_s = drain_s
        self.out = out
        self.on_interrupt = on_interrupt
        self.interrupted = False
        self.signal: int | None = None  # the first SIGINT / SIGTERM received
        self.episode_running = False  # the simulator logged an episode's start and not yet its end
        # the simulator found another graph and ran nothing: the recorder is stopped first, else it
        # recorded the other graph's next episode into this launch's directory while the others stopped
        self.none_of_its_own = False
        # episodes the simulator said it started, and bags the recorder said it finished (pumped lines)
        self.episodes_started = 0
        self.bags_finished = 0

    def log(self, text: str) -> None:
        self.out.write(f"[launch] {text}\n")
        self.out.flush()

    def start(self) -> None:
        env = {**self.env, LAUNCHER_PID_ENV: str(os.getpid())}  # a node stops if we die (launcher_death)
        for node in self.nodes:
            node.proc = subprocess.Popen(
                node.argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, errors="replace",
                start_new_session=True,  # the terminal's Ctrl-C reaches us only; we forward it
            )
            if node.niceness:  # (after the fork: a preexec_fn is unsafe while the pump threads run)
                try:
                    os.setpriority(os.PRIO_PROCESS, node.proc.pid, node.niceness)
                except OSError as err:
                    self.log(f"{node.name}: niceness {node.niceness} not set ({err}); it runs at normal priority")
            on_line = self._on_simulator_line if node.ends_launch else self._on_recorder_line if node.records else None
            node.pump = threading.Thread(target=_pump, args=(node.name, node.proc.stdout, self.out, node.spoke,
                                                             on_line, node.last_line),
                                         daemon=True)
            node.pump.start()
            self.log(STARTED_LINE.format(name=node.name, pid=node.proc.pid, command=" ".join(node.argv)))

    def _on_simulator_line(self, line: str) -> None:
        if match := G.EPISODE_LOG_PATTERN.search(line):  # (whether an episode is running)
            self.episode_running = match.group(1) == "start"
            self.episodes_started += self.episode_running

    def _on_recorder_line(self, line: str) -> None:
        if G.BAG_FINISHED_LOG_PATTERN.search(line):
            self.bags_finished += 1

    def _recorder_caught_up(self) -> bool:
        """Whether the recorder said it finished a bag for every episode the simulator started (and
        the simulator started one): then no message is in flight for it. Else (an episode it has not
        finished, a bag of the whole run, a line not pumped yet) its stop waits ``drain_s``."""
        return 0 < self.episodes_started <= self.bags_finished and not self.episode_running

    def _on_signal(self, signum, frame) -> None:  # noqa: ARG002
        first = not self.interrupted
        self.interrupted = True
        self.signal = self.signal or signum
        if first and self.on_interrupt is not None:
            self.on_interrupt()

    def run(self) -> int:
        """Start everything, wait for the end, stop everyone; returns the exit code."""
        old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            self.start()
            code = self._watch()
        finally:
            self.stop()
            for s, handler in old.items():
                signal.signal(s, handler)
        failed = [n for n in self.nodes if n.returncode not in (0, None)]
        for n in failed:
            bag_lost = n.returncode == G.EXIT_BAG_NOT_WRITTEN
            meaning = " (an episode's bag was not written: its log says why)" if bag_lost else ""
            self.log(f"{n.name} exited with code {n.returncode}{meaning}")
        # a node that died wins (1); else a simulator that says an episode failed (4) is that, not a death
        episode_failed = [n for n in failed if n.ends_launch and n.returncode == G.EXIT_EPISODE_FAILED]
        if code in (0, G.EXIT_EPISODE_FAILED) and len(failed) > len(episode_failed):
            code = EXIT_NODE_DIED
        elif code == 0 and episode_failed:
            code = G.EXIT_EPISODE_FAILED
        self.log(f"done, exit code {code}")
        return code

    def _watch(self) -> int:
        t0 = time.monotonic()
        while True:
            if self.interrupted:
                self.log("interrupted; stopping all nodes")
                if self.interrupt_ends_run and not self.episode_running:  # (mid-episode: a cut stopped short)
                    return 0
                return EXIT_TERMINATED if self.signal == signal.SIGTERM else EXIT_INTERRUPTED
            for node in self.nodes:
                rc = node.proc.poll()
                if rc is None or node.returncode is not None:
                    continue  # running, or a node that is not required died and was reported
                node.returncode = rc
                if node.ends_launch and rc == 0:
                    self.log(f"{node.name} finished; stopping the others")
                    return 0
                if node.ends_launch and rc == G.EXIT_EPISODE_FAILED:
                    self.log(f"{node.name} finished, but an episode ended in error (its log says why; exit code "
                             f"{rc}); stopping the others")
                    return rc
                if rc == G.EXIT_BAD_CONFIG:  # any node: the user's set-up is wrong, not the run
                    self.log(f"{node.name} refused its parameters (exit code {rc}); stopping the others")
                    return EXIT_NODE_DIED
                if rc == G.EXIT_ANOTHER_GRAPH:
                    self.none_of_its_own = True
                    self.log(f"{node.name} found another graph on domain {self.env.get('ROS_DOMAIN_ID', '?')} (exit "
                             f"code {rc}; its log names the nodes); stopping the others: give this launch another "
                             "--domain-id, or each machine's graph a --namespace of its own")
                    return EXIT_NODE_DIED
                if node.required:
                    self.log(f"{node.name} died (exit code {rc}); stopping the others"
                             + (f" ({node.after_death})" if node.after_death else ""))
                    return EXIT_NODE_DIED
                self.log(f"{node.name} {'exited' if rc == 0 else 'died'} (exit code {rc}); not required, the others go on "
                         f"({node.without})")
            if self.timeout_s and time.monotonic() - t0 > self.timeout_s:
                self.log(f"timeout after {self.timeout_s} s; stopping all nodes")
                return EXIT_TIMEOUT
            time.sleep(0.05)

    def stop(self) -> None:
        """SIGINT each running node in stop order, waiting for each; escalate if one hangs (the
        order reversed, the recorder first, when the graph ran nothing of its own)."""
        first = True
        order = -1 if self.none_of_its_own else 1
        for node in sorted(self.nodes, key=lambda n: order * n.stop_order):
            if node.proc is None:
                continue
            if node.proc.poll() is None:
                last_stage = node.stop_order >= max(n.stop_order for n in self.nodes)
                if not first and not self.none_of_its_own and last_stage and not (node.records and self._recorder_caught_up()):
                    time.sleep(self.drain_s)  # the last stage (recorder) gets the in-flight data
                first = False
                node.returncode = self._stop_one(node)
            elif node.returncode is None:
                node.returncode = node.proc.returncode
            if node.pump is not None:
                node.pump.join(timeout=2.0)

    def _stop_one(self, node: NodeProcess) -> int:
        # A node that has said nothing yet may still be importing, where a SIGINT is a
        # KeyboardInterrupt traceback burying the launch's real error; SIGTERM ends it quietly
        # there, and a node that is up handles either alike (``ros_adapter``).
        first = signal.SIGINT if node.spoke.is_set() else signal.SIGTERM
        limit_at = time.monotonic() + STOP_REPORTING_LIMIT_S  # (one limit for both stages that wait while it reports)
        for sig, wait in ((first, self.stop_timeout_s), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
            try:
                node.proc.send_signal(sig)
            except ProcessLookupError:
                break
            try:
                rc = (self._wait_while_it_reports(node, wait, limit_at) if sig != signal.SIGKILL
                      else node.proc.wait(timeout=wait))
                if sig != first:
                    self.log(f"{node.name} needed {signal.Signals(sig).name}"
                             + (f" ({node.after_death})" if node.after_death and sig == signal.SIGKILL else ""))
                return rc
            except subprocess.TimeoutExpired:
                continue
        return node.proc.wait(timeout=5.0)

    @staticmethod
    def _wait_while_it_reports(node: NodeProcess, quiet_s: float, limit_at: float) -> int:
        """The node's exit code once it stops, waiting as long as it says something at least every
        ``quiet_s`` (until ``limit_at``, time.monotonic()); TimeoutExpired once it falls silent that
        long. Why: a recorder making an hour-long episode's bag (~30 s for 1.5 M messages, saying
        it is at work every 2 s) was killed 15 s after the stop, its bag half written."""
        start = time.monotonic()
        while True:
            try:
                return node.proc.wait(timeout=0.2)
            except subprocess.TimeoutExpired:
                now = time.monotonic()
                if now - max(start, node.last_line[0]) >= quiet_s or now >= limit_at:
                    raise


def started_nodes(log_path: Path) -> dict[int, tuple[str, str]]:
    """pid -> (name, command line) of the nodes a launch's log says it started ({} if unreadable)."""
    try:
        text = Path(log_path).read_text(errors="replace")
    except OSError:
        return {}
    return {int(pid): (name, cmd) for name, pid, cmd in _STARTED_RE.findall(text)}


def stop_logged_nodes(log_path: Path) -> list[str]:
    """SIGKILL the nodes a launch's log says it started that are still running: those of a
    launch that could not stop them (it was killed itself; its nodes run in their own sessions,
    and since 2026-12-04 stop when it dies, ``launcher_death``, except where that cannot be
    arranged: not Linux, a wrapper between launcher and node, a node that ignores SIGTERM). Only
    a process whose command line is still the logged one is touched: a recycled pid is left
    alone. Returns 'name (pid)' of each node killed."""
    killed = []
    for pid, (name, cmd) in started_nodes(log_path).items():
        try:
            cmdline = " ".join(Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")).strip()
        except OSError:
            continue
        if cmdline.endswith(cmd.strip()):
            try:
                os.kill(pid, signal.SIGKILL)
                killed.append(f"{name} ({pid})")
            except ProcessLookupError:
                pass
    return killed


def _params(pairs: list[str]) -> list[str]:
    out = []
    for pair in pairs:
        name, sep, value = pair.partition(":=")
        if not sep or not name.strip() or not value.strip():
            raise ValueError(f"parameter {pair!r} is not of the form name:=value")
        out += ["-p", pair]
    return out


def _ros_node(script: str, params_file, params: list[str], namespace: str = "") -> list[str]:
    """argv of a node's console script in ``namespace`` ("": the root) with its --params-file and
    -p overrides."""
    argv = [executable(script), "--ros-args", *_namespace_args(namespace)]
    if params_file:
        argv += ["--params-file", str(params_file)]
    return argv + _params(params)


def _namespace_args(namespace: str) -> list[str]:
    """rcl's remap that puts a node into ``namespace`` (none for the root)."""
    return ["-r", f"__ns:={namespace}"] if namespace else []


def unless_given(node: str, params: list[str], defaults: list[str]) -> list[str]:
    """The launcher's own ``name:=value`` ``defaults`` for ``node`` less those whose name the user
    gives by ``-p`` (``params``). Why not rcl's "the last -p wins": a later -p of another type than
    an earlier one is dropped without a word (``exit_when_done:=maybe`` after the launcher's: the
    node ran with the launcher's value). A params file does not count: the launch's wiring
    (``wait_for``, ``exit_when_done``, ``depth_source``) must not be undone by a params file copied
    with its defaults, which would open the loop or start the simulator before its readers."""
    names = [d.partition(":=")[0] for d in defaults]
    on_line = given_params(node, None, params, names)
    return [d for d, name in zip(defaults, names) if on_line[name] is None]


def _sections_for(params_file, node_path: str) -> list[dict]:
    """The sections of a params file rcl applies to the node ``node_path`` ([] if unreadable)."""
    try:
        sections = read_params_file(params_file)
    except ValueError:
        return []  # the node reports its own params file
    return node_parameters(sections, node_path)


def given_params(node: str, params_file, params: list[str], names, namespace: str = "") -> dict[str, str | None]:
    """What the node ``node`` (launched in ``namespace``, "" the root) is given for each of ``names``
    as text (None: not given): the last ``-p`` of ``params``, else the last value in its params
    file's sections that apply to it by rcl's rules (``params_files.node_parameters``), as it reads them."""
    given: dict[str, str | None] = {name: None for name in names}
    for section in _sections_for(params_file, f"{namespace}/{node}") if params_file else ():
        for key in given:
            if key in section:
                given[key] = "" if section[key] is None else str(section[key])
    for pair in params:
        name, _, value = pair.partition(":=")
        if name.strip() in given:
            given[name.strip()] = value.strip().strip("'\"")
    return given


def world_checkpoint_param(args: argparse.Namespace) -> list[str]:
    """``["checkpoint:=<models>/pinn_<world>.pt"]`` for an estimator given no checkpoint in a world
    with a shipped model of its own other than the default (the fee world): the model, its
    calibration and the planner's terms then follow the world, as ``soil_cut_report`` runs them.
    Before, a fee-world launch estimated with the default world's model (its F̂_x ~40 % off there).
    A checkpoint given, even empty (the node's "the shipped default"), is the user's choice."""
    from pinn_estimator.shipped import DEFAULT_WORLD, shipped_checkpoint

    world = (given_params(G.NODE_NAMES["sim"], args.sim_params_file, args.sim_param, ("world_mode",),
                          args.namespace)["world_mode"] or "").strip()
    chosen = given_params(G.NODE_NAMES["estimator"], args.estimator_params_file, args.estimator_param, ("checkpoint",),
                          args.namespace)
    if not world or world == DEFAULT_WORLD or chosen["checkpoint"] is not None:
        return []
    path = shipped_checkpoint(world)
    if not path.is_file():
        return []
    print(f"soil_launch: the {world} world: the estimator runs its shipped model {path}", file=sys.stderr)
    return [f"checkpoint:={path}"]


def _given_wait(node: str, params_file, params: list[str], name: str, hand_default: float, namespace: str) -> str | None:
    """The ``name`` wait the user gives ``node``: by -p, or in its params file unless there it is the
    hand-started default the shipped params files list (None: not given)."""
    on_line = given_params(node, None, params, (name,))[name]
    if on_line is not None:
        return on_line
    in_file = given_params(node, params_file, [], (name,), namespace)[name] if params_file else None
    try:
        return None if in_file is None or float(in_file) == hand_default else in_file
    except ValueError:
        return in_file  # (the node refuses it)


def launch_waits(args: argparse.Namespace) -> tuple[list[str], float | None]:
    """The simulator's start wait the launch gives it (``wait_timeout_s:=…``, [] if the user gave
    one) and how long the launch's own nodes wait for each other's writers (``inputs_wait_s``, the
    recorder's ``--inputs-wait``): half the simulator's wait, so they join well before it gives up
    on them, as nodes started by hand wait ``G.INPUTS_WAIT_S`` of its ``G.SIM_START_WAIT_S``; with
    the simulator waiting for ever (0), half the launch's own (an input whose writer never comes
    held a node an hour). A params file's value counts unless it is the hand-started default the
    shipped params files list. None: the user's wait is not a number the simulator takes (it
    refuses it, and the launch stops), so the nodes keep theirs."""
    given = _given_wait(G.NODE_NAMES["sim"], args.sim_params_file, args.sim_param, "wait_timeout_s",
                        G.SIM_START_WAIT_S, args.namespace)
    if given is None:
        return [f"wait_timeout_s:={G.LAUNCH_START_WAIT_S}"], G.LAUNCH_START_WAIT_S / 2
    try:
        start_wait_s = float(given)
    except ValueError:
        return [], None
    if not 0.0 <= start_wait_s <= G.MAX_WAIT_S:
        return [], None
    return [], (G.LAUNCH_START_WAIT_S if start_wait_s == 0.0 else start_wait_s) / 2


def _inputs_wait(node: str, params_file, params: list[str], namespace: str, wait_s: float | None) -> list[str]:
    """``["inputs_wait_s:=…"]`` for a launched node given none (``launch_waits``, ``_given_wait``)."""
    if wait_s is None or _given_wait(node, params_file, params, "inputs_wait_s", G.INPUTS_WAIT_S, namespace) is not None:
        return []
    return [f"inputs_wait_s:={wait_s}"]


def _speed_follow(args: argparse.Namespace) -> list[str]:
    """``["follow_episode_speed:=false"]`` for the planner when the controller is told not to follow
    the episodes' targets (it cuts at its own target_speed_m_s, which the planner then cannot know:
    its cut_speed_m_s stays the user's); [] otherwise."""
    given = given_params(G.NODE_NAMES["controller"], args.controller_params_file, args.controller_param,
                         ("follow_episode_targets",), args.namespace)["follow_episode_targets"]
    return ["follow_episode_speed:=false"] if given is not None and given.strip().lower() == "false" else []


def recorder_option_given(args: argparse.Namespace, option: str, shortest: int) -> bool:
    """Whether ``--recorder-arg`` gives the recorder ``option``, or a prefix of it longer than
    ``shortest`` characters (argparse takes an unambiguous prefix: --o for --out)."""
    return any(len(o := a.split("=", 1)[0]) > shortest and option.startswith(o) for a in args.recorder_arg)


def _count(wait: dict[str, int], endpoints: dict[str, int]) -> None:
    for topic, n in endpoints.items():
        wait[topic] = wait.get(topic, 0) + n


def _await(wait: dict[str, int], named: list[str], node_name: str, endpoints: dict[str, int],
           namespace: str) -> None:
    """One of the launch's own nodes for the simulator's wait: its endpoints counted, and named
    ('topic@/namespace/node'): the counts alone were met by readers outside the launch (a monitor,
    another recorder on the domain) before its own recorder listened, and the first episode went
    unrecorded."""
    _count(wait, endpoints)
    named += [f"{topic}@{namespace or ''}/{node_name}" for topic in endpoints]


def own_recorder_name(graph_id: str) -> str:
    """The launch's recorder's node name, its own: a recorder started by hand beside the launch
    is named ``soil_bag_record`` too, and by that name it met the simulator's wait for the
    launch's recorder (whose first episodes then went unrecorded, the launch exiting 0). The
    controller, estimator and planner keep their names: their params files' sections name them."""
    token = re.sub(r"[^A-Za-z0-9]", "_", graph_id)[-24:].strip("_") or uuid.uuid4().hex[:8]
    return f"{G.NODE_NAMES['recorder']}_{token}"


def build_nodes(args: argparse.Namespace) -> list[NodeProcess]:
    """The graph for these arguments, with the simulator told whom to wait for."""
    wait: dict[str, int] = {}
    named: list[str] = []  # each of the launch's own nodes by its name too (``_await``)
    nodes: list[NodeProcess] = []
    # this launch's own id, in its simulator's /sim/status events: its recorder records no other
    # launch's episodes (two graphs in one namespace of one domain), and its controller, estimator and
    # planner follow no other graph's events (``episode_follow``); the user's -p graph_id if given,
    # the same for all (a recorder given another would record nothing)
    graph_id = ((given_params(G.NODE_NAMES["sim"], None, args.sim_param, ("graph_id",))["graph_id"] or "").strip()
                or f"launch-{os.getpid()}-{uuid.uuid4().hex[:8]}")
    sim_wait, join_wait_s = launch_waits(args)
    if args.record:
        # With the estimator, its outputs go into the episode bags too (compare live vs replay).
        extra = ["--all-episode-topics", "--topics", *G.ESTIMATOR_OUTPUTS] if args.estimator else []
        extra += list(G.PLANNER_OUTPUTS) if args.planner else []
        if join_wait_s is not None and not recorder_option_given(args, "--inputs-wait", 2):
            extra += ["--inputs-wait", str(join_wait_s)]
        # (a name the user gives it, --recorder-arg __node:=NAME after --ros-args, is waited for instead)
        given = [m.group(1) for a in args.recorder_arg if (m := RECORDER_NAME_REMAP_RE.fullmatch(a))]
        recorder_name = given[-1] if given else own_recorder_name(graph_id)
        ros = _namespace_args(args.namespace) + ([] if given else ["-r", f"__node:={recorder_name}"])
        nodes.append(NodeProcess("recorder", [executable("soil_bag_record"), "--out", str(args.record),
                                              "--graph-id", graph_id, *extra, *args.recorder_arg,
                                              *(["--ros-args", *ros] if ros else [])], stop_order=3, records=True,
                                 after_death=f"what it had flushed is in the *.partial journals under {args.record}: "
                                             f"`soil_bag_repair {args.record}` makes bags of them"))
        _await(wait, named, recorder_name, RECORDER_ENDPOINTS, args.namespace)
    # the world's shipped model unless one is given (``world_checkpoint_param`` looks)
    follow = [f"graph_id:={graph_id}"]
    estimator_param = ((world_checkpoint_param(args) if args.estimator else [])
                       + unless_given(G.NODE_NAMES["estimator"], args.estimator_param, follow)
                       + _inputs_wait(G.NODE_NAMES["estimator"], args.estimator_params_file, args.estimator_param,
                                      args.namespace, join_wait_s)
                       + list(args.estimator_param))
    if args.estimator:
        # advice too (unless --require estimator): nothing in the loop waits for its estimates
        # (the simulator steps on the controller's commands), and a planner without them sends no targets
        without = "no more estimates" + ("; the planner sends no targets and the controller cuts to its own "
                                         "target_depth_m" if args.planner else "")
        nodes.append(NodeProcess("estimator", _ros_node("pinn_estimator", args.estimator_params_file,
                                                        estimator_param, args.namespace), stop_order=2,
                                 required="estimator" in args.require, without=without))
        _await(wait, named, G.NODE_NAMES["estimator"], ESTIMATOR_ENDPOINTS, args.namespace)
    if args.planner:
        # (the posterior's physics and bound law: the planner hears them from the estimator, unless given)
        # advice, not the machine: a controller whose planner goes silent cuts to its own
        # target_depth_m (planner_timeout_s; in lockstep after waiting planner_wait_s once), so a
        # planner that dies does not stop the cut; the launch says so and exits non-zero at the end
        nodes.append(NodeProcess("planner", _ros_node("soil_planner", args.planner_params_file,
                                                      unless_given(G.NODE_NAMES["planner"], args.planner_param,
                                                                   follow + _speed_follow(args))
                                                      + _inputs_wait(G.NODE_NAMES["planner"], args.planner_params_file,
                                                                     args.planner_param, args.namespace, join_wait_s)
                                                      + args.planner_param, args.namespace),
                                 stop_order=2, niceness=PLANNER_NICENESS, required="planner" in args.require,
                                 without="the controller cuts to its own target_depth_m"))
        _await(wait, named, G.NODE_NAMES["planner"], PLANNER_ENDPOINTS, args.namespace)
    if not args.no_controller:
        # the planner's loop unless the user sets depth_source
        closed = unless_given(G.NODE_NAMES["controller"], args.controller_param,
                              (["depth_source:=planner"] if args.planner else []) + follow)
        closed += _inputs_wait(G.NODE_NAMES["controller"], args.controller_params_file, args.controller_param,
                               args.namespace, join_wait_s)
        nodes.append(NodeProcess("controller", _ros_node("anti_stall_controller", args.controller_params_file,
                                                         closed + args.controller_param, args.namespace),
                                 stop_order=1))
        _await(wait, named, G.NODE_NAMES["controller"], CONTROLLER_ENDPOINTS, args.namespace)
    for entry in args.wait_for:  # subscribers outside the launch (a monitor, a planner, a test probe)
        topic, _, count = entry.rpartition(":")
        if not topic.startswith("/") or not G.COUNT_RE.fullmatch(count):
            raise ValueError(f"--wait-for {entry!r} is not of the form /topic:count")
        if topic not in G.SIM_WAITABLE_TOPICS:
            # the simulator would refuse it only once every node was up, and the launch exit 1
            raise ValueError(f"--wait-for {entry!r}: the simulator waits only for endpoints of its own topics, "
                             f"one of {', '.join(G.SIM_WAITABLE_TOPICS)} (for a planner, the ones it reads: "
                             f"/soil/known_params, /blade/force, /sim/status)")
        _count(wait, {topic: int(count)})
    sim = _ros_node("soil_sim_node", args.sim_params_file, [], args.namespace)
    # Only what was given on the command line overrides the params file (later -p wins).
    sim += [a for name in ("pacing", "rate") if getattr(args, name) is not None
            for a in ("-p", f"{name}:={getattr(args, name)}")]
    own = [f"exit_when_done:={'false' if args.keep_running else 'true'}", f"graph_id:={graph_id}", *sim_wait]
    if wait:
        own.append("wait_for:=[" + ",".join([f"'{t}:{n}'" for t, n in sorted(wait.items())]
                                            + [f"'{entry}'" for entry in named]) + "]")
        if given_params(G.NODE_NAMES["sim"], None, args.sim_param, ("wait_for",))["wait_for"] is not None:
            # the user's list is the simulator's whole list, as any -p the user gives
            if args.wait_for:
                raise ValueError(f"--sim-param wait_for replaces the whole list the simulator waits for, "
                                 f"--wait-for {' '.join(args.wait_for)} with it: give one of them")
            print("soil_launch: --sim-param wait_for replaces the launch's own wait for its nodes ("
                  + ", ".join(named) + "): the first ticks may go out before they listen; "
                  "--wait-for /TOPIC:N adds to it instead", file=sys.stderr)
    sim += _params(unless_given(G.NODE_NAMES["sim"], args.sim_param, own)
                   + args.sim_param)
    nodes.append(NodeProcess("sim", sim, stop_order=0, ends_launch=True))
    return nodes


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="soil_launch", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--pacing", choices=("realtime", "lockstep"),
                   help="simulator pacing (default: the params file's, else realtime)")
    p.add_argument("--rate", type=float, help="real-time factor for pacing realtime (default: params file's, else 1)")
    p.add_argument("--record", type=bags_dir, help="record every episode as a bag under this directory")
    add_domain_id_option(p, 0)
    p.add_argument("--namespace", default="", metavar="/NS",
                   help="put every node, and so every topic of the graph, under this ROS namespace (e.g. /dozer1): "
                        "graphs of several machines then share one domain without hearing each other; the bags "
                        "keep the topics' own names (default: the root namespace)")
    p.add_argument("--sim-params-file", type=Path, help="YAML parameters for soil_sim_node")
    p.add_argument("--sim-param", action="append", default=[], metavar="NAME:=VALUE",
                   help="a parameter of soil_sim_node (repeatable; `soil_sim_node --help` lists them)")
    p.add_argument("--controller-params-file", type=Path, help="YAML parameters for anti_stall_controller")
    p.add_argument("--controller-param", action="append", default=[], metavar="NAME:=VALUE",
                   help="a parameter of anti_stall_controller (repeatable; `anti_stall_controller --help` lists them)")
    p.add_argument("--estimator", action="store_true", help="also run the online PINN estimator (pinn_estimator)")
    p.add_argument("--estimator-params-file", type=Path, help="YAML parameters for pinn_estimator")
    p.add_argument("--estimator-param", action="append", default=[], metavar="NAME:=VALUE",
                   help="a parameter of pinn_estimator (repeatable; `pinn_estimator --help` lists them)")
    p.add_argument("--planner", action="store_true",
                   help="also run the soil-aware planner (implies --estimator) and let the controller follow it")
    p.add_argument("--planner-params-file", type=Path, help="YAML parameters for soil_planner")
    p.add_argument("--planner-param", action="append", default=[], metavar="NAME:=VALUE",
                   help="a parameter of soil_planner (repeatable; `soil_planner --help` lists them)")
    p.add_argument("--require", action="append", default=[], choices=ADVISORY_NODES,
                   help="stop the launch when this advisory node dies, as when the simulator, controller or recorder "
                        "does (repeatable; by default the cut goes on without it and the launch exits 1 at the end)")
    p.add_argument("--recorder-arg", action="append", default=[], help="extra argument for soil_bag_record")
    p.add_argument("--wait-for", action="append", default=[], metavar="/TOPIC:N",
                   help="also wait for N more matched subscribers of a topic the simulator publishes (or "
                        "publishers of a command topic) before the first tick: nodes started outside the launch")
    p.add_argument("--no-controller", action="store_true", help="do not start the controller")
    p.add_argument("--keep-running", action="store_true",
                   help="keep the simulator up after its episodes (end with Ctrl-C); default: end with them")
    p.add_argument("--timeout", type=float, default=0.0,
                   help="stop everything after this many seconds (0: never); the launch then exits 3")
    p.add_argument("--stop-timeout", type=float, default=10.0, help="seconds of silence a stopping node gets before SIGTERM (one that keeps reporting, the "
                        "recorder making its bags, is waited for up to 10 min; default 10)")
    args = p.parse_args(argv)
    check_graph_options(p, args)
    if args.namespace == "/":
        args.namespace = ""  # (the root)
    if args.namespace and not G.ROS_PATH_RE.fullmatch(args.namespace):
        p.error(f"--namespace {args.namespace!r} is not a ROS namespace: '/' then names of letters, digits and '_' "
                "(not starting with a digit) joined by '/', e.g. /dozer1 or /site_a/dozer1")
    if len(args.namespace) > MAX_NAMESPACE_LEN:
        p.error(f"--namespace of {len(args.namespace)} characters: at most {MAX_NAMESPACE_LEN} leave room for the "
                "graph's names under it (ROS names are at most 247 characters)")
    for flag, node in PARAMS_FILE_NODES.items():
        path = getattr(args, f"{flag}_params_file")
        if path is not None and not path.is_file():  # else the node dies at start with rclpy's traceback
            p.error(f"--{flag}-params-file {path}: " + ("a directory, not a YAML file" if path.is_dir() else "no such file"))
        if path is not None:
            try:  # (rcl would refuse it in the node, after the others had started)
                read_params_file(path)
            except ValueError as exc:
                p.error(f"--{flag}-params-file: {exc}")
        if args.namespace and path is not None \
                and not _sections_for(path, f"{args.namespace}/{node}") and _sections_for(path, f"/{node}"):
            p.error(f"--{flag}-params-file {path}: its sections are for /{node}, not for {args.namespace}/{node} "
                    f"where --namespace puts it (rcl would apply none of them): name the section /**/{node} or "
                    f"nest it under the namespace")
    for flag, value in (("--timeout", args.timeout), ("--stop-timeout", args.stop_timeout)):
        if not math.isfinite(value) or value < 0 or (flag == "--stop-timeout" and value == 0):
            p.error(f"{flag} {value} must be a finite number of seconds, {'> 0' if flag == '--stop-timeout' else '>= 0 (0: never)'}")
    if args.planner:
        args.estimator = True
        check_lockstep_stride(p, args)
    # options of a node this launch does not start would be ignored without a word
    runs = {"estimator": args.estimator, "planner": args.planner, "controller": not args.no_controller}
    for node, running in runs.items():
        given = ([f"--{node}-param"] if getattr(args, f"{node}_param") else []) \
            + ([f"--{node}-params-file"] if getattr(args, f"{node}_params_file") is not None else []) \
            + ([f"--require {node}"] if node in args.require else [])
        if given and not running:
            p.error(f"{', '.join(given)} given, but this launch starts no {node} "
                    f"({'--no-controller' if node == 'controller' else f'add --{node}'})")
    if args.recorder_arg and not args.record:
        p.error("--recorder-arg given, but this launch starts no recorder (add --record DIR)")
    # the recorder's last --out would win over --record's; any prefix of it too (argparse takes --o, --ou)
    if recorder_option_given(args, "--out", 2):
        p.error("--recorder-arg --out: the recorder writes where --record says; give the directory there")
    if any(re.search(r"(^|:)__ns:=", a) for a in args.recorder_arg):  # (the simulator would wait for it elsewhere)
        p.error("--recorder-arg __ns:=: the launch puts every node, the recorder too, where --namespace says")
    if recorder_option_given(args, "--graph-id", 4):
        p.error("--recorder-arg --graph-id: the launch gives its simulator and recorder one id; give it as "
                "--sim-param graph_id:=ID")
    return args


def check_lockstep_stride(p: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """The planner in lockstep needs an estimate every tick: the controller answers tick k once the
    planner's target for tick k − 2 came, and the planner plans a tick when its estimate comes. With
    the estimator's ``stride`` above 1 most ticks have none, and each waited the controller's
    ``planner_wait_s`` (2 s): 42 s for a 1 s episode (an outside tester's). Refused before the graph starts."""
    sim_given = given_params(G.NODE_NAMES["sim"], None, args.sim_param, ("pacing",))["pacing"]
    pacing = sim_given or args.pacing or given_params(G.NODE_NAMES["sim"], args.sim_params_file, [], ("pacing",),
                                                      args.namespace)["pacing"]
    stride = given_params(G.NODE_NAMES["estimator"], args.estimator_params_file, args.estimator_param, ("stride",),
                          args.namespace)["stride"]
    if pacing == "lockstep" and stride is not None and stride.strip() != "1":
        p.error(f"the estimator's stride {stride} with the planner in lockstep: the controller keeps step with a plan "
                "for every tick, and the planner plans a tick from its estimate; give stride 1 (the default) or "
                "--pacing realtime")


def check_graph_options(p: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--rate`` as soil_launch and soil_demo take it (their ``--domain-id``: ``add_domain_id_option``): the rate in the
    simulator's own range, checked before the graph starts (a rate of 5000 or inf was taken, and
    the simulator refused it once its node was up), and none with lockstep pacing (a lockstep
    episode runs as fast as the graph answers: silently ignored, it misled)."""
    from soil_sim_node.pacing import RATE_RANGE

    if args.rate is None:
        return
    if args.pacing == "lockstep":
        p.error(f"--rate {args.rate:g} is the real-time factor of --pacing realtime; lockstep has none")
    if not RATE_RANGE[0] <= args.rate <= RATE_RANGE[1]:  # (NaN too)
        p.error(f"--rate {args.rate:g} outside [{RATE_RANGE[0]:g}, {RATE_RANGE[1]:g}], the simulator's real-time factors")


def launch_for(args: argparse.Namespace, out=sys.stdout, on_interrupt: Callable[[], None] | None = None) -> Launch:
    """The launch ``soil_launch`` runs for these (parsed) arguments, its output to ``out``.

    ValueError / FileNotFoundError if the graph cannot be built (bad parameter, missing node)."""
    return Launch(build_nodes(args), loopback_env(args.domain_id), timeout_s=args.timeout,
                  stop_timeout_s=args.stop_timeout, out=out, on_interrupt=on_interrupt,
                  interrupt_ends_run=args.keep_running)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        launch = launch_for(args)
    except (ValueError, FileNotFoundError) as err:
        print(f"soil_launch: {err}", file=sys.stderr)
        return EXIT_BAD_ARGS
    return launch.run()


if __name__ == "__main__":
    raise SystemExit(main())
