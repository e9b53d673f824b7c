"""Localizer: the ROS-free engine the node, the offline replay and the benchmarks all drive.

GPS fixes and DF readings go in as a vehicle gives them (lat/lon, azimuths, qualities, stamps);
estimates come out with ENU metres, lat/lon and a 2x2 covariance. Every input that is not used is
counted under a reason (`view().rejected`) and logged; no exception escapes for bad data. What programs read
leaves as values copied when asked (`view`, `posterior`: engine/outputs/view.py), never the engine's objects.
An input goes to the intake (ingest/intake.py), and the points it closes to the estimates (outputs/estimates.py):
one way, no call back.
"""
from __future__ import annotations

import functools
import logging
import math
import threading
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import replace
from types import MappingProxyType
from typing import Any, Protocol

import numpy as np

from aoa_localizer.engine.channels import Channel, Channels
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.inference.global_search import Points
from aoa_localizer.engine.inference.receiver_pool import PooledNoise
from aoa_localizer.engine.ingest.gps_track import GpsTrack
from aoa_localizer.engine.ingest.intake import Intake, as_float
from aoa_localizer.engine.outputs.estimates import Estimates
from aoa_localizer.engine.outputs.next_goal import NextGoal
from aoa_localizer.engine.outputs.posterior_grid import PosteriorGrid
from aoa_localizer.engine.outputs.view import ChannelView, LocalizerView, PosteriorView, frozen
from aoa_localizer.engine.rejections import Rejections
from aoa_localizer.engine.scheduling.scheduler import Scheduler
from aoa_localizer.engine.survey.survey_solver import SurveySolver, pooled_solver
from aoa_localizer.engine.types import Estimate, Input, Reading

log = logging.getLogger("aoa_localizer")


# The required fields of each kind of input (Localizer.feed); the add_ calls' other arguments are optional.
_INPUT_FIELDS = {"fix": ("stamp", "lat", "lon"), "bearing": ("stamp", "azimuth_deg"),
                 "bearing_pose": ("stamp", "yaw_rad"), "heading": ("stamp", "yaw_rad")}


class Observer(Protocol):
    """What a program may watch, per input, without reading the engine's internals (reports keep a trace)."""

    def on_fix(self, stamp: float, east: float, north: float, station: str) -> None:
        """An accepted fix, at its ENU position, and its station ("" : the default one)."""

    def on_point(self, readings: Sequence[Reading], kept: np.ndarray) -> None:
        """The readings of a closed observation point, and which of them it kept (False: gated out as wild)."""


def _one_at_a_time(method):
    """A Localizer call made whole before another thread's starts (its state is one stream's: two threads feeding
    it at once broke its random generators' and arrays' invariants, counted as internal_error)."""
    @functools.wraps(method)
    def serialised(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)
    return serialised


class Localizer:
    """Pairs bearings with the interpolated GPS track, builds observation points, starts and runs a filter; one
    track per emitter (channel, by frequency) and one GPS track per station."""

    def __init__(self, config: LocalizerConfig | None = None, observer: Observer | None = None,
                 on_estimate: Callable[[Estimate], None] | None = None, live: bool = False,
                 survey_solver: SurveySolver | None = pooled_solver, datum: LocalFrame | None = None):
        """`observer`: told of every accepted fix and every closed point (see Observer), for reports.
        `on_estimate`: called with every new estimate, whichever input made it (a fix often closes the point
        that makes it; the add_ calls return the newest one). `live`: a node's Localizer, scheduled `realtime`
        under `scheduling: auto`. `survey_solver`: the survey model of the channels heard from fixed sites or
        standing antennas (default aoa_localizer.pooled's; None: none, such a channel keeps its filter's estimate).
        `datum`: the map frame of an earlier Localizer (a datum it took from a fix), kept so that a restart with new
        settings does not move the map; a configured datum (datum_lat, datum_lon) wins."""
        self._lock = threading.RLock()  # the calls below are made one at a time (_one_at_a_time)
        self._cfg = cfg = config or LocalizerConfig()
        self._survey_solver = survey_solver
        self._rng = np.random.default_rng(cfg.seed)
        frame = datum
        if cfg.datum_lat is not None and cfg.datum_lon is not None:
            frame = LocalFrame(cfg.datum_lat, cfg.datum_lon, cfg.datum_alt or 0.0)
        self._rejections = Rejections()
        realtime = cfg.scheduling == "realtime" or (cfg.scheduling == "auto" and live)
        self._scheduler = Scheduler(realtime, self._rejections)
        self._channels = Channels(cfg, self._rng, self._rejections, self._scheduler)
        self._intake = Intake(cfg, self._channels, self._rejections, frame, observer)
        self._fixed_stations: dict[str, tuple[float, float, float, float] | None] = {}  # configured positions
        self._start_tracks(on_estimate)

    def _start_tracks(self, on_estimate: Callable[[Estimate], None] | None):
        """The state of a fresh start on the current channels (the fixed stations placed again)."""
        self._estimates = Estimates(self._cfg, self._channels, self._intake, self._scheduler, self._rejections,
                                    on_estimate, self._survey_solver)
        for name, position in self._fixed_stations.items():
            self._intake.add_station(name, fixed=True)
            if position is not None:
                self._intake.place(name, *position)

    # -- what programs read ------------------------------------------------------------------------
    @property
    def config(self) -> LocalizerConfig:
        """The configuration the Localizer runs with (read-only: a change is a new Localizer, or `reset`)."""
        return self._cfg

    @_one_at_a_time
    def view(self, light: bool = False) -> LocalizerView:
        """The Localizer as a program reads it, copied now (engine/outputs/view.py): the newest estimate, the state
        in one line, the inputs not used by reason, the events, the map frame, each channel and the noise. `light`:
        without the channels, the noise and the clock hint (empty), for a caller that reads the rest once per
        estimate among hundreds of channels."""
        latest, intake = self._estimates.latest, self._intake
        primary = self._channels.primary()
        vehicles = {name: (float(st.gps.e[-1]), float(st.gps.n[-1])) for name, st in intake.stations.items()
                    if isinstance(st.gps, GpsTrack) and len(st.gps)}
        every = self._channels.all()
        view = LocalizerView(
            estimate=self._estimates.newest, status=self._status(), primary=None if primary is None else primary.id,
            latest=latest.id, track=latest.track.summary(),
            estimates=MappingProxyType({c.id: c.estimate for c in every if c.estimate is not None}), channels=(),
            rejected=frozen(self._rejections.counts),
            events=frozen(latest.track.events + intake.input_events), unknown_quality=intake.pairing.unknown_quality,
            other_band=intake.other_band, frame=intake.frame, stations=tuple(intake.stations),
            vehicles=MappingProxyType(vehicles), noise=MappingProxyType({}), clock_hint=None, receiver_noise=None)
        if light:
            return view
        channels = tuple(ChannelView(c.id, c.frequency_hz, c.retired, c.estimate, c.track.summary(),
                                     frozen(c.track.events)) for c in every)
        return replace(view, channels=channels, noise=MappingProxyType(latest.track.noise_summary()),
                       clock_hint=latest.track.supervisor.clock_hint, receiver_noise=self._receiver_noise())

    @_one_at_a_time
    def posterior(self, cid: str | None = None) -> PosteriorView | None:
        """The posterior of channel `cid` (None: the latest estimate's), copied now, with its grid and next goal
        (engine/outputs/view.py); None when the channel is not heard or has no estimate yet."""
        channel = self._channel(cid)
        if channel is None or channel.estimate is None or not channel.track.estimating:
            return None
        track = channel.track
        cloud = track.cloud
        start = track.initiator.start_cloud
        return PosteriorView(channel.id, channel.estimate, np.array(cloud.x, float), np.array(cloud.weights, float),
                             track.cloud_is_current, Points.of(track.posterior_points().rows()), track.robust(),
                             tuple(track.modes), track.used_points(), None if start is None else np.array(start, float))

    def _channel(self, cid: str | None = None) -> Channel | None:
        """The channel `cid` (retired ones too), or without `cid` the latest estimate's."""
        if cid is None:
            return self._estimates.latest
        return self._channels.live.get(cid) or self._channels.retired.get(cid)

    def _status(self) -> str:
        intake = self._intake
        base = intake.waiting_line if intake.waiting_for_gps else self._estimates.latest.track.status.words()
        return base + self._rejections.refused_line()

    def _receiver_noise(self) -> PooledNoise | None:
        """The receiver's noise pooled over the channels that calibrated theirs (receiver_pool.py), when more than
        one frequency was heard (with one, its own calibration says it all); None otherwise."""
        if sum(not math.isnan(c.frequency_hz) for c in self._channels.all()) < 2 or not self._cfg.calibrate_noise:
            return None
        return self._channels.pooled_noise()

    # -- inputs -----------------------------------------------------------------------------------
    @_one_at_a_time
    def add_station(self, name: str, fixed: bool = False, position: tuple | None = None) -> bool:
        """Declare a station (stations are also made at their first input, moving). `fixed`: a site that does not
        move; its position comes from `position` (lat, lon[, alt[, sigma_m]]; kept across reset(); it sets the datum
        when none is set yet) or its fixes (the newest wins), not a track. False (the reason counted) for a position
        a fix could not have."""
        if fixed or position is not None:
            self._fixed_stations.setdefault(name, None)
        self._intake.add_station(name, fixed or position is not None)
        return True if position is None else self._place_station(name, *position)

    def _place_station(self, name: str, lat, lon, alt=float("nan"), sigma_m=0.0) -> bool:
        lat, lon, alt, sigma_m = map(as_float, (lat, lon, alt, sigma_m))
        why = self._intake.bad_position(lat, lon, alt)
        if why:
            self._rejections(why)
            return False
        position = (lat, lon, alt, sigma_m if math.isfinite(sigma_m) and sigma_m >= 0 else 0.0)
        self._fixed_stations[name] = position
        self._intake.place(name, *position)
        return True

    @_one_at_a_time
    def add_fix(self, stamp, lat, lon, alt=float("nan"), status: int = 0, sigma_m=float("nan"),
                station: str = "") -> Estimate | None:
        """A NavSatFix's content; `sigma_m` the horizontal position sigma from its covariance (NaN: unknown);
        `station` the station it places ("": the default one). Returns the newest estimate this fix made
        possible, if any."""
        closed = self._intake.add_fix(stamp, lat, lon, alt, status, sigma_m, station)
        return self._estimates.take_points(closed)

    @_one_at_a_time
    def add_heading(self, stamp, yaw_rad, station: str = "", variance_rad2=float("nan")) -> None:
        """The vehicle's heading from an IMU: REP-103 yaw (rad, counter-clockwise from east, ENU at the vehicle), as
        sensor_msgs/Imu gives it, and the yaw's variance (rad^2; NaN, 0 or negative: not known, taken as exact). Used
        with `bearing_reference: vehicle` and `heading_source: imu`."""
        self._intake.add_heading(stamp, yaw_rad, station, variance_rad2)

    @_one_at_a_time
    def add_bearing(self, stamp, azimuth_deg, quality=float("nan"), station: str = "",
                    frequency_hz=float("nan"), sigma_deg=float("nan")) -> Estimate | None:
        """A DF record: azimuth (deg) and quality of the carrier at `frequency_hz` (0 or NaN: the default
        channel) seen from `station`; `sigma_deg` the reading's own sigma when it has one (a hand-held bearing's,
        a pose's; NaN or None: the one its quality gives; outside [0.001, 180] deg or not a number: refused,
        `bad_sigma`).
        Returns the estimate this reading produced (when it closed an observation point), else None."""
        closed = self._intake.take_bearing(stamp, azimuth_deg, quality, sigma_deg, station, frequency_hz)
        return self._estimates.take_points(closed)

    def _add_bearing_enu(self, stamp, yaw_rad, variance_rad2=float("nan"), station: str = "",
                         frequency_hz=float("nan")) -> Estimate | None:
        """A bearing as a REP-103 yaw (rad, counter-clockwise from east at the antenna) with its variance
        (the `pose` encoding, fed as a `bearing_pose` input): add_bearing with its azimuth and sigma. No quality:
        counted as unknown quality. A variance of NaN or 0 (ROS's "not filled in") means the configured sigma; a
        negative or infinite one is refused as add_bearing refuses such a sigma (`bad_sigma`)."""
        yaw, var = as_float(yaw_rad), as_float(variance_rad2)
        azimuth = 90.0 - math.degrees(yaw) if math.isfinite(yaw) else yaw
        if math.isnan(var) or var == 0.0:
            sigma = math.nan
        else:
            sigma = math.copysign(math.degrees(math.sqrt(abs(var))), var)
        return self.add_bearing(stamp, azimuth, math.nan, station, frequency_hz, sigma)

    def feed(self, event: Input) -> Estimate | None:
        """One input as a source gives it (an Input, or anything with its fields, as a bag's events): handed to the
        add_ call of its kind; a kind that is not the engine's is passed over. Returns what that call returns. Its
        values are checked as the add_ calls check them; a record without a required field is a programming error
        (TypeError naming the field); optional ones (alt, status, sigma_m, quality, frequency_hz, variance_rad2)
        may be left out."""
        kind, station = event.kind, event.station
        if kind not in _INPUT_FIELDS:
            return None
        r = event.record
        missing = [name for name in _INPUT_FIELDS[kind] if not hasattr(r, name)]
        if missing:
            raise TypeError(f"a {kind} input's record has no {', '.join(missing)}: {r!r}")
        nan = math.nan
        if kind == "fix":
            return self.add_fix(r.stamp, r.lat, r.lon, getattr(r, "alt", nan), getattr(r, "status", 0),
                                getattr(r, "sigma_m", nan), station=station)
        if kind == "bearing":
            return self.add_bearing(r.stamp, r.azimuth_deg, getattr(r, "quality", nan), station=station,
                                    frequency_hz=getattr(r, "frequency_hz", nan),
                                    sigma_deg=getattr(r, "sigma_deg", nan))
        if kind == "bearing_pose":
            return self._add_bearing_enu(r.stamp, r.yaw_rad, getattr(r, "variance_rad2", nan), station=station)
        self.add_heading(r.stamp, r.yaw_rad, station=station, variance_rad2=getattr(r, "variance_rad2", nan))
        return None

    def run(self, source: Iterable[Input]) -> Iterator[Estimate]:
        """Offline, in one call: every input of `source` fed in order, then the end of data (flush, finish) and the
        worker stopped. Yields, after each input and then after flush and finish, each channel's newest estimate
        it made (one input can close several channels' points; the constructor's `on_estimate` is told of every
        one). Under `scheduling: realtime` the worker is waited for and the owed moves made after each input
        (catch_up), so the run is what a node at the receiver's pace would make."""
        made: dict[str, Estimate] = {}
        told = self._estimates.on_estimate

        def collect(est: Estimate) -> None:
            made[est.channel] = est
            if told is not None:
                told(est)

        def drained() -> list[Estimate]:
            out = list(made.values())
            made.clear()
            return out

        self._estimates.on_estimate = collect
        try:
            for event in source:
                self.feed(event)
                if self._scheduler.realtime:
                    self.catch_up()
                yield from drained()
            self.flush()
            yield from drained()
            self.finish()
            yield from drained()
        finally:
            self._estimates.on_estimate = told
            self.close()

    # -- the lifecycle ----------------------------------------------------------------------------
    @_one_at_a_time
    def flush(self) -> Estimate | None:
        """End of data: bearings still waiting for a fix are dropped, the open observation points are used."""
        return self._estimates.take_points(self._intake.flush())

    @_one_at_a_time
    def finish(self) -> Estimate | None:
        """After flush(), offline: one last global check over all the data (calibration, modes, moves) on every
        live channel, so the final estimates and their modes reflect everything; those Estimates have
        `end_of_data` set. Returns the last of them (None if no filter runs, or the last points just had a check).
        A live node never sees the end of data and never calls it."""
        return self._estimates.finish()

    @_one_at_a_time
    def idle(self) -> list[Estimate]:
        """Between inputs (`scheduling: realtime`; the node calls it every few ms): the worker's finished results
        applied now rather than at each channel's next point, so a channel whose data paused still gets the start,
        check, transmitter count or site-part fit it was due, and one owed move made, for the channel owing the most,
        so the points that follow carry none. Returns the estimates the results made (each also goes to
        `on_estimate`)."""
        live = list(self._channels.live.values())
        ready = self._scheduler.owners_done()
        done = []
        for c in live if ready else ():
            t = c.track
            if any(place in ready for place in t.places):
                applied = t in ready and t.apply_job()
                # its count and site-part fit, after a start: begun now, rather than at a point that may never come
                if (t.between_points() or applied) and t.estimating:
                    done.append(c)
        made = [est for est in (self._estimates.publish(c) for c in done) if est is not None]
        owing = self._scheduler.owing()
        self._scheduler.move_one(c.track.debtor for c in live if c.track.filter in owing)
        return made

    @_one_at_a_time
    def catch_up(self) -> int:
        """Wait for the worker's jobs, then make every owed move (`scheduling: realtime`; nothing otherwise): what a
        receiver's pace leaves time for between messages, so a replay runs live-like however fast it is fed. The
        jobs' results are applied at each channel's next point (or by idle()), as live. Returns how many moves it
        made."""
        self._wait_for_worker()
        tracks = [c.track for c in self._channels.live.values()]
        made = 0
        while self._scheduler.move_one(t.debtor for t in tracks):
            made += 1
        return made

    def _wait_for_worker(self) -> None:
        """Wait until the check worker has finished the live channels' jobs, counts and site-part fits included
        (`scheduling: realtime`; nothing otherwise)."""
        self._scheduler.wait(place for c in self._channels.live.values() for place in c.track.places)

    def close(self):
        """Stop the background checks' worker (a check running finishes; its result is dropped)."""
        self._scheduler.close()

    def __reduce_ex__(self, protocol):
        """A Localizer holds a worker process, locks and random generators mid-run: it is neither pickled nor copied
        (docs/interface.md, "Python API")."""
        raise TypeError("a Localizer cannot be pickled or copied (it holds a worker process and locks): make a new "
                        "one with the same config and seed and feed it the same inputs")

    @_one_at_a_time
    def reset(self, drop_datum: bool = False):
        """Drop the tracks, the points, the filters and the channels; keep the counters and the fixed stations'
        configured positions (the node's ~/reset). The datum is kept, so the map frame stays put, unless
        `drop_datum` and it was not configured: then the next confirmed fix sets a new one (the way out of a datum
        taken from a bad fix)."""
        if drop_datum and not self._cfg.has_datum:
            self._intake.frame = None
        self._channels = Channels(self._cfg, self._rng, self._rejections, self._scheduler)
        self._intake.reset(self._channels)
        self._start_tracks(self._estimates.on_estimate)

    def _adopt_datum(self, frame: LocalFrame | None):
        if frame is not None and not self._cfg.has_datum and self._intake.frame is None and not self._intake.stations:
            self._intake.frame = frame

    def _recent_points(self, n: int | None = None, channel: str | None = None) -> np.ndarray:
        found = self._estimates.latest if channel is None else self._channels.live.get(channel)
        rows = found.track.used_points() if found is not None else np.zeros((0, 5))
        return rows if n is None else rows[len(rows) - min(n, len(rows)):]

    # -- the old face, working for one more round with a DeprecationWarning (docs/interface.md, "Python API") ----
    def __getattr__(self, name: str):
        old = None if name.startswith("_") else _DEPRECATED.get(name)
        if old is None:
            raise AttributeError(f"'Localizer' object has no attribute {name!r}")
        advice, get = old
        warnings.warn(f"Localizer.{name} is deprecated: {advice}", DeprecationWarning, stacklevel=2)
        return get(self)

    def __setattr__(self, name: str, value) -> None:
        if name in ("on_estimate", "observer"):
            warnings.warn(f"setting Localizer.{name} is deprecated: give {name} to the constructor",
                          DeprecationWarning, stacklevel=2)
            if name == "on_estimate":
                self._estimates.on_estimate = value
            else:
                self._intake.observer = value
            return
        object.__setattr__(self, name, value)


def _by_channel(channel) -> str | None:
    """The old face's channel argument (a Channel, its id, or None) as an id."""
    return channel if channel is None or isinstance(channel, str) else channel.id


def _grid(loc: Localizer, channel=None) -> PosteriorGrid | None:
    post = loc.posterior(_by_channel(channel))
    return None if post is None else post.grid()


def _goal(loc: Localizer, vehicle: tuple[float, float], radius_m: float, channel=None) -> NextGoal | None:
    post = loc.posterior(_by_channel(channel))
    return None if post is None else post.next_goal(vehicle, radius_m)


# Each old member: what to use instead, and its value (a method's: a callable taking the old arguments)
_DEPRECATED: dict[str, tuple[str, Callable[[Localizer], Any]]] = {
    "estimate": ("read view().estimate, or what the add_ calls return", lambda loc: loc._estimates.newest),
    "on_estimate": ("give on_estimate to the constructor", lambda loc: loc._estimates.on_estimate),
    "observer": ("give observer to the constructor", lambda loc: loc._intake.observer),
    "channels": ("read view().channels (values; the engine's channels stay inside it)", lambda loc: loc._channels),
    "channel": ("read view().channel(cid)", lambda loc: loc._channel),
    "rejected": ("read view().rejected", lambda loc: loc._rejections.counts),
    "frame": ("read view().frame", lambda loc: loc._intake.frame),
    "datum_frame": ("read view().frame (None before the datum is set)", lambda loc: loc._intake.datum_frame),
    "stations": ("read view().stations", lambda loc: loc._intake.stations),
    "unknown_quality": ("read view().unknown_quality", lambda loc: loc._intake.pairing.unknown_quality),
    "other_band": ("read view().other_band", lambda loc: loc._intake.other_band),
    "status": ("read view().status", lambda loc: loc._status()),
    "events": ("read view().events",
               lambda loc: loc._estimates.latest.track.events + loc._intake.input_events),
    "track_status": ("read view().channel(cid).track",
                     lambda loc: lambda channel=None: (channel or loc._estimates.latest).track.summary()),
    "noise_summary": ("read view().noise",
                      lambda loc: lambda channel=None: (channel or loc._estimates.latest).track.noise_summary()),
    "clock_hint": ("read view().clock_hint", lambda loc: lambda: loc._estimates.latest.track.supervisor.clock_hint),
    "receiver_noise": ("read view().receiver_noise", lambda loc: loc._receiver_noise),
    "vehicle_place": ("read view().vehicles.get(station)",
                      lambda loc: lambda station="": loc.view(light=True).vehicles.get(station)),
    "recent_points": ("call posterior(cid).recent_points(n)", lambda loc: loc._recent_points),
    "start_cloud": ("read posterior().start_cloud",
                    lambda loc: loc._estimates.latest.track.initiator.start_cloud),
    "posterior_grid": ("call posterior(cid).grid()", lambda loc: functools.partial(_grid, loc)),
    "next_goal": ("call posterior(cid).next_goal(vehicle, radius_m)", lambda loc: functools.partial(_goal, loc)),
    "set_station_position": ("call add_station(name, fixed=True, position=(lat, lon, alt, sigma_m))",
                             lambda loc: lambda name, *position: loc.add_station(name, True, position)),
    "add_bearing_enu": ("feed an Input of kind bearing_pose", lambda loc: loc._add_bearing_enu),
    "wait_for_worker": ("call catch_up()", lambda loc: loc._wait_for_worker),
    "adopt_datum": ("give datum= to the constructor", lambda loc: loc._adopt_datum),
}
