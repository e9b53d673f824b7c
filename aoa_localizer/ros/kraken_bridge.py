"""KrakenSDR bridge (`kraken_bridge`): polls the Kraken App output of krakensdr_doa and publishes DF records.

    python -m aoa_localizer.kraken_bridge --url http://HOST:8081/DOA_value.html --gps [--record DIR] [--ros-args -r ...]

Each new line (one per VFO) becomes a DF record on `df/bearing` (geometry_msgs/Vector3Stamped): the stamp at the
middle of the acquisition interval, `vector.x` the azimuth, `vector.y` a quality from the confidence (40 at
`--conf-low` dB, 100 at `--conf-high`), `vector.z` the VFO frequency (Hz). With `--scan`, the lines of one
acquisition (all VFOs) go out as one scan on `df/scan` (sensor_msgs/PointCloud2, fields azimuth_deg, quality,
frequency_hz) instead: one message per acquisition, whatever the number of VFOs. With `--gps`, the line's position goes
out on `gps/fix` too (NavSatFix, skipped while the receiver has no fix).

Azimuths: the Kraken App line gives the DoA clockwise from the array's zero, not turned by any heading.
`--azimuth true` (default) adds the line's heading (the receiver's GPS track), so the azimuths are from true
north and the node's default `bearing_reference: true_north` agrees; lines without a GPS fix are then skipped
(their heading is 0, not a heading). `--azimuth relative` publishes the array-relative DoA: run the node with
`bearing_reference:=vehicle` (and its `mount_offset_deg`, `heading_source`).

Lines that repeat (the page holds a line until the next CPI), go backwards or are malformed are counted and
skipped, never fatal. Each poll is bounded (`--timeout` for the whole answer, `--max-bytes` of page; a redirect is
refused with its target): a dead, slow or hostile server is retried every second with one log line per outage.
The lines of one CPI (one per VFO) share their GPS position, which goes out on `gps/fix` once. While every line is
skipped for want of a GPS heading, a warning says so every 30 s. `--record DIR` records every topic of the graph
(the bridge's records and fixes, and a node's outputs if one runs) into a rosbag2 MCAP bag, for `replay --offline`
and `report` afterwards (docs/kraken_drive.md). Exit 0 on Ctrl-C or SIGTERM (within a second, whatever the server
does), with the counts; 2 for bad options.
"""
from __future__ import annotations

import argparse
import itertools
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import rclpy
from rclpy.node import Node

from aoa_localizer.common.http_poll import DEFAULT_MAX_BYTES, PollFailed, http_get
from aoa_localizer.common.kraken_csv import KrakenLine, LineFilter, MalformedLine, parse_line, quality_from_confidence
from aoa_localizer.common.output import check_folder
from aoa_localizer.engine.geodesy import wrap_360
from aoa_localizer.ros.ros_main import Stop, run_node
from msgs_adapters import build

RETRY_S = 1.0
TIMEOUT_MAX_S = 60.0
SKIPPED_SAY_EVERY_S = 30.0  # while every line is skipped for want of a GPS heading, say so this often


def parse_args(argv) -> argparse.Namespace:
    own = list(argv[1:] if argv else sys.argv[1:])
    own = own[: own.index("--ros-args")] if "--ros-args" in own else own
    parser = argparse.ArgumentParser(prog="python -m aoa_localizer.kraken_bridge", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--url", required=True, help="the Kraken App page, e.g. http://192.168.1.10:8081/DOA_value.html")
    parser.add_argument("--rate", type=float, default=10.0, help="polls per second (default 10)")
    parser.add_argument("--gps", action="store_true", help="also publish the lines' positions on gps/fix")
    parser.add_argument("--scan", action="store_true",
                        help="publish the VFO lines of one acquisition as one scan on df/scan (PointCloud2), not a "
                             "df/bearing record each")
    parser.add_argument("--azimuth", choices=("true", "relative"), default="true",
                        help="true: add the line's heading (default); relative: the array-relative DoA")
    parser.add_argument("--conf-low", type=float, default=1.0, help="confidence (dB) mapped to quality 40 (default 1)")
    parser.add_argument("--conf-high", type=float, default=10.0,
                        help="confidence (dB) mapped to quality 100 (default 10)")
    parser.add_argument("--timeout", type=float, default=2.0,
                        help=f"the longest a whole poll may take, s (default 2, at most {TIMEOUT_MAX_S:g})")
    parser.add_argument("--max-bytes", type=int, default=DEFAULT_MAX_BYTES,
                        help=f"the largest page taken, bytes (default {DEFAULT_MAX_BYTES}); a larger one is skipped")
    parser.add_argument("--record", metavar="DIR", help="record every topic into this rosbag2 MCAP bag directory (it "
                        "must not exist yet)")
    args = parser.parse_args(own)
    if args.record is not None:
        try:
            check_folder(Path(args.record), "--record", new=True)  # exists, under a file, /proc: before the graph
        except ValueError as exc:
            parser.error(str(exc))
    if not args.url.startswith(("http://", "https://")):
        parser.error(f"--url must be an http(s) address, got {args.url!r}")
    if not (0 < args.rate <= 1000 and 0 < args.timeout <= TIMEOUT_MAX_S and 1024 <= args.max_bytes <= 2**30):
        parser.error(f"--rate must be in (0, 1000], --timeout in (0, {TIMEOUT_MAX_S:g}], --max-bytes in [1024, 2^30]")
    if not args.conf_high > args.conf_low:
        parser.error("--conf-high must be > --conf-low")
    return args


class KrakenBridge(Node):
    """Polls the page, turns new lines into DF records (and fixes), counts what it skips."""

    def __init__(self, args: argparse.Namespace):
        super().__init__("kraken_bridge")
        self.args = args
        self.T = build.rclpy_types()
        self.pub_df = self.create_publisher(self.T.Vector3Stamped, "df/bearing", 100)
        self.pub_scan = self.create_publisher(self.T.PointCloud2, "df/scan", 100) if args.scan else None
        self.scan: list[tuple] = []  # with --scan, this poll's readings: (stamp, frame, azimuth, quality, Hz)
        self.pub_fix = self.create_publisher(self.T.NavSatFix, "gps/fix", 100) if args.gps else None
        self.filter = LineFilter()
        self.counts: Counter = Counter()
        self.down_since: float | None = None
        self.last_fix_stamp = -float("inf")  # the lines of one CPI repeat its position: one fix each
        self.skipped_said = time.monotonic()
        self.counts_said = (0, 0)  # (no_gps_heading, published) when the skipped lines were last looked at
        self.stop = Stop()  # run()'s, from run_node: SIGINT or SIGTERM
        self.recorder = None
        if args.record is not None:
            from msgs_adapters.recorder import BagRecorder

            self.recorder = BagRecorder(self, args.record)
            self.recorder.poll()  # its own topics, before the first line
        self.get_logger().info(
            f"polling {args.url} at {args.rate:g} Hz; publishing "
            + ("azimuths from true north (DoA + the line's heading)" if args.azimuth == "true"
               else "array-relative azimuths: run the node with bearing_reference:=vehicle")
        )

    def fetch(self) -> str | None:
        """The page's text, or None while the server is unreachable (one log line per outage)."""
        try:
            text = http_get(self.args.url, self.args.timeout, self.args.max_bytes, lambda: self.stop.requested)
        except PollFailed as exc:
            if self.stop.requested:
                return None
            if self.down_since is None:
                self.down_since = time.monotonic()
                self.get_logger().warning(f"cannot read {self.args.url} ({exc}); retrying every {RETRY_S:g} s")
            self.counts["poll_failed"] += 1
            return None
        if self.down_since is not None:
            self.get_logger().info(f"{self.args.url} answers again after {time.monotonic() - self.down_since:.0f} s")
            self.down_since = None
        return text

    def take(self, text: str):
        for line in text.splitlines():
            if not line.strip():
                continue
            try:
                r = parse_line(line)
            except MalformedLine as exc:
                if not self.counts["malformed"]:
                    self.get_logger().warning(f"malformed line skipped ({exc}); further ones are counted")
                self.counts["malformed"] += 1
                continue
            if self.filter.fresh(r):
                self.publish(r)
        self._publish_scans()
        self._say_skipped()

    def _say_skipped(self):
        """Every line skipped for want of a GPS heading since the last word: say so (not only at exit)."""
        now = time.monotonic()
        if now - self.skipped_said < SKIPPED_SAY_EVERY_S:
            return
        no_gps, published = self.counts["no_gps_heading"], self.counts["published"]
        skipped = no_gps - self.counts_said[0]
        if skipped and published == self.counts_said[1]:
            self.get_logger().warning(
                f"{skipped} lines in the last {now - self.skipped_said:.0f} s skipped and none published: the "
                "receiver has no GPS fix, so its lines carry no heading (--azimuth true); "
                "give it GPS, or use --azimuth relative with the node's bearing_reference:=vehicle")
        self.skipped_said, self.counts_said = now, (no_gps, published)

    def publish(self, r: KrakenLine):
        if self.args.azimuth == "true" and not r.has_gps:
            self.counts["no_gps_heading"] += 1
            return
        azimuth = r.doa_deg + (r.heading_deg if self.args.azimuth == "true" else 0.0)
        quality = quality_from_confidence(r.confidence_db, self.args.conf_low, self.args.conf_high)
        if self.pub_fix is not None and r.has_gps and r.stamp > self.last_fix_stamp:
            self.last_fix_stamp = r.stamp
            self.pub_fix.publish(build.navsatfix(self.T, r.stamp, r.lat, r.lon, 0.0, frame_id="gps"))
        frame = r.station or "df_antenna"
        if self.pub_scan is not None:
            self.scan.append((r.stamp, frame, float(wrap_360(azimuth)), quality, r.frequency_hz))
        else:
            self.pub_df.publish(build.df_record(self.T, r.stamp, float(wrap_360(azimuth)), quality, r.frequency_hz,
                                                frame_id=frame))
        self.counts["published"] += 1

    def _publish_scans(self):
        """With --scan, the poll's readings as one scan per acquisition (stamp and receiver)."""
        if self.pub_scan is None or not self.scan:
            return
        for (stamp, frame), rows in itertools.groupby(self.scan, key=lambda x: x[:2]):
            values = np.array([x[2:] for x in rows], float)
            self.pub_scan.publish(build.df_scan(self.T, stamp, values[:, 0], values[:, 1], values[:, 2],
                                                frame_id=frame))
            self.counts["scans"] += 1
        self.scan = []

    def run(self, stop: Stop):
        self.stop = stop
        period = 1.0 / self.args.rate
        while not self.stop.requested:
            t0 = time.monotonic()
            if self.recorder is not None:
                self.recorder.poll()  # topics that appeared since (a node's outputs)
            text = self.fetch()
            if text is not None and not self.stop.requested:
                self.take(text)
            wait = (RETRY_S if text is None else period) - (time.monotonic() - t0)
            rclpy.spin_once(self, timeout_sec=max(min(wait, 0.1), 0.0))
            while not self.stop.requested and time.monotonic() - t0 < (RETRY_S if text is None else period):
                rclpy.spin_once(self, timeout_sec=0.05)

    def destroy_node(self):
        counts = dict(self.counts, **{k: v for k, v in self.filter.dropped.items() if v})
        if self.recorder is not None:
            self.recorder.close()
            counts["recorded"] = self.recorder.count
            if self.recorder.failed:
                print(f"kraken_bridge: recording stopped: {self.recorder.failed}", file=sys.stderr, flush=True)
        print("kraken_bridge: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()) if v), file=sys.stderr,
              flush=True)
        return super().destroy_node()


def main(argv=None) -> int:
    args = parse_args(argv)
    return run_node("kraken_bridge", lambda: KrakenBridge(args), KrakenBridge.run, (ValueError,), argv, __doc__)


if __name__ == "__main__":
    sys.exit(main())
