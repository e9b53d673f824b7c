"""The engine alone on scripts/node_load.py's stream (a vehicle circling at 15 m/s, --emitters carriers at 20 Hz, all
channels of a scan at one stamp, 10 Hz GPS), fed as fast as it goes through the Python API with `scheduling:
realtime` (its check worker in a process of its own, as the node's): the resident memory and the time taken every
50 s of stream, to show what a channel keeps and when that stops growing (docs/benchmarks.md).

    python scripts/engine_memory.py --emitters 250 --seconds 400
"""
from __future__ import annotations

import argparse
import logging
import math
import time

import numpy as np

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.scheduling.memory import settle_process

DATUM = (39.1, 117.2, 5.0)
RADIUS_M, SPEED, DF_HZ = 1000.0, 15.0, 20.0


def rss_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return math.nan


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--emitters", type=int, default=250)
    parser.add_argument("--seconds", type=float, default=400.0, help="stream time")
    args = parser.parse_args()
    settle_process()
    logging.getLogger("aoa_localizer").setLevel(logging.ERROR)
    rng = np.random.default_rng(0)  # node_load.py's emitters
    angle = rng.uniform(0, 2 * math.pi, args.emitters)
    reach = rng.uniform(200.0, 2500.0, args.emitters)
    emitters = np.column_stack([reach * np.cos(angle), reach * np.sin(angle)])
    freqs = 400e6 + 25e3 * np.arange(args.emitters)
    frame = LocalFrame(*DATUM)
    loc = Localizer(LocalizerConfig(max_channels=max(64, args.emitters + 1), scheduling="realtime"), live=True,
                    datum=frame)
    stamp0, scans, fixes = 1.7e9, 0, 0
    wall0, cpu0 = time.perf_counter(), time.process_time()
    print(f"stream s | wall s | CPU s | RSS MB   ({args.emitters} channels at {DF_HZ:g} Hz)")
    try:
        while (t := scans / DF_HZ) < args.seconds:
            east, north = RADIUS_M * math.cos(SPEED * t / RADIUS_M), RADIUS_M * math.sin(SPEED * t / RADIUS_M)
            if t >= fixes / 10.0:
                lat, lon, alt = frame.to_geodetic(east, north)
                loc.add_fix(stamp0 + t, float(lat), float(lon), float(alt))
                fixes += 1
            az = np.degrees(np.arctan2(emitters[:, 0] - east, emitters[:, 1] - north))
            az = (az + rng.normal(0, 2.0, args.emitters)) % 360
            for a, f in zip(az.tolist(), freqs.tolist(), strict=True):
                loc.add_bearing(stamp0 + t, a, 80.0, "", f)
            loc.idle()
            scans += 1
            if scans % int(50 * DF_HZ) == 0:
                print(f"{scans / DF_HZ:8.0f} | {time.perf_counter() - wall0:6.1f} | {time.process_time() - cpu0:5.1f} "
                      f"| {rss_mb():6.0f}", flush=True)
    finally:
        loc.close()


if __name__ == "__main__":
    main()
