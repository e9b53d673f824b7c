"""Does the node keep up with a fast DF receiver? Publish DF records at --rate Hz (and 10 Hz fixes) from a
vehicle driving past the emitter, for --seconds, into a real node process over Fast DDS; then read the
node's /diagnostics: messages received against sent, callback time, filter updates.

    python scripts/node_throughput.py --rate 200 --seconds 20
"""
from __future__ import annotations

import argparse
import math
import random
import time

from node_rig import NodeRig

from aoa_localizer.engine.geodesy import LocalFrame
from msgs_adapters import build

DATUM = (39.1, 117.2, 5.0)
EMITTER = (300.0, 250.0)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rate", type=float, default=200.0, help="DF records per second")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--particles", type=int, default=100)
    args = parser.parse_args()
    diag: dict = {}
    with NodeRig([f"num_particles:={args.particles}"], on_status=diag.update) as rig:
        T, frame = rig.T, LocalFrame(*DATUM)
        t0, sent, next_fix = time.monotonic(), 0, 0.0
        stamp0 = time.time()
        while (t := time.monotonic() - t0) < args.seconds:
            east, north = 20.0 * t, 0.0  # 20 m/s along the x axis, past the emitter
            if t >= next_fix:
                lat, lon, alt = frame.to_geodetic(east, north)
                rig.pub_fix.publish(build.navsatfix(T, stamp0 + t, float(lat), float(lon), float(alt)))
                next_fix += 0.1
            az = math.degrees(math.atan2(EMITTER[0] - east, EMITTER[1] - north)) % 360
            rig.pub_df.publish(build.df_record(T, stamp0 + t, az + random.gauss(0, 1.0), 90.0))
            sent += 1
            rig.spin_until(t0 + sent / args.rate)
        rig.spin_until(time.monotonic() + 3)
        received = int(diag.get("bearings_received", 0))
        print(f"sent {sent} DF records in {args.seconds:g} s ({sent / args.seconds:.0f}/s); node received {received} "
              f"({100 * received / max(sent, 1):.1f} %); used {diag.get('bearings_used')} in {diag.get('points_used')} "
              f"points; status {diag.get('status')}")
        print(f"callback time in the last diagnostics period: mean {diag.get('callback_mean_ms')} ms, "
              f"max {diag.get('callback_max_ms')} ms; N = {args.particles}")


if __name__ == "__main__":
    main()
