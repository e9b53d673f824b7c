"""Replay a rosbag2 bag (MCAP or sqlite3; split, compressed, with or without metadata.yaml).

Live (default): publish the bag's messages into the ROS graph in log-time order with the recorded
timing divided by --rate (0: as fast as --max-rate allows), each topic with its recorded QoS,
optionally remapped (--remap /gps/fix:=/car/gps/fix). Only the inputs are played unless --topics or --all-topics
say otherwise, so a bag's recorded node outputs never reach a running node's subscribers twice.
`--offline`: straight through the engine, no ROS, one JSON line per estimate.

Exit codes: 0 done; 1 the bag is damaged (offline: estimates made before the damage are written);
2 bad options, an unreadable bag, or one without the fix and bearing topics (it says which topics it has);
3 (offline) the bag was read but gave no estimate (the reason is printed).
"""
from __future__ import annotations

import argparse
import contextlib
import json
import signal
import sys
import threading
from pathlib import Path

from aoa_localizer.common.bag_run import run_bag, summary
from aoa_localizer.common.cli import (
    HelpFormatter,
    add_engine_args,
    add_topic_args,
    bag_stations,
    bag_topics,
    config_from_args,
    finite_number,
    interrupted,
    seeded,
    setup_logging,
)
from aoa_localizer.common.output import StagedFile, check_output
from aoa_localizer.core.spec import ConfigError
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.scheduling.memory import settle_process
from aoa_localizer.reporting.words import robustness_lines
from msgs_adapters.bag import BagError


def _staged(args) -> StagedFile | None:
    """The offline output, staged beside --output (None: stdout); a ValueError for one that cannot be written or
    is the bag."""
    if args.output == "-":
        return None
    check_output(Path(args.output), (Path(args.bag),))
    return StagedFile(Path(args.output))


def run_offline(args) -> int:
    try:
        cfg = seeded(config_from_args(args, LocalizerConfig()))
        stations = bag_stations(args)
        staged = _staged(args)  # placed at --output once the bag proved readable: a typo destroys nothing
    except (ConfigError, ValueError) as exc:
        print(f"replay: {exc}", file=sys.stderr)
        return 2
    loc = Localizer(cfg)
    written = 0
    out = staged.file if staged is not None else sys.stdout
    header = [json.dumps({"configuration": cfg.to_dict(), "bag": str(args.bag)}) + "\n"]

    def write_header():
        """The header line, once the bag proved readable: the configuration the estimates were made with (the
        report redraws the gate and the bound with it), and the bag."""
        if header:
            out.write(header.pop())
            if staged is not None:
                staged.place()

    def write(est):
        nonlocal written
        write_header()
        line = json.dumps(est.to_json_dict()) + "\n"
        with _ctrl_c_held():  # a line written is a line counted: the count said at Ctrl-C is what the file holds
            out.write(line)
            out.flush()
            written += 1

    try:
        run = run_bag(args.bag, bag_topics(args), loc, write, stations=stations)
        write_header()
    except BagError as exc:
        print(f"replay: {exc}", file=sys.stderr)
        _settle(staged, keep=False)
        return 2
    except KeyboardInterrupt:
        _settle(staged, keep=True)
        return interrupted("replay", f"the {written} estimates written to {args.output} are kept")
    except BaseException:
        _settle(staged, keep=False)  # what was placed stays: the lines written before the failure
        raise
    _settle(staged, keep=True)
    return _told(loc, run, written, args.output)


@contextlib.contextmanager
def _ctrl_c_held():
    """A Ctrl-C (SIGINT) during the block raised as KeyboardInterrupt right after it (in the main thread, where
    Python runs signal handlers; elsewhere the block runs as it is)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list = []
    previous = signal.signal(signal.SIGINT, lambda *_: caught.append(True))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if caught:
            raise KeyboardInterrupt


def _settle(staged: StagedFile | None, keep: bool) -> None:
    """The output kept (placed and closed) or dropped (removed unless placed); nothing for stdout."""
    if staged is not None:
        staged.keep() if keep else staged.drop()


def _told(loc: Localizer, run, written: int, output: str) -> int:
    """The run's summary on stderr, and the exit code: 1 for a damaged bag, 3 without an estimate."""
    if run.damage:
        print(f"replay: {run.damage}", file=sys.stderr)
    for line in summary(loc, run.truths, run.datum) + robustness_lines(loc):
        print(line, file=sys.stderr)
    if run.foreign:
        print("messages of a type their topic should not carry (or scans without readings), skipped: "
              + ", ".join(f"{k} {v}" for k, v in sorted(run.foreign.items())), file=sys.stderr)
    print(f"{written} estimates written to {output}", file=sys.stderr)
    if run.damage:
        return 1
    return 0 if loc.view(light=True).estimate is not None else 3


def main(argv=None) -> int:
    settle_process()  # freed memory reused, BLAS on one thread (scheduling/memory.py)
    parser = argparse.ArgumentParser(prog="python -m aoa_localizer.replay", description=__doc__,
                                     formatter_class=HelpFormatter)
    parser.add_argument("bag", help="rosbag2 bag: a directory (MCAP or sqlite3, split, compressed; metadata.yaml "
                        "optional) or one .mcap/.db3 file")
    parser.add_argument("--offline", action="store_true", help="run the engine on the bag without ROS")
    parser.add_argument("--rate", type=finite_number(0.0), default=1.0,
                        help="live: playback rate (0: as fast as --max-rate)")
    parser.add_argument("--max-rate", type=finite_number(0.0, low_open=True), default=400.0,
                        help="live, --rate 0: messages per second")
    parser.add_argument("--remap", action="append", default=[], metavar="FROM:=TO", help="live: rename a topic")
    parser.add_argument("--topics", nargs="+", help="live: play these topics (unset: the fix and bearing topics and "
                        "/sim/truth, /sim/datum; never the bag's recorded node outputs)")
    parser.add_argument("--all-topics", action="store_true", help="live: play every topic of the bag")
    parser.add_argument("--clock", action="store_true", help="live: publish /clock at the bag's log time (for "
                        "nodes with use_sim_time:=true)")
    parser.add_argument("--wait", type=finite_number(0.0), default=3.0,
                        help="live: seconds to wait for every topic to have a subscriber")
    parser.add_argument("--output", default="-", help="offline: JSON-lines file for the estimates (-: stdout)")
    add_topic_args(parser)
    add_engine_args(parser)
    args = parser.parse_args(argv)
    setup_logging(args.verbose)
    if args.offline:
        return run_offline(args)
    if not args.bag or not Path(args.bag).exists():
        print(f"replay: no bag at {args.bag}", file=sys.stderr)
        return 2
    from aoa_localizer.ros.replay_live import run_live  # rclpy only for live replay

    return run_live(args)


if __name__ == "__main__":
    sys.exit(main())
