"""Locate emitters from bearings taken by hand or from fixed sites (wildlife telemetry, fox hunting, DF masts).

The CSV has a header row (its names in any case). Columns: `time` (ISO 8601 with a UTC offset, or epoch seconds),
`lat`, `lon` (WGS84; or projected `x`, `y` with --crs EPSG:NNNN), `azimuth_deg` (clockwise from true north, unless
-p bearing_reference says otherwise); optional `quality` (0-100), `sigma_deg` (that bearing's own standard
deviation), `station` (a name, for the messages) and `id` (one emitter per id; no id: one emitter). Each row is a
bearing taken at its own place. Fields are separated by commas, or by semicolons or tabs (a spreadsheet's export in
a locale that writes decimal commas: then 46,5 is read as 46.5). A bad row is reported with its line number and
skipped, never used. The engine runs its defaults with 2000 particles (a survey's few bearings make that cheap;
--particles to change).

Output: one JSON line per id (--output), a table on stdout, and with --report DIR a map, KML and GeoJSON of every
id. Exit codes: 0 every id located; 1 some id has no estimate (the reason is printed); 2 unreadable input or bad
options.
"""
from __future__ import annotations

import argparse
import csv
import datetime
import difflib
import json
import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

from aoa_localizer.common.cli import (
    HelpFormatter,
    add_engine_args,
    config_from_args,
    integer_in,
    interrupted,
    raise_terminated,
    seeded,
    setup_logging,
)
from aoa_localizer.common.cot import write_cot_files
from aoa_localizer.common.output import StagedFile, check_folder, check_output, file_names, write_staged
from aoa_localizer.core.spec import ConfigError
from aoa_localizer.engine.crlb import ellipse_axes
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.scheduling.memory import settle_process
from aoa_localizer.engine.site_bearings import SURVEY_PARTICLES, SiteBearing, locate_bearings, survey_config
from aoa_localizer.engine.survey.survey_log import counted
from aoa_localizer.engine.types import SIGMA_RANGE_DEG, Estimate
from aoa_localizer.pooled import SurveyReading, locate_pooled
from aoa_localizer.pooled.noise_family import RECEIVER_CLASSES
from aoa_localizer.pooled.region import size_text

PROG = "python -m aoa_localizer.locate"
MAPS = 200  # --report's per-id maps by default: about a minute of drawing; the rest are listed in summary.md
PROGRESS_S = 10.0  # a long run says how far it is on stderr this often


@dataclass(frozen=True)
class Row:
    """One bearing of the survey."""

    line: int
    stamp: float
    lat: float
    lon: float
    azimuth_deg: float
    quality: float
    sigma_deg: float
    station: str
    id: str
    receiver: str = ""


class NoOffset(ValueError):
    """A time without a UTC offset and no --time-zone: the rows are summed up in one message."""


def _stamp(text: str, decimal_comma: bool = False, zone: datetime.tzinfo | None = None) -> float:
    """Epoch seconds from epoch seconds or ISO 8601 with an offset; a time without one is in `zone` (--time-zone),
    and refused without it (it is ambiguous: NoOffset); no time at all is NaN (a survey without times)."""
    if not text.strip():
        return math.nan
    try:
        value = float(text.replace(",", ".") if decimal_comma else text)
    except ValueError:
        pass
    else:
        if not math.isfinite(value):
            raise ValueError(f"time {text!r} is not a finite number")
        return value
    try:
        when = datetime.datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise ValueError(f"time {text!r} is neither epoch seconds nor an ISO 8601 time") from None
    if when.tzinfo is None:
        if zone is None:
            raise NoOffset(f"time {text!r} has no UTC offset")
        when = when.replace(tzinfo=zone)
    return when.timestamp()


def _number(row: dict, name: str, required: bool = True, decimal_comma: bool = False) -> float:
    text = (row.get(name) or "").strip()
    if not text:
        if required:
            raise ValueError(f"no {name}")
        return float("nan")
    try:
        value = float(text.replace(",", ".") if decimal_comma else text)
    except ValueError:
        raise ValueError(f"{name} {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"{name} is not a finite number ({text!r})")
    return value


# Epoch times in this range are milliseconds (as seconds they would be after the year 5138; a receiver's log or a
# JavaScript tool writes them): every row's must be, or none is read so
_MILLISECONDS = (1e11, 1e14)


def read_rows(path: Path, crs: str | None, zone: datetime.tzinfo | None = None) -> tuple[list[Row], list[str]]:
    """The survey's good rows and one message per bad row (with its line number), and a note when every time is in
    milliseconds (then read as such); raises OSError, ValueError."""
    to_wgs84 = _projection(crs)
    rows, bad = [], []
    no_offset: list[tuple[int, str]] = []
    with open(path, newline="", encoding="utf-8-sig") as fh:
        delimiter = _delimiter(fh.readline())
        fh.seek(0)
        reader = csv.DictReader(fh, delimiter=delimiter)
        _check_header(path, reader.fieldnames or [], ("x", "y") if to_wgs84 else ("lat", "lon"))
        header = {name.strip().lower() for name in reader.fieldnames or []}
        comma = delimiter != ","  # a locale whose lists take semicolons writes decimal commas
        while True:
            try:
                record = next(reader)
            except StopIteration:
                break
            except csv.Error as exc:  # a field over the csv module's limit, a NUL byte: the row cannot be read
                bad.append(f"{path}: the row after line {reader.line_num}: {exc}; row skipped")
                continue
            try:
                rows.append(_row(reader.line_num, {k.strip().lower(): v for k, v in record.items() if k is not None},
                                 to_wgs84, comma, zone))
            except NoOffset as exc:
                no_offset.append((reader.line_num, str(exc)))
            except ValueError as exc:
                bad.append(f"{path}:{reader.line_num}: {exc}; row skipped")
    if no_offset:  # one message for them all: a file of local times would otherwise give a line a row
        lines = ", ".join(str(n) for n, _ in no_offset[:5]) + (", ..." if len(no_offset) > 5 else "")
        bad.append(f"{path}: {len(no_offset)} rows (lines {lines}) skipped: {no_offset[0][1]} (write e.g. "
                   "2024-05-01T10:00:00+00:00, or give the zone the times were taken in: --time-zone Europe/Berlin, "
                   "--time-zone +02:00)")
    timed = [r for r in rows if math.isfinite(r.stamp)]
    if timed and all(_MILLISECONDS[0] <= r.stamp < _MILLISECONDS[1] for r in timed):
        bad.append(f"{path}: the times look like milliseconds since 1970 ({timed[0].stamp:.6g}): read as such")
        rows = [replace(r, stamp=r.stamp / 1000.0) for r in rows]
    if len(timed) < len(rows):
        bad.append(f"{path}: {len(rows) - len(timed)} of {len(rows)} rows have no time: located as a survey "
                   "without times (an id's transmitters are not counted: that needs every reading's time; "
                   f"--model filter takes such an id's rows in the file's order){_renames(header, _untimed(header))}")
    return rows, bad


def _projection(crs: str | None):
    """The transformer from the CRS of projected x, y columns to WGS84 (None: lat, lon columns)."""
    if not crs:
        return None
    try:
        from pyproj import Transformer
        from pyproj.exceptions import CRSError
    except ImportError as exc:
        raise ValueError("--crs needs pyproj: pip install 'aoa_localizer[survey]' (or pyproj)") from exc
    try:
        return Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    except CRSError as exc:
        raise ValueError(f"--crs {crs}: {exc}") from exc


def _check_header(path: Path, fieldnames, position: tuple[str, str]) -> None:
    """A ValueError for a header naming a column twice (in any case) or lacking one this program needs."""
    names = [name.strip().lower() for name in fieldnames]  # `Lat` is `lat`
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"{path}: the header names {', '.join(twice)} more than once (names are read in any "
                         "case): which one holds the data?")
    header = set(names)
    missing = [c for c in (*position, "azimuth_deg") if c not in header]
    if missing:  # a time is optional, but when the file seems to hold it under another name that is said too
        raise ValueError(f"{path}: the header lacks column(s) {', '.join(missing)} "
                         f"(has: {', '.join(sorted(header))}){_renames(header, [*_untimed(header), *missing])}")


def _untimed(header: set[str]) -> list[str]:
    """["time"] when the header has no time column, else []."""
    return [] if "time" in header else ["time"]


def _row(line: int, row: dict, to_wgs84, comma: bool, zone: datetime.tzinfo | None = None) -> Row:
    """One row's bearing, or a ValueError saying what is wrong with it."""
    stamp = _stamp(row.get("time") or "", comma, zone)
    if to_wgs84:
        lon, lat = to_wgs84.transform(_number(row, "x", True, comma), _number(row, "y", True, comma))
    else:
        lat, lon = _number(row, "lat", True, comma), _number(row, "lon", True, comma)
    if not (abs(lat) <= 90 and abs(lon) <= 180):
        raise ValueError(f"position {lat}, {lon} is not a latitude and longitude")
    quality = _number(row, "quality", False, comma)
    sigma = _number(row, "sigma_deg", False, comma)
    if not (math.isnan(sigma) or SIGMA_RANGE_DEG[0] <= sigma <= SIGMA_RANGE_DEG[1]):
        raise ValueError(f"sigma_deg must be in [{SIGMA_RANGE_DEG[0]:g}, {SIGMA_RANGE_DEG[1]:g}] deg, got {sigma:g}")
    receiver = (row.get("receiver") or row.get("observer") or "").strip()
    return Row(line, stamp, lat, lon, _number(row, "azimuth_deg", True, comma), quality, sigma,
               (row.get("station") or "").strip(), (row.get("id") or "").strip(), receiver)


def _zone(text: str) -> datetime.tzinfo:
    """--time-zone: an IANA zone name (daylight saving applied per time) or a fixed offset (+HH:MM)."""
    try:
        return datetime.datetime.strptime(text, "%z").tzinfo or datetime.UTC
    except ValueError:
        pass
    try:
        from zoneinfo import ZoneInfo

        return ZoneInfo(text)
    except (ValueError, KeyError, OSError) as exc:  # ZoneInfoNotFoundError is a KeyError
        raise argparse.ArgumentTypeError(f"{text!r} is neither a zone name (Europe/Berlin) nor an offset "
                                         "(+02:00)") from exc


def _delimiter(header: str) -> str:
    """The header's field separator: a comma, unless the header has none and has semicolons or tabs."""
    if "," in header:
        return ","
    return next((d for d in (";", "\t") if d in header), ",")


# Names other programs give our columns: suggested in the error, never assumed (a hand compass's "bearing" is often
# magnetic, and "time" without an offset is refused anyway)
_OTHER_NAMES = {"lat": ("latitude",), "lon": ("longitude", "long", "lng"), "x": ("easting",), "y": ("northing",),
                "azimuth_deg": ("azimuth", "bearing", "bearing_deg", "az", "heading"),
                "time": ("timestamp", "datetime", "date_time", "utc", "stamp")}


def _renames(header: set[str], missing: list[str]) -> str:
    """A hint for the columns missing from `header` that it seems to hold under other names, or under a name
    spelt nearly like it (`azimuth_dge`)."""
    hints = []
    for name in missing:
        others = [o for o in _OTHER_NAMES.get(name, ()) if o in header]
        others = others or difflib.get_close_matches(name, sorted(header), n=1, cutoff=0.7)
        hints += [f"{other} -> {name}" for other in others]
    return f"; if they hold what this program reads, rename {', '.join(hints)}" if hints else ""


def locate(rows: list[Row], cfg, datum: tuple[float, float]) -> tuple[Estimate | None, Localizer]:
    """The end-of-data estimate of one emitter's bearings (each row a site of its own) and its Localizer; an id
    with a row without a time takes its rows in the file's order (a second a line)."""
    untimed = any(not math.isfinite(row.stamp) for row in rows)
    bearings = [SiteBearing(f"{row.station or 'row'}@{row.line}", float(row.line) if untimed else row.stamp,
                            row.lat, row.lon, row.azimuth_deg, row.quality, row.sigma_deg) for row in rows]
    return locate_bearings(bearings, cfg.with_changes(datum_lat=datum[0], datum_lon=datum[1]))


def check_outputs(source: Path, output: Path | None, report: Path | None):
    """Refuse, before any work, an output that cannot be written or would destroy the input (a ValueError)."""
    if output is not None:
        check_output(output, (source,))
    if report is not None:
        check_folder(report, "--report")


def record(ident: str, est: Estimate, rows: int) -> dict:
    whole = est.to_json_dict()
    return {"id": ident, "lat": est.lat, "lon": est.lon, "east": est.east, "north": est.north,
            "cov": [[float(v) for v in r] for r in est.cov], "state": est.state, "warnings": list(est.warnings),
            "bearings_used": est.bearings_used, "bearings_given": rows,
            **{k: whole[k] for k in ("modes", "transmitter_count", "count_probability", "transmitters")}}


def write_report(out: Path, frame: LocalFrame, found: dict[str, tuple[Estimate, list[Row]]], maps: int,
                 refused: dict[str, str]):
    """map.png (every id's estimate and 95 % ellipse, numbered), maps/<id>.png (each id zoomed to its bearings:
    reporting/survey_map.py) for the first `maps` ids, emitter.kml, emitter.geojson, an emitter_<id>.cot (TAK) of
    every id, and summary.md: each id's state and files (its file names as output.file_names makes them)."""
    import matplotlib

    matplotlib.use("Agg")

    from aoa_localizer.reporting import survey_map
    from aoa_localizer.reporting.export import geojson, kml

    out.mkdir(parents=True, exist_ok=True)
    named = [replace(est, channel=ident or "default") for ident, (est, _) in found.items()]
    (out / "emitter.geojson").write_text(json.dumps(geojson(frame, named, {}), indent=1))
    (out / "emitter.kml").write_text(kml(frame, named, {}))
    print(f"locate: {write_cot_files(out, named)}", file=sys.stderr)
    names = file_names(est.channel for est in named)
    drawn = list(found)[:maps]
    write_staged(out / "summary.md", summary(found, names, set(drawn), refused))
    survey_map.overview(out / "map.png", frame, found)
    if drawn:
        (out / "maps").mkdir(exist_ok=True)
    clock = _Clock("drawing the maps", len(drawn))
    for k, ident in enumerate(drawn):
        est, rows = found[ident]
        survey_map.id_map(out / "maps" / f"{names[ident or 'default']}.png", frame, ident, est, rows)
        clock.tick(k + 1)
    if len(found) > maps:
        print(f"locate: maps/ holds the first {maps} of {len(found)} ids (--maps to draw more); summary.md lists "
              "every id", file=sys.stderr)


def summary(found: dict[str, tuple[Estimate, list[Row]]], names: dict[str, str], drawn: set[str],
            refused: dict[str, str]) -> str:
    """summary.md of a survey's report: a row per id with its place, state and files."""
    lines = ["# Survey report", "", f"{len(found)} ids located, {len(refused)} without an estimate.", "",
             "| id | lat | lon | state | TAK file | map |", "|---|---|---|---|---|---|"]
    for ident, (est, _) in found.items():
        name = names[ident or "default"]
        shown = json.dumps(ident)[1:-1].replace("|", "\\|")
        lines.append(f"| {shown} | {est.lat:.6f} | {est.lon:.6f} | {est.state} | emitter_{name}.cot | "
                     + (f"maps/{name}.png |" if ident in drawn else "not drawn (--maps) |"))
    lines += [f"| {json.dumps(ident)[1:-1]} | - | - | no estimate: {why} | - | - |" for ident, why in refused.items()]
    return "\n".join(lines) + "\n"


class _Clock:
    """A long stage's progress on stderr: a line every PROGRESS_S, from the first PROGRESS_S on (a short run
    prints none)."""

    def __init__(self, stage: str, total: int):
        self.stage, self.total = stage, total
        self.start = self.last = time.monotonic()

    def tick(self, done: int, stage: str | None = None) -> None:
        now = time.monotonic()
        if now - self.last >= PROGRESS_S:
            self.last = now
            print(f"locate: {stage or self.stage}: {done} of {self.total} ids, {now - self.start:.0f} s",
                  file=sys.stderr, flush=True)


class _Lines:
    """Where each id's result goes as it is done: the table row now, its JSON line into --output (placed at the
    first line and flushed a line at a time, so an interrupted run keeps every id done), and the progress."""

    def __init__(self, output: Path | None, total: int):
        self.staged = StagedFile(output) if output is not None else None
        self.clock = _Clock("located", total)
        self.written = self.failed = 0
        self.found: dict[str, tuple[Estimate, list[Row]]] = {}
        self.refused: dict[str, str] = {}

    def fixed(self, ident: str, est: Estimate, group: list[Row], line: dict) -> None:
        self.found[ident] = (est, group)
        if self.staged is not None:
            self.staged.place()
            self.staged.file.write(json.dumps(line) + "\n")
            self.staged.file.flush()
        self.written += 1
        _print_row(ident, est)  # after its line: a row on the table is an id kept
        self.clock.tick(self.written + self.failed)

    def none(self, ident: str, why: str) -> None:
        self.refused[ident] = why
        self.failed += 1
        print(f"{ident or '-':<12} no estimate: {why}")

    def close(self, whole: bool) -> None:
        """Keep what was written: the whole file, or (interrupted) the ids done, each line whole."""
        if self.staged is not None:
            if whole or self.written:
                self.staged.keep()
            else:
                self.staged.drop()


def _filter_run(groups: dict[str, list[Row]], cfg, datum, lines: _Lines) -> None:
    """--model filter: each id through its own particle filter (the round-3 engine)."""
    for ident, group in groups.items():
        est, loc = locate(group, cfg, datum)
        if est is None:
            lines.none(ident, loc.view(light=True).status)
        else:
            lines.fixed(ident, est, group, record(ident, est, len(group)))


def _print_row(ident: str, est: Estimate):
    a, b, _ = (size_text(v) for v in ellipse_axes(est.cov))
    print(f"{ident or '-':<12} {est.lat:11.6f} {est.lon:12.6f} {a:>8} x {b:<8} {est.bearings_used:8d}  "
          f"{est.state}" + "".join(f"\n{'':<12} {w}" for w in est.warnings))


def _pooled_run(groups: dict[str, list[Row]], frame: LocalFrame, receiver_class: str, max_k: int,
                lines: _Lines) -> None:
    """--model pooled: every id at once, each receiver calibrated over the ids it heard (aoa_localizer.pooled);
    each id's line goes out as soon as its group's noise is learned."""
    readings = [SurveyReading(row.id, row.lat, row.lon, row.azimuth_deg, row.station, row.receiver, row.sigma_deg,
                              row.stamp) for group in groups.values() for row in group]
    calibrating = _Clock("calibrating", len(groups))

    def on_fix(ident: str, fix, noise: dict | None) -> None:
        if isinstance(fix, str):
            lines.none(ident, fix)
            return
        group = groups[ident]
        east, north = frame.to_enu(fix.lat, fix.lon)
        est = Estimate(group[-1].stamp, float(east), float(north), fix.lat, fix.lon, fix.cov, fix.readings,
                       fix.stations, float("nan"), "pooled", modes=[(float(east), float(north), 1.0)],
                       channel=ident or "default", state=fix.state, warnings=list(fix.warnings), regions=fix.hpd,
                       **counted(fix.count, frame))
        lines.fixed(ident, est, group, pooled_record(ident, est, fix, len(group), noise))

    result = locate_pooled(readings, receiver_class, max_k, on_fix,
                           lambda stage, done, of: calibrating.tick(done, stage))
    for warning in result.warnings:
        print(f"locate: warning: {warning}", file=sys.stderr)
    for ident in groups:
        if ident not in result.fixes and ident not in lines.refused:
            lines.none(ident, "no usable bearing")
    for text in receiver_lines(result):
        print(text)


def pooled_record(ident: str, est: Estimate, fix, rows: int, noise: dict | None) -> dict:
    """A JSON line of the pooled model (docs/interface.md, "locate"): the filter's fields and the regions, and the
    noise of the group its receivers are in."""
    out = record(ident, est, rows)
    out.update({"model": "pooled", "stations": fix.stations, "receivers": fix.receivers,
                "hpd": est.to_json_dict()["hpd"],
                "ellipse_mass": {f"{100 * lvl:.0f}": round(m, 3) for lvl, m in fix.ellipse_mass.items()},
                "noise": noise})
    return out


def receiver_lines(result) -> list[str]:
    """One line per receiver and per pooled group: what the survey taught about them."""
    out = []
    for cal in result.receivers.values():
        bias = (f"bias {cal.bias_deg:+.1f} +- {cal.bias_sd_deg:.1f} deg (the part the crossings show)"
                if math.isfinite(cal.bias_deg) else "no bias learned (heard over fewer than 3 ids)")
        out.append(f"receiver {cal.name}: {cal.emitters} ids, {cal.stations} stations; {bias}")
    for g in result.noise:
        out.append(f"station error of {', '.join(g['receivers'][:5])}{' ...' if len(g['receivers']) > 5 else ''}: "
                   f"{g['scale_deg']:.1f} deg ({g['scale_deg_90'][0]:.1f}-{g['scale_deg_90'][1]:.1f} deg at 90 %), "
                   f"wild share {g['wild_share']:.2f}, over {g['emitters']} ids")
    return out


class _Table:
    """stdout for the table: once its reader has gone (`locate ... | head`), the rest is dropped and the run goes on,
    so --output and --report are still written."""

    def __init__(self, stream):
        self.stream, self.gone = stream, False

    def write(self, text: str) -> int:
        if not self.gone:
            try:
                return self.stream.write(text)
            except BrokenPipeError:
                self.gone = True
                os.dup2(os.open(os.devnull, os.O_WRONLY), self.stream.fileno())  # the interpreter's last flush too
        return len(text)

    def flush(self) -> None:
        if not self.gone:
            try:
                self.stream.flush()
            except BrokenPipeError:
                self.gone = True
                os.dup2(os.open(os.devnull, os.O_WRONLY), self.stream.fileno())


def main(argv=None) -> int:
    settle_process()  # freed memory reused, BLAS on one thread (scheduling/memory.py)
    stdout, sys.stdout = sys.stdout, _Table(sys.stdout)
    terminate = None
    if threading.current_thread() is threading.main_thread():  # SIGTERM ends a run as Ctrl-C does: what is done stays
        terminate = signal.signal(signal.SIGTERM, raise_terminated)
    try:
        return _main(argv)
    except KeyboardInterrupt as exc:  # before the run started: nothing to keep
        return interrupted("locate", "nothing written", exc)
    finally:
        sys.stdout = stdout
        if terminate is not None:
            signal.signal(signal.SIGTERM, terminate)


def _main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__, formatter_class=HelpFormatter)
    parser.add_argument("csv", type=Path, help="the bearings (CSV with a header)")
    parser.add_argument("--output", type=Path, metavar="OUT.jsonl", help="one JSON line per id")
    parser.add_argument("--report", type=Path, metavar="DIR", help="map.png, emitter.kml, emitter.geojson")
    parser.add_argument("--maps", type=integer_in(0, 1_000_000), default=MAPS, metavar="N",
                        help=f"with --report: draw maps/<id>.png for the first N ids (a map takes about 0.3 s; "
                             f"summary.md lists every id; default {MAPS})")
    parser.add_argument("--crs", metavar="EPSG:NNNN", help="the CRS of projected x, y columns (instead of lat, lon)")
    parser.add_argument("--model", choices=("pooled", "filter"), default="pooled",
                        help="pooled: every id at once on a grid, receivers calibrated jointly (default); filter: "
                             "each id through its own particle filter (uses quality, --algorithm, --particles, -p)")
    parser.add_argument("--receiver-class", choices=tuple(RECEIVER_CLASSES), default="unknown",
                        help="what the receiver is, for the prior on its error (pooled model)")
    parser.add_argument("--time-zone", metavar="ZONE", type=_zone,
                        help="the zone of times written without a UTC offset (an IANA name such as Europe/Berlin, "
                             "or an offset such as +02:00); without it such times are refused")
    add_engine_args(parser, SURVEY_PARTICLES)
    args = parser.parse_args(argv)
    setup_logging(args.verbose)
    try:
        cfg = config_from_args(args, survey_config())
        cfg = seeded(cfg)  # one file, one answer
        check_outputs(args.csv, args.output, args.report)
        if args.csv.is_file() and args.csv.stat().st_size == 0:
            raise ValueError(f"{args.csv} is empty: a header line (time,lat,lon,azimuth_deg,...) and a row a "
                             "bearing are needed")
        rows, bad = read_rows(args.csv, args.crs, args.time_zone)
    except (ConfigError, OSError, ValueError, UnicodeDecodeError, csv.Error) as exc:
        print(f"locate: {exc}", file=sys.stderr)
        return 2
    for message in bad:
        print(f"locate: {message}", file=sys.stderr)
    if not rows:
        print(f"locate: {args.csv}: no usable row", file=sys.stderr)
        return 2
    datum = (rows[0].lat, rows[0].lon)
    frame = LocalFrame(datum[0], datum[1], 0.0)
    groups: dict[str, list[Row]] = {}
    for row in rows:
        groups.setdefault(row.id, []).append(row)
    print(f"{'id':<12} {'lat':>11} {'lon':>12} {'95% semi-axes (m)':>18} {'bearings':>8}  state")
    lines = _Lines(args.output, len(groups))
    try:
        if args.model == "filter":
            _filter_run(groups, cfg, datum, lines)
        else:
            _pooled_run(groups, frame, args.receiver_class, cfg.max_emitters_per_channel, lines)
    except KeyboardInterrupt as exc:
        lines.close(whole=False)
        kept = (f"{lines.written} of {len(groups)} ids' lines kept in {args.output}" if args.output and lines.written
                else "no id was done: nothing written")
        return interrupted("locate", kept + ("; no report" if args.report else ""), exc)
    lines.close(whole=True)
    if args.report and lines.found:
        try:
            write_report(args.report, frame, lines.found, args.maps, lines.refused)
        except KeyboardInterrupt as exc:
            return interrupted("locate", f"--output is whole; the report in {args.report} is not complete", exc)
    return 1 if lines.failed else 0
