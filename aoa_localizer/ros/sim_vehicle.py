"""The simulated monitoring vehicle (`sim_vehicle`): plays a scenario onto gps/fix, df/bearing and sim/truth.

    python -m aoa_localizer.sim_vehicle --ros-args -p scenario:=urban -p speedup:=10.0

Parameters pick a public scenario (docs/benchmarks.md) and override any part of it: track, speed, emitter, datum,
GPS rate/noise/drop-outs, DF rate, bearing noise, quality range, wild-bearing share, the data seed. Messages are
paced in real time divided by `speedup` (0: as fast as `max_rate_hz` allows); header stamps follow the simulated
clock, starting at the wall time of the start. The truth goes out latched on `sim/truth` (PointStamped, emitter in
`map`) and `sim/datum` (NavSatFix of the datum `map` is at): the scenario's, then the node's once it publishes
emitter/datum, so the graph has one map frame. The node exits when the scenario is played. A scenario with several
stations (`pair`: two cars) plays each on NAME/gps/fix and NAME/df/bearing; overrides apply to single-vehicle
scenarios only. With `drive:=goal` the vehicle drives its track until the localizer publishes `emitter/next_goal`,
then towards the newest goal, stop by stop (simulation/goal_drive.py), for `duration_s` or as long as its scenario.
"""
from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from aoa_localizer.core.spec import ConfigError, ParameterSpec, Spec
from aoa_localizer.engine.channels import channel_id
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.ros.declare import declare, refuse_unknown
from aoa_localizer.ros.ros_main import Stop, run_node
from aoa_localizer.simulation.fleet import FLEETS, Fleet, simulate_fleet
from aoa_localizer.simulation.goal_drive import GoalDrive
from aoa_localizer.simulation.scenarios import (
    SCENARIOS,
    Trajectory,
    emitter_trajectory,
    mounted,
    moving_cells,
    simulate,
)
from msgs_adapters import build

HISTORY_DEPTH = 2000  # messages a publisher keeps for a reliable reader's resend: seconds of a fast play


def _number(doc: str, kind: type = float, **bounds) -> Spec:
    return Spec(doc, kind, optional=True, **bounds)


# Scenario fields a parameter may override (unset: the scenario's own value).
OVERRIDES = [
    ParameterSpec("emitter_east", None, _number("emitter east (m, map)")),
    ParameterSpec("emitter_north", None, _number("emitter north (m, map)")),
    ParameterSpec("track", None, Spec("track polyline as a flat list e0, n0, e1, n1, ... (m, map)", list,
                                      optional=True)),
    ParameterSpec("emitters", None, Spec("transmitters instead of the scenario's one, as a flat list f0, e0, n0, f1, "
                                         "... (frequency Hz > 0, east and north m in map): each on its frequency, "
                                         "a channel each", list, optional=True)),
    ParameterSpec("co_channel", None, Spec("more transmitters on the emitter's frequency, as a flat list e0, n0, e1, "
                                           "n1, ... (m, map), taking turns with it in 5-30 s push-to-talk bursts "
                                           "at equal air time (co-channel; azimuths from true north)", list,
                                           optional=True)),
    ParameterSpec("speed", None, _number("vehicle speed (m/s)", low=0.0, low_open=True, high=100.0)),
    ParameterSpec("points", None, _number("observation points (stop-and-go); 0: drive without stopping", int,
                                          low=0, high=100_000)),
    ParameterSpec("readings_per_point", None, _number("DF readings per observation point", int, low=1,
                                                      high=10_000)),
    ParameterSpec("quality_low", None, _number("lowest DF quality", low=0.0, high=100.0)),
    ParameterSpec("quality_high", None, _number("highest DF quality", low=0.0, high=100.0)),
    ParameterSpec("sigma_deg", None, _number("bearing noise (deg), constant", low=0.0, high=180.0)),
    ParameterSpec("wild_share", None, _number("share of wild (multipath) bearings", low=0.0, high=1.0)),
    ParameterSpec("gps_rate_hz", None, _number("GPS rate (Hz)", low=0.0, low_open=True, high=1000.0)),
    ParameterSpec("gps_noise_m", None, _number("GPS noise per axis (m)", low=0.0, high=10_000.0)),
    ParameterSpec("gps_dropout_prob", None, _number("share of GPS fixes lost", low=0.0, high=1.0, high_open=True)),
    ParameterSpec("df_rate_hz", None, _number("DF rate (Hz)", low=0.0, low_open=True, high=10_000.0)),
    ParameterSpec("mount_offset_deg", None, _number("publish azimuths from the vehicle's forward axis, the DF "
                                                    "array's zero this far clockwise from it (deg; unset: azimuths "
                                                    "from true north); every station of a fleet", low=-360.0,
                                                    high=360.0)),
    ParameterSpec("datum_lat", None, _number("datum latitude (deg)", low=-89.0, high=89.0)),
    ParameterSpec("datum_lon", None, _number("datum longitude (deg)", low=-180.0, high=180.0)),
    ParameterSpec("datum_alt", None, _number("datum altitude (m)", low=-1000.0, high=10_000.0)),
]

# The vehicle's own settings besides the scenario overrides.
SETTINGS = [
    ParameterSpec("scenario", "seed", Spec("public scenario (`pair`: two stations), or a transmitter that moves "
                                           "(walker, car, drone, stand_walk_stand: sim/truth follows it)", str,
                                           choices=tuple(SCENARIOS) + tuple(FLEETS) + tuple(moving_cells()))),
    ParameterSpec("drive", "track", Spec("`track`: the scenario's track; `goal`: its track until the localizer "
                                         "publishes emitter/next_goal, then towards the newest goal (a stop-and-go "
                                         "single-vehicle scenario)", str, choices=("track", "goal"))),
    ParameterSpec("data_seed", 0, Spec("seed of the simulated data", int, low=0)),
    ParameterSpec("speedup", 1.0, Spec("simulated seconds per wall second; 0: as fast as max_rate_hz", float,
                                       low=0.0)),
    ParameterSpec("max_rate_hz", 400.0, Spec("message rate cap when speedup is 0", float, low=0.0, low_open=True)),
    ParameterSpec("duration_s", 0.0, Spec("stop after this much simulated time (0: the whole scenario)", float,
                                          low=0.0)),
    ParameterSpec("bearing_encoding", "df_record", Spec("df_record (Vector3Stamped) or pose "
                                                        "(PoseWithCovarianceStamped) on df/bearing, or scan: the "
                                                        "readings of one stamp as one PointCloud2 on df/scan", str,
                                                        choices=("df_record", "pose", "scan"))),
    ParameterSpec("wait_for_subscribers", 1, Spec("play once gps/fix and df/bearing each have this many "
                                                  "subscribers", int, low=0)),
    ParameterSpec("start_timeout_s", 10.0, Spec("play anyway after waiting this long for subscribers (s)", float,
                                                low=0.0)),
    ParameterSpec("start_delay_s", 0.5, Spec("pause after the subscribers are there (s), for matching to settle",
                                             float, low=0.0)),
]
VEHICLE_SPECS = {p.name: p for p in SETTINGS + OVERRIDES}


def scenario_from(name: str, o: dict):
    """The named scenario with the set overrides applied."""
    sc = SCENARIOS[name] if name in SCENARIOS else moving_cells()[name]
    changes: dict[str, Any] = {}

    def given(key: str, default: float) -> float:
        return float(o[key]) if o.get(key) is not None else default

    if o.get("emitter_east") is not None or o.get("emitter_north") is not None:
        changes["emitter"] = (given("emitter_east", sc.emitter[0]), given("emitter_north", sc.emitter[1]))
    if o.get("track") is not None:
        flat = [float(v) for v in o["track"]]
        if len(flat) < 4 or len(flat) % 2:
            raise ValueError("track needs an even number of values (e, n pairs), at least two points")
        changes["track"] = tuple(zip(flat[::2], flat[1::2], strict=False))
    if o.get("co_channel") is not None:
        flat = [float(v) for v in o["co_channel"]]
        if not flat or len(flat) % 2 or not all(math.isfinite(v) for v in flat):
            raise ValueError("co_channel needs finite e, n pairs (e0, n0, e1, n1, ...)")
        changes["co_channel"] = tuple(zip(flat[::2], flat[1::2], strict=False))
    for key in ("speed", "points", "readings_per_point", "wild_share", "gps_rate_hz", "gps_noise_m",
                "gps_dropout_prob", "df_rate_hz"):
        if o.get(key) is not None:
            changes[key] = o[key]
    if o.get("quality_low") is not None or o.get("quality_high") is not None:
        changes["quality"] = (given("quality_low", sc.quality[0]), given("quality_high", sc.quality[1]))
    if o.get("sigma_deg") is not None:
        changes.update(sigma_rad=math.radians(o["sigma_deg"]), sigma_q_deg=None)
    if any(o.get(k) is not None for k in ("datum_lat", "datum_lon", "datum_alt")):
        changes["datum"] = (given("datum_lat", sc.datum[0]), given("datum_lon", sc.datum[1]),
                            given("datum_alt", sc.datum[2]))
    return dataclasses.replace(sc, **changes)


def emitters_from(flat: list) -> dict[float, tuple[float, float]]:
    """The `emitters` parameter (f0, e0, n0, f1, ...) by frequency; ValueError when it is not such triples."""
    values = [float(v) for v in flat]
    if not values or len(values) % 3:
        raise ValueError("emitters needs frequency, east, north triples (f0, e0, n0, f1, ...)")
    triples = list(zip(values[::3], values[1::3], values[2::3], strict=True))
    if any(not (f > 0 and math.isfinite(f) and math.isfinite(e) and math.isfinite(n)) for f, e, n in triples):
        raise ValueError("emitters: each frequency must be > 0 Hz and each place finite")
    return {f: (e, n) for f, e, n in triples}


class SimVehicle(Node):
    """Publishes one simulated run, paced by the simulated clock."""

    def __init__(self):
        super().__init__("sim_vehicle")
        self.stop = Stop()  # play()'s, from run_node: SIGINT or SIGTERM
        self.sigma_rad = 0.0
        s = declare(self, SETTINGS)  # raises ConfigError: refused at start with the reason
        overrides = declare(self, OVERRIDES)
        refuse_unknown(self)
        self.scenario_name, self.data_seed, self.speedup = s["scenario"], s["data_seed"], s["speedup"]
        self.max_rate_hz, self.duration_s, self.encoding = s["max_rate_hz"], s["duration_s"], s["bearing_encoding"]
        self.wait_for, self.start_timeout_s = s["wait_for_subscribers"], s["start_timeout_s"]
        self.start_delay_s = s["start_delay_s"]
        self.T = build.rclpy_types()
        self.goal: tuple[float, float] | None = None  # the newest emitter/next_goal, in the scenario's frame
        self.node_datum: LocalFrame | None = None
        self.counts: tuple[int, int] | None = None  # fixes and DF readings of a run made ahead (drive:=track)
        self.sigma_of: dict[float, float] = {}  # each bearing's noise by its stamp, for the pose encoding
        self.goal_end_s = 0.0
        self.truths: dict[str, np.ndarray] = {}  # with several transmitters, each one's by its channel
        self.path: Trajectory | None = None  # a moving transmitter's (sim/truth follows it at each fix)
        self.stations = self._goal_drive(overrides) if s["drive"] == "goal" else self._simulate(overrides)
        latched = QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
        )
        bearing_type, bearing_topic = {"df_record": (self.T.Vector3Stamped, "df/bearing"),
                                       "pose": (self.T.PoseWithCovarianceStamped, "df/bearing"),
                                       "scan": (self.T.PointCloud2, "df/scan")}[self.encoding]
        self.pubs = {}
        for name in self.stations:
            prefix = f"{name}/" if name else ""
            # a deep history: a reliable reader that fell behind gets what it missed again
            self.pubs[name] = (self.create_publisher(self.T.NavSatFix, prefix + "gps/fix", HISTORY_DEPTH),
                               self.create_publisher(bearing_type, prefix + bearing_topic, HISTORY_DEPTH))
        self.pub_truth = self.create_publisher(self.T.PointStamped, "sim/truth", latched)
        self.channel_truths = {channel: self.create_publisher(self.T.PointStamped, f"sim/{channel}/truth", latched)
                               for channel in self.truths}
        self.pub_datum = self.create_publisher(self.T.NavSatFix, "sim/datum", latched)
        self.truth_stamp: float | None = None  # when the truths went out (None: not yet)
        # one map for the graph: the truths go out again in the node's frame once it says where that is
        self.create_subscription(self.T.NavSatFix, "emitter/datum", self.on_node_datum, latched)
        if s["drive"] == "goal":
            self.create_subscription(self.T.PoseStamped, "emitter/next_goal", self.on_goal, 1)

    def _goal_drive(self, overrides: dict) -> list[str]:
        """`drive:=goal`: the vehicle's legs are made as it goes (`events` a generator reading `goal` at each stop);
        ConfigError for a scenario it cannot drive."""
        if self.scenario_name in FLEETS:
            raise ConfigError(f"drive goal: one vehicle follows the goal; {self.scenario_name} has several stations")
        if overrides.get("emitters") is not None:
            raise ConfigError("drive goal: the goal is one emitter's; emitters gives several")
        if overrides.get("co_channel") is not None:
            raise ConfigError("drive goal: the goal is one transmitter's; co_channel puts more on its frequency")
        sc = mounted(scenario_from(self.scenario_name, overrides), overrides.get("mount_offset_deg"))
        if not sc.points:
            raise ConfigError(f"drive goal: {self.scenario_name} drives without stopping; goal driving is stop-and-go "
                              f"(set points > 0)")
        drive = GoalDrive(sc, self.data_seed)
        self.datum, self.emitter = sc.datum, np.array(sc.emitter, float)  # as a played run's truth
        stops = [drive.spacing_m * k for k in range(sc.points)]
        self.goal_end_s = Trajectory(sc.track, sc.speed, stops, sc.dwell_s).duration

        def legs():
            while True:
                leg = drive.leg(self.goal)
                self.sigma_of.update(zip(leg.bearings[:, 0].tolist(), leg.sigma.tolist(), strict=False))
                yield from ((row[0], "", kind, row) for kind, row in leg.events())

        self.events = legs()
        return [""]

    def on_node_datum(self, msg):
        """The node's map frame: the truths are published again in it, so a client comparing sim/truth with
        emitter/pose in `map` compares them in one frame."""
        self.node_datum = LocalFrame(msg.latitude, msg.longitude, msg.altitude)
        if self.truth_stamp is not None:
            self._publish_truths(self.truth_stamp)

    def _publish_truths(self, stamp: float):
        """sim/datum, sim/truth and each channel's truth, in the node's map frame when it is known (emitter/datum),
        else in the scenario's."""
        T, scenario = self.T, LocalFrame(*self.datum)
        frame = self.node_datum or scenario
        self.truth_stamp = stamp

        def moved(where) -> tuple[float, float]:
            lat, lon, _ = scenario.to_geodetic(float(where[0]), float(where[1]))
            east, north = frame.to_enu(float(lat), float(lon))
            return float(east), float(north)

        self.pub_datum.publish(build.navsatfix(T, stamp, frame.lat0, frame.lon0, frame.alt0, frame_id="map"))
        self.pub_truth.publish(build.point_stamped(T, stamp, *moved(self.emitter)))
        for channel, where in self.truths.items():
            self.channel_truths[channel].publish(build.point_stamped(T, stamp, *moved(where)))

    def on_goal(self, msg):
        """The localizer's goal, from its map frame (at emitter/datum) into the scenario's."""
        if self.node_datum is None:
            return
        lat, lon, _ = self.node_datum.to_geodetic(msg.pose.position.x, msg.pose.position.y)
        east, north = LocalFrame(*self.datum).to_enu(float(lat), float(lon))
        self.goal = (float(east), float(north))

    def _simulate(self, overrides: dict) -> list[str]:
        """Simulate the run; sets `events` ((t, station, kind, row) in stamp order), `datum`, `emitter` (ENU) and
        `sigma_of` (each bearing's noise, for the pose encoding); returns the station names ("" for one vehicle)."""
        fleet = FLEETS.get(self.scenario_name)
        emitters, mount = overrides.pop("emitters", None), overrides.pop("mount_offset_deg", None)
        if emitters is not None and overrides.get("co_channel") is not None:
            raise ConfigError("co_channel puts more transmitters on one vehicle's one frequency; emitters gives each "
                              "its own frequency: set one of them")
        if emitters is not None:
            stations = fleet.stations if fleet is not None else {"": scenario_from(self.scenario_name, overrides)}
            fleet, overrides = Fleet(stations, emitters_from(emitters)), {}
        if fleet is None:
            d = simulate(mounted(scenario_from(self.scenario_name, overrides), mount), self.data_seed)
            self.events = [(row[0], "", kind, row) for kind, row in d.events()]
            self.datum, self.emitter, self.counts = d.scenario.datum, d.emitter_enu, (len(d.fixes), len(d.bearings))
            self.path = emitter_trajectory(d.scenario)  # a moving transmitter's: sim/truth follows it
            if self.path is not None:
                self.emitter = self.path.at(np.array([0.0]))[0]
            self.sigma_of = dict(zip(d.bearings[:, 0].tolist(), d.sigma.tolist(), strict=False))
            return [""]
        given = sorted(k for k, v in overrides.items() if v is not None)
        if given:
            raise ConfigError(f"{', '.join(given)}: overrides apply to single-vehicle scenarios, not "
                              f"{self.scenario_name}")
        stations = {name: mounted(sc, mount) for name, sc in fleet.stations.items()}
        f = simulate_fleet(stations, fleet.emitters, self.data_seed)
        self.events = [(row[0], name, kind, row) for kind, name, row in f.events()]
        self.datum, self.emitter = f.scenario.datum, next(iter(f.truth.values()))
        # each transmitter's truth on sim/<channel>/truth (sim/truth keeps the first's), as simulate's bags carry
        self.truths = {channel_id(freq): where for freq, where in f.truth.items() if freq}
        self.counts = (sum(map(len, f.fixes.values())), sum(map(len, f.bearings.values())))
        self.sigma_rad = f.scenario.sigma_rad
        return list(fleet.stations)

    def serve(self, seconds: float):
        """Wait `seconds` while serving the node's callbacks (parameter services, discovery), not sleeping."""
        end = time.monotonic() + seconds
        while not self.stop.requested and (left := end - time.monotonic()) > 0:
            rclpy.spin_once(self, timeout_sec=left)

    def play(self, stop: Stop):
        """Publish the run; returns when it is played, the duration is reached or `stop` is requested."""
        self.stop = stop
        deadline = time.monotonic() + self.start_timeout_s
        every = [pub for pair in self.pubs.values() for pub in pair]
        while (
            time.monotonic() < deadline
            and not self.stop.requested
            and min(pub.get_subscription_count() for pub in every) < self.wait_for
        ):
            self.serve(0.05)
        self.serve(self.start_delay_s)
        base = time.time()
        self._publish_truths(base)
        events = self.events
        if self.counts is None:
            end = self.duration_s or self.goal_end_s
            self.get_logger().info(f"driving {self.scenario_name} towards emitter/next_goal: {end:.0f} s simulated at "
                                   f"speed-up {self.speedup:g}")
        else:
            end = events[-1][0] if not self.duration_s else min(events[-1][0], self.duration_s)
            self.get_logger().info(
                f"playing {self.scenario_name}: {self.counts[0]} fixes, {self.counts[1]} DF readings, "
                f"{end:.0f} s simulated at speed-up {self.speedup:g}"
            )
        t_wall0, next_log = time.monotonic(), 0.0
        if self.encoding == "scan":
            events = scans(events)
        for t, station, kind, row in events:
            if t > end or self.stop.requested:
                break
            if self.speedup > 0:
                delay = t_wall0 + t / self.speedup - time.monotonic()
            else:
                delay = 1.0 / self.max_rate_hz
            if delay > 0:
                self.serve(delay)
            self._publish(t, station, kind, row, base)
            if t >= next_log:
                self.get_logger().info(f"t = {t:.0f} s")
                next_log += 30.0
        self.serve(0.5)  # let the last messages leave
        self.get_logger().info("scenario played")


    def _publish(self, t: float, station: str, kind: str, row, base: float) -> None:
        """One event of the run at `base + t`: a fix (and a moving transmitter's truth there), or a DF message in
        the encoding set."""
        T = self.T
        pub_fix, pub_bearing = self.pubs[station]
        if kind == "fix":
            pub_fix.publish(build.navsatfix(T, base + t, row[1], row[2], row[3]))
            if self.path is not None:  # a moving transmitter's truth, where it is at each fix
                self.emitter = self.path.at(np.array([t]))[0]
                self._publish_truths(base + t)
        elif self.encoding == "df_record":
            pub_bearing.publish(build.df_record(T, base + t, *row[1:4]))
        elif self.encoding == "scan":
            rows = np.asarray(row, float)
            freq = rows[:, 3] if rows.shape[1] > 3 else None
            pub_bearing.publish(build.df_scan(T, base + t, rows[:, 1], rows[:, 2], freq))
        else:
            yaw = math.radians(90.0 - row[1])
            pub_bearing.publish(build.pose_bearing(T, base + t, yaw, self.sigma_of.get(t, self.sigma_rad) ** 2))


def scans(events: Iterable[tuple]) -> Iterator[tuple]:
    """The events with each run of one station's bearings at one stamp as one ('scan', rows) event: what a receiver
    reading all its channels at once publishes."""
    held: list = []
    for ev in events:
        if held and (ev[2] != "bearing" or (ev[0], ev[1]) != (held[0][0], held[0][1])):
            yield held[0][0], held[0][1], "scan", [h[3] for h in held]
            held = []
        if ev[2] == "bearing":
            held.append(ev)
        else:
            yield ev
    if held:
        yield held[0][0], held[0][1], "scan", [h[3] for h in held]


def usage() -> str:
    """--help: how to start the vehicle and its parameters."""
    lines = [
        "usage: aoa_sim_vehicle [-h] [--ros-args -p NAME:=VALUE]",
        "   or: ros2 run aoa_localizer aoa_sim_vehicle [-h] [--ros-args ...]",
        "   or: python -m aoa_localizer.sim_vehicle [-h] [--ros-args ...]",
        "",
        __doc__.strip(),
        "",
        "parameters (-p name:=value):",
    ]
    lines += [f"  {p.name} = {p.default}  {p.spec.doc} ({p.spec.describe()})" for p in SETTINGS]
    lines += [f"  {p.name} (unset: the scenario's)  {p.spec.doc} ({p.spec.describe()})" for p in OVERRIDES]
    return "\n".join(lines)


def main(argv=None) -> int:
    return run_node("sim_vehicle", SimVehicle, SimVehicle.play, (ConfigError, ValueError), argv, usage())


if __name__ == "__main__":
    sys.exit(main())
