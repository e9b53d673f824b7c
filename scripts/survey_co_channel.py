"""Co-channel transmitters in the survey model (issue 54, `locate`'s default), measured: the count, each
transmitter's error and its 95 % ellipse's coverage, and a second transmitter reported where there is one.

    python scripts/survey_co_channel.py [--runs 20] [--jobs 2]

Cells (simulation/surveys.py, shared_frequency): six fixed stations 2 km out, each with a steady bias N(0, 3 deg)
and 1.5 deg scatter a reading; two transmitters 600 m apart taking turns of 5-30 s at air-time shares 50/50 or
80/20 while every station reads once a second for ten minutes (`masts`), or a surveyor's six stops of a minute,
5 min apart (`stops`); one transmitter in both ways; and the indoor anchors of simulation/surveys.py (16 places,
four anchors, 250 readings each with a steady 20 deg site error), their readings stamped 0.2 s apart. Run r on
data seed r. A transmitter of a count of two is matched to the nearer truth.
"""
from __future__ import annotations

import argparse
import math
import statistics
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.pooled.solver import locate_pooled
from aoa_localizer.pooled.stations import SurveyReading
from aoa_localizer.simulation.surveys import DATUM, indoor_anchors, shared_frequency

CELLS = {"two 50/50, masts": (2, True, None), "two 80/20, masts": (2, True, (0.8, 0.2)),
         "two 50/50, stops": (2, False, None), "one, masts": (1, True, None), "one, stops": (1, False, None)}
FRAME = LocalFrame(*DATUM)


def one_run(name: str, run: int) -> dict:
    rng = np.random.default_rng(run)
    if name == "indoor anchors":
        return _indoor(rng)
    transmitters, together, shares = CELLS[name]
    heard = shared_frequency(rng, transmitters, together, shares=shares)
    started = time.perf_counter()
    fix = locate_pooled(heard.readings(), max_k=3).fixes["x"]
    out: dict = {"count": fix.count.count if fix.count else 1, "seconds": time.perf_counter() - started,
                 "transmitters": []}
    for t in fix.count.transmitters if fix.count else ():
        east, north = FRAME.to_enu(t.lat, t.lon)
        miss = heard.transmitters - [east, north]
        k = int(np.argmin(np.hypot(*miss.T)))
        out["transmitters"].append({"error": float(np.hypot(*miss[k])),
                                    "inside": float(miss[k] @ np.linalg.solve(t.cov, miss[k])) < -2 * math.log(0.05)})
    return out


def _indoor(rng: np.random.Generator) -> dict:
    s = indoor_anchors(rng)
    seen: dict[tuple, int] = {}
    readings = []
    for e, st, (x, y), az in zip(s.emitter, s.station, s.places, s.azimuth_deg, strict=True):
        k = seen[(e, st)] = seen.get((e, st), -1) + 1
        lat, lon, _ = FRAME.to_geodetic(x, y)
        readings.append(SurveyReading(e, float(lat), float(lon), float(az), st, stamp=1000.0 * int(e[1:]) + 0.2 * k))
    started = time.perf_counter()
    fixes = locate_pooled(readings, max_k=3).fixes.values()
    return {"places": len(fixes), "seconds": time.perf_counter() - started,
            "second": sum(1 for f in fixes if f.count and f.count.count >= 2),
            "ghost": sum(1 for f in fixes if any("second place" in w for w in f.warnings))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    names = [*CELLS, "indoor anchors"]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = {n: list(pool.map(one_run, [n] * args.runs, range(args.runs))) for n in names}
    print("| cell | runs | count right | median error (m) | truth inside its 95 % ellipse | seconds a run |")
    print("|---|---|---|---|---|---|")
    for name in CELLS:
        runs, want = results[name], CELLS[name][0]
        right = sum(r["count"] == want for r in runs)
        ts = [t for r in runs for t in r["transmitters"]]
        err = f"{statistics.median(t['error'] for t in ts):.0f}" if ts else "-"
        inside = f"{sum(t['inside'] for t in ts)}/{len(ts)}" if ts else "-"
        sec = statistics.median(r["seconds"] for r in runs)
        print(f"| {name} | {len(runs)} | {right}/{len(runs)} | {err} | {inside} | {sec:.2f} |")
    runs = results["indoor anchors"]
    places = sum(r["places"] for r in runs)
    print(f"| indoor anchors (places) | {places} | {places - sum(r['second'] for r in runs)}/{places} | - | "
          f"ghost said at {sum(r['ghost'] for r in runs)} | {statistics.median(r['seconds'] for r in runs):.2f} |")


if __name__ == "__main__":
    main()
