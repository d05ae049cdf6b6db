"""``soil_bag_play``: replay bags onto the live graph with their original timing.

Thin rclpy adapter around ``playback.py``: one publisher per topic with the graph's
publisher QoS (``ros_adapter.publisher_qos``), the raw CDR bytes of each message published as they are (no
deserialisation), timed by ``playback.Pacer`` on absolute deadlines. Episode bags are
framed by ``/sim/status`` ``episode_start``/``episode_end`` events (as the simulator does),
so ``soil_bag_record`` splits a replay into the same bags and estimators reset in step.

    soil_bag_play BAG [BAG ...] [--rate R] [--loop] [--topics T ...] [--exclude T ...]
                  [--clock HZ] [--wait-for-subscribers N] [--wait-timeout S] [--no-status]
                  [--ros-args ...]

Exit codes: 0 at the end, 130 / 143 on Ctrl-C / SIGTERM, 6 where another node publishes a played
topic (unless --allow-other-publishers), 2 for a bad BAG argument, a truncated or corrupt bag
(every bag's metadata.yaml, CRCs and namespace are checked before the first is played: each bad
one named, nothing played), or a --topics/--exclude selection that leaves no message in any bag
(a topic missing from only some bags is a warning).
"""
from __future__ import annotations

import argparse
import dataclasses
import signal
import sys
import time

import numpy as np
import rclpy
from rclpy.node import Node

from soil_msgs_py.graph import (EVENT_EPISODE_END, EXIT_ANOTHER_GRAPH, EXIT_BAD_CONFIG, NODE_NAMES, SIM_EPISODE_TOPIC,
                                SIM_STATUS_TOPIC, STRING_MSGTYPE, UNKNOWN_NODE_NAME, EpisodeEvent)
from soil_msgs_py.cli_paths import input_text
from soil_msgs_py.values import finite_number
from .playback import (
    CLOCK_MSGTYPE, CLOCK_TOPIC, RATE_LIMITS, BagPathError, LoadedBag, Pacer, check_rate, episode_events,
    expand_bag_args, load_bag, string_cdr, unreadable_bags, with_clock,
)
from soil_msgs_py.ros_adapter import (endpoint_node, init_rclpy, local, message_class, own_arguments_or_refusal,
                                      params_file_refusal, print_refusal, publisher_qos, stopping_said, wait_for_acks)

EPISODE_CONTROL_TOPICS = (SIM_STATUS_TOPIC, SIM_EPISODE_TOPIC)  # the episode's events, said as a simulator says them
STATUS_LEAD_S = 0.1  # episode_start goes out this long before the bag's first message
SETTLE_S = 0.2  # after --wait-for-subscribers succeeded: let the last matches settle
DRAIN_S = 1.0  # at most this long waiting for reliable subscribers to acknowledge


# The fastest /clock: far beyond the 60 Hz every node of the graph ticks at, and one /clock message
# a millisecond of bag time is what a replay keeps in memory besides the bag.
MAX_CLOCK_HZ = 1000.0
# How often (wall time) a replay looks for another publisher of the topics it plays [s]: a live
# simulator on the domain (a replay into a running graph recorded bags holding both robots' state).
OTHERS_CHECK_PERIOD_S = 0.5
# Before the first message: how long to look for them while DDS discovers the domain [s] (found at
# once they stop the replay before anything went out; a reviewer's runs without it had sent 540 and
# 1141 messages first, a live recorder taking the replay's episode_start). 1 s was too short at a load
# of 3-4 on 2 cores: 3 of 7 replays beside a live simulator sent 541-1149 messages first (an outside
# tester's); DDS has no "discovery done", so a slower machine may still find them later, while playing.
OTHERS_DISCOVERY_S = 2.0
UNNAMED = "a node not discovered by name yet"


class AnotherGraph(Exception):
    """Another node publishes a topic the replay plays (``Player.others``)."""


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="soil_bag_play", description="Replay rosbag2 bags with their original timing.")
    p.add_argument("bags", nargs="+", metavar="BAG", type=input_text,
                   help="bag directory, or a directory of bags (played in path order)")
    p.add_argument("--rate", type=float, default=1.0,
                   help="playback speed factor, in [%g, %g] (default 1.0)" % RATE_LIMITS)
    p.add_argument("--loop", action="store_true", help="start over after the last bag, until Ctrl-C")
    p.add_argument("--topics", nargs="+", metavar="T", help="play only these topics (give the bags first: the option "
                                                            "takes every name after it)")
    p.add_argument("--exclude", nargs="+", default=[], metavar="T", help="do not play these topics (bags first, as for "
                                                                         "--topics)")
    p.add_argument("--clock", type=float, metavar="HZ",
                   help="publish /clock at HZ (at most 1000) from bag time, the first stamp + floor(k·1e9/HZ) ns (at "
                        "60 Hz the ticks' own stamps), and not the bag's own /clock; a recorder of the replay needs one /clock "
                        "per tick: at another HZ its bags lack it")
    p.add_argument("--wait-for-subscribers", type=int, default=0, metavar="N",
                   help="before playing, wait until every publisher has N matched subscriptions (default 0)")
    p.add_argument("--wait-timeout", type=float, default=10.0, metavar="S",
                   help="give up waiting for subscribers after S s and play anyway (default 10)")
    p.add_argument("--no-status", action="store_true", help="do not publish /sim/status episode events (nor /sim/episode; a bag's own recorded ones still play)")
    p.add_argument("--allow-other-publishers", action="store_true",
                   help="play even where another node publishes a played topic (default: refused, exit 6: a live "
                        "simulator on the domain mixes two robots' data in every reader and bag; --exclude the topics "
                        "a live node publishes, e.g. /soil/estimate beside a live estimator)")
    opts = p.parse_args(argv)
    try:
        check_rate(opts.rate)
    except ValueError as err:
        p.error(f"--{err}")
    if opts.clock is not None and not (finite_number(opts.clock) and 0 < opts.clock <= MAX_CLOCK_HZ):
        # inf: endless /clock at t0; 1e12 Hz: 10^13 /clock messages for a 10 s bag, made before the first
        p.error(f"--clock {opts.clock} Hz must be a finite number in (0, {MAX_CLOCK_HZ:g}]")
    if opts.wait_for_subscribers < 0:
        p.error(f"--wait-for-subscribers {opts.wait_for_subscribers} must be >= 0")
    if not (finite_number(opts.wait_timeout) and opts.wait_timeout >= 0):  # nan: a deadline never reached
        p.error(f"--wait-timeout {opts.wait_timeout} s must be a finite number >= 0")
    return opts


def installed(msgtype: str) -> bool:
    """Whether this machine has the Python message class of ``msgtype`` (a player can publish it)."""
    try:
        message_class(msgtype)
    except ValueError:
        return False
    return True


class Player:
    """Publishers plus the play loop; the node is only used to create publishers and log."""

    def __init__(self, node: Node, opts: argparse.Namespace):
        self.node, self.opts, self.log = node, opts, node.get_logger()
        self.pubs: dict[str, object] = {}
        self.types: dict[str, str] = {}
        self.status = None if opts.no_status else self._publisher(SIM_STATUS_TOPIC, STRING_MSGTYPE)
        # latched, as the simulator's; a bag that holds the topic (``ros2 bag record -a``) plays through it
        self.episode_pub = None if opts.no_status else self._publisher(SIM_EPISODE_TOPIC, STRING_MSGTYPE)
        if opts.clock:
            self._publisher(CLOCK_TOPIC, CLOCK_MSGTYPE)
        self.pacer = Pacer(opts.rate)
        self.episode = 0
        self.published = 0
        self.checked_at = -float("inf")  # time.monotonic() of the last look for other publishers

    def _say(self, event: EpisodeEvent) -> None:
        """An episode's event on /sim/status, and latched on /sim/episode, as the simulator says them."""
        raw = string_cdr(event.to_json())
        self.status.publish(raw)
        self.episode_pub.publish(raw)

    def _publisher(self, topic: str, msgtype: str):
        if topic in self.pubs:
            if self.types[topic] != msgtype:
                raise BagPathError(f"topic {topic} has type {msgtype} here but {self.types[topic]} in an earlier bag")
            return self.pubs[topic]
        self.types[topic] = msgtype
        self.pubs[topic] = self.node.create_publisher(message_class(msgtype), local(topic), publisher_qos(topic))
        return self.pubs[topic]

    def _load(self, path) -> LoadedBag:
        bag = load_bag(path, topics=self.opts.topics, exclude=self.opts.exclude,
                       drop=[CLOCK_TOPIC] if self.opts.clock else [], log=self.log.warning)
        # a topic whose message package this machine lacks (a robot's /tf: tf2_msgs) is not played,
        # and said; the rest is (it had refused the whole bag, exit 2, naming neither topic nor way out)
        if lacking := {t: m for t, m in bag.topics.items() if t not in self.pubs and not installed(m)}:
            self.log.warning(f"{bag.path}: not played, their message types not installed here: "
                             + ", ".join(f"{t} ({m})" for t, m in sorted(lacking.items()))
                             + f" (--exclude {' '.join(sorted(lacking))} says so without this warning)")
            bag = dataclasses.replace(bag, topics={t: m for t, m in bag.topics.items() if t not in lacking},
                                      messages=[m for m in bag.messages if m[1] not in lacking])
        for topic, msgtype in bag.topics.items():
            self._publisher(topic, msgtype)
        return bag

    def wait_for_subscribers(self) -> None:
        n, timeout = self.opts.wait_for_subscribers, self.opts.wait_timeout
        end = time.monotonic() + timeout
        while True:
            # (/sim/episode is latched: a reader that comes later gets it all the same)
            counts = {t: p.get_subscription_count() for t, p in self.pubs.items() if t not in EPISODE_CONTROL_TOPICS}
            # /sim/status: every status subscriber the graph knows of must be matched too.
            status_ok = self.status is None or (
                self.status.get_subscription_count() >= self.node.count_subscribers(local(SIM_STATUS_TOPIC)))
            if all(c >= n for c in counts.values()) and status_ok:
                break
            if time.monotonic() > end:
                short = {t: c for t, c in counts.items() if c < n}
                self.log.warning(f"--wait-timeout {timeout} s: topics with fewer than {n} subscribers {short}; "
                                 "playing anyway")
                break
            time.sleep(0.02)
        time.sleep(SETTLE_S)

    def others(self) -> dict[str, list[str]]:
        """{played data topic: the other nodes publishing it} (this player's own writer counts one;
        /sim/status and /sim/episode are left out: test harnesses and monitors publish them, a live
        graph's state topics give it away anyway)."""
        out = {}
        for topic in self.pubs:
            if topic not in EPISODE_CONTROL_TOPICS and self.node.count_publishers(local(topic)) > 1:
                out[topic] = sorted({UNNAMED if i.node_name == UNKNOWN_NODE_NAME else
                                     endpoint_node(i)
                                     for i in self.node.get_publishers_info_by_topic(local(topic))}
                                    - {self.node.get_fully_qualified_name()})
        return out

    def check_others(self, force: bool = False) -> None:
        """AnotherGraph naming the topics and nodes, unless --allow-other-publishers; at most every
        OTHERS_CHECK_PERIOD_S of wall time unless ``force``."""
        now = time.monotonic()
        if self.opts.allow_other_publishers or (not force and now - self.checked_at < OTHERS_CHECK_PERIOD_S):
            return
        self.checked_at = now
        if found := self.others():
            named = "; ".join(f"{t} by {', '.join(n) or 'another soil_bag_play'}" for t, n in sorted(found.items()))
            raise AnotherGraph(f"other nodes publish topics this replay plays ({named}): a live graph on this domain "
                               "would mix two robots' data in every reader and bag. Stop them, give the replay its own "
                               "ROS_DOMAIN_ID, --exclude the topics they publish, or --allow-other-publishers (a node "
                               "killed in the last 20 s still shows until its DDS lease runs out)")

    def discover_others(self) -> None:
        """``check_others`` while DDS discovers the domain (``OTHERS_DISCOVERY_S``), before anything is
        published."""
        if self.opts.allow_other_publishers:
            return
        time.sleep(OTHERS_DISCOVERY_S)  # (all of it: found early, the list named only some of them)
        named_by = time.monotonic() + OTHERS_DISCOVERY_S
        while (found := self.others()) and any(UNNAMED in n for n in found.values()) and time.monotonic() < named_by:
            time.sleep(0.05)
        self.check_others(force=True)

    def play_bag(self, bag: LoadedBag) -> None:
        messages = list(with_clock(bag.messages, self.opts.clock)) if self.opts.clock else bag.messages
        events = None if self.status is None else episode_events(bag, self.episode)
        if events:
            self._say(events[0])
        self.pacer.begin(messages[0][0], time.perf_counter() + (STATUS_LEAD_S if events else 0.0))
        late = np.empty(len(messages))
        last_stamp, ticks = -1, 0
        try:
            for i, (t, topic, raw) in enumerate(messages):
                late[i] = self.pacer.wait(t)
                self.check_others()
                self.pubs[topic].publish(raw)
                self.published += 1
                if t != last_stamp and not (self.opts.clock and topic == CLOCK_TOPIC):  # synthetic clock
                    last_stamp, ticks = t, ticks + 1
        except (KeyboardInterrupt, AnotherGraph):
            if events:  # tell recorders/estimators the episode stopped here
                ev = events[1]
                end = EpisodeEvent(event=EVENT_EPISODE_END, episode=ev.episode, name=ev.name, meta=ev.meta,
                                   first_stamp_ns=ev.first_stamp_ns, planned_ticks=ev.planned_ticks,
                                   last_stamp_ns=last_stamp, ticks=ticks, reason="shutdown", stats=ev.stats)
                self._say(end)
            raise
        if events:
            self._say(events[1])
        self.episode += 1
        ms = late * 1e3
        self.log.info(f"played {bag.path}: {len(messages)} messages, {bag.ticks} ticks, "
                      f"{(messages[-1][0] - messages[0][0]) * 1e-9:.2f} s bag time at rate {self.opts.rate}; "
                      f"lateness p50 {np.percentile(ms, 50):.3f} ms, p99 {np.percentile(ms, 99):.3f} ms, "
                      f"max {ms.max():.3f} ms")

    def run(self, paths) -> None:
        """Play ``paths`` (again and again with --loop). ValueError if a pass finds nothing to play
        in any bag: a mistyped --topics once exited 0 having played nothing, or spun with --loop."""
        cache: dict = {}
        first = True
        while True:
            played, held = False, set()
            for path in paths:
                bag = cache.get(path) or self._load(path)
                if len(paths) == 1:
                    cache[path] = bag  # --loop over one bag: read it once
                held |= bag.held
                if not bag.messages:
                    self.log.warning(f"{bag.path}: no message to play")
                    continue
                if first:
                    first = False
                    if self.opts.wait_for_subscribers > 0:
                        self.wait_for_subscribers()
                    self.discover_others()
                self.play_bag(bag)
                played = True
            if not played:
                raise ValueError(self._nothing_to_play(held, len(paths)))
            if not self.opts.loop:
                return

    def _nothing_to_play(self, held: set[str], n_bags: int) -> str:
        o = self.opts
        asked = f"--topics {' '.join(o.topics)}" if o.topics else "every topic"
        if o.exclude:
            asked += f" minus --exclude {' '.join(o.exclude)}"
        if o.clock:
            asked += f" minus {CLOCK_TOPIC} (--clock makes its own)"
        return (f"{asked}: no message to play in the {n_bags} bag(s); their topics: "
                f"{', '.join(sorted(held)) or 'none'}")

    def drain(self) -> None:
        """Wait (bounded) until reliable subscribers acknowledged everything published."""
        if not wait_for_acks(self.node, DRAIN_S):  # acknowledgements ride on DDS heartbeats; delivery is normally done
            self.log.debug(f"not everything acknowledged within {DRAIN_S} s")


def main(args: list[str] | None = None) -> int:
    argv = list(sys.argv if args is None else args)
    own = own_arguments_or_refusal(argv)
    if own is None:
        return EXIT_BAD_CONFIG
    opts = parse_args(own)
    notes: list[str] = []
    try:
        paths = expand_bag_args(opts.bags, notes)
    except BagPathError as err:
        print(f"soil_bag_play: {err}", file=sys.stderr)
        return EXIT_BAD_CONFIG
    for note in notes:  # a killed recorder's journal beside the bags: played without it, said with its repair
        print(f"soil_bag_play: {note}", file=sys.stderr)
    try:
        bad = unreadable_bags(paths, opts.topics, opts.exclude)  # every bag checked before the first is played
    except KeyboardInterrupt:  # (a large dataset's check takes seconds)
        print(f"soil_bag_play: {stopping_said(signal.SIGINT)}", file=sys.stderr)
        return 128 + int(signal.SIGINT)
    if bad:
        print(f"soil_bag_play: {len(bad)} of the {len(paths)} bag(s) cannot be read; nothing played (repair the ones "
              "whose line names soil_bag_repair, or leave them out):", file=sys.stderr)
        for problem in bad:
            print(f"soil_bag_play:   {problem}", file=sys.stderr)
        return EXIT_BAD_CONFIG
    # Our own handlers (not rclpy's): the context stays valid after Ctrl-C, so the player can
    # still publish the episode_end of an interrupted bag.
    signals: list[int] = []

    def interrupt(signum, frame):  # noqa: ARG001 - SIGINT/SIGTERM stop the blocking play loop
        signals.append(signum)
        raise KeyboardInterrupt

    refusal = params_file_refusal(argv)
    if refusal:
        print(f"soil_bag_play: cannot start: {refusal}", file=sys.stderr)
        return EXIT_BAD_CONFIG
    try:
        init_rclpy(argv, interrupt)
    except RuntimeError as err:  # rcl cannot read a --params-file
        print_refusal(argv, err)
        return EXIT_BAD_CONFIG
    node = Node(NODE_NAMES["player"])
    code = 0
    player = None
    try:
        player = Player(node, opts)
        player.run(paths)
        player.drain()
    except KeyboardInterrupt:
        # said, and 128 + the signal as a shell gives it: an interrupted replay exited 0 with no word, as a
        # finished one does (an outside tester's)
        signum = signals[0] if signals else signal.SIGINT
        node.get_logger().info(stopping_said(signum))
        code = 128 + int(signum)
        if player is not None:
            try:
                player.drain()
            except KeyboardInterrupt:
                pass
    except ValueError as err:  # BagReadError (damaged bag), BagPathError, unknown message type, nothing to play
        node.get_logger().error(str(err))
        code = 2
    except AnotherGraph as err:
        node.get_logger().error(f"{err}; stopped")
        code = EXIT_ANOTHER_GRAPH
        if player is not None:
            player.drain()  # (the episode_end it published on the way out reaches its readers)
    finally:
        node.get_logger().info(f"published {player.published if player else 0} messages")
        node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
