"""Replay a rosbag2 MCAP bag.

Live (default): publish the bag's messages into the ROS graph in log-time order with the recorded
timing divided by --rate (0: as fast as --max-rate allows), each topic with its recorded QoS,
optionally remapped (--remap /gps/fix:=/car/gps/fix) or restricted (--topics).
`--offline`: straight through the engine, no ROS, one JSON line per estimate.

Exit codes: 0 done; 1 the bag is damaged (offline: estimates made before the damage are written);
2 bad options or unreadable bag; 3 (offline) the bag was read but gave no estimate (the reason is printed).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from tqdm import tqdm

from .cli import add_engine_args, config_from_args, setup_logging
from .config import ConfigError, LocalizerConfig
from .localizer import Localizer


def feed(loc: Localizer, event):
    """Give one bag event to the engine; returns an estimate or None."""
    r = event.record
    if event.kind == "fix":
        return loc.add_fix(r.stamp, r.lat, r.lon, r.alt, r.status, r.sigma_m)
    if event.kind == "bearing":
        return loc.add_bearing(r.stamp, r.azimuth_deg, r.quality)
    if event.kind == "bearing_pose":
        return loc.add_bearing_enu(r.stamp, r.yaw_rad, r.variance_rad2)
    return None


def summary(loc: Localizer, truth, datum) -> list[str]:
    """Human-readable closing lines: estimate, ellipse, counts, and error when the bag carries the truth."""

    from .crlb import ellipse_axes

    lines = []
    est = loc.estimate
    if est is None:
        lines.append(f"no estimate: {loc.status}")
    else:
        a, b, _ = ellipse_axes(est.cov)
        lines.append(f"estimate: lat {est.lat:.7f} lon {est.lon:.7f} (E {est.east:.1f} m, N {est.north:.1f} m), "
                     f"95% ellipse {a:.1f} x {b:.1f} m, {est.bearings_used} bearings in {est.points_used} points")
        if truth is not None and datum is not None:
            from .geodesy import LocalFrame

            e, n = LocalFrame(*datum).to_enu(est.lat, est.lon)
            lines.append(f"error against the bag's truth: {math.hypot(e - truth[1], n - truth[2]):.2f} m")
    rejected = ", ".join(f"{k} {v}" for k, v in sorted(loc.rejected.items())) or "none"
    lines.append(f"inputs not used: {rejected}")
    return lines + loc.robustness_lines()


class BagRun:
    """What running a bag through the engine left: the truth and datum it carried, and the damage if any."""

    def __init__(self):
        self.truth = None  # (stamp, east, north) in the scenario's map
        self.datum = None  # (lat, lon, alt) of that map
        self.damage: str | None = None
        self.messages = 0
        self.foreign: dict[str, int] = {}  # "topic (type)": messages of a type the topic should not carry


def run_bag(bag, topics: dict, loc: Localizer, on_estimate, desc: str = "replay") -> BagRun:
    """Feed a bag's fixes and bearings to `loc` in log-time order, call on_estimate(est) for each estimate
    (the final flush included). Raises BagError when nothing could be read; damage later is recorded."""
    from msgs_adapters.bag import BagError, read_bag

    result = BagRun()
    with tqdm(desc=desc, unit="msg", disable=None, file=sys.stderr) as bar:
        try:
            for event in read_bag(bag, topics):
                bar.update()
                result.messages += 1
                if event.kind == "truth":
                    result.truth = event.record
                elif event.kind == "datum":
                    result.datum = (event.record.lat, event.record.lon, event.record.alt)
                elif event.kind == "foreign":
                    key = "{} ({})".format(*event.record)
                    result.foreign[key] = result.foreign.get(key, 0) + 1
                est = feed(loc, event)
                if est is not None:
                    on_estimate(est)
        except BagError as exc:
            if not result.messages:
                raise
            result.damage = str(exc)
    for est in (loc.flush(), loc.finish()):
        if est is not None:
            on_estimate(est)
    return result


def run_offline(args) -> int:
    from msgs_adapters.bag import BagError

    try:
        cfg = config_from_args(args, LocalizerConfig())
    except ConfigError as exc:
        print(f"replay: {exc}", file=sys.stderr)
        return 2
    loc = Localizer(cfg)
    written = 0
    out = open(args.output, "w") if args.output != "-" else sys.stdout

    def write(est):
        nonlocal written
        out.write(json.dumps(est.to_json_dict()) + "\n")
        out.flush()
        written += 1

    try:
        run = run_bag(args.bag, {"fix": args.fix_topic, "bearing": args.bearing_topic}, loc, write)
    except BagError as exc:
        print(f"replay: {exc}", file=sys.stderr)
        return 2
    finally:
        if out is not sys.stdout:
            out.close()
    if run.damage:
        print(f"replay: {run.damage}", file=sys.stderr)
    for line in summary(loc, run.truth, run.datum):
        print(line, file=sys.stderr)
    if run.foreign:
        print("messages of a type their topic should not carry, skipped: "
              + ", ".join(f"{k} {v}" for k, v in sorted(run.foreign.items())), file=sys.stderr)
    print(f"{written} estimates written to {args.output}", file=sys.stderr)
    if run.damage:
        return 1
    return 0 if loc.estimate is not None else 3


def live_qos(profiles):
    """The recorded offered QoS as an rclpy profile (reliable/volatile, depth 100, when none was recorded)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    if not profiles:
        return QoSProfile(depth=100)
    q = profiles[0]
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(100, int(q.depth)),
                      reliability=ReliabilityPolicy(q.reliability.value) if q.reliability.value in (1, 2)
                      else ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy(q.durability.value) if q.durability.value in (1, 2)
                      else DurabilityPolicy.VOLATILE)


def run_live(args) -> int:
    import time

    import rclpy
    from rosbags.rosbag2 import Reader

    from msgs_adapters.types import message_class

    remap = {}
    for item in args.remap:
        src, sep, dst = item.partition(":=")
        if not sep:
            print(f"replay: --remap takes FROM:=TO, got {item!r}", file=sys.stderr)
            return 2
        remap[src] = dst
    try:
        reader = Reader(args.bag)
        reader.open()
    except Exception as exc:
        print(f"replay: cannot read {args.bag}: {exc} (a damaged bag can still be salvaged with --offline)",
              file=sys.stderr)
        return 2
    rclpy.init()
    node = rclpy.create_node("aoa_replay")
    code, sent = 0, 0
    try:
        pubs = {}
        for conn in reader.connections:
            if args.topics and conn.topic not in args.topics:
                continue
            cls = message_class(conn.msgtype)
            if cls is None:
                print(f"replay: skipping {conn.topic}: type {conn.msgtype} is not installed", file=sys.stderr)
                continue
            pubs[conn.id] = node.create_publisher(cls, remap.get(conn.topic, conn.topic),
                                                  live_qos(conn.ext.offered_qos_profiles))
        deadline = time.monotonic() + args.wait
        while time.monotonic() < deadline and not all(p.get_subscription_count() for p in pubs.values()):
            rclpy.spin_once(node, timeout_sec=0.05)
        conns = [c for c in reader.connections if c.id in pubs]
        t_wall0, t_log0 = time.monotonic(), None
        for conn, log_time, raw in reader.messages(connections=conns):
            if not rclpy.ok():
                break
            t_log0 = log_time if t_log0 is None else t_log0
            delay = (t_wall0 + (log_time - t_log0) * 1e-9 / args.rate - time.monotonic()) if args.rate > 0 \
                else 1.0 / args.max_rate
            if delay > 0:
                time.sleep(delay)
            pubs[conn.id].publish(bytes(raw))
            sent += 1
        time.sleep(0.5)  # let the last messages leave
        print(f"replayed {sent} messages from {args.bag}", file=sys.stderr)
    except KeyboardInterrupt:
        code = 0
    except Exception as exc:  # a damaged chunk part-way
        print(f"replay: {args.bag}: damaged after {sent} messages: {exc}", file=sys.stderr)
        code = 1
    finally:
        reader.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return code


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m aoa_localizer.replay", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bag", help="rosbag2 MCAP bag (directory with metadata.yaml, or a .mcap file)")
    parser.add_argument("--offline", action="store_true", help="run the engine on the bag without ROS")
    parser.add_argument("--rate", type=float, default=1.0, help="live: playback rate (0: as fast as --max-rate)")
    parser.add_argument("--max-rate", type=float, default=400.0, help="live, --rate 0: messages per second")
    parser.add_argument("--remap", action="append", default=[], metavar="FROM:=TO", help="live: rename a topic")
    parser.add_argument("--topics", nargs="+", help="live: play only these topics")
    parser.add_argument("--wait", type=float, default=3.0, help="live: seconds to wait for every topic to have a subscriber")
    parser.add_argument("--output", default="-", help="JSON-lines file for the estimates (default: stdout)")
    parser.add_argument("--fix-topic", default="/gps/fix")
    parser.add_argument("--bearing-topic", default="/df/bearing")
    add_engine_args(parser)
    args = parser.parse_args(argv)
    setup_logging(args.verbose)
    if args.offline:
        return run_offline(args)
    if not args.bag or not Path(args.bag).exists():
        print(f"replay: no bag at {args.bag}", file=sys.stderr)
        return 2
    return run_live(args)


if __name__ == "__main__":
    sys.exit(main())
