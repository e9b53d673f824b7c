"""A simulated vehicle that drives where it is told (closed loop): stop-and-go along its scenario's track until it
has a goal, then toward the newest goal, taking its scenario's DF readings at each stop. The goal comes from a
localizer fed with what the vehicle recorded so far (`sim_vehicle -p drive:=goal`, scripts/goal_drive.py).

A leg is one stop: the vehicle drives at most `spacing_m` (the scenario's distance between observation points)
towards its target, waits `dwell_s` there, and takes `readings_per_point` readings from 1 s after arriving, as the
stop-and-go scenarios do; the GPS fixes keep the scenario's clock and rate across legs.
"""
from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.types import Estimate
from aoa_localizer.simulation.evaluation import feed
from aoa_localizer.simulation.scenarios import Scenario, ScenarioData, Trajectory, df_records, gps_fixes

ARRIVED_M = 1.0  # a target nearer than this is reached: the vehicle stays and takes its readings there


class GoalDrive:
    """The vehicle of `scenario` (its track, speed, dwell, DF and GPS settings), its data seeded from `seed`."""

    def __init__(self, scenario: Scenario, seed: int):
        if not scenario.points:
            raise ValueError(f"{scenario.name} drives without stopping; a goal drive is stop-and-go")
        self.sc = scenario
        self.frame = LocalFrame(*scenario.datum)
        self.rng = np.random.default_rng(seed)
        self.route = Trajectory(scenario.track, 1.0)  # position by arc length (at 1 m/s, time is arc length)
        self.spacing_m = self.route.length / max(1, scenario.points - 1)
        self.route_s = 0.0
        self.place = np.array(scenario.track[0], float)
        self.course = float(self.route.course(0.0))  # the vehicle's forward axis (ENU angle, rad)
        self.t = 0.0  # the simulated clock at the start of the next leg (s)
        self.odometer_m = 0.0
        self.legs = 0

    def target(self, goal: tuple[float, float] | None) -> np.ndarray:
        """The next stop: `spacing_m` further along the track (no goal), or towards the goal, at most `spacing_m`
        away."""
        if goal is None:
            self.route_s = min(self.route_s + (self.spacing_m if self.legs else 0.0), self.route.length)
            return self.route.at(self.route_s)
        step = np.asarray(goal, float) - self.place
        distance = float(np.hypot(*step))
        if distance < ARRIVED_M:
            return self.place.copy()
        return self.place + step * min(1.0, self.spacing_m / distance)

    def leg(self, goal: tuple[float, float] | None = None) -> ScenarioData:
        """Drive to the next stop and take its readings: the leg's fixes and DF records, with the truth."""
        sc = self.sc
        target = self.target(goal)
        distance = float(np.hypot(*(target - self.place)))
        drive_s = distance / sc.speed
        t0, t1 = self.t, self.t + drive_s + sc.dwell_s

        def at(t: np.ndarray) -> np.ndarray:
            share = np.clip((t - t0) / drive_s, 0.0, 1.0)[:, None] if drive_s > 0 else np.ones((t.size, 1))
            return self.place + share * (target - self.place)

        period = 1.0 / sc.gps_rate_hz
        first = math.ceil((t0 - sc.gps_clock_offset_s) / period - 1e-9)
        t_gps = sc.gps_clock_offset_s + period * np.arange(first, math.ceil((t1 - sc.gps_clock_offset_s) / period))
        t_gps = t_gps[(t_gps >= t0) & (t_gps < t1)]
        t_df = t0 + drive_s + 1.0 + np.arange(sc.readings_per_point) / sc.df_rate_hz
        fixes = gps_fixes(sc, self.frame, self.rng, t_gps, at(t_gps))
        sensor = at(t_df)
        if distance > 0:
            self.course = math.atan2(target[1] - self.place[1], target[0] - self.place[0])
        bearings, sigma, wild, emitter = df_records(sc, self.frame, self.rng, t_df, sensor,
                                                    np.full(t_df.size, self.course))
        self.place, self.t = target, t1
        self.odometer_m += distance
        self.legs += 1
        e_lat, e_lon, _ = self.frame.to_geodetic(emitter[0], emitter[1])
        return ScenarioData(sc, fixes, bearings, sensor, sigma, wild, emitter, (float(e_lat), float(e_lon)))


def closed_loop(drive: GoalDrive, loc: Localizer, radius_m: float, follow_goal: bool = True
                ) -> Iterator[Estimate | None]:
    """Leg by leg, the vehicle's records into `loc` (its deferred work done, as at a receiver's pace), then, when
    `follow_goal`, the next leg towards `loc`'s goal for the vehicle's newest fix; yields the newest estimate after
    each leg (None before the first). Ends when the vehicle has no goal and its track is driven."""
    goal = None
    while goal is not None or drive.route_s < drive.route.length or not drive.legs:
        feed(loc, drive.leg(goal))
        if follow_goal:
            place = loc.view(light=True).vehicles.get("")
            post = loc.posterior() if place is not None else None
            found = post.next_goal(place, radius_m) if post is not None and place is not None else None
            goal = (found.east, found.north) if found is not None else None
        yield loc.view(light=True).estimate
