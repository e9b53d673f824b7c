"""Real bearings with a surveyed truth: each id's error, coverage at 50 % and 95 %, sharpness, least squares beside.

    python scripts/real_bearings.py ../shared/data/real/telemetry_observer_a.csv \
        ../shared/data/real/telemetry_observer_a_truth.csv [--receiver-class unknown] [--scale 1] [--per-id]

The bearings go through the pooled survey model (aoa_localizer.pooled, what `locate` runs by default), or with
`--model filter` through `locate --model filter` (a particle filter per id, the round-3 path; no regions); `--scale`
multiplies every station's offset from the first one (the same bearings on a smaller or larger layout).
Coverage counts the truth inside the covariance's ellipse (chi-square 2 at the level) and inside the
highest-density polygon; sharpness is the 95 % semi-major over the error.
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import math
import tempfile
from pathlib import Path

import numpy as np

from aoa_localizer.engine.crlb import inside_ellipse
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.site_bearings import least_squares_fix
from aoa_localizer.pooled import SurveyReading, locate_pooled
from aoa_localizer.pooled.region import ELLIPSE_50
from aoa_localizer.pooled.solver import EmitterFix, PooledResult
from aoa_localizer.tools.locate import main as main_locate
from aoa_localizer.tools.locate import read_rows


def inside_rings(rings, lat: float, lon: float) -> bool:
    from matplotlib.path import Path as MplPath

    return any(MplPath(np.asarray(r)[:, ::-1]).contains_point((lon, lat)) for r in rings)


def filter_fixes(readings: list[SurveyReading], seed: int) -> PooledResult:
    """`locate --model filter` on the readings: fixes shaped like the pooled model's (no regions)."""
    with tempfile.TemporaryDirectory() as tmp:
        src, out = Path(tmp) / "in.csv", Path(tmp) / "out.jsonl"
        lines = ["time,lat,lon,azimuth_deg,station,id"] + [
            f"{1.7e9 + 600 * i},{r.lat!r},{r.lon!r},{r.azimuth_deg!r},{r.station},{r.emitter}"
            for i, r in enumerate(readings)]
        src.write_text("\n".join(lines) + "\n")
        with contextlib.redirect_stdout(io.StringIO()):
            main_locate([str(src), "--model", "filter", "--output", str(out), "--seed", str(seed)])
        fixes = {}
        for line in out.read_text().splitlines():
            g = json.loads(line)
            fixes[g["id"]] = EmitterFix(g["id"], g["lat"], g["lon"], np.array(g["cov"]), g["state"], g["warnings"],
                                        g["bearings_used"], g["bearings_given"], [], {0.5: [], 0.95: []}, {})
    return PooledResult(fixes=fixes)


def api_fixes(rows, path: str, seed: int) -> PooledResult:
    """Through `Localizer` as a program would feed it: `api_walk` one Localizer for the whole survey, a walking
    observer whose fix comes with each azimuth and a channel per id (a made-up frequency each); `api_walk_each` one
    Localizer per id, the same way; `api_fixed_each` one per id, each stop a fixed station."""
    from aoa_localizer import Localizer, LocalizerConfig

    ids = sorted({r.id for r in rows})
    freq = {ident: 1e8 + 1e6 * k for k, ident in enumerate(ids)}  # channels far apart: one per id
    groups = [sorted(rows, key=lambda r: r.stamp)] if path == "api_walk" else [
        sorted((r for r in rows if r.id == ident), key=lambda r: r.stamp) for ident in ids]
    fixes = {}
    for group in groups:
        loc = Localizer(LocalizerConfig(seed=seed))
        for r in group:
            if path == "api_fixed_each":
                loc.add_station(f"{r.station}@{r.line}", fixed=True, position=(r.lat, r.lon))
                loc.add_bearing(r.stamp, r.azimuth_deg, float("nan"), station=f"{r.station}@{r.line}")
            else:
                loc.add_fix(r.stamp, r.lat, r.lon)
                loc.add_bearing(r.stamp, r.azimuth_deg, float("nan"), frequency_hz=freq[r.id])
        loc.flush()
        loc.finish()
        for channel in loc.view().channels:
            est = channel.estimate
            ident = (min(freq, key=lambda i: abs(freq[i] - channel.frequency_hz)) if path == "api_walk"
                     else group[0].id)
            if est is not None:
                fixes[ident] = EmitterFix(ident, est.lat, est.lon, est.cov, est.state, est.warnings,
                                          est.bearings_used, est.bearings_used, [], {0.5: [], 0.95: []}, {})
        loc.close()
        rejected = loc.view(light=True).rejected
        if rejected:
            print(f"inputs refused: {dict(rejected)}")
    return PooledResult(fixes=fixes)


def scaled(readings: list[SurveyReading], truth: dict, factor: float):
    """The readings and truths with every place's offset from the first reading multiplied by `factor`."""
    frame = LocalFrame(readings[0].lat, readings[0].lon)

    def move(lat, lon):
        e, n = frame.to_enu(lat, lon)
        la, lo, _ = frame.to_geodetic(e * factor, n * factor)
        return la, lo

    out = [SurveyReading(r.emitter, *move(r.lat, r.lon), r.azimuth_deg, r.station, r.receiver, r.sigma_deg)
           for r in readings]
    return out, {k: move(*v) for k, v in truth.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bearings", type=Path)
    ap.add_argument("truth", type=Path)
    ap.add_argument("--receiver-class", default="unknown")
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--per-id", action="store_true")
    ap.add_argument("--model", choices=("pooled", "filter", "api_walk", "api_walk_each", "api_fixed_each"),
                    default="pooled")
    ap.add_argument("--seed", type=int, default=1, help="the filter's seed (--model filter)")
    args = ap.parse_args(argv)
    rows, bad = read_rows(args.bearings, None)
    assert not bad, bad
    readings = [SurveyReading(r.id, r.lat, r.lon, r.azimuth_deg, r.station, "", r.sigma_deg) for r in rows]
    with open(args.truth, newline="") as fh:
        truth = {r["id"]: (float(r["lat"]), float(r["lon"])) for r in csv.DictReader(fh)}
    if args.scale != 1.0:
        readings, truth = scaled(readings, truth, args.scale)
    if args.model == "pooled":
        res = locate_pooled(readings, args.receiver_class)
    elif args.model == "filter":
        res = filter_fixes(readings, args.seed)
    else:
        res = api_fixes(rows, args.model, args.seed)
    errs, ls_errs, in50, in95, hpd50, hpd95, sharp, tracking_out = [], [], 0, 0, 0, 0, [], 0
    for ident, fix in res.fixes.items():
        t_lat, t_lon = truth[ident]
        frame = LocalFrame(t_lat, t_lon)
        err = np.array(frame.to_enu(fix.lat, fix.lon))
        e = float(np.hypot(*err))
        errs.append(e)
        a50, a95 = inside_ellipse(-err, fix.cov, ELLIPSE_50), inside_ellipse(-err, fix.cov)
        in50 += a50
        in95 += a95
        hpd50 += inside_rings(fix.hpd[0.5], t_lat, t_lon)
        hpd95 += inside_rings(fix.hpd[0.95], t_lat, t_lon)
        tracking_out += fix.state == "tracking" and not a95
        sharp.append(fix.semi_axes()[0] / max(e, 1e-9 * args.scale))
        mine = [r for r in readings if r.emitter == ident]
        st = np.array([frame.to_enu(r.lat, r.lon) for r in mine])
        ls = least_squares_fix(st, np.array([r.azimuth_deg for r in mine]))
        ls_errs.append(float(np.hypot(*ls)) if ls is not None else math.inf)
        if args.per_id:
            print(f"{ident:<24} err {e:8.3g} m  a95 {fix.semi_axes()[0]:8.3g} m  in50 {a50:d} in95 {a95:d}  "
                  f"ls {ls_errs[-1]:8.3g}  {fix.state}  {'; '.join(fix.warnings)}")
    n = len(res.fixes)
    print(f"{n} of {len(truth)} located ({len(res.refused)} refused); median error {np.median(errs):.4g} m "
          f"(least squares {np.median(ls_errs):.4g} m)")
    print(f"inside the 50 % ellipse {in50}/{n} ({100 * in50 / n:.0f} %), 95 % ellipse {in95}/{n} "
          f"({100 * in95 / n:.0f} %); inside the 50 % region {hpd50}/{n}, 95 % region {hpd95}/{n}")
    print(f"median sharpness {np.median(sharp):.2f}; tracking outside its 95 % ellipse: {tracking_out}")
    for cal in res.receivers.values():
        print(f"receiver {cal.name}: bias {cal.bias_deg:+.1f} +- {cal.bias_sd_deg:.1f} deg over {cal.emitters} "
              f"emitters, {cal.stations} stations")
    for group in res.noise:
        print(f"noise: {group}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
