"""``soil_bag_record``: record the episode topics, one rosbag2 bag per ``/sim/status`` episode.

Thin rclpy adapter around ``recorder.Recorder`` (routing, journals, bag conversion): raw
(CDR bytes) subscriptions with ``graph.RECORDER_QOS`` for the data, ``/sim/status`` with
``CONTROL_QOS``, a timer that flushes the journals every ``--flush-period`` and finishes
episodes. Each message goes to the recorder with its writer's publication sequence number
from the message info, so another publisher's messages on a recorded topic (episode topic
or labelled extra) are refused (see ``recorder``). SIGINT/SIGTERM only set a flag that the spin loop checks, so a signal never lands
in the middle of a journal write; the open bags are then finished cleanly (truncated to
whole ticks). A SIGKILL leaves ``<out>/<name>.partial/`` for ``soil_bag_repair``.

    soil_bag_record --out DIR [--topics T ...] [--all-episode-topics] [--no-split]
                    [--flush-period S] [--end-grace S] [--inputs-wait S] [--graph-id ID] [--ros-args ...]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time

from rclpy.node import Node
from rclpy.qos import ReliabilityPolicy
from std_msgs.msg import String

from soil_msgs_py import messages as M
from soil_msgs_py.cli_paths import bags_dir
from soil_msgs_py.graph import (CONTROL_QOS, EXIT_BAD_CONFIG, EXIT_BAG_NOT_WRITTEN, INPUTS_WAIT_S, MAX_WAIT_S, NODE_NAMES,
                                RECORDER_QOS, SIM_STATE_TOPICS, SIM_STATUS_TOPIC, graph_id_problem)
from .bag_writer import offered_qos
from .recorder import END_GRACE_S, Recorder
from soil_msgs_py.ros_adapter import (JoinAfterInputs, local, message_class, own_arguments_or_refusal, qos_profile,
                                      spin_node, wall_timer)
from soil_msgs_py.topics import EPISODE_TOPICS, GRAPH_TOPICS_BY_NAME, TOPICS_BY_NAME, with_guesses

_DISCOVERY_PERIOD_S = 0.5
_PENDING_SAY_AFTER_S = 5.0  # a --topics name with no publisher this long is said to the user


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="soil_bag_record",
        description="Record the episode topics into one rosbag2 (MCAP) bag per /sim/status episode.",
        epilog=f"Exit code {EXIT_BAG_NOT_WRITTEN} if an episode went without its bag (its journal could not be made, "
               "closed or converted; each said when it happened; a journal left behind: soil_bag_repair); 2 for "
               "refused arguments.",
    )
    p.add_argument("--out", type=bags_dir, required=True, help="directory that receives the bags")
    p.add_argument("--topics", nargs="+", default=[], metavar="T",
                   help="record these topics (types of non-episode topics are discovered on the graph)")
    p.add_argument("--all-episode-topics", action="store_true",
                   help="also record every episode topic (the default when --topics is not given)")
    p.add_argument("--no-split", action="store_true",
                   help="one bag record_<UTC time> until Ctrl-C, ignoring /sim/status")
    p.add_argument("--flush-period", type=float, default=0.25, metavar="S",
                   help="journal flush period [s] of wall-clock and of simulation time: the most a SIGKILL can lose (default 0.25)")
    p.add_argument("--end-grace", type=float, default=END_GRACE_S, metavar="S",
                   help="after episode_end, finish an incomplete episode once no message came for this long [s] "
                        f"(default {END_GRACE_S:g}: more than Fast DDS's 3 s heartbeat, after which lost samples are re-sent)")
    p.add_argument("--inputs-wait", type=float, default=INPUTS_WAIT_S, metavar="S",
                   help="subscribe to the simulator's topics once the recorded topics other nodes publish (commands, "
                        "estimates, plans) have a publisher, or after this long [s] (default %(default)g; 0: at once), so a "
                        "simulator waiting for this recorder starts no episode before it can hear those nodes")
    p.add_argument("--graph-id", default="", metavar="ID",
                   help="record only episodes whose /sim/status events carry this graph id (soil_launch gives its "
                        "nodes one: a second launch, or a stray writer of /sim/status, on the same topics is not "
                        "recorded)")
    opts = p.parse_args(argv)
    if problem := graph_id_problem(opts.graph_id):
        p.error(f"--graph-id {opts.graph_id!r} {problem}")
    if not 0 <= opts.inputs_wait <= MAX_WAIT_S:
        p.error(f"--inputs-wait {opts.inputs_wait} must be a number of seconds in [0, {MAX_WAIT_S:g}]")
    if not opts.flush_period > 0:
        p.error(f"--flush-period {opts.flush_period} must be > 0 s")
    if not opts.end_grace >= 0:
        p.error(f"--end-grace {opts.end_grace} must be >= 0 s")
    if bad := [t for t in opts.topics if not t.startswith("/")]:
        p.error(f"--topics {bad}: topic names must be absolute (start with '/')")
    return opts


class RecordNode(Node):
    def __init__(self, opts: argparse.Namespace):
        super().__init__(NODE_NAMES["recorder"])
        wanted = list(dict.fromkeys(opts.topics))
        if opts.all_episode_topics or not wanted:
            wanted = [t.name for t in EPISODE_TOPICS] + [t for t in wanted if t not in TOPICS_BY_NAME]
        known = {t: GRAPH_TOPICS_BY_NAME[t].msgtype for t in wanted if t in GRAPH_TOPICS_BY_NAME}
        self._pending = [t for t in wanted if t not in known]
        try:
            self.recorder = Recorder(
                opts.out, known, split=not opts.no_split, end_grace_s=opts.end_grace, flush_sim_s=opts.flush_period,
                qos_for=offered_qos, log=self.get_logger(), graph_id=opts.graph_id,
            )
            tempfile.TemporaryFile(dir=opts.out).close()  # writable, or no episode could be recorded there
        except OSError as err:  # a directory that cannot be made or written: refused at start (exit 2)
            raise ValueError(f"--out {str(opts.out)!r}: cannot create or use it: {err.strerror or err}") from None
        # Created first: when status and data are ready in the same wait, status is taken first.
        self.create_subscription(String, local(SIM_STATUS_TOPIC), self._on_status, qos_profile(CONTROL_QOS))
        # The simulator's topics (which a simulator waits for) once the other nodes' writers of the
        # recorded topics have matched (at most --inputs-wait): matched late under load, a bag
        # lacked the controller's first commands. (``JoinAfterInputs``)
        from_others = {t: m for t, m in known.items() if t not in SIM_STATE_TOPICS}
        inputs = {topic: self._subscribe(topic, msgtype, best_effort=False) for topic, msgtype in from_others.items()}
        self.inputs_join = JoinAfterInputs(
            self, inputs, lambda: [self._subscribe(t, m, best_effort=False) for t, m in known.items()
                                   if t not in from_others], opts.inputs_wait,
            self._joined_without)
        wall_timer(self, opts.flush_period, self.recorder.poll)
        if self._pending:
            self.get_logger().info(f"waiting for publishers of {self._pending} to learn their types")
            self._discovery = wall_timer(self, _DISCOVERY_PERIOD_S, self._discover)
            self._pending_since = time.monotonic()
            self._pending_said = False
        mode = "one bag" if opts.no_split else "one bag per /sim/status episode"
        count = len(known) + len(self._pending)
        self.get_logger().info(f"recording {count} topic{'' if count == 1 else 's'} to {opts.out} ({mode})")

    def _joined_without(self, missing: list[str]) -> None:
        self.recorder.joined_without.update(missing)  # the bags then say where those topics start
        self.get_logger().warning(f"recording the simulator's topics without a publisher of {missing} yet")

    def _on_status(self, msg: String) -> None:
        self.recorder.on_status(msg.data)

    def _subscribe(self, topic: str, msgtype: str, *, best_effort: bool):
        qos = qos_profile(RECORDER_QOS)
        if best_effort:  # a RELIABLE reader would never match a BEST_EFFORT writer
            qos.reliability = ReliabilityPolicy.BEST_EFFORT
        return self.create_subscription(message_class(msgtype), local(topic), self._callback(topic), qos, raw=True)

    def _callback(self, topic: str):
        """Raw message plus its message info: the writer's publication sequence number is what
        tells two publishers of one topic apart (rclpy's info carries no publisher gid)."""
        def callback(raw: bytes, info) -> None:
            self.recorder.on_message(topic, raw, time.time_ns(), info.get("publication_sequence_number"))
        return callback

    def _discover(self) -> None:
        # (a topic of the graph's own, /soil/estimator/physics, by its name in this recorder's namespace)
        graph = dict(self.get_topic_names_and_types())
        types = {t: graph.get(self.resolve_topic_name(local(t))) for t in self._pending} | graph
        if not self._pending_said and time.monotonic() - self._pending_since >= _PENDING_SAY_AFTER_S:
            self._pending_said = True
            waiting = [t for t in self._pending if not types.get(t)]
            if waiting:  # a misspelt --topics name waits for ever: say so while the user is watching
                self.get_logger().warning(f"no publisher of {_with_guesses(waiting, types)} after "
                                          f"{_PENDING_SAY_AFTER_S:g} s: not recorded until one appears")
        for topic in [t for t in self._pending if types.get(t)]:
            self._pending.remove(topic)
            msgtype = types[topic][0]
            if msgtype not in M.TYPESTORE.types:
                self.get_logger().warning(f"{topic}: type {msgtype} unknown to the Jazzy typestore; not recorded")
                continue
            infos = self.get_publishers_info_by_topic(local(topic))
            best_effort = any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos)
            self.recorder.add_topic(topic, msgtype)
            self._subscribe(topic, msgtype, best_effort=best_effort)
            self.get_logger().info(f"recording {topic} ({msgtype})")
        if not self._pending:
            self._discovery.cancel()

    def draining(self) -> bool:
        """Asked to stop (``spin_node``): an episode that has ended but whose data is still
        arriving is let in first (``Recorder.draining``; bounded by the end grace)."""
        return self.recorder.draining()

    @property
    def exit_code(self) -> int:
        """``EXIT_BAG_NOT_WRITTEN`` once an episode went without its bag (``Recorder.unwritten``, each
        said when it happened), else 0: a script or ``soil_launch`` must not take such a run for a good one."""
        return EXIT_BAG_NOT_WRITTEN if self.recorder.unwritten else 0

    def close(self) -> None:
        try:
            self.recorder.close()
        finally:  # said even when finishing the open sessions failed
            if self.recorder.unwritten:
                self.get_logger().error(f"{len(self.recorder.unwritten)} episode(s) without a bag a reader takes: "
                                        f"{', '.join(self.recorder.unwritten)} (why: above); exit code "
                                        f"{EXIT_BAG_NOT_WRITTEN}")
        if self._pending:
            try:
                graph = dict(self.get_topic_names_and_types())
            except Exception:  # noqa: BLE001 - a context already shut down: the names alone are said
                graph = {}
            self.get_logger().warning(f"never recorded (no publisher seen): {_with_guesses(self._pending, graph)}")


def _with_guesses(topics: list[str], graph_types: dict) -> str:
    """The topics, each with the name it may have been meant as (the contract's and the graph's)."""
    return with_guesses(topics, set(GRAPH_TOPICS_BY_NAME) | set(graph_types))


def main(args: list[str] | None = None) -> int:
    argv = list(sys.argv if args is None else args)
    own = own_arguments_or_refusal(argv)
    if own is None:
        return EXIT_BAD_CONFIG
    opts = parse_args(own)
    return spin_node(lambda: RecordNode(opts), argv)


if __name__ == "__main__":
    sys.exit(main())
