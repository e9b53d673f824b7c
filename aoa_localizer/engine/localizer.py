"""Localizer: the ROS-free engine the node, the offline replay and the benchmarks all drive.

GPS fixes and DF readings go in as a vehicle gives them (lat/lon, azimuths, qualities, stamps);
estimates come out with ENU metres, lat/lon and a 2x2 covariance. Every input that is not used is
counted under a reason (`rejected`) and logged; no exception escapes for bad data. An input goes to the intake
(ingest/intake.py), and the points it closes to the estimates (outputs/estimates.py): one way, no call back.
"""
from __future__ import annotations

import functools
import logging
import math
import threading
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from typing import Protocol

import numpy as np

from aoa_localizer.engine.channels import Channel, Channels
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.inference.clock_check import ClockHint
from aoa_localizer.engine.inference.receiver_pool import PooledNoise
from aoa_localizer.engine.ingest.gps_track import GpsTrack
from aoa_localizer.engine.ingest.intake import Intake, as_float
from aoa_localizer.engine.ingest.station import Station
from aoa_localizer.engine.outputs.estimates import Estimates, noise_summary
from aoa_localizer.engine.outputs.next_goal import NextGoal, next_goal
from aoa_localizer.engine.outputs.posterior_grid import PosteriorGrid, posterior_grid
from aoa_localizer.engine.rejections import Rejections
from aoa_localizer.engine.scheduling.scheduler import Scheduler
from aoa_localizer.engine.survey.survey_solver import SurveySolver, pooled_solver
from aoa_localizer.engine.track.state import TrackStatus
from aoa_localizer.engine.types import Estimate, Input, Reading

log = logging.getLogger("aoa_localizer")


# The required fields of each kind of input (Localizer.feed); the add_ calls' other arguments are optional.
_INPUT_FIELDS = {"fix": ("stamp", "lat", "lon"), "bearing": ("stamp", "azimuth_deg"),
                 "bearing_pose": ("stamp", "yaw_rad"), "heading": ("stamp", "yaw_rad")}


class Observer(Protocol):
    """What a program may watch, per input, without reading the engine's internals (reports keep a trace)."""

    def on_fix(self, stamp: float, east: float, north: float, station: str) -> None:
        """An accepted fix, at its ENU position, and its station ("" : the default one)."""

    def on_point(self, readings: list[Reading], kept: np.ndarray) -> None:
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
                 survey_solver: SurveySolver | None = pooled_solver):
        """`observer`: told of every accepted fix and every closed point (see Observer), for reports.
        `on_estimate`: called with every new estimate, whichever input made it (a fix often closes the point
        that makes it); `estimate` always holds the latest one (None before the first). `live`: a node's
        Localizer, scheduled `realtime` under `scheduling: auto`. `survey_solver`: the survey model of the
        channels heard from fixed sites or standing antennas (default aoa_localizer.pooled's; None: none, such a
        channel keeps its filter's estimate)."""
        self._lock = threading.RLock()  # the calls below are made one at a time (_one_at_a_time)
        self._cfg = cfg = config or LocalizerConfig()
        self._survey_solver = survey_solver
        self._rng = np.random.default_rng(cfg.seed)
        frame = None
        if cfg.datum_lat is not None and cfg.datum_lon is not None:
            frame = LocalFrame(cfg.datum_lat, cfg.datum_lon, cfg.datum_alt or 0.0)
        self._rejections = Rejections()
        realtime = cfg.scheduling == "realtime" or (cfg.scheduling == "auto" and live)
        self._scheduler = Scheduler(realtime, self._rejections)
        self.channels = Channels(cfg, self._rng, self._rejections, self._scheduler)
        self._intake = Intake(cfg, self.channels, self._rejections, frame, observer)
        self._fixed_stations: dict[str, tuple[float, float, float, float] | None] = {}  # configured positions
        self._start_tracks(on_estimate)

    def _start_tracks(self, on_estimate: Callable[[Estimate], None] | None):
        """The state of a fresh start on the current channels (the fixed stations placed again)."""
        self._estimates = Estimates(self._cfg, self.channels, self._intake, self._scheduler, self._rejections,
                                    on_estimate, self._survey_solver)
        for name, position in self._fixed_stations.items():
            self._intake.add_station(name, fixed=True)
            if position is not None:
                self._intake.place(name, *position)

    # -- what programs read ------------------------------------------------------------------------
    @property
    def estimate(self) -> Estimate | None:
        """The newest estimate of any channel; None before the first."""
        return self._estimates.newest

    @property
    def on_estimate(self) -> Callable[[Estimate], None] | None:
        """Called with every new estimate, whichever input or call made it (None: nobody is told)."""
        return self._estimates.on_estimate

    @on_estimate.setter
    def on_estimate(self, on_estimate: Callable[[Estimate], None] | None):
        self._estimates.on_estimate = on_estimate

    @property
    def config(self) -> LocalizerConfig:
        """The configuration the Localizer runs with (read-only: a change is a new Localizer, or `reset`)."""
        return self._cfg

    def channel(self, cid: str | None = None) -> Channel | None:
        """The channel `cid` (its id, "default" for readings without a frequency), None if it is not heard; without
        `cid`, the channel of the latest estimate (the default channel before one). A retired channel is found too."""
        return self._estimates.latest if cid is None else next((c for c in self.channels.all() if c.id == cid), None)

    @property
    def rejected(self) -> Counter:
        """Inputs not used, by reason (rejections.Reason: docs/design.md's table)."""
        return self._rejections.counts

    @property
    def frame(self) -> LocalFrame | None:
        """The map frame at the datum; None before it is set."""
        return self._intake.frame

    @property
    def stations(self) -> dict[str, Station]:
        return self._intake.stations

    @property
    def unknown_quality(self) -> int:
        """Readings used with NaN quality (no correction, the default sigma)."""
        return self._intake.pairing.unknown_quality

    @property
    def other_band(self) -> int:
        """DF records outside `frequency_band_hz` (another node's band), not used and not refused."""
        return self._intake.other_band

    @property
    def observer(self) -> Observer | None:
        return self._intake.observer

    @observer.setter
    def observer(self, observer: Observer | None):
        self._intake.observer = observer

    @property
    def status(self) -> str:
        """One line on the state: waiting for a fix, collecting bearings, waiting for geometry, tracking, checking;
        and, when more than half of the latest inputs were refused, the commonest reason."""
        intake = self._intake
        base = intake.waiting_line if intake.waiting_for_gps else self._estimates.latest.track.status.words()
        return base + self._rejections.refused_line()

    def track_status(self, channel: Channel | None = None) -> TrackStatus:
        """The state of `channel`'s track (None: the channel of the latest estimate)."""
        return (channel or self._estimates.latest).track.summary()

    def recent_points(self, n: int | None = None, channel: str | None = None) -> np.ndarray:
        """The latest `n` (all: None) observation points the filter of `channel` (None: the latest estimate's) uses,
        oldest first, as rows of antenna east, north (m), bearing theta (ENU rad), its sigma (rad) and the antenna
        position's sigma (m); (0, 5) before the start."""
        found = self._estimates.latest if channel is None else self.channels.live.get(channel)
        rows = found.track.used_points() if found is not None else np.zeros((0, 5))
        return rows if n is None else rows[len(rows) - min(n, len(rows)):]

    @property
    def start_cloud(self) -> np.ndarray | None:
        """The particles the latest estimate's filter started from (after its latest start or re-start), or None."""
        return self._estimates.latest.track.initiator.start_cloud

    @property
    def events(self) -> Counter:
        """Robustness events (alarm, global_restart, emitter_moved, recalibrated) and input events
        (fix_clock_jump, df_clock_jump)."""
        return self._estimates.latest.track.events + self._intake.input_events

    def noise_summary(self, channel: Channel | None = None) -> dict:
        """The self-calibrated noise of a channel (default: the latest estimate's): sigma (deg) per quality band with
        data, reading and point outlier rates."""
        return noise_summary(channel or self._estimates.latest, self._cfg)

    def clock_hint(self) -> ClockHint | None:
        """The DF clock offset the bearings point to, from the latest estimate's last global check (None: none)."""
        return self._estimates.latest.track.supervisor.clock_hint

    def receiver_noise(self) -> PooledNoise | None:
        """The receiver's noise pooled over the channels that calibrated theirs (receiver_pool.py), when more than
        one frequency was heard (with one, its own calibration says it all); None otherwise."""
        if sum(not math.isnan(c.frequency_hz) for c in self.channels.all()) < 2 or not self._cfg.calibrate_noise:
            return None
        return self.channels.pooled_noise()

    def posterior_grid(self, channel: Channel | None = None) -> PosteriorGrid | None:
        """The posterior of `channel`'s track (None: the latest estimate's channel) on a map grid around its
        estimate (engine/outputs/posterior_grid.py); None before its first estimate."""
        channel = channel or self._estimates.latest
        track, est = channel.track, channel.estimate
        if est is None or not track.estimating:
            return None
        places = np.vstack([track.cloud.x, np.array([m[:2] for m in est.modes]).reshape(-1, 2)])
        return posterior_grid(track.posterior_points(), track.robust(), np.array([est.east, est.north]), est.cov,
                              places, track.modes)

    def vehicle_place(self, station: str = "") -> tuple[float, float] | None:
        """A moving station's newest accepted fix (east, north in the map frame, m); None before one, or for a fixed
        site."""
        st = self._intake.stations.get(station)
        if st is None or not isinstance(st.gps, GpsTrack) or not len(st.gps):
            return None
        return st.gps.e[-1], st.gps.n[-1]

    def next_goal(self, vehicle: tuple[float, float], radius_m: float, channel: Channel | None = None
                  ) -> NextGoal | None:
        """Where within `radius_m` of `vehicle` (east, north) the next bearing is expected to shrink the posterior of
        `channel` (None: the latest estimate's) most (engine/outputs/next_goal.py), for a bearing as noisy as the
        median of the points used; None before its first estimate, and while a provisional one is behind the points
        held (the vehicle should drive on, across its bearings)."""
        channel = channel or self._estimates.latest
        track, est = channel.track, channel.estimate
        if est is None or not track.cloud_is_current:
            return None
        sigma = float(np.median(track.posterior_points().sigma))
        return next_goal(track.cloud.x, track.cloud.weights, vehicle, radius_m, sigma)

    def datum_frame(self) -> LocalFrame:
        """The map frame at the datum (ENU metres); raises RuntimeError before the datum is set."""
        return self._intake.datum_frame()

    # -- inputs -----------------------------------------------------------------------------------
    def add_station(self, name: str, fixed: bool = False) -> Station:
        """Declare a station (stations are also made at their first input, moving). `fixed`: a site that does not
        move; its position comes from `set_station_position` or its fixes (the newest wins), not a track."""
        if fixed:
            self._fixed_stations.setdefault(name, None)
        return self._intake.add_station(name, fixed)

    @_one_at_a_time
    def set_station_position(self, name: str, lat, lon, alt=float("nan"), sigma_m=0.0) -> bool:
        """A fixed station's position (kept across reset()); it sets the datum when none is set yet. False (the
        reason counted) for a position a fix could not have."""
        lat, lon, alt, sigma_m = map(as_float, (lat, lon, alt, sigma_m))
        why = self._intake.bad_position(lat, lon, alt)
        if why:
            self._rejections(why)
            return False
        self.add_station(name, fixed=True)
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

    def add_bearing_enu(self, stamp, yaw_rad, variance_rad2=float("nan"), station: str = "",
                        frequency_hz=float("nan")) -> Estimate | None:
        """A bearing as a REP-103 yaw (rad, counter-clockwise from east at the antenna) with its variance
        (the `pose` encoding): add_bearing with its azimuth and sigma. No quality: counted as unknown quality.
        A variance of NaN or 0 (ROS's "not filled in") means the configured sigma; a negative or infinite one is
        refused as add_bearing refuses such a sigma (`bad_sigma`)."""
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
            return self.add_bearing_enu(r.stamp, r.yaw_rad, getattr(r, "variance_rad2", nan), station=station)
        self.add_heading(r.stamp, r.yaw_rad, station=station, variance_rad2=getattr(r, "variance_rad2", nan))
        return None

    def run(self, source: Iterable[Input]) -> Iterator[Estimate]:
        """Offline, in one call: every input of `source` fed in order, then the end of data (flush, finish) and the
        worker stopped. Yields each estimate an input made, as feed() returns it, then flush's and finish's. Under
        `scheduling: realtime` the worker is waited for and the owed moves made after each input (catch_up), so the
        run is what a node at the receiver's pace would make."""
        try:
            for event in source:
                estimate = self.feed(event)
                if self._scheduler.realtime:
                    self.catch_up()
                if estimate is not None:
                    yield estimate
            for estimate in (self.flush(), self.finish()):
                if estimate is not None:
                    yield estimate
        finally:
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
        live = list(self.channels.live.values())
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
        jobs' results are applied at each channel's next point, as live. Returns how many moves it made."""
        self.wait_for_worker()
        tracks = [c.track for c in self.channels.live.values()]
        made = 0
        while self._scheduler.move_one(t.debtor for t in tracks):
            made += 1
        return made

    @_one_at_a_time
    def wait_for_worker(self) -> None:
        """Wait until the check worker has finished the live channels' jobs, counts and site-part fits included
        (`scheduling: realtime`; nothing otherwise); their results are applied at each channel's next point, or by
        idle()."""
        self._scheduler.wait(place for c in self.channels.live.values() for place in c.track.places)

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
        self.channels = Channels(self._cfg, self._rng, self._rejections, self._scheduler)
        self._intake.reset(self.channels)
        self._start_tracks(self._estimates.on_estimate)

    @_one_at_a_time
    def adopt_datum(self, frame: LocalFrame | None):
        """Keep the map frame of an earlier Localizer (a datum it took from a fix) so that a restart with new
        settings does not move the map; a configured datum (datum_lat, datum_lon) wins and is kept."""
        if frame is not None and not self._cfg.has_datum and self.frame is None and not self.stations:
            self._intake.frame = frame
