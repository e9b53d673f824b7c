"""Replay a rosbag2 MCAP bag. `--offline`: straight through the engine, no ROS, one JSON line per estimate.

Exit codes: 0 done; 1 the bag is damaged (estimates made before the damage are written); 2 bad
options or unreadable bag; 3 the bag was read but gave no estimate (the reason is printed).
"""
from __future__ import annotations

import argparse
import json
import math
import sys

from tqdm import tqdm

from .cli import add_engine_args, config_from_args, setup_logging
from .config import ConfigError, LocalizerConfig
from .localizer import Localizer


def feed(loc: Localizer, event):
    """Give one bag event to the engine; returns an estimate or None."""
    r = event.record
    if event.kind == "fix":
        return loc.add_fix(r.stamp, r.lat, r.lon, r.alt, r.status)
    if event.kind == "bearing":
        return loc.add_bearing(r.stamp, r.azimuth_deg, r.quality)
    return None


def summary(loc: Localizer, truth, datum) -> list[str]:
    """Human-readable closing lines: estimate, ellipse, counts, and error when the bag carries the truth."""
    from .crlb import ELLIPSE_95
    import numpy as np

    lines = []
    est = loc.estimate
    if est is None:
        lines.append(f"no estimate: {loc.status}")
    else:
        vals, _ = np.linalg.eigh(est.cov)
        a, b = np.sqrt(ELLIPSE_95 * np.maximum(vals[::-1], 0))
        lines.append(f"estimate: lat {est.lat:.7f} lon {est.lon:.7f} (E {est.east:.1f} m, N {est.north:.1f} m), "
                     f"95% ellipse {a:.1f} x {b:.1f} m, {est.bearings_used} bearings in {est.points_used} points")
        if truth is not None and datum is not None:
            from .geodesy import LocalFrame

            e, n = LocalFrame(*datum).to_enu(est.lat, est.lon)
            lines.append(f"error against the bag's truth: {math.hypot(e - truth[1], n - truth[2]):.2f} m")
    rejected = ", ".join(f"{k} {v}" for k, v in sorted(loc.rejected.items())) or "none"
    lines.append(f"inputs not used: {rejected}")
    return lines


def run_offline(args) -> int:
    from msgs_adapters.bag import BagError, read_bag

    try:
        cfg = config_from_args(args, LocalizerConfig())
    except ConfigError as exc:
        print(f"replay: {exc}", file=sys.stderr)
        return 2
    loc = Localizer(cfg)
    topics = {"fix": args.fix_topic, "bearing": args.bearing_topic}
    truth = datum = None
    code, written = 0, 0
    out = open(args.output, "w") if args.output != "-" else sys.stdout
    try:
        with tqdm(desc="replay", unit="msg", disable=None, file=sys.stderr) as bar:
            try:
                for event in read_bag(args.bag, topics):
                    bar.update()
                    if event.kind == "truth":
                        truth = event.record
                    elif event.kind == "datum":
                        datum = (event.record.lat, event.record.lon, event.record.alt)
                    est = feed(loc, event)
                    if est is not None:
                        out.write(json.dumps(est.to_json_dict()) + "\n")
                        out.flush()
                        written += 1
            except BagError as exc:
                print(f"replay: {exc}", file=sys.stderr)
                code = 1 if written or bar.n else 2
        est = loc.flush()
        if est is not None:
            out.write(json.dumps(est.to_json_dict()) + "\n")
            written += 1
    finally:
        if out is not sys.stdout:
            out.close()
    for line in summary(loc, truth, datum):
        print(line, file=sys.stderr)
    print(f"{written} estimates written to {args.output}", file=sys.stderr)
    if code == 0 and loc.estimate is None:
        return 3
    return code


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m aoa_localizer.replay", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bag", help="rosbag2 MCAP bag (directory with metadata.yaml, or a .mcap file)")
    parser.add_argument("--offline", action="store_true", help="run the engine on the bag without ROS")
    parser.add_argument("--output", default="-", help="JSON-lines file for the estimates (default: stdout)")
    parser.add_argument("--fix-topic", default="/gps/fix")
    parser.add_argument("--bearing-topic", default="/df/bearing")
    add_engine_args(parser)
    args = parser.parse_args(argv)
    setup_logging(args.verbose)
    if not args.offline:
        print("replay: live replay into a ROS graph is not built yet (issue 3); use --offline", file=sys.stderr)
        return 2
    return run_offline(args)


if __name__ == "__main__":
    sys.exit(main())
