"""Live replay: a bag's messages published into the ROS graph in log-time order with their recorded timing and QoS."""
from __future__ import annotations

import signal
import sys
import time

import rclpy
from builtin_interfaces.msg import Time
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from aoa_localizer.ros.ros_main import bounded_teardown
from msgs_adapters.bag import TOPICS, BagError, RawReader, found_stations
from msgs_adapters.bag_files import BagFiles, BagFilesError, describe_topics
from msgs_adapters.types import message_class

HISTORY_DEPTH = 2000  # messages a replayed topic keeps for a reliable reader's resend
SETTLE_S = 0.5  # after every publisher has a subscriber: the subscriber's side of the match lags its publisher's


def live_qos(profiles):
    """The recorded offered QoS as an rclpy profile (reliable/volatile when none was recorded), with a history of
    at least HISTORY_DEPTH: a reliable reader that fell behind a fast replay gets what it missed again."""
    if not profiles:
        return QoSProfile(depth=HISTORY_DEPTH)
    q = profiles[0]
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(HISTORY_DEPTH, int(q.depth)),
                      reliability=ReliabilityPolicy(q.reliability.value) if q.reliability.value in (1, 2)
                      else ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy(q.durability.value) if q.durability.value in (1, 2)
                      else DurabilityPolicy.VOLATILE)


def _remaps(items) -> dict[str, str] | str:
    """--remap FROM:=TO items as a dict, or the message for a malformed one."""
    remap = {}
    for item in items:
        src, sep, dst = item.partition(":=")
        if not sep:
            return f"--remap takes FROM:=TO, got {item!r}"
        remap[src] = dst
    return remap


def played_topics(args, inventory) -> list:
    """The topics live replay publishes: --topics, every topic with --all-topics, else the inputs (fix, bearing,
    IMU heading, scans, and the simulated truth and datum), so that a bag's recorded node outputs never reach a running
    node's graph."""
    if args.topics:
        chosen = set(args.topics)
    elif args.all_topics:
        chosen = {t.name for t in inventory}
    else:
        chosen = {args.fix_topic, args.bearing_topic, args.heading_topic, TOPICS["scan"], TOPICS["truth"],
                  TOPICS["datum"]}
        chosen |= {topic for _, topics in args.station or [] for topic in topics.values()}
        if not args.station:  # a bag of several stations: their inputs, as its topic names show them
            wanted = {"fix": args.fix_topic, "bearing": args.bearing_topic, "scan": TOPICS["scan"]}
            found = found_stations(args.bag, inventory, wanted) or {}
            chosen |= {topic for topics in found.values() for topic in topics.values()}
    return [t for t in inventory if t.name in chosen]


class LivePlayer:
    """Publishers for the chosen topics (recorded QoS, remapped names) and, with `clock`, /clock at the bag's log
    time, so nodes with use_sim_time follow the bag."""

    def __init__(self, node, topics, remap: dict[str, str], clock: bool):
        self.node = node
        self.pubs = {}
        for topic in topics:
            cls = message_class(topic.msgtype)
            if cls is None:
                print(f"replay: skipping {topic.name}: type {topic.msgtype} is not installed", file=sys.stderr)
                continue
            self.pubs[topic.name] = node.create_publisher(cls, remap.get(topic.name, topic.name), live_qos(topic.qos))
        self.clock = node.create_publisher(Clock, "/clock", 10) if clock else None
        self.sent = 0
        self.stopped_by: str | None = None  # the signal that asked to stop (the context stays valid meanwhile)

    def stop(self, signum, _frame):
        self.stopped_by = signal.Signals(signum).name

    def _wait(self, seconds: float):
        """Sleep in short steps so a stop request is seen at once."""
        end = time.monotonic() + seconds
        while self.stopped_by is None and (left := end - time.monotonic()) > 0:
            time.sleep(min(left, 0.05))

    def wait_for_subscribers(self, seconds: float) -> list[str]:
        """Spin until every played topic has a subscriber (then SETTLE_S more: a best-effort subscriber drops what
        arrives before its own side of the match), or `seconds` passed; the topics still without one."""
        deadline = time.monotonic() + seconds
        while (time.monotonic() < deadline and self.stopped_by is None
               and not all(p.get_subscription_count() for p in self.pubs.values())):
            rclpy.spin_once(self.node, timeout_sec=0.05)
        alone = sorted(name for name, p in self.pubs.items() if not p.get_subscription_count())
        settle = time.monotonic() + (0.0 if alone else SETTLE_S)
        while self.stopped_by is None and time.monotonic() < settle:
            rclpy.spin_once(self.node, timeout_sec=0.05)
        return alone

    def play(self, messages, rate: float, max_rate: float):
        """Publish in log-time order with the recorded timing divided by `rate` (0: `max_rate` messages/s)."""
        t_wall0, t_log0 = time.monotonic(), None
        for msg in messages:
            t_log0 = msg.log_time if t_log0 is None else t_log0
            delay = (t_wall0 + (msg.log_time - t_log0) * 1e-9 / rate - time.monotonic()) if rate > 0 \
                else 1.0 / max_rate
            if delay > 0:
                self._wait(delay)
            if self.stopped_by is not None:
                return
            if self.clock is not None:
                self.clock.publish(Clock(clock=Time(sec=msg.log_time // 1_000_000_000,
                                                    nanosec=msg.log_time % 1_000_000_000)))
            self.pubs[msg.topic].publish(msg.data)
            self.sent += 1
        self._wait(0.5)  # let the last messages leave


def open_bag(args) -> tuple[BagFiles, RawReader, list] | str:
    """The bag's files, reader and the topics to play, or why there is nothing to play."""
    try:
        files = BagFiles(args.bag)
    except BagFilesError as exc:
        return str(exc)
    reader = RawReader(files)
    inventory = reader.topics()
    topics = played_topics(args, inventory)
    if not topics:
        files.close()
        return f"nothing to play; {args.bag} has {describe_topics(inventory)}"
    return files, reader, topics


def run_live(args) -> int:
    remap = _remaps(args.remap)
    if isinstance(remap, str):
        print(f"replay: {remap}", file=sys.stderr)
        return 2
    opened = open_bag(args)
    if isinstance(opened, str):
        print(f"replay: {opened}", file=sys.stderr)
        return 2
    files, reader, topics = opened
    # Our own SIGINT/SIGTERM handling: rclpy's would invalidate the context under a publish (an RCLError traceback)
    # args=[]: replay's own options are not ROS arguments (rcl would read --remap's FROM:=TO as an old-style remap)
    rclpy.init(args=[], signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node("aoa_replay")
    player = LivePlayer(node, topics, remap, args.clock)
    old = {s: signal.signal(s, player.stop) for s in (signal.SIGINT, signal.SIGTERM)}
    code = 1  # until the bag was played whole
    try:
        alone = player.wait_for_subscribers(args.wait)
        if alone and player.stopped_by is None:
            print(f"replay: no subscriber on {', '.join(alone)} after {args.wait:g} s (--wait); playing anyway",
                  file=sys.stderr, flush=True)
        player.play(reader.messages(set(player.pubs)), args.rate, args.max_rate)
        stopped = f" (stopped by {player.stopped_by})" if player.stopped_by else ""
        names = [f"{t} as {remap[t]}" if t in remap else t for t in sorted(player.pubs)]
        print(f"replayed {player.sent} messages of {', '.join(names)} from {args.bag}{stopped}", file=sys.stderr)
        if reader.damage:
            print(f"replay: {args.bag}: damaged ({'; '.join(reader.damage)}); every intact message was played",
                  file=sys.stderr)
        else:
            code = 0
    except BagError as exc:
        print(f"replay: {exc}", file=sys.stderr)
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
        files.close()

        def teardown():
            try:
                node.destroy_node()
            finally:
                rclpy.try_shutdown()

        bounded_teardown("replay", teardown, code)
    return code
