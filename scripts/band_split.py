"""Two localizers over adjacent bands (`frequency_band_hz`) share one receiver's records of 50 emitters, as two nodes
would: is every emitter localised exactly once, and how far from its CRLB?

    python scripts/band_split.py [--emitters 50] [--seed 0]

Each channel draws from its own generator (seed and channel id), so a band's run gives each emitter the estimate a
single localizer over the whole spectrum gives it; what the split adds is only who takes which record.
"""
from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace

import numpy as np

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.engine.channels import channel_id
from aoa_localizer.engine.crlb import crlb_rmse
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.simulation.evaluation import feed_fleet
from aoa_localizer.simulation.fleet import simulate_fleet
from aoa_localizer.simulation.scenarios import SCENARIOS, simulate

SPACING_HZ = 25e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--emitters", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated data")
    args = parser.parse_args()
    rng = np.random.default_rng(7)
    emitters = {400e6 + SPACING_HZ * k: (float(rng.uniform(300, 1800)), float(rng.uniform(300, 1300)))
                for k in range(args.emitters)}
    scenario = SCENARIOS["seed"]
    fleet = simulate_fleet({"": scenario}, emitters, args.seed)
    split = 400e6 + SPACING_HZ * (args.emitters // 2)
    found: dict[str, list] = {}
    t0 = time.perf_counter()
    for band in ([400e6, split], [split, 400e6 + SPACING_HZ * (args.emitters + 1)]):
        loc = Localizer(LocalizerConfig(seed=1, frequency_band_hz=band))
        feed_fleet(loc, fleet)
        loc.flush()
        loc.finish()
        for channel in loc.view().channels:
            if channel.estimate is not None:
                found.setdefault(channel.id, []).append(channel.estimate)
    wall = time.perf_counter() - t0
    frame = LocalFrame(*fleet.scenario.datum)
    ratios = []
    for k, (f, truth) in enumerate(emitters.items()):
        (est,) = found[channel_id(f)]
        e, n = frame.to_enu(est.lat, est.lon)
        # the emitter's own bearings, as simulate_fleet drew them (same seed), give its bound
        data = simulate(replace(scenario, emitter=truth, datum=fleet.scenario.datum), args.seed * 1000 + k)
        bound = crlb_rmse(np.array(truth), data.sensor_enu[~data.wild], data.sigma[~data.wild])
        ratios.append(math.hypot(e - truth[0], n - truth[1]) / bound)
    r = np.array(ratios)
    once = len(found) == len(emitters) and all(len(v) == 1 for v in found.values())
    print(f"{len(emitters)} emitters over 2 bands: each localised exactly once: {once}; {wall:.1f} s")
    print(f"error / CRLB: RMS {math.sqrt(np.mean(r ** 2)):.2f}, median {np.median(r):.2f}, max {r.max():.2f}, "
          f"share <= 1.5: {np.mean(r <= 1.5):.2f}")


if __name__ == "__main__":
    main()
