"""rclpy glue shared by every node of the graph (the only soil_msgs_py module importing rclpy).

* ``qos_profile(spec)`` / ``topic_qos(name)``: graph.QosSpec -> rclpy QoSProfile.
* ``message_class(msgtype)``: "pkg/msg/Name" -> the installed Python message class.
* ``declare_parameters(node, table)``: a node's parameter table declared, with descriptions (a whole
  number given for a float parameter taken as that float).
* ``spin_node(factory, args)``: the Jazzy entry-point pattern (init, spin, clean shutdown
  on Ctrl-C / SIGTERM / external shutdown) so every node's ``main`` is two lines; given the
  node's parameter table it also answers ``--help`` and refuses arguments that are not ROS ones.
"""
from __future__ import annotations

import collections
import difflib
import importlib
import math
import signal
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.context import Context
from rclpy.exceptions import NameValidationException, ParameterException, ParameterUninitializedException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from .dds_profile import use_graph_profile
from .episode_follow import EpisodeFollower
from .params_files import node_parameters, read_params_file
from .values import number_in
from .yaml_file import DuplicateKey
from .launcher_death import stop_with_launcher
from .graph import (DATA_QOS, EXIT_BAD_CONFIG, GRAPH_OWN_TOPICS, INPUT_SILENCE_S, MAX_WAIT_S, SIM_STATUS_TOPIC,
                    STRING_MSGTYPE, TOPIC_QOS, EpisodeEvent, QosSpec, publisher_qos_spec)

RCLError = _rclpy.RCLError  # rcl's own refusal (e.g. of a node namespace it cannot validate)
_RELIABILITY = {"reliable": ReliabilityPolicy.RELIABLE, "best_effort": ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {"volatile": DurabilityPolicy.VOLATILE, "transient_local": DurabilityPolicy.TRANSIENT_LOCAL}


def declare_parameters(node: Node, table: dict) -> Callable[[str], object]:
    """Declare ``{name: (default, description[, typed_default])}`` on ``node``; returns ``get(name)``.

    ``typed_default`` (e.g. ``Parameter.Type.STRING_ARRAY``) is declared instead of ``default``
    where the default alone cannot give the type (an empty list), then given ``default`` as that
    type if nothing set it. ``get`` reads the current value (``default`` for one that has none).
    """
    doubles = {name for name, (default, *_) in table.items() if isinstance(default, float)}
    overrides = getattr(node, "_parameter_overrides", {})  # rclpy's (no public API): what -p and params files gave it
    for name in doubles & set(overrides):
        overrides[name] = as_double(overrides[name])
    for name, (default, description, *typed) in table.items():
        node.declare_parameter(name, typed[0] if typed else default, ParameterDescriptor(description=description))
        if typed:
            try:
                node.get_parameter(name)
            except ParameterUninitializedException:
                # declared by its type alone a parameter has no value, and rclpy's get_parameters
                # service then answers nothing for a request naming it (`ros2 param get`/`dump`
                # fail): give it its default, typed (an empty list of that type)
                node.set_parameters([Parameter(name, typed[0], list(default))])
    node.add_pre_set_parameters_callback(lambda params: [as_double(p) if p.name in doubles else p for p in params])
    for text in unknown_parameter_warnings(node):
        node.get_logger().warning(text)

    def get(name: str) -> object:
        try:
            return node.get_parameter(name).value
        except ParameterUninitializedException:
            return table[name][0]

    return get


def as_double(parameter: Parameter) -> Parameter:
    """An INTEGER parameter as the DOUBLE of the same value; any other unchanged.

    Why: a parameter declared with a float default is typed DOUBLE, and rclpy refuses
    ``-p margin:=1`` or a run-time set to 1 as "of type INTEGER, expecting type DOUBLE", though
    1 is a valid margin. YAML and the command line write whole numbers without a point."""
    if parameter.type_ == Parameter.Type.INTEGER:
        return Parameter(parameter.name, Parameter.Type.DOUBLE, float(parameter.value))
    return parameter


def unknown_parameter_warnings(node: Node) -> list[str]:
    """One warning per parameter given to ``node`` (``-p``, a params file) that it does not declare.

    Why: rclpy keeps such an override and never uses it, so a misspelt ``-p duraton_s:=2.0`` would
    change nothing and say nothing. A warning, not an error: a params file's ``/**`` section is
    shared by every node, each of which declares only its own."""
    overrides = getattr(node, "_parameter_overrides", {})  # rclpy's (no public API): what -p and params files gave it
    declared = list(node.list_parameters([], 0).names)  # depth 0: every declared name
    out = []
    for name in sorted(n for n in overrides if not node.has_parameter(n)):
        close = difflib.get_close_matches(name, declared, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        out.append(f"parameter {name!r} is not a parameter of this node{hint}; ignored")
    return out


def qos_profile(spec: QosSpec) -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=spec.depth,
        reliability=_RELIABILITY[spec.reliability],
        durability=_DURABILITY[spec.durability],
    )


def topic_qos(topic: str) -> QoSProfile:
    """The graph's QoS for ``topic`` (DATA_QOS for topics outside the table)."""
    return qos_profile(TOPIC_QOS.get(topic, DATA_QOS))


def publisher_qos(topic: str) -> QoSProfile:
    """What a node publishes ``topic`` with (``graph.publisher_qos_spec``); subscribers keep
    ``topic_qos``."""
    return qos_profile(publisher_qos_spec(topic))


def local(topic: str) -> str:
    """A topic of the graph's own (``graph.GRAPH_OWN_TOPICS``, by the contract's absolute name,
    ``/blade/force``) as the relative name a node creates its endpoint by; any other name as given.
    In the root namespace that is the same topic; under ``--ros-args -r __ns:=/dozer1``
    (``soil_launch --namespace``) it is ``/dozer1/blade/force``, so a machine's whole graph moves
    into its namespace and two machines share a DDS domain without hearing each other. Why: an
    absolute name ignores the namespace, and two graphs given namespaces of their own had each
    estimated, planned and recorded on both machines' data."""
    return topic.lstrip("/") if topic in GRAPH_OWN_TOPICS else topic


def endpoint_node(info) -> str:
    """The fully qualified name of the node behind a topic endpoint (an rclpy
    ``TopicEndpointInfo``): ``/dozer1/soil_bag_record``, ``/soil_bag_record`` in the root namespace."""
    return f"{info.node_namespace.rstrip('/')}/{info.node_name}"


def message_class(msgtype: str):
    """Python class of a ROS 2 interface name like ``geometry_msgs/msg/WrenchStamped``."""
    parts = msgtype.split("/")
    if len(parts) != 3 or parts[1] != "msg":
        raise ValueError(f"message type {msgtype!r} is not of the form 'package/msg/Name'")
    pkg, _, name = parts
    try:
        return getattr(importlib.import_module(f"{pkg}.msg"), name)
    except (ImportError, AttributeError):
        raise ValueError(f"message type {msgtype!r} is not installed (no Python module {pkg}.msg.{name})") from None


class WarnLimiter:
    """Warn on the 1st, 10th, 100th ... occurrence of each kind of problem.

    A node that keeps running on bad input must not flood its log at 60 Hz, yet every
    kind of problem is reported at least once, with its running count."""

    def __init__(self, logger) -> None:
        self.logger = logger
        self.counts: collections.Counter = collections.Counter()

    def __call__(self, kind: str, text: str) -> None:
        self.counts[kind] += 1
        n = self.counts[kind]
        if n == 1 or math.log10(n).is_integer():
            self.logger.warning(text + (f" ({n} so far)" if n > 1 else ""))


def wall_timer(node: Node, period_s: float, callback: Callable, **kwargs):
    """A timer on the steady clock: the graph's polls, waits and silences are wall-time matters.
    Why: on a node given ``use_sim_time:=true`` a default timer runs on /clock, which does not move
    before the first tick, while the simulator waits for readers those timers create (an outside
    tester's lockstep graph waited 10 s and ended its episode at tick 1)."""
    return node.create_timer(period_s, callback, clock=Clock(clock_type=ClockType.STEADY_TIME), **kwargs)


class InputSilence:
    """Says when a node's inputs stop mid-episode and when they come back.

    Why: with the simulator killed mid-episode the controller, the estimator and the planner
    stayed up, as they should, and said nothing for as long as it was gone, so a user could not
    tell a dead simulator from a slow one. Armed by an episode_start (``start``), disarmed by its
    episode_end (``end``): between episodes, or before a node's first episode, silence is normal.
    ``heard`` is called on every input message (cheap: one clock read)."""

    def __init__(self, node: Node, what: str, limit_s: float = INPUT_SILENCE_S):
        self.logger, self.what, self.limit_s = node.get_logger(), what, limit_s
        self.episode: str | None = None
        self.last = 0.0  # time.monotonic() [s] of the last input heard (or of the episode's start)
        self.silent = False
        wall_timer(node, min(0.5, limit_s / 2), self._check)

    def start(self, episode: str) -> None:
        self.episode, self.last, self.silent = episode, time.monotonic(), False

    def end(self) -> None:
        self.episode = None

    @property
    def gone(self) -> bool:
        """No input for ``limit_s``: the source of the episode under way is presumed gone
        (``episode_follow.EpisodeFollower.refusal``'s ``source_silent``)."""
        return time.monotonic() - self.last >= self.limit_s

    def heard(self) -> None:
        now = time.monotonic()
        if self.silent:
            self.silent = False
            self.logger.info(f"{self.what} again after {now - self.last:.1f} s")
        self.last = now

    def _check(self) -> None:
        if self.episode is None or self.silent:
            return
        quiet = time.monotonic() - self.last
        if quiet >= self.limit_s:
            self.silent = True
            self.logger.warning(f"no {self.what} for {quiet:.1f} s in episode {self.episode}: has its publisher "
                                "stopped? (waiting for it; said again when it comes back)")


def status_event(text: str, warn: WarnLimiter) -> EpisodeEvent | None:
    """A ``/sim/status`` message's event, or None (warned, naming the problem) if malformed:
    a bad status message never stops a node."""
    try:
        return EpisodeEvent.from_json(text)
    except (ValueError, ArithmeticError) as err:  # (the parser gives ValueError; a number it missed, not a crash)
        warn("status", f"{SIM_STATUS_TOPIC}: {err}; ignored")
        return None


def followed_status_event(text: str, warn: WarnLimiter, follower: EpisodeFollower,
                          silence: InputSilence) -> EpisodeEvent | None:
    """A ``/sim/status`` message's event if it is well formed and the node's to take (``episode_follow``:
    the episode under way's own, a start of its graph), else None, warned: a stray writer of
    /sim/status neither retargets nor stops a node mid-episode."""
    event = status_event(text, warn)
    if event is None:
        return None
    if why := follower.refusal(event, source_silent=silence.gone):
        warn("foreign_status", f"{SIM_STATUS_TOPIC}: {why}")
        return None
    return event


class JoinAfterInputs:
    """Calls ``join()`` (it creates the readers a simulator waits for before tick 0) only once
    every reader in ``inputs`` (topic -> subscription) has a matched publisher, or ``wait_s``
    after construction (then ``on_missing(topics)`` is told which had none).

    Why: a simulator holds tick 0 until its own writers and readers have matched, but nothing
    waits for a node's readers of other nodes' topics (the controller's commands, the
    estimator's estimates, the planner's targets); matched late on a loaded machine, a
    volatile reader never sees the first ticks. Joining the simulator's topics last makes the
    simulator wait for them too. Polled by a node timer (``POLL_S``), cancelled once joined.
    """

    POLL_S = 0.02

    def __init__(self, node: Node, inputs: dict, join: Callable[[], object], wait_s: float,
                 on_missing: Callable[[list[str]], None] | None = None):
        number_in("inputs_wait_s", wait_s, 0.0, MAX_WAIT_S, what="a number of seconds")
        self.node, self.inputs, self.join, self.on_missing = node, dict(inputs), join, on_missing
        self.joined = False
        self._deadline = time.monotonic() + float(wait_s)
        self._timer = wall_timer(node, self.POLL_S, self.poll)
        self.poll()

    def poll(self) -> None:
        if self.joined:
            return
        missing = [topic for topic, sub in self.inputs.items() if sub.get_publisher_count() < 1]
        if missing and time.monotonic() < self._deadline:
            return
        if missing and self.on_missing is not None:
            self.on_missing(missing)
        self.joined = True
        self._timer.cancel()
        self.join()


def status_after_inputs(node: Node, inputs: dict, callback: Callable, wait_s: float,
                        on_missing: Callable[[list[str]], None] | None = None) -> JoinAfterInputs:
    """The node's /sim/status reader, created once ``inputs`` matched (``JoinAfterInputs``)."""
    return JoinAfterInputs(node, inputs, lambda: node.create_subscription(
        message_class(STRING_MSGTYPE), local(SIM_STATUS_TOPIC), callback, topic_qos(SIM_STATUS_TOPIC)), wait_s,
        on_missing)


def stopping_said(signum: int | None) -> str:
    """What a node logs when it stops on a signal (None: its ROS context was shut down): a node that
    stopped with exit code 0 and no reason looked like a crash (an outside tester's)."""
    return "stopping: the ROS context was shut down" if signum is None else f"stopping: {signal.Signals(signum).name} received"


def init_context(domain_id: int, **init_kwargs) -> Context:
    """A fresh rclpy context on ``domain_id`` for an in-process participant beside the graph (a
    monitor, a probe), initialised as the graph's nodes are: with the graph's Fast DDS profile
    (``dds_profile``), loaded before the first participant of the process exists."""
    use_graph_profile()
    context = Context()
    rclpy.init(context=context, domain_id=domain_id, **init_kwargs)
    return context


def init_rclpy(args: list[str] | None, on_signal: Callable) -> None:
    """``rclpy.init`` without rclpy's signal handlers; SIGINT and SIGTERM call ``on_signal``.

    Why: rclpy's handlers shut the context down at once, after which a node can no longer
    publish its last ``/sim/status`` event or finish a bag on the way out.
    """
    use_graph_profile()
    rclpy.init(args=sys.argv if args is None else args, signal_handler_options=SignalHandlerOptions.NO)
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    # started by soil_launch: a launcher killed outright stops this node too (a SIGTERM, above)
    watch = stop_with_launcher()
    if watch not in ("", "watching"):
        rclpy.logging.get_logger(_program(sys.argv if args is None else args)).warning(watch)


DRAIN_LIMIT_S = 10.0  # most a stopping node may spend letting in what is in flight
ACK_LIMIT_S = 5.0  # most a stopping node may wait for its reliable readers to acknowledge its samples


def wait_for_acks(node: Node, limit_s: float = ACK_LIMIT_S) -> bool:
    """Before a node's publishers go: wait (at most ``limit_s`` in all) until every reliable
    reader acknowledged every sample. A writer's history dies with its process, so a reader
    that fell behind (a recorder behind a lockstep graph) would otherwise never get the
    samples its transport dropped. True if all were acknowledged in time."""
    from rclpy.duration import Duration

    deadline = time.monotonic() + limit_s
    acked = True
    for publisher in list(node.publishers):
        left = deadline - time.monotonic()
        try:
            acked &= left > 0 and publisher.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9)))
        except Exception:  # noqa: BLE001 - best effort on the way out (a destroyed or best-effort writer)
            continue
    return acked


HELP_FLAGS = ("-h", "--help")


def usage(prog: str, parameters: dict, summary: str = "") -> str:
    """A node's ``--help``: how its settings are given and its parameter table
    (``{name: (default, description[, typed_default])}``, as ``declare_parameters`` takes it)."""
    lines = [f"usage: {prog} [--ros-args [-p NAME:=VALUE ...] [--params-file FILE] [-r __node:=NAME] ...]"]
    if summary:
        lines += ["", summary]
    lines += ["", "parameters (NAME (default): description):"]
    lines += [f"  {name} ({default!r}): {description}" for name, (default, description, *_) in parameters.items()]
    return "\n".join(lines)


def rcl_error_text(err: Exception) -> str:
    """rcl's message without the C source locations it appends (", at /project/src/...")."""
    return str(err).split(", at /")[0]


def own_arguments(argv: list[str]) -> list[str]:
    """The arguments of ``argv`` (program name first) that are not ROS arguments. RuntimeError
    (rcl's) where the ROS arguments do not parse (``-p soil`` without ``:=``).

    ``NAME:=VALUE`` outside ``--ros-args`` counts as the node's own: rcl takes it as a remap rule
    of the deprecated syntax (a warning, then nothing), so ``soil_sim_node pacing:=lockstep`` ran in
    real time as if it had not been typed (a number, ``duration_s:=1.0``, is no valid remap and
    was refused)."""
    from rclpy.utilities import remove_ros_args

    outside = [arg for arg, in_ros, _ in _ros_scan(argv[1:]) if not in_ros and ":=" in arg]
    kept = list(remove_ros_args(argv)[1:])
    return kept + [a for a in outside if a not in kept]


def _ros_scan(args: list[str]):
    """(arg, inside --ros-args, the argument after it) for each argument but the markers
    ``--ros-args`` and ``--`` themselves (rcl's rule: ROS arguments run from ``--ros-args`` to ``--``)."""
    in_ros = False
    for i, arg in enumerate(args):
        if arg == "--ros-args":
            in_ros = True
        elif arg == "--":
            in_ros = False
        else:
            yield arg, in_ros, args[i + 1] if i + 1 < len(args) else ""


def _program(argv: list[str]) -> str:
    return Path(argv[0]).name if argv else "node"


def print_refusal(argv: list[str], err: Exception) -> None:
    """rcl's refusal of the ROS arguments (its RCLError / RCLInvalidROSArgsError) in one line."""
    print(f"{_program(argv)}: cannot start: {rcl_error_text(err)}", file=sys.stderr)


def own_arguments_or_refusal(argv: list[str]) -> list[str] | None:
    """``own_arguments(argv)``, or None after printing rcl's refusal of the ROS arguments in one
    line (the caller exits 2), for a tool that parses its own arguments beside the ROS ones."""
    try:
        return own_arguments(argv)
    except RuntimeError as err:
        print_refusal(argv, err)
        return None


def params_files(argv: list[str]) -> list[str]:
    """The ``--params-file`` paths among ``argv``'s ROS arguments (between ``--ros-args`` and ``--``)."""
    return [after for arg, in_ros, after in _ros_scan(argv) if in_ros and arg == "--params-file"]


def params_file_refusal(argv: list[str]) -> str | None:
    """Why a ``--params-file`` of ``argv`` is refused before the node starts, or None: one that
    gives a key twice in a mapping (``yaml_file.DuplicateKey``), of which rcl would take one in
    silence (the node had started with it and a warning; soil_launch refuses such a file too)."""
    for path in params_files(argv):
        try:
            read_params_file(path)
        except DuplicateKey as err:
            return str(err)
        except ValueError:
            continue  # rcl refuses a file it cannot read or parse, in its own words
    return None


def params_file_warnings(argv: list[str], node: Node) -> list[str]:
    """One warning per ``--params-file`` with no section for ``node``: rcl applies none of it, so a
    misspelt node name (``soil_sim_nod:``) would change nothing and say nothing."""
    out = []
    for path in params_files(argv):
        try:
            sections = read_params_file(path)
        except ValueError:
            continue  # rcl read it already (it refuses a file it cannot read or parse); a key given twice: refused
        keys = [str(k) for k in sections]
        # (nested namespace maps too: rcl gives ``ns: {node: {ros__parameters: …}}`` to /ns/node)
        if not (keys and node_parameters(sections, node.get_fully_qualified_name())):
            close = difflib.get_close_matches(node.get_name(), [k.strip("/") for k in keys], n=1)
            hint = f" (is {close[0]} a misspelling of {node.get_name()}?)" if close else ""
            out.append(f"params file {path} has no section for this node ({node.get_fully_qualified_name()}; "
                       f"its sections: {', '.join(keys) or 'none'}){hint}: nothing in it applies")
    return out


def spin_node(factory: Callable[[], Node], args: list[str] | None = None, parameters: dict | None = None,
              summary: str = "") -> int:
    """Run one node until Ctrl-C, SIGTERM, ``rclpy.shutdown`` or ``node.finished``.

    SIGINT and SIGTERM only set a flag that the spin loop checks (within 0.1 s), so a signal
    never lands in the middle of a callback (a journal write, a publish) and the context is
    still valid in ``node.close()``: a node can publish its last status or finish a bag on
    the way out. A factory that raises ValueError or a ParameterException (a bad parameter)
    logs the message and exits with code 2, as do ROS arguments rcl cannot parse (a params file
    that is missing, not YAML or gives a key twice, ``-p NAME`` without a value). Given the node's ``parameters``
    table (a node whose command line holds nothing but ROS arguments), ``--help`` prints
    ``usage`` (exit 0) and any other argument that is not a ROS one is refused (exit 2): the
    node would otherwise start and ignore it. Otherwise the exit code is ``node.exit_code``
    (default 0).
    """
    argv = list(sys.argv if args is None else args)
    own = own_arguments_or_refusal(argv)
    if own is None:
        return EXIT_BAD_CONFIG
    if parameters is not None and any(a in HELP_FLAGS for a in own):
        print(usage(_program(argv), parameters, summary))
        return 0
    if parameters is not None and own:
        hint = (" (outside --ros-args, NAME:=VALUE is an old-style remap rule to rcl, not a parameter)"
                if any(":=" in a for a in own) else "")
        print(f"{_program(argv)}: error: unrecognised argument(s) {' '.join(own)}{hint}: a node takes its settings as "
              "--ros-args -p NAME:=VALUE or --ros-args --params-file FILE (--help lists them)", file=sys.stderr)
        return EXIT_BAD_CONFIG
    refusal = params_file_refusal(argv)
    if refusal:
        print(f"{_program(argv)}: cannot start: {refusal}", file=sys.stderr)
        return EXIT_BAD_CONFIG
    stop: list[int] = []
    try:
        init_rclpy(argv, lambda signum, frame: stop.append(signum))
    except RuntimeError as err:  # a --params-file rcl cannot read or parse
        print_refusal(argv, err)
        return EXIT_BAD_CONFIG
    node = executor = None
    code = 0
    shown = warnings.showwarning
    try:
        with warnings.catch_warnings(record=True) as caught:  # said through the node's log, below
            warnings.filterwarnings("ignore", message="Failed to fini rosout publisher", category=RuntimeWarning)
            node = factory()
        # a Python warning (a fusion config lacking keys) is a log line of the node's, not a source
        # line on stderr beside its log (an outside tester's)
        warnings.showwarning = lambda message, *_, **__: node.get_logger().warning(str(message))
        for text in [*(str(w.message) for w in caught), *params_file_warnings(argv, node)]:
            node.get_logger().warning(text)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while rclpy.ok() and not stop and not getattr(node, "finished", False):
            executor.spin_once(timeout_sec=0.1)
        if stop or not rclpy.ok():
            node.get_logger().info(stopping_said(stop[0] if stop else None))
        # A node with data in flight that it must not lose (the recorder, the estimator) says so
        # through ``draining()``; it gets up to its ``drain_limit_s`` (DRAIN_LIMIT_S) more spinning
        # before ``close``. A second signal (another Ctrl-C, soil_launch's SIGTERM) ends it at once.
        draining = getattr(node, "draining", None)
        deadline, signals = time.monotonic() + getattr(node, "drain_limit_s", DRAIN_LIMIT_S), len(stop)
        while (draining is not None and rclpy.ok() and len(stop) <= signals and draining()
               and time.monotonic() < deadline):
            executor.spin_once(timeout_sec=0.05)
    except ExternalShutdownException:  # (the context shut down inside spin_once: said as above)
        if node is not None:
            node.get_logger().info(stopping_said(None))
    except (ValueError, ParameterException) as err:  # a bad parameter value or type
        if node is not None:
            raise
        rclpy.logging.get_logger(_program(argv)).error(f"cannot start: {err}")
        code = EXIT_BAD_CONFIG
    except (NameValidationException, RCLError) as err:
        # a namespace rcl cannot make the node's names under (``-r __ns:=`` too long: a traceback before)
        if node is not None:
            raise
        first = rcl_error_text(err).strip().splitlines()[0].rstrip(": ")
        named = isinstance(err, NameValidationException) or "name" in first.lower()
        hint = " (its namespace or name, e.g. -r __ns:=, is too long or not a ROS name)" if named else ""
        print(f"{_program(argv)}: cannot start: {first}{hint}", file=sys.stderr)
        code = EXIT_BAD_CONFIG
    finally:
        warnings.showwarning = shown
        try:
            if node is not None:
                close = getattr(node, "close", None)
                if close is not None:
                    close()
                wait_for_acks(node)
                node.destroy_node()
        finally:
            if executor is not None:  # before the context goes: else its __del__ at exit prints a traceback
                executor.shutdown(timeout_sec=1.0)
            rclpy.try_shutdown()
    return code or int(getattr(node, "exit_code", 0) or 0)
