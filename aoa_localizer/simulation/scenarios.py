"""The public benchmark scenarios (docs/benchmarks.md, "Scenarios"), simulated as a vehicle would record them.

Output is what crosses the public interface: GPS fixes (stamp, lat, lon, alt) on the GPS clock and
DF records (stamp, azimuth from true north, quality) on the receiver's clock, plus the truth the
benchmark scores against (emitter, true antenna positions, each bearing's true sigma and whether it
was wild). Azimuths are geodesic (what a real DF measures), not angles in our ENU plane.

Stop-and-go scenarios (`seed`, `straight`, `homing`): the vehicle drives at `speed` between equally
spaced observation points (by arc length) and stops `dwell_s` at each; its DF readings are taken
at 10 Hz from 1 s after arrival, so 1 Hz fixes taken during the stop bracket them. `urban` drives
on without stopping.
"""
from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np
from pymap3d import vincenty

from aoa_localizer.engine.geodesy import LocalFrame, wrap_360
from aoa_localizer.engine.types import BearingInput, FixInput, Input

DATUM = (39.1, 117.2, 5.0)
PAPER_SIGMA_RAD = math.sqrt(3.801e-4)
SEED_TRACK = ((0, 0), (1000, 400), (1500, 600), (1600, 1400))


@dataclass(frozen=True)
class Scenario:
    """Everything that defines a simulated run; the four public ones are in SCENARIOS."""

    name: str
    emitter: tuple[float, float]
    track: tuple[tuple[float, float], ...]
    points: int = 60  # observation points (stop-and-go); 0 = continuous driving
    readings_per_point: int = 5
    quality: tuple[float, float] = (55.0, 100.0)  # uniform range; equal ends = constant
    sigma_rad: float = PAPER_SIGMA_RAD  # constant bearing noise, unless sigma_q is set
    sigma_q_deg: tuple[float, float] | None = None  # (sigma at Q=100, sigma at Q=40), linear in Q
    wild_share: float = 0.0
    # Multipath off one building: this share of readings points at `reflector` (a consistent ghost) instead.
    reflector: tuple[float, float] | None = None
    reflector_share: float = 0.0
    quality_known: bool = True  # False: the receiver reports NaN quality (the noise still follows `sigma_*`)
    # The emitter is switched off at `moved_at_s` and another comes up at `moved_to` (None: one emitter).
    moved_to: tuple[float, float] | None = None
    moved_at_s: float = 0.0
    speed: float = 10.0
    dwell_s: float = 3.0
    df_rate_hz: float = 10.0
    gps_rate_hz: float = 1.0
    gps_noise_m: float = 0.0
    gps_dropout_prob: float = 0.0  # share of fixes lost (drop-outs)
    gps_clock_offset_s: float = 0.37
    df_clock_offset_s: float = 0.05
    datum: tuple[float, float, float] = DATUM
    # None: azimuths from true north. A number: azimuths from the vehicle's forward axis (its direction of travel),
    # as a DF array mounted with its zero this far clockwise from that axis measures them.
    mount_offset_deg: float | None = None
    # Filter settings this scenario asks for (the prior of `straight`, the receiver calibration of `urban`).
    filter_overrides: dict = field(default_factory=dict)
    # Other transmitters on the emitter's frequency (co-channel): their places, the air-time shares of the emitter
    # and each of them (equal when empty), and how they take turns: push-to-talk bursts of uniform length in
    # `bursts_s` (each burst one transmitter, drawn by the shares), or None: interleaved, reading by reading.
    co_channel: tuple[tuple[float, float], ...] = ()
    co_shares: tuple[float, ...] = ()
    bursts_s: tuple[float, float] | None = (5.0, 30.0)
    # Site error that repeats along the road: a smooth random field over the antenna's place (sd `site_field_deg`,
    # squared-exponential correlation over `site_field_m`) added to every reading that is not wild.
    site_field_deg: float = 0.0
    site_field_m: float = 300.0
    # A transmitter that moves (issue 68): it stands at `emitter` until `emitter_start_s`, then follows these
    # waypoints (ENU m) at `emitter_speed` (m/s) and stands at the last. Empty: it stands.
    emitter_path: tuple[tuple[float, float], ...] = ()
    emitter_speed: float = 0.0
    emitter_start_s: float = 0.0


SCENARIOS = {
    "seed": Scenario("seed", (1200, 800), SEED_TRACK),
    "straight": Scenario("straight", (1200, 800), ((0, -200), (2400, -200)), readings_per_point=1,
                         quality=(90.0, 90.0),
                         filter_overrides={"prior_east": 1350.0, "prior_north": 700.0, "prior_sigma_m": 300.0}),
    "urban": Scenario("urban", (1200, 800), SEED_TRACK, points=0, quality=(40.0, 100.0), sigma_q_deg=(1.0, 8.0),
                      wild_share=0.15, gps_noise_m=3.0,
                      filter_overrides={"sigma_model": "quality", "sigma_q100_deg": 1.0, "sigma_q40_deg": 8.0,
                                        "point_weighting": "inverse_variance", "gps_sigma_m": 3.0}),
    "homing": Scenario("homing", (1500, 1500), ((0, 0), (1200, 1200), (1600, 1000), (2000, 1700)),
                       readings_per_point=3),
}


def mounted(sc: Scenario, mount_offset_deg: float | None) -> Scenario:
    """`sc` with its DF array mounted on the vehicle at this offset (None: `sc` as it is)."""
    return sc if mount_offset_deg is None else replace(sc, mount_offset_deg=float(mount_offset_deg))


def receiver_settings(mount_offset_deg: float | None) -> dict:
    """The localizer settings that read a scenario's DF records as its array took them: none for azimuths from true
    north; the vehicle's forward axis, its course from the GPS track and the mount offset otherwise."""
    if mount_offset_deg is None:
        return {}
    return {"bearing_reference": "vehicle", "heading_source": "track", "mount_offset_deg": float(mount_offset_deg)}


def robustness_cells() -> dict[str, Scenario]:
    """The robustness benchmark's cells: the `seed` track, 120 points 10 s apart, 3 readings each,
    quality U(40, 100), noise 1 deg at Q 100 to 8 deg at Q 40, then one kind of mess per cell."""
    base = Scenario("robust", (1200, 800), SEED_TRACK, points=120, readings_per_point=3, quality=(40.0, 100.0),
                    sigma_q_deg=(1.0, 8.0), speed=10.0, dwell_s=8.0)
    cells = {f"wild{int(100 * w)}": replace(base, name=f"wild{int(100 * w)}", wild_share=w)
             for w in (0.0, 0.1, 0.2, 0.3, 0.4)}
    cells["reflector"] = replace(base, name="reflector", reflector=(300.0, 1100.0), reflector_share=0.2,
                                 wild_share=0.05)
    for k in (0.5, 2.0, 4.0):  # a constant noise k times the configured default sigma
        name = f"sigma_x{k:g}"
        cells[name] = replace(base, name=name, sigma_q_deg=None, sigma_rad=k * PAPER_SIGMA_RAD)
    cells["quality_nan"] = replace(base, name="quality_nan", sigma_q_deg=None, sigma_rad=math.radians(3.0),
                                   quality_known=False)
    return cells


_LOOP = tuple((300.0 * math.cos(a), 300.0 * math.sin(a)) for a in np.linspace(0.0, 2.0 * math.pi, 30))


def geometry_cells() -> dict[str, Scenario]:
    """Geometries unlike the public scenarios', each driven on without stops and read with the default
    configuration (constant noise, not told): a pass 30 m from the emitter on a straight road (the bearings swing
    180 deg in seconds, before any estimate), the same pass after a turn (an estimate before the pass), an emitter
    8 km off a 5 km road, a walk around a block at 1.5 m/s with a 5 deg hand-held DF at 1 Hz, a loop around the
    emitter, and an emitter behind the start that the vehicle drives away from."""
    drive = replace(SCENARIOS["seed"], points=0, quality=(80.0, 80.0))
    return {
        "close_pass": replace(drive, name="close_pass", emitter=(1000.0, 30.0), track=((0, 0), (2000, 0)),
                              sigma_rad=math.radians(2.0), df_rate_hz=5.0),
        "turn_then_pass": replace(drive, name="turn_then_pass", emitter=(1000.0, 30.0),
                                  track=((300, -600), (300, 0), (2000, 0)), sigma_rad=math.radians(2.0),
                                  df_rate_hz=5.0),
        "far_side": replace(drive, name="far_side", emitter=(2500.0, 8000.0), track=((0, 0), (5000, 0)),
                            sigma_rad=math.radians(1.0), speed=20.0, df_rate_hz=2.0),
        "walk": replace(drive, name="walk", emitter=(400.0, 300.0),
                        track=((0, 0), (200, 0), (200, 200), (0, 200), (0, 0)), speed=1.5, df_rate_hz=1.0,
                        sigma_rad=math.radians(5.0)),
        "loop_around": replace(drive, name="loop_around", emitter=(50.0, -80.0), track=_LOOP,
                               sigma_rad=math.radians(3.0), df_rate_hz=2.0),
        "behind": replace(drive, name="behind", emitter=(-600.0, 150.0), track=((0, 0), (1500, 0), (1500, 600)),
                          sigma_rad=math.radians(2.0), df_rate_hz=2.0),
    }


_RING = tuple((1000.0 + 900.0 * math.cos(a), 1000.0 + 900.0 * math.sin(a)) for a in np.linspace(0.0, 4.0 * math.pi, 61))


def _laps(path: tuple[tuple[float, float], ...], times: int) -> tuple[tuple[float, float], ...]:
    return tuple(path[1:]) * times


def moving_cells() -> dict[str, Scenario]:
    """Transmitters that move, watched from a DF vehicle driving twice around them on a 900 m ring at 10 m/s
    (it turns all the time: the range of a mover is observable), 2 deg noise at 2 Hz, not told the noise: a walker
    at 1.4 m/s, a car at 15 m/s on a block of roads, a drone at 10 m/s on straight legs with sharp turns, and a
    transmitter that stands, walks 300 m and stands again."""
    base = replace(SCENARIOS["seed"], name="moving", emitter=(1000.0, 1000.0), track=_RING, points=0,
                   quality=(80.0, 80.0), sigma_rad=math.radians(2.0), df_rate_hz=2.0)
    walk = ((1000.0, 1000.0), (1150.0, 1000.0), (1150.0, 1200.0), (900.0, 1250.0), (850.0, 1050.0),
            (1000.0, 1000.0))
    block = ((1000.0, 1000.0), (1300.0, 1000.0), (1300.0, 1300.0), (800.0, 1300.0), (800.0, 1000.0),
             (1000.0, 1000.0))
    legs = ((1000.0, 1000.0), (1400.0, 1100.0), (1000.0, 1300.0), (700.0, 900.0), (1200.0, 700.0),
            (1000.0, 1000.0))
    return {
        "walker": replace(base, name="walker", emitter_path=_laps(walk, 2), emitter_speed=1.4),
        "car": replace(base, name="car", emitter_path=_laps(block, 9), emitter_speed=15.0),
        "drone": replace(base, name="drone", emitter_path=_laps(legs, 5), emitter_speed=10.0),
        "stand_walk_stand": replace(base, name="stand_walk_stand", emitter_path=((1300.0, 1000.0),),
                                    emitter_speed=1.4, emitter_start_s=300.0),
    }


@dataclass
class ScenarioData:
    """One simulated run: public inputs plus the truth."""

    scenario: Scenario
    fixes: np.ndarray  # (F, 4): stamp, lat, lon, alt
    bearings: np.ndarray  # (B, 3): stamp, azimuth deg, quality
    sensor_enu: np.ndarray  # (B, 2): true antenna position at each bearing
    sigma: np.ndarray  # (B,): true bearing sigma, rad
    wild: np.ndarray  # (B,) bool
    emitter_enu: np.ndarray  # (2,)
    emitter_lat_lon: tuple[float, float]
    # Which transmitter each bearing came from (0: the emitter, k: co_channel[k - 1]); every transmitter's place
    source: np.ndarray | None = None
    transmitters_enu: np.ndarray | None = None

    def emitter_at(self, t) -> np.ndarray:
        """The emitter's ENU place at times t (a moving one's on its path; else where it stands, its last)."""
        path = emitter_trajectory(self.scenario)
        if path is None:
            return np.broadcast_to(self.emitter_enu, np.shape(t) + (2,)).copy()
        return path.at(t)

    @property
    def frame(self) -> LocalFrame:
        return LocalFrame(*self.scenario.datum)

    def events(self):
        """Fixes and bearings merged in stamp order, as ('fix', row) / ('bearing', row): a vehicle's stream."""
        tagged = [(f[0], 0, "fix", f) for f in self.fixes] + [(b[0], 1, "bearing", b) for b in self.bearings]
        tagged.sort(key=lambda e: (e[0], e[1]))
        return [(kind, row) for _, _, kind, row in tagged]

    def inputs(self) -> Iterator[Input]:
        """The same stream as Localizer inputs (Localizer.run)."""
        for kind, row in self.events():
            yield Input(kind, FixInput(*row[:4]) if kind == "fix" else BearingInput(*row[:3]))


class Trajectory:
    """Position along a polyline as a function of time, with optional stops at given arc lengths."""

    def __init__(self, track, speed: float, stops=(), dwell_s: float = 0.0):
        self.v = np.asarray(track, float)
        seg = np.diff(self.v, axis=0)
        self.cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
        self.length = float(self.cum[-1])
        # Knots of the (time, arc length) curve: drive to each stop, wait, drive on.
        t_knots, s_knots, t, s = [0.0], [0.0], 0.0, 0.0
        for stop in stops:
            t += (stop - s) / speed
            t_knots += [t, t + dwell_s]
            s_knots += [stop, stop]
            t, s = t + dwell_s, stop
        t += (self.length - s) / speed
        t_knots.append(t)
        s_knots.append(self.length)
        self.t_knots, self.s_knots = np.array(t_knots), np.array(s_knots)
        self.duration = t

    def arrival(self, stop_index: int) -> float:
        """Time the vehicle reaches its stop number `stop_index`."""
        return float(self.t_knots[1 + 2 * stop_index])

    def course(self, t) -> np.ndarray:
        """The vehicle's forward axis at times t as an ENU angle (rad): the direction of the segment it drives, or at
        a vertex the one it arrived by (a stopped vehicle faces the way it came)."""
        s = np.interp(t, self.t_knots, self.s_knots)
        seg = np.clip(np.searchsorted(self.cum, s, side="left") - 1, 0, len(self.v) - 2)
        step = self.v[seg + 1] - self.v[seg]
        return np.arctan2(step[..., 1], step[..., 0])

    def at(self, t) -> np.ndarray:
        """ENU positions at times t."""
        s = np.interp(t, self.t_knots, self.s_knots)
        x = np.interp(s, self.cum, self.v[:, 0])
        y = np.interp(s, self.cum, self.v[:, 1])
        return np.stack([x, y], axis=-1)


def emitter_trajectory(sc: Scenario) -> Trajectory | None:
    """A moving transmitter's trajectory (None: it stands): from `emitter` along `emitter_path`, standing
    `emitter_start_s` first. A path that cannot be driven is refused with the reason."""
    if not sc.emitter_path:
        return None
    path = np.array([sc.emitter, *sc.emitter_path], float)
    if not np.isfinite(path).all():
        raise ValueError("the transmitter's path has a coordinate that is not a finite number")
    if not (math.isfinite(sc.emitter_speed) and sc.emitter_speed > 0.0):
        raise ValueError(f"the transmitter's speed must be a positive number of m/s, not {sc.emitter_speed!r}")
    if not (math.isfinite(sc.emitter_start_s) and sc.emitter_start_s >= 0.0):
        raise ValueError(f"the transmitter's start must be a time >= 0 s, not {sc.emitter_start_s!r}")
    if not np.hypot(*np.diff(path, axis=0).T).sum() > 0.0:
        raise ValueError("the transmitter's path has no length: every waypoint is where it starts")
    return Trajectory(path, sc.emitter_speed, (0.0,), sc.emitter_start_s)


def _sigma_of_quality(q, sigma_q_deg):
    s100, s40 = sigma_q_deg
    return np.radians(s40 + (s100 - s40) * (np.clip(q, 40, 100) - 40) / 60)


def simulate(scenario: Scenario | str, seed: int) -> ScenarioData:
    """One run of a scenario with its data seeded from `seed`."""
    sc = SCENARIOS[scenario] if isinstance(scenario, str) else scenario
    rng = np.random.default_rng(seed)
    frame = LocalFrame(*sc.datum)
    if sc.points:
        track_len = Trajectory(sc.track, sc.speed).length
        stops = np.linspace(0.0, track_len, sc.points)
        traj = Trajectory(sc.track, sc.speed, stops, sc.dwell_s)
        k = np.arange(sc.readings_per_point) / sc.df_rate_hz
        t_df = np.concatenate([traj.arrival(i) + 1.0 + k for i in range(sc.points)])
    else:
        traj = Trajectory(sc.track, sc.speed)
        t_df = np.arange(sc.df_clock_offset_s, traj.duration, 1.0 / sc.df_rate_hz)
    t_gps = np.arange(sc.gps_clock_offset_s - 1.0 / sc.gps_rate_hz, traj.duration + 2.0, 1.0 / sc.gps_rate_hz)
    t_gps = t_gps[t_gps >= 0]
    fixes = gps_fixes(sc, frame, rng, t_gps, traj.at(t_gps))
    sensor = traj.at(t_df)
    bearings, sigma, wild, emitter = df_records(sc, frame, rng, t_df, sensor, traj.course(t_df))
    source = np.zeros(t_df.size, int)
    if sc.co_channel:  # drawn after everything else: a scenario without them keeps its data to the bit
        source = co_channel_records(sc, frame, rng, bearings, sensor, sigma, wild)
    if sc.site_field_deg:  # drawn last too
        bearings[~wild, 1] = wrap_360(bearings[~wild, 1] + site_field(sc, rng, sensor[~wild]))
    e_lat, e_lon, _ = frame.to_geodetic(emitter[0], emitter[1])
    return ScenarioData(sc, fixes, bearings, sensor, sigma, wild, emitter, (float(e_lat), float(e_lon)), source,
                        np.array([emitter, *sc.co_channel], float))


_FIELD_WAVES = 64  # random Fourier features of the site-error field


def site_field(sc: Scenario, rng: np.random.Generator, places: np.ndarray) -> np.ndarray:
    """The scenario's site-error field (deg) at the antenna `places` (N, 2): one draw of a Gaussian field with sd
    `site_field_deg` and a squared-exponential correlation over `site_field_m` (random Fourier features)."""
    waves = rng.standard_normal((_FIELD_WAVES, 2)) / sc.site_field_m
    phase = rng.uniform(0.0, 2.0 * np.pi, _FIELD_WAVES)
    return sc.site_field_deg * np.sqrt(2.0 / _FIELD_WAVES) * np.cos(places @ waves.T + phase).sum(axis=1)


def on_air(sc: Scenario, rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """Which transmitter (0: the emitter, k: co_channel[k - 1]) is heard at each time `t`: push-to-talk bursts of
    uniform length in `bursts_s`, each drawn by the air-time shares, or (None) each reading drawn on its own."""
    k = 1 + len(sc.co_channel)
    shares = np.array(sc.co_shares or [1.0] * k, float)
    shares /= shares.sum()
    if sc.bursts_s is None:
        return rng.choice(k, size=t.size, p=shares)
    lo, hi = sc.bursts_s
    edges, who = [], []
    at = float(t.min()) - rng.uniform(0.0, hi)
    while at <= t.max():
        edges.append(at)
        who.append(rng.choice(k, p=shares))
        at += rng.uniform(lo, hi)
    return np.array(who)[np.searchsorted(np.array(edges), t, side="right") - 1]


def co_channel_records(sc: Scenario, frame: LocalFrame, rng: np.random.Generator, bearings: np.ndarray,
                       sensor: np.ndarray, sigma: np.ndarray, wild: np.ndarray) -> np.ndarray:
    """The bearings taken while another transmitter on the frequency was on the air point at it instead (with
    the same noise; wild ones stay wild), in place; which transmitter each came from. Azimuths from true north
    only (no mount offset)."""
    if sc.mount_offset_deg is not None:
        raise ValueError("co-channel transmitters are simulated with azimuths from true north (no mount offset)")
    source = on_air(sc, rng, bearings[:, 0])
    s_lat, s_lon, _ = frame.to_geodetic(sensor[:, 0], sensor[:, 1])
    noise = np.degrees(sigma * rng.standard_normal(sigma.size))
    for j, place in enumerate(sc.co_channel, start=1):
        theirs = (source == j) & ~wild
        az = _azimuths(frame, sensor, s_lat, s_lon, np.array(place, float)) + noise
        bearings[theirs, 1] = wrap_360(az[theirs])
    return source


def gps_fixes(sc: Scenario, frame: LocalFrame, rng: np.random.Generator, t_gps: np.ndarray,
              true_enu: np.ndarray) -> np.ndarray:
    """(F, 4) fixes stamp, lat, lon, alt: the true positions at `t_gps` with the scenario's GPS noise and drop-outs."""
    gps_enu = true_enu + sc.gps_noise_m * rng.standard_normal((t_gps.size, 2))
    if sc.gps_dropout_prob:
        kept = rng.random(t_gps.size) >= sc.gps_dropout_prob
        t_gps, gps_enu = t_gps[kept], gps_enu[kept]
    lat, lon, alt = frame.to_geodetic(gps_enu[:, 0], gps_enu[:, 1])
    return np.column_stack([t_gps, lat, lon, alt])


def df_records(sc: Scenario, frame: LocalFrame, rng: np.random.Generator, t_df: np.ndarray, sensor: np.ndarray,
               course: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """DF records (B, 3) stamp, azimuth deg, quality taken at `t_df` from the antenna places `sensor`: the geodesic
    azimuth to the emitter with the scenario's noise, wild bearings and reflector (from the vehicle's forward axis,
    `course` an ENU angle, when the scenario has a mount offset); with each bearing's true sigma, whether it was
    wild, and the emitter's place at the end."""
    s_lat, s_lon, _ = frame.to_geodetic(sensor[:, 0], sensor[:, 1])
    e_lat, e_lon, _ = frame.to_geodetic(sc.emitter[0], sc.emitter[1])
    _, az_true = vincenty.vdist(s_lat, s_lon, np.full(t_df.size, e_lat), np.full(t_df.size, e_lon))
    lo, hi = sc.quality
    quality = np.full(t_df.size, lo) if lo == hi else rng.uniform(lo, hi, t_df.size)
    sigma = _sigma_of_quality(quality, sc.sigma_q_deg) if sc.sigma_q_deg else np.full(t_df.size, sc.sigma_rad)
    az_true = np.asarray(az_true, float)
    emitter = np.array(sc.emitter, float)
    if sc.moved_to is not None:
        emitter = np.array(sc.moved_to, float)
        late = t_df >= sc.moved_at_s
        az_true = np.where(late, _azimuths(frame, sensor, s_lat, s_lon, emitter), az_true)
    path = emitter_trajectory(sc)
    if path is not None:
        places = path.at(t_df)
        p_lat, p_lon, _ = frame.to_geodetic(places[:, 0], places[:, 1])
        az_true = np.asarray(vincenty.vdist(s_lat, s_lon, p_lat, p_lon)[1], float)
        emitter = places[-1]
    az = az_true + np.degrees(sigma * rng.standard_normal(t_df.size))
    wild = rng.random(t_df.size) < sc.wild_share
    az = np.where(wild, rng.uniform(0, 360, t_df.size), az)
    if sc.reflector is not None:
        ghost = ~wild & (rng.random(t_df.size) < sc.reflector_share / max(1e-12, 1.0 - sc.wild_share))
        az_ghost = _azimuths(frame, sensor, s_lat, s_lon, np.array(sc.reflector, float))
        az = np.where(ghost, az_ghost + np.degrees(sigma * rng.standard_normal(t_df.size)), az)
        wild = wild | ghost
    if not sc.quality_known:
        quality = np.full(t_df.size, np.nan)
    if sc.mount_offset_deg is not None:  # the forward axis as an azimuth from true north, at the antenna
        heading = np.degrees(np.asarray(frame.north_angle(s_lat, s_lon)) - course)
        az = az - heading - sc.mount_offset_deg
    return np.column_stack([t_df, wrap_360(az), quality]), sigma, wild, emitter


def _azimuths(frame: LocalFrame, sensor: np.ndarray, s_lat, s_lon, target: np.ndarray) -> np.ndarray:
    """Geodesic azimuths (deg) from each sensor position to one ENU target."""
    t_lat, t_lon, _ = frame.to_geodetic(target[0], target[1])
    _, az = vincenty.vdist(s_lat, s_lon, np.full(sensor.shape[0], t_lat), np.full(sensor.shape[0], t_lon))
    return np.asarray(az, float)
