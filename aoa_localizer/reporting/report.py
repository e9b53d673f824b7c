"""A localisation report a monitoring engineer can use: map, error plot, KML, GeoJSON and a summary.

    python -m aoa_localizer.report bags/urban --out report/ --params-file bags/urban.params.yaml
    python -m aoa_localizer.report estimates.jsonl --bag bags/seed --out report/

INPUT is a rosbag2 bag (MCAP or sqlite3) (run through the engine offline, with the options of offline replay) or
a JSON-lines file of estimates (offline replay's output) with --bag, the bag it came from (for the
track and the bearings; the estimates are the file's). Writes map.png, emitter.kml, emitter.geojson,
summary.md, and error.png when the bag carries the truth (sim/truth). Exit codes: 0 written; 1 the bag
is damaged (the report covers what came before the damage); 2 unreadable input or no estimate.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from aoa_localizer.common.bag_run import run_bag, truth_of
from aoa_localizer.common.cli import (
    HelpFormatter,
    add_engine_args,
    add_topic_args,
    bag_stations,
    bag_topics,
    config_from_args,
    interrupted,
    seeded,
    setup_logging,
)
from aoa_localizer.common.cot import write_cot_files
from aoa_localizer.common.output import check_folder, file_names
from aoa_localizer.core.spec import ConfigError
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.crlb import crlb_rmse, crlb_so_far, ellipse_axes, inside_ellipse
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.inference.noise import sentence as noise_sentence
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.rejections import REASONS
from aoa_localizer.engine.scheduling.memory import settle_process
from aoa_localizer.engine.types import Estimate
from aoa_localizer.reporting import export, plots
from msgs_adapters.bag import BagError


class Trace:
    """What a report draws, kept as the engine runs (a Localizer Observer): every accepted fix (stamp, east, north)
    and every reading paired with a position (stamp, east, north, theta, sigma, kept), `kept` False for readings
    gated out as wild."""

    def __init__(self):
        self.fixes: list[tuple] = []
        self.fix_stations: list[str] = []  # the station of each fix
        self.readings: list[tuple] = []

    def on_fix(self, stamp: float, east: float, north: float, station: str = "") -> None:
        self.fixes.append((stamp, east, north))
        self.fix_stations.append(station)

    def tracks(self) -> dict[str, np.ndarray]:
        """Each station's fixes as rows stamp, east, north."""
        rows = np.array(self.fixes, float).reshape(-1, 3)
        of = np.array(self.fix_stations, dtype=object)
        return {name: rows[of == name] for name in dict.fromkeys(self.fix_stations)}

    def on_point(self, readings, kept) -> None:
        self.readings += [
            (r.stamp, r.east, r.north, r.theta, r.sigma, bool(k)) for r, k in zip(readings, kept, strict=False)
        ]


def configuration_of(path: Path) -> dict | None:
    """The configuration on an offline-replay file's header line (None: a file without one)."""
    try:
        with open(path) as fh:
            first = json.loads(fh.readline() or "{}")
    except (OSError, ValueError) as exc:
        raise ReportError(f"{path}: not a JSON-lines file of estimates ({exc})") from exc
    return first.get("configuration") if isinstance(first, dict) else None


def estimates_from_jsonl(path: Path, frame_of) -> list[Estimate]:
    """Estimates of an offline-replay JSON-lines file, placed in our frame through their lat/lon."""
    out = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            d = json.loads(line)
            if "configuration" in d:
                continue  # the header line
            east, north = frame_of.to_enu(d["lat"], d["lon"])
            out.append(
                Estimate(
                    stamp=float(d["stamp"]),
                    east=float(east),
                    north=float(north),
                    lat=float(d["lat"]),
                    lon=float(d["lon"]),
                    cov=np.array(d["cov"], float),
                    bearings_used=int(d["bearings_used"]),
                    points_used=int(d.get("points_used", 0)),
                    ess=float(d.get("ess", float("nan"))),
                    algorithm=str(d.get("algorithm", "?")),
                    channel=str(d.get("channel", "default")),
                    frequency_hz=float(d.get("frequency_hz") or float("nan")),
                    motion=str(d.get("motion", "static")),
                )
            )
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{path}:{n}: not an estimate line ({exc})") from exc
    return out


def error_series(estimates, readings: np.ndarray, truth) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per estimate: time, error, the CRLB of the readings used up to it (their modelled sigma), 95 % semi-major."""
    t = np.array([e.stamp for e in estimates])
    err = np.array([math.hypot(e.east - truth[0], e.north - truth[1]) for e in estimates])
    major = np.array([ellipse_axes(e.cov)[0] for e in estimates])
    r = readings[np.argsort(readings[:, 0])]
    bound = crlb_so_far(truth, r[:, 1:3], r[:, 4], r[:, 0], t) if len(r) else np.full(len(t), np.inf)
    return t, err, bound, major


def _error_words(est: Estimate, truth) -> str:
    """An estimate's error against its truth (map m) and whether its 95 % ellipse holds it; "-" without one."""
    if truth is None:
        return "-"
    err = np.array([est.east - truth[0], est.north - truth[1]])
    return f"{math.hypot(*err):.2f} m, {'inside' if inside_ellipse(err, est.cov) else 'outside'} its ellipse"


def write_summary(path: Path, inp, loc: Localizer, trace: Trace, est: Estimate, truth, bound, damage, others=(),
                  truths=None, cot_files=()):
    a, b, azimuth = ellipse_axes(est.cov)
    used = int(sum(1 for r in trace.readings if r[5]))
    view = loc.view()
    frame = view.frame
    assert frame is not None  # write_files comes after report() found a fix
    lines = [
        f"# Emitter localisation: {Path(inp).name}",
        "",
        f"* **Estimate**{'' if est.channel == 'default' else f' (channel {est.channel}, {_mhz(est.frequency_hz)})'}"
        f": {est.lat:.7f}, {est.lon:.7f} (east {est.east:.1f} m, north {est.north:.1f} m "
        f"of the datum {frame.lat0:.7f}, {frame.lon0:.7f})",
        f"* **95 % error ellipse**: semi-axes {a:.1f} m x {b:.1f} m, major axis at {azimuth:.0f} deg from north",
        f"* **Algorithm**: {est.algorithm}, N = {loc.config.num_particles}, seed {loc.config.seed}",
        f"* **Bearings used**: {est.bearings_used} in {est.points_used} observation points "
        f"(of {len(trace.readings)} paired with a GPS position; {used} kept inside their points)",
    ]
    if truth is not None:
        err = np.array([est.east - truth[0], est.north - truth[1]])
        lines.append(
            f"* **Final error against the truth**: {math.hypot(*err):.2f} m; Cramer-Rao bound of the bearings "
            f"used {bound:.2f} m; the truth is {'inside' if inside_ellipse(err, est.cov) else 'outside'} "
            "the 95 % ellipse"
        )
    lines.append(f"* **State**: {est.state}" + "".join(f"; {w}" for w in est.warnings))
    if damage:
        lines.append(f"* **Input damaged**: {damage}; this report covers the data before the damage")
    if loc.config.calibrate_noise:
        lines.append(f"* **Receiver noise (self-calibrated)**: {noise_sentence(dict(view.noise))}")
    pooled = view.receiver_noise
    if pooled is not None:
        lines.append(f"* **The receiver over its channels**: {pooled.sentence()}")
    if len(est.modes) > 1:
        lines.append(
            "* **Alternative hypotheses** (posterior modes and their probability): "
            + "; ".join(
                f"{lat:.7f}, {lon:.7f} ({100 * m:.0f} %)"
                for (lat, lon), (_, _, m) in zip(
                    (frame.to_geodetic(e, n)[:2] for e, n, _ in est.modes), est.modes, strict=False
                )
            )
        )
    if others:
        lines += ["", "## Other emitters (channels)", "", "| channel | frequency | estimate | 95 % ellipse | points | "
                  "error against its truth |", "|---|---|---|---|---|---|"]
        lines += [f"| `{e.channel}` | {_mhz(e.frequency_hz)} | {e.lat:.7f}, {e.lon:.7f} | "
                  f"{ellipse_axes(e.cov)[0]:.1f} x {ellipse_axes(e.cov)[1]:.1f} m | {e.points_used} | "
                  f"{_error_words(e, (truths or {}).get(e.channel))} |" for e in others]
        lines.append("")
    events = {k: v for k, v in view.events.items() if k != "alarm_points"}
    if events:
        lines.append("* **Robustness events**: " + ", ".join(f"{k} {v}" for k, v in sorted(events.items())))
    lines += ["", "## Inputs not used", ""]
    if view.rejected:
        lines += ["| reason | count | meaning |", "|---|---|---|"]
        lines += [f"| `{k}` | {v} | {REASONS[k]} |" for k, v in sorted(view.rejected.items())]
    else:
        lines.append("none")
    lines += [
        "",
        "Files: `map.png`, `emitter.kml`, `emitter.geojson`" + (", `error.png`" if truth is not None else "")
        + "".join(f", `{name}`" for name in cot_files) + ", `summary.md`",
    ]
    path.write_text("\n".join(lines) + "\n")


def _mhz(frequency_hz: float) -> str:
    return f"{frequency_hz / 1e6:.3f} MHz" if math.isfinite(frequency_hz) else "none"


class ReportError(Exception):
    """Why the report cannot be written (exit 2)."""


def parse_args(argv) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m aoa_localizer.report", description=__doc__,
                                     formatter_class=HelpFormatter)
    parser.add_argument("input", type=Path, help="rosbag2 bag, or a JSON-lines file of estimates with --bag")
    parser.add_argument("--bag", type=Path, help="with a JSON-lines INPUT: the bag the estimates came from")
    parser.add_argument("--out", type=Path, required=True, help="directory for the report's files")
    add_topic_args(parser)
    add_engine_args(parser)
    return parser.parse_args(argv)


def main(argv=None) -> int:
    settle_process()  # freed memory reused, BLAS on one thread (scheduling/memory.py)
    args = parse_args(argv)
    setup_logging(args.verbose)
    try:
        return make_report(args)
    except ReportError as exc:
        print(f"report: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return interrupted("report", f"the report in {args.out} is not complete (files written so far are kept)")


def _made_with(path: Path) -> LocalizerConfig:
    """The configuration a JSON-lines file's estimates were made with, the base under the report's own options;
    the defaults, with a warning, for a file without the header line."""
    values = configuration_of(path)
    if values is None:
        print(f"report: {path} has no configuration line (written before it was added): the gate and the bound "
              "are drawn with the defaults plus the given options", file=sys.stderr)
        return LocalizerConfig()
    try:
        return LocalizerConfig.from_dict(values)
    except ConfigError as exc:
        raise ReportError(f"{path}: its configuration line is not valid here: {exc}") from exc


def make_report(args) -> int:
    """Run the bag through the engine (or place the given estimates), write the files; 1 when the bag is damaged."""
    jsonl = args.input.suffix in (".jsonl", ".json")
    bag = args.bag if jsonl else args.input
    if jsonl and bag is None:
        raise ReportError("a JSON-lines input needs --bag, the bag it came from")
    for path in (args.input, bag):
        if not path.exists():
            raise ReportError(f"no such input: {path}")
    try:
        check_folder(args.out, "--out")  # under a file, /proc: said now, not after the whole bag
    except ValueError as exc:
        raise ReportError(str(exc)) from None
    try:
        cfg = seeded(config_from_args(args, _made_with(args.input) if jsonl else None))
        stations = bag_stations(args)
    except ConfigError as exc:
        raise ReportError(str(exc)) from exc
    trace = Trace()
    loc = Localizer(cfg, observer=trace)
    estimates: list[Estimate] = []
    try:
        run = run_bag(bag, bag_topics(args), loc, estimates.append, desc="report", stations=stations)
    except BagError as exc:
        raise ReportError(str(exc)) from exc
    if run.damage:
        print(f"report: {run.damage}; reporting what came before", file=sys.stderr)
    view = loc.view(light=True)
    if view.frame is None:
        raise ReportError("the bag holds no usable GPS fix")
    if jsonl:
        try:
            estimates = estimates_from_jsonl(args.input, view.frame)
        except (OSError, ValueError) as exc:
            raise ReportError(str(exc)) from exc
    if not estimates:
        raise ReportError(f"no estimate ({view.status})")
    write_files(args, loc, trace, estimates, run)
    print(f"report written to {args.out}: " + ", ".join(sorted(p.name for p in args.out.iterdir())), file=sys.stderr)
    return 1 if run.damage else 0


def write_files(args, loc: Localizer, trace: Trace, estimates: list[Estimate], run):
    """map.png, error.png (with the truth), emitter.kml, emitter.geojson and summary.md in args.out. Every emitter
    (channel) is drawn and exported, a moving one's path as a line; the error plot and the summary's figures are the
    last estimate's channel's."""
    view, est = loc.view(light=True), estimates[-1]
    frame = view.frame
    assert frame is not None  # report() found a fix
    finals = list({e.channel: e for e in estimates}.values())  # each channel's last estimate
    paths = export.moving_paths(estimates)  # a moving transmitter's path, per channel
    all_estimates, estimates = estimates, [e for e in estimates if e.channel == est.channel]
    truths = {}  # each channel's truth (bag_run.truth_of), in the engine's map
    for e in finals:
        of = truth_of(run.truths, e.channel, len(finals))
        if of is not None and run.datum is not None:
            lat, lon, _ = LocalFrame(*run.datum).to_geodetic(of[1], of[2])
            truths[e.channel] = tuple(float(v) for v in frame.to_enu(lat, lon))
    truth = truths.get(est.channel)
    tracks = trace.tracks()
    readings = np.array(trace.readings, dtype=float).reshape(-1, 6)
    kept = readings[:, 5].astype(bool)
    args.out.mkdir(parents=True, exist_ok=True)
    others = [e for e in finals if e.channel != est.channel]
    own = loc.posterior() if view.estimate is est else None  # the run's own estimate, not a file's
    posterior = own.grid() if own is not None else None
    plots.map_figure(args.out / "map.png", frame, tracks, readings[:, :5], kept, est, truth, others=others,
                     posterior=posterior, history=all_estimates)
    bound = None
    if truth is not None:
        t, err, bounds, major = error_series(estimates, readings[kept][:, :5], truth)
        plots.error_figure(args.out / "error.png", t, err, bounds, major)
        bound = crlb_rmse(truth, readings[kept][:, 1:3], readings[kept][:, 4]) if kept.any() else float("inf")
    enu = {name: rows[:, 1:3] for name, rows in tracks.items()}
    (args.out / "emitter.kml").write_text(export.kml(frame, finals, enu, paths))
    (args.out / "emitter.geojson").write_text(json.dumps(export.geojson(frame, finals, enu, paths), indent=1))
    print(f"report: {write_cot_files(args.out, finals)}", file=sys.stderr)
    cot = [f"emitter_{name}.cot" for name in file_names(e.channel for e in finals).values()]
    write_summary(args.out / "summary.md", args.input, loc, trace, est, truth, bound, run.damage, others, truths,
                  [name for name in cot if (args.out / name).exists()])


if __name__ == "__main__":
    sys.exit(main())
