"""Co-channel transmitters (issue 54), measured: the count, each transmitter's error against the CRLB of its own
readings and its 95 % ellipse's coverage, a second transmitter reported where there is one, and the count's cost.

    python scripts/co_channel.py [--runs 20] [--jobs 2] [--cells "two 50/50,three 40/30/30"] [--no-cost]

Cells on the robustness cells' drive (120 points 10 s apart, 3 readings each, quality U(40, 100), 1-8 deg linear
in quality), the default configuration, run r on data seed r and filter seed 1000 + r:
* `two 50/50`, `two 80/20`: a second transmitter on the frequency 300, 650 or 1000 m from the first (by run), in a
  direction that turns with the run; push-to-talk bursts of 5-30 s, air-time shares 50/50 or 80/20;
* `two interleaved`: the same at 50/50, reading by reading (bearings alone cannot tell it from a reflection);
* `three 40/30/30`: a second and a third transmitter, 300, 650 or 1000 m from the first (the third a step further
  in that list), 120 deg apart around it, in bursts;
* `one`, `wild 20 %`, `wild 25 %`, `reflector 20 %`: one transmitter, clean, with 20 or 25 % wild bearings, with a
  reflection's ghost;
* `five limit 3`, `five limit 5`: five transmitters at 20 % each, under the default limit and with `max_emitters_per_
  channel` 5; `site field 3 deg`: one transmitter, a smooth site error (sd 3 deg over 300 m of road);
* `second receiver +6 deg`, `+12 deg`: one transmitter heard by two cars (biased_pair), the second's receiver off.
Each transmitter of a right count is matched to a truth (the pairing of least total distance); its error is scored
against the CRLB of the readings it sent (crlb_rmse); a count of one in a one-transmitter cell scores the estimate.
The cost rows run the public scenarios with `max_emitters_per_channel` 1 (never counted) and 3 (the default).
"""
from __future__ import annotations

import argparse
import itertools
import math
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.engine.crlb import crlb_rmse, inside_ellipse
from aoa_localizer.engine.types import EstimateState
from aoa_localizer.simulation.evaluation import feed_fleet, scenario_config
from aoa_localizer.simulation.fleet import FleetData, simulate_fleet
from aoa_localizer.simulation.scenarios import SCENARIOS, Scenario, robustness_cells, simulate

DISTANCES_M = (300.0, 650.0, 1000.0)


def cells() -> dict[str, tuple[Scenario, dict]]:
    """Each cell's scenario and its configuration's changes from the defaults."""
    robust = robustness_cells()
    base = robust["wild0"]
    five = replace(base, co_shares=(0.2,) * 5)
    return {"two 50/50": (replace(base, co_shares=(0.5, 0.5)), {}),
            "two 80/20": (replace(base, co_shares=(0.8, 0.2)), {}),
            "two interleaved": (replace(base, co_shares=(0.5, 0.5), bursts_s=None), {}),
            "three 40/30/30": (replace(base, co_shares=(0.4, 0.3, 0.3)), {}),
            "five limit 3": (five, {}), "five limit 5": (five, {"max_emitters_per_channel": 5}),
            "one": (base, {}), "wild 20 %": (robust["wild20"], {}),
            "wild 25 %": (replace(base, name="wild25", wild_share=0.25), {}),
            "reflector 20 %": (robust["reflector"], {}),
            "site field 3 deg": (replace(base, site_field_deg=3.0), {})}


def placed(sc: Scenario, run: int) -> Scenario:
    """A co-channel cell's other transmitters for run `run` (none for the one-transmitter cells): the k-th at
    DISTANCES_M[(run + k) % 3] from the emitter, evenly round it (at least 120 deg apart), turning with the run."""
    if not sc.co_shares:
        return sc
    n = len(sc.co_shares) - 1
    others = []
    for k in range(n):
        d, angle = DISTANCES_M[(run + k) % 3], 2.0 * math.pi * run / 20.0 + k * 2.0 * math.pi / max(3, n)
        others.append((sc.emitter[0] + d * math.cos(angle), sc.emitter[1] + d * math.sin(angle)))
    return replace(sc, co_channel=tuple(others))


BIASED_CELLS = {"second receiver +6 deg": 6.0, "second receiver +12 deg": 12.0}


def biased_pair(run: int, bias_deg: float) -> FleetData:
    """Two cars on the robustness drive's roads (the second's mirrored through the emitter), 60 points each, one
    transmitter; the second car's receiver reads `bias_deg` clockwise of the truth."""
    base = robustness_cells()["wild0"]
    pair = {"car1": replace(base, name="car1", points=60),
            "car2": replace(base, name="car2", track=tuple((2400 - e, 1600 - n) for e, n in base.track), points=60)}
    data = simulate_fleet(pair, {433.92e6: base.emitter}, run)
    data.bearings["car2"][:, 1] = (data.bearings["car2"][:, 1] + bias_deg) % 360.0
    return data


def one_run(name: str, run: int) -> dict:
    if name in BIASED_CELLS:
        return biased_run(name, run)
    sc, changes = cells()[name]
    sc = placed(sc, run)
    data = simulate(sc, run)
    loc = Localizer(LocalizerConfig(seed=1000 + run, **changes))
    final = None
    for est in loc.run(data.inputs()):
        final = est if est is not None else final
    events = loc.view(light=True).events
    offset_said = events.get("offset_learned", 0) > events.get("offset_taken_back", 0)  # standing at the end
    loc.close()
    if final is None:
        return {"count": 0}
    truths = data.transmitters_enu if data.transmitters_enu is not None else data.emitter_enu[None, :]
    mean = np.array([final.east, final.north])
    channel_inside = any(inside_ellipse(mean - t, final.cov) for t in truths)
    places = [(np.array([t.east, t.north]), t.cov, t.state) for t in final.transmitters] or [
        (mean, final.cov, final.state)]
    out: dict = {"count": final.transmitter_count, "p": final.count_probability,
                 "ghost": any("interleaved" in w for w in final.warnings),
                 "more_said": any("more transmitters than" in w for w in final.warnings),
                 "offset_said": offset_said,
                 "channel_ok": channel_inside or final.state != EstimateState.TRACKING,
                 "tracking_places": sum(st == EstimateState.TRACKING for _, _, st in places),
                 "confidently_wrong": sum(st == EstimateState.TRACKING and not any(
                     inside_ellipse(x - t, c) for t in truths) for x, c, st in places)}
    if len(truths) == 1 and final.transmitter_count == 1:  # one transmitter: the estimate itself
        err = mean - data.emitter_enu
        mine = ~data.wild
        out["transmitters"] = [{"error": float(np.hypot(*err)), "inside": bool(inside_ellipse(err, final.cov)),
                                "crlb": crlb_rmse(data.emitter_enu, data.sensor_enu[mine], data.sigma[mine])}]
    elif final.transmitter_count == len(truths) >= 2:
        n = len(truths)
        ours = [np.array([t.east, t.north]) for t in final.transmitters]
        order = min(itertools.permutations(range(n)),
                    key=lambda p: sum(np.hypot(*(ours[i] - truths[j])) for i, j in enumerate(p)))
        scored = []
        for i, j in enumerate(order):
            mine = (data.source == j) & ~data.wild
            err = ours[i] - truths[j]
            scored.append({"error": float(np.hypot(*err)), "crlb": crlb_rmse(truths[j], data.sensor_enu[mine],
                                                                             data.sigma[mine]),
                           "inside": bool(inside_ellipse(err, final.transmitters[i].cov))})
        out["transmitters"] = scored
    return out


def biased_run(name: str, run: int) -> dict:
    """A biased-receiver cell's run: the count, and whether the channel's estimate is honest."""
    data = biased_pair(run, BIASED_CELLS[name])
    loc = Localizer(LocalizerConfig(seed=1000 + run))
    feed_fleet(loc, data)
    loc.flush()
    loc.finish()
    final = loc.view(light=True).estimate
    loc.close()
    if final is None:
        return {"count": 0}
    truth = next(iter(data.truth.values()))
    mean = np.array([final.east, final.north])
    inside = bool(inside_ellipse(mean - truth, final.cov))
    places = [(np.array([t.east, t.north]), t.cov, t.state) for t in final.transmitters] or [
        (mean, final.cov, final.state)]
    return {"count": final.transmitter_count, "p": final.count_probability,
            "ghost": any("interleaved" in w for w in final.warnings), "offset_said": False,
            "more_said": any("more transmitters than" in w for w in final.warnings),
            "channel_ok": inside or final.state != EstimateState.TRACKING,
            "tracking_places": sum(st == EstimateState.TRACKING for _, _, st in places),
            "confidently_wrong": sum(st == EstimateState.TRACKING and not inside_ellipse(x - truth, c)
                                     for x, c, st in places)}


def cost(name: str, max_k: int, runs: int) -> float:
    """Seconds a public scenario's run takes, median of `runs`."""
    times = []
    for run in range(runs):
        data = simulate(name, run)
        loc = Localizer(scenario_config(data, LocalizerConfig(seed=1000 + run, max_emitters_per_channel=max_k)))
        t0 = time.perf_counter()
        for _ in loc.run(data.inputs()):
            pass
        times.append(time.perf_counter() - t0)
        loc.close()
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--cells", help="a comma-separated subset of the cells (default: all)")
    ap.add_argument("--no-cost", action="store_true", help="skip the public scenarios' cost rows")
    args = ap.parse_args()
    every = {**cells(), **{n: (robustness_cells()["wild0"], {}) for n in BIASED_CELLS}}
    chosen = {n: c for n, c in every.items() if not args.cells or n in args.cells.split(",")}
    print("| cell | count right | count (runs) | median p | error / CRLB (RMS, each transmitter) | inside 95 % | "
          "ghost said | offset standing | 'more than' said | channel estimate inside or not tracking | tracking places "
          "outside |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    said: list[tuple[float, bool]] = []  # (p, right) of every count whose truth is within its limit
    with ProcessPoolExecutor(args.jobs) as pool:
        for name, (sc, changes) in chosen.items():
            res = list(pool.map(one_run, [name] * args.runs, range(args.runs)))
            truth = len(sc.co_shares) if sc.co_shares and sc.bursts_s is not None else 1
            limit = changes.get("max_emitters_per_channel", LocalizerConfig().max_emitters_per_channel)
            counts = [r["count"] for r in res]
            if truth <= limit:
                said += [(r["p"], r["count"] == truth) for r in res if math.isfinite(r.get("p", math.nan))]
            tally = ", ".join(f"{c}: {counts.count(c)}" for c in sorted(set(counts)))
            ps = [r["p"] for r in res if "p" in r and math.isfinite(r["p"])]
            scored = [t for r in res for t in r.get("transmitters", [])]
            ratio = (math.sqrt(statistics.mean(t["error"] ** 2 for t in scored))
                     / math.sqrt(statistics.mean(t["crlb"] ** 2 for t in scored))) if scored else float("nan")
            inside = f"{sum(t['inside'] for t in scored)}/{len(scored)}" if scored else "-"
            print(f"| {name} | {counts.count(truth)}/{len(res)} | {tally} | "
                  f"{statistics.median(ps) if ps else float('nan'):.2f} | {ratio:.2f} | {inside} | "
                  f"{sum(r.get('ghost', False) for r in res)}/{len(res)} | "
                  f"{sum(r.get('offset_said', False) for r in res)}/{len(res)} | "
                  f"{sum(r.get('more_said', False) for r in res)}/{len(res)} | "
                  f"{sum(r.get('channel_ok', False) for r in res)}/{len(res)} | "
                  f"{sum(r.get('confidently_wrong', 0) for r in res)}/{sum(r.get('tracking_places', 0) for r in res)}"
                  " |", flush=True)
    print("\n| count probability | counts said | right |")
    print("|---|---|---|")
    for lo, hi in ((0.0, 0.5), (0.5, 0.7), (0.7, 0.9), (0.9, 0.99), (0.99, 1.01)):
        band = [right for p, right in said if lo <= p < hi]
        share = f"{100 * sum(band) / len(band):.0f} %" if band else "-"
        print(f"| {lo:.2f}-{min(hi, 1.0):.2f} | {len(band)} | {share} |")
    if args.no_cost:
        return
    print("\n| public scenario | s per run, never counted (max 1) | s per run, counted (max 3) | ratio |")
    print("|---|---|---|---|")
    for name in SCENARIOS:
        never, counted = cost(name, 1, 5), cost(name, 3, 5)
        print(f"| {name} | {never:.2f} | {counted:.2f} | {counted / never:.2f} |", flush=True)


if __name__ == "__main__":
    main()
