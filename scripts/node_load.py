"""Many emitters through one node: a vehicle circles a town at 15 m/s while its receiver reports --emitters carriers
at --df-hz each (all channels of a scan share one stamp, as a KrakenSDR's VFOs do) plus 10 Hz GPS, for --seconds,
into a real node process over Fast DDS with its default configuration. Every diagnostics period the node reports
the latency from the arrival of each message that made a pose to that pose's publication (p50, p99, max over the
period, and the p99 since the node started, to 6 %); this script keeps them, samples the resident memory of the
node (and of its check worker process) every 10 s, takes each channel's last emitter/<channel>/fix after the run
against its emitter (the error, and whether the 95 % ellipse holds it), and prints the figures of
docs/benchmarks.md "Many emitters through one node".

    python scripts/node_load.py --emitters 50 --df-hz 20 --seconds 600
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time

import numpy as np
from node_rig import NodeRig
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from aoa_localizer.engine.channels import channel_id
from aoa_localizer.engine.geodesy import LocalFrame
from msgs_adapters import build

DATUM = (39.1, 117.2, 5.0)
RADIUS_M, SPEED = 1000.0, 15.0  # the vehicle's loop


def children(pid: int) -> list[int]:
    """The node's child processes (its check worker)."""
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as fh:
            return [int(c) for c in fh.read().split()]
    except OSError:
        return []


def tree_rss_mb(pid: int) -> float:
    """Resident memory of the node and its worker process (MB)."""
    return rss_mb(pid) + sum(rss_mb(c) for c in children(pid))


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (s)."""
    with open(f"/proc/{pid}/stat") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return round((int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK"), 1)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--emitters", type=int, default=50)
    parser.add_argument("--df-hz", type=float, default=20.0, help="DF records per second per emitter")
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--quality", type=float, default=80.0,
                        help="the records' quality (below the node's quality_min 30: transport cost alone)")
    parser.add_argument("--node-param", action="append", default=[], metavar="NAME:=VALUE",
                        help="a node parameter besides the defaults (repeatable), e.g. num_particles:=50")
    parser.add_argument("--attach", type=int, metavar="PID",
                        help="measure a node already running (e.g. under a profiler) in ROS_DOMAIN_ID, not a new one")
    parser.add_argument("--scan", action="store_true",
                        help="each stamp's records as one scan on df/scan (PointCloud2), not one message each")
    parser.add_argument("--json", help="write the figures here too")
    parser.add_argument("--listen-posteriors", action="store_true",
                        help="subscribe to every channel's emitter/<channel>/posterior (a map client's load)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    angle = rng.uniform(0, 2 * math.pi, args.emitters)
    reach = rng.uniform(200.0, 2500.0, args.emitters)
    emitters = np.column_stack([reach * np.cos(angle), reach * np.sin(angle)])
    freqs = 400e6 + 25e3 * np.arange(args.emitters)
    last: dict = {}
    periods: list[dict] = []
    rss: list = []

    def on_status(values):
        last.clear()
        last.update(values)
        if "pose_latency_p99_ms" in values:
            periods.append(values)

    grids = [0]
    with NodeRig(args.node_param, on_status, args.attach) as rig:
        T, frame = rig.T, LocalFrame(*DATUM)
        if args.listen_posteriors:
            for f in freqs:
                rig.node.create_subscription(T.OccupancyGrid, f"emitter/{channel_id(float(f))}/posterior",
                                             lambda _m: grids.__setitem__(0, grids[0] + 1), 1)
        t0, sent, scans, next_fix, next_rss = time.monotonic(), 0, 0, 0.0, 0.0
        stamp0 = time.time()
        while (t := time.monotonic() - t0) < args.seconds:
            phase = SPEED * t / RADIUS_M
            east, north = RADIUS_M * math.cos(phase), RADIUS_M * math.sin(phase)
            if t >= next_fix:
                lat, lon, alt = frame.to_geodetic(east, north)
                rig.pub_fix.publish(build.navsatfix(T, stamp0 + t, float(lat), float(lon), float(alt)))
                next_fix += 0.1
            if t >= next_rss:
                rss.append((round(t, 1), round(rss_mb(rig.proc.pid), 1), round(tree_rss_mb(rig.proc.pid), 1)))
                next_rss += 10.0
            az = np.degrees(np.arctan2(emitters[:, 0] - east, emitters[:, 1] - north)) + rng.normal(0, 2.0, len(freqs))
            if args.scan:
                rig.pub_scan.publish(build.df_scan(T, stamp0 + t, az % 360, np.full(len(freqs), args.quality), freqs))
            else:
                for a, f in zip(az % 360, freqs, strict=True):
                    rig.pub_df.publish(build.df_record(T, stamp0 + t, float(a), args.quality, float(f)))
            sent += len(freqs)
            scans += 1
            rig.spin_until(t0 + scans / args.df_hz)
        rig.spin_until(time.monotonic() + 3)
        rss.append((round(time.monotonic() - t0, 1), round(rss_mb(rig.proc.pid), 1),
                    round(tree_rss_mb(rig.proc.pid), 1)))
        figures = {"posterior_grids_received": grids[0], "node_cpu_s": cpu_seconds(rig.proc.pid),
                   "worker_cpu_s": round(sum(cpu_seconds(c) for c in children(rig.proc.pid)), 1)}
        figures.update(final_estimates(rig, freqs, emitters, frame))
    figures.update(summarise(args, sent, last, periods, rss))
    print(json.dumps(figures, indent=1))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(figures, fh, indent=1)


def final_estimates(rig: NodeRig, freqs: np.ndarray, emitters: np.ndarray, frame: LocalFrame) -> dict:
    """Each channel's last emitter/<channel>/fix (latched), taken after the run, against its emitter: the error and
    whether the emitter lies inside the fix's 95 % ellipse (its ENU covariance), over the channels that have one."""
    fixes: dict[int, object] = {}
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)
    for k, f in enumerate(freqs):
        rig.node.create_subscription(rig.T.NavSatFix, f"emitter/{channel_id(float(f))}/fix",
                                     lambda m, k=k: fixes.__setitem__(k, m), latched)
    rig.spin_until(time.monotonic() + 5)
    errors, inside = [], 0
    for k, m in fixes.items():
        east, north = frame.to_enu(m.latitude, m.longitude)
        d = np.array([float(east) - emitters[k, 0], float(north) - emitters[k, 1]])
        cov = np.array(m.position_covariance, float).reshape(3, 3)[:2, :2]
        errors.append(float(np.hypot(*d)))
        inside += bool(d @ np.linalg.solve(cov, d) <= 5.991)
    return {"channels_with_estimate": len(fixes), "median_error_m": float(np.median(errors)) if errors else None,
            "inside_95_ellipse": inside}


def summarise(args, sent: int, last: dict, periods: list[dict], rss: list) -> dict:
    p99 = [float(p["pose_latency_p99_ms"]) for p in periods]
    p50 = [float(p["pose_latency_p50_ms"]) for p in periods]
    top = [float(p["pose_latency_max_ms"]) for p in periods]
    poses = sum(int(p["poses_in_period"]) for p in periods)
    warm = [m for t, m, _ in rss if t >= 60.0]  # after the channels and their filters exist
    warm_tree = [m for t, _, m in rss if t >= 60.0]
    return {
        "emitters": args.emitters, "df_hz_each": args.df_hz, "seconds": args.seconds, "scan": args.scan,
        "df_records_sent": sent, "df_records_received": int(last.get("bearings_received", 0)),
        "fixes_received": int(last.get("fixes_received", 0)), "bearings_used": int(last.get("bearings_used", 0)),
        "df_records_shed": int(last.get("records_shed", 0)), "kept_share_at_end": last.get("records_kept_share"),
        "input_messages_missed": int(last.get("input_messages_missed", 0)),
        "rejected": {k: v for k, v in last.items() if k.startswith("rejected.")},
        "poses": poses, "periods": len(periods),
        "latency_p50_ms_median_of_periods": float(np.median(p50)) if p50 else None,
        "latency_p99_ms_worst_period": max(p99) if p99 else None,
        "latency_p99_ms_median_of_periods": float(np.median(p99)) if p99 else None,
        "latency_max_ms": max(top) if top else None,
        "latency_p99_ms_whole_run": float(last["pose_latency_p99_ms_since_start"])
        if "pose_latency_p99_ms_since_start" in last else None,
        "periods_with_p99_over_20ms": sum(v > 20.0 for v in p99),
        "periods_saying_overload": sum("overload" in p for p in periods),
        "periods_saying_messages_lost": sum("messages_lost" in p for p in periods),
        "overload_said_first": next((p["overload"] for p in periods if "overload" in p), None),
        "p99_ms_by_period": [round(v, 1) for v in p99],
        "rss_mb_at_60s": warm[0] if warm else None, "rss_mb_at_end": warm[-1] if warm else None,
        "with_worker_rss_mb_at_60s": warm_tree[0] if warm_tree else None,
        "with_worker_rss_mb_at_end": warm_tree[-1] if warm_tree else None,
        "rss_mb_samples": rss,
        "load_pct_last_period": last.get("load_pct"), "status": last.get("status"),
    }


if __name__ == "__main__":
    main()
