"""A refactor's check: every estimate of 21 seeded configurations (each algorithm, the public scenarios, the
robustness cells, the paper's start, the filters alone, an unknown receiver, two emitters) hashed, so a change meant
to move no arithmetic can show it moved none.

    python scripts/fingerprint.py --json before.json          # on the code before
    python scripts/fingerprint.py --compare before.json       # after: each configuration same or changed

Runs are `scheduling: reproducible` (a seed repeats a run bit for bit); the hash covers each estimate's stamp,
place, covariance, state, warnings, points and bearings used, and the run's robustness events.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from collections.abc import Callable

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.types import Estimate
from aoa_localizer.filters import REGISTRY
from aoa_localizer.simulation.evaluation import feed_fleet, scenario_config
from aoa_localizer.simulation.fleet import simulate_fleet
from aoa_localizer.simulation.scenarios import SCENARIOS, robustness_cells, simulate

Run = Callable[[], tuple[list[Estimate], dict]]


def _scenario(name: str, data_seed: int, **changes) -> Run:
    def run():
        cells = robustness_cells()
        data = simulate(cells[name] if name in cells else SCENARIOS[name], data_seed)
        cfg = scenario_config(data, LocalizerConfig(scheduling="reproducible", seed=7)).with_changes(**changes)
        loc = Localizer(cfg)
        try:
            estimates = [e for e in loc.run(data.inputs()) if e is not None]
            return estimates, dict(loc.view(light=True).events)
        finally:
            loc.close()
    return run


def _two_emitters() -> tuple[list[Estimate], dict]:
    data = simulate_fleet({"car": SCENARIOS["seed"]}, {433.92e6: (1200.0, 800.0), 446.0e6: (400.0, 1100.0)}, 3)
    estimates: list[Estimate] = []
    loc = Localizer(LocalizerConfig(scheduling="reproducible", seed=7), on_estimate=estimates.append)
    try:
        feed_fleet(loc, data)
        loc.flush()
        loc.finish()
        return estimates, dict(loc.view(light=True).events)
    finally:
        loc.close()


def configurations() -> dict[str, Run]:
    runs = {f"seed/{name}": _scenario("seed", 1, algorithm=name) for name in REGISTRY}
    runs |= {f"{name}/afsa": _scenario(name, 2) for name in ("straight", "urban", "homing")}
    runs |= {f"{cell}/afsa": _scenario(cell, 3) for cell in ("wild30", "reflector", "sigma_x4", "quality_nan")}
    runs["seed/triangulation"] = _scenario("seed", 4, init_method="triangulation")
    runs["wild20/filters_alone"] = _scenario("wild20", 5, global_safety=False)
    runs["sigma_x2/noise_unknown"] = _scenario("sigma_x2", 6, noise="unknown")
    runs["urban/paper_variant"] = _scenario("urban", 7, **{"afsa.variant": "paper"})
    runs["seed/afsa_1000"] = _scenario("seed", 8, num_particles=1000)
    runs["fleet/two_emitters"] = _two_emitters
    return runs


def fingerprint(estimates: list[Estimate], events: dict) -> str:
    h = hashlib.sha256()
    for e in estimates:
        h.update(np.array([e.stamp, e.east, e.north, *np.ravel(e.cov), e.points_used, e.bearings_used]).tobytes())
        h.update(f"{e.channel}|{e.state}|{'|'.join(e.warnings)}".encode())
    h.update(json.dumps(sorted(events.items())).encode())
    return h.hexdigest()[:16]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="write {configuration: fingerprint} here")
    ap.add_argument("--compare", help="a --json file of an earlier run: say which configurations changed")
    args = ap.parse_args()
    before = json.loads(open(args.compare).read()) if args.compare else {}
    out, changed = {}, []
    for name, run in configurations().items():
        t0 = time.perf_counter()
        estimates, events = run()
        out[name] = fingerprint(estimates, events)
        final = estimates[-1] if estimates else None
        where = f"E {final.east:8.1f} N {final.north:8.1f}" if final is not None else "no estimate"
        verdict = "" if name not in before else ("same" if before[name] == out[name] else "CHANGED")
        if verdict == "CHANGED":
            changed.append(name)
        print(f"{name:28s} {out[name]}  {len(estimates):4d} estimates  {where}  {time.perf_counter() - t0:5.1f} s  "
              f"{verdict}", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    if args.compare:
        print(f"{len(out) - len(changed)} of {len(out)} the same" + (f"; changed: {', '.join(changed)}" if changed
                                                                      else ""))
    return 1 if changed else 0


if __name__ == "__main__":
    sys.exit(main())
