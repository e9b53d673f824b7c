"""The simulated monitoring vehicle (`sim_vehicle`): plays a scenario onto gps/fix, df/bearing and sim/truth.

    python -m aoa_localizer.sim_vehicle --ros-args -p scenario:=urban -p speedup:=10.0

Parameters pick a public scenario (BENCHMARKS.md) and override any part of it: track, speed,
emitter, datum, GPS rate/noise/drop-outs, DF rate, bearing noise, quality range, wild-bearing share,
the data seed. Messages are paced in real time divided by `speedup` (0: as fast as `max_rate_hz`
allows); header stamps follow the simulated clock, starting at the wall time of the start. The
truth goes out latched on `sim/truth` (PointStamped, emitter in `map` at the scenario's datum) and
`sim/datum` (NavSatFix of that datum). The node exits when the scenario is played.
"""
from __future__ import annotations

import dataclasses
import math
import sys
import time

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from msgs_adapters import build

from aoa_localizer.ros.ros_main import run_node
from aoa_localizer.engine.scenarios import SCENARIOS, simulate

# Scenario fields a parameter may override (unset: the scenario's own value).
OVERRIDES = {
    "emitter_east": "emitter east (m, map)", "emitter_north": "emitter north (m, map)",
    "track": "track polyline as a flat list e0, n0, e1, n1, ... (m, map)",
    "speed": "vehicle speed (m/s)", "points": "observation points (stop-and-go); 0: drive without stopping",
    "readings_per_point": "DF readings per observation point", "quality_low": "lowest DF quality",
    "quality_high": "highest DF quality", "sigma_deg": "bearing noise (deg), constant",
    "wild_share": "share of wild (multipath) bearings", "gps_rate_hz": "GPS rate (Hz)",
    "gps_noise_m": "GPS noise per axis (m)", "gps_dropout_prob": "share of GPS fixes lost",
    "df_rate_hz": "DF rate (Hz)", "datum_lat": "datum latitude (deg)", "datum_lon": "datum longitude (deg)",
    "datum_alt": "datum altitude (m)",
}


def scenario_from(name: str, o: dict):
    """The named scenario with the set overrides applied."""
    sc = SCENARIOS[name]
    changes = {}
    if o.get("emitter_east") is not None or o.get("emitter_north") is not None:
        changes["emitter"] = (float(o.get("emitter_east") if o.get("emitter_east") is not None else sc.emitter[0]),
                              float(o.get("emitter_north") if o.get("emitter_north") is not None else sc.emitter[1]))
    if o.get("track") is not None:
        flat = [float(v) for v in o["track"]]
        if len(flat) < 4 or len(flat) % 2:
            raise ValueError("track needs an even number of values (e, n pairs), at least two points")
        changes["track"] = tuple(zip(flat[::2], flat[1::2]))
    for key in ("speed", "points", "readings_per_point", "wild_share", "gps_rate_hz", "gps_noise_m",
                "gps_dropout_prob", "df_rate_hz"):
        if o.get(key) is not None:
            changes[key] = o[key]
    if o.get("quality_low") is not None or o.get("quality_high") is not None:
        changes["quality"] = tuple(float(o[k]) if o.get(k) is not None else q
                                   for k, q in zip(("quality_low", "quality_high"), sc.quality))
    if o.get("sigma_deg") is not None:
        changes.update(sigma_rad=math.radians(o["sigma_deg"]), sigma_q_deg=None)
    if any(o.get(k) is not None for k in ("datum_lat", "datum_lon", "datum_alt")):
        changes["datum"] = tuple(float(o[k]) if o.get(k) is not None else d
                                 for k, d in zip(("datum_lat", "datum_lon", "datum_alt"), sc.datum))
    return dataclasses.replace(sc, **changes)


class SimVehicle(Node):
    """Publishes one simulated run, paced by the simulated clock."""

    def __init__(self):
        super().__init__("sim_vehicle")
        p = lambda name, default, text: self.declare_parameter(  # noqa: E731
            name, default, ParameterDescriptor(description=text, dynamic_typing=default is None)).value
        self.scenario_name = p("scenario", "seed", f"public scenario: {', '.join(SCENARIOS)}")
        self.data_seed = p("data_seed", 0, "seed of the simulated data")
        self.speedup = p("speedup", 1.0, "simulated seconds per wall second; 0: as fast as max_rate_hz")
        self.max_rate_hz = p("max_rate_hz", 400.0, "message rate cap when speedup is 0")
        self.duration_s = p("duration_s", 0.0, "stop after this much simulated time (0: the whole scenario)")
        self.encoding = p("bearing_encoding", "df_record", "df_record (Vector3Stamped) or pose (PoseWithCovarianceStamped)")
        self.wait_for = p("wait_for_subscribers", 1, "play once gps/fix and df/bearing each have this many subscribers")
        self.start_timeout_s = p("start_timeout_s", 10.0, "play anyway after waiting this long for subscribers (s)")
        self.start_delay_s = p("start_delay_s", 0.5, "pause after the subscribers are there (s), for matching to settle")
        overrides = {k: p(k, None, text) for k, text in OVERRIDES.items()}
        if self.scenario_name not in SCENARIOS:
            raise ValueError(f"scenario must be one of {', '.join(SCENARIOS)}, got {self.scenario_name!r}")
        if self.encoding not in ("df_record", "pose"):
            raise ValueError(f"bearing_encoding must be df_record or pose, got {self.encoding!r}")
        self.data = simulate(scenario_from(self.scenario_name, overrides), self.data_seed)
        self.T = build.rclpy_types()
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_fix = self.create_publisher(self.T.NavSatFix, "gps/fix", 100)
        bearing_type = self.T.Vector3Stamped if self.encoding == "df_record" else self.T.PoseWithCovarianceStamped
        self.pub_bearing = self.create_publisher(bearing_type, "df/bearing", 100)
        self.pub_truth = self.create_publisher(self.T.PointStamped, "sim/truth", latched)
        self.pub_datum = self.create_publisher(self.T.NavSatFix, "sim/datum", latched)

    def play(self):
        """Publish the run; returns when it is played (or the duration is reached)."""
        d, T = self.data, self.T
        deadline = time.monotonic() + self.start_timeout_s
        while time.monotonic() < deadline and rclpy.ok() and min(
                self.pub_fix.get_subscription_count(), self.pub_bearing.get_subscription_count()) < self.wait_for:
            time.sleep(0.05)
        time.sleep(self.start_delay_s)
        base = time.time()
        self.pub_datum.publish(build.navsatfix(T, base, *d.scenario.datum, frame_id="map"))
        self.pub_truth.publish(build.point_stamped(T, base, *d.emitter_enu))
        sigma_of = dict(zip(d.bearings[:, 0].tolist(), d.sigma.tolist()))
        events = d.events()
        end = events[-1][1][0] if not self.duration_s else min(events[-1][1][0], self.duration_s)
        self.get_logger().info(f"playing {self.scenario_name}: {len(d.fixes)} fixes, {len(d.bearings)} DF readings, "
                               f"{end:.0f} s simulated at speed-up {self.speedup:g}")
        t_wall0, next_log = time.monotonic(), 0.0
        for kind, row in events:
            t = row[0]
            if t > end or not rclpy.ok():
                break
            if self.speedup > 0:
                delay = t_wall0 + t / self.speedup - time.monotonic()
            else:
                delay = 1.0 / self.max_rate_hz
            if delay > 0:
                time.sleep(delay)
            if kind == "fix":
                self.pub_fix.publish(build.navsatfix(T, base + t, row[1], row[2], row[3]))
            elif self.encoding == "df_record":
                self.pub_bearing.publish(build.df_record(T, base + t, row[1], row[2]))
            else:
                yaw = math.radians(90.0 - row[1])
                self.pub_bearing.publish(build.pose_bearing(T, base + t, yaw, sigma_of[t] ** 2))
            if t >= next_log:
                self.get_logger().info(f"t = {t:.0f} s")
                next_log += 30.0
        time.sleep(0.5)  # let the last messages leave
        self.get_logger().info("scenario played")


def main(argv=None) -> int:
    return run_node("sim_vehicle", SimVehicle, SimVehicle.play, (ValueError, TypeError), argv)


if __name__ == "__main__":
    sys.exit(main())
