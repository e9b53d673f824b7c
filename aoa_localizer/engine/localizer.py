"""Localizer: the ROS-free engine the node, the offline replay and the benchmarks all drive.

GPS fixes and DF readings go in as a vehicle gives them (lat/lon, azimuths, qualities, stamps);
estimates come out with ENU metres, lat/lon and a 2x2 covariance. Every input that is not used is
counted under a reason (`rejected`) and logged; no exception escapes for bad data.
"""
from __future__ import annotations

import functools
import logging
import math
import threading
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import replace
from typing import Protocol

import numpy as np

from aoa_localizer.engine.channels import Channel, Channels
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame, ground_to_map
from aoa_localizer.engine.inference.noise import sentence as noise_sentence
from aoa_localizer.engine.inference.receiver_pool import PooledNoise
from aoa_localizer.engine.ingest.gps_track import GpsTrack
from aoa_localizer.engine.ingest.intake import Closed, Intake, as_float
from aoa_localizer.engine.ingest.preprocess import reading_sigma
from aoa_localizer.engine.ingest.station import Station
from aoa_localizer.engine.outputs import survey_solver
from aoa_localizer.engine.outputs.next_goal import NextGoal, next_goal
from aoa_localizer.engine.outputs.posterior_grid import PosteriorGrid, posterior_grid
from aoa_localizer.engine.outputs.survey_log import SurveyFix, counted, live_fix, survey_sentence
from aoa_localizer.engine.rejections import Reason, Rejections
from aoa_localizer.engine.scheduling import slices
from aoa_localizer.engine.scheduling.memory import keep_freed_memory
from aoa_localizer.engine.scheduling.scheduler import PendingJob, Scheduler
from aoa_localizer.engine.track.report import co_channel, others_share
from aoa_localizer.engine.track.state import TrackStatus
from aoa_localizer.engine.types import Estimate, Input, Reading, Transmitter

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
    it at once broke its generators' and arrays' invariants, counted as internal_error)."""
    @functools.wraps(method)
    def serialised(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)
    return serialised


def _positive_definite(cov) -> bool:
    """Finite and full rank to working precision (a cloud of 2 particles, or all on one line, is not)."""
    (a, _), (b, c) = np.asarray(cov, float).tolist()  # 2x2 symmetric: its eigenvalues in closed form
    if not all(map(math.isfinite, (a, b, c))):
        return False
    high = 0.5 * (a + c) + math.hypot(0.5 * (a - c), b)
    return high > 0 and (a * c - b * b) / high > 1e-9 * high  # the low eigenvalue as det / high


class Localizer:
    """Pairs bearings with the interpolated GPS track, builds observation points, starts and runs a filter; one
    track per emitter (channel, by frequency) and one GPS track per station."""

    def __init__(self, config: LocalizerConfig | None = None, observer: Observer | None = None,
                 on_estimate: Callable[[Estimate], None] | None = None, live: bool = False):
        """`observer`: told of every accepted fix and every closed point (see Observer), for reports.
        `on_estimate`: called with every new estimate, whichever input made it (a fix often closes the point
        that makes it); `estimate` always holds the latest one (None before the first). `live`: a node's
        Localizer, scheduled `realtime` under `scheduling: auto`."""
        self._lock = threading.RLock()  # the calls below are made one at a time (_one_at_a_time)
        self._cfg = cfg = config or LocalizerConfig()
        self.on_estimate = on_estimate
        keep_freed_memory()  # the particle temporaries are reused, not mapped afresh (memory.py)
        self._rng = np.random.default_rng(cfg.seed)
        frame = None
        if cfg.datum_lat is not None and cfg.datum_lon is not None:
            frame = LocalFrame(cfg.datum_lat, cfg.datum_lon, cfg.datum_alt or 0.0)
        self._rejections = Rejections()
        realtime = cfg.scheduling == "realtime" or (cfg.scheduling == "auto" and live)
        self._scheduler = Scheduler(realtime, self._rejections)
        self.channels = Channels(cfg, self._rng, self._rejections, self._scheduler)
        self._intake = Intake(cfg, self.channels, self._rejections, frame, observer)
        self._intake.make_room = self._make_room
        self._room: Closed = []  # points of channels retired to make room for a record, used with its call
        self._fixed_stations: dict[str, tuple[float, float, float, float] | None] = {}  # configured positions
        self._start_tracks()

    def _start_tracks(self):
        """The state of a fresh start on the current channels (the fixed stations placed again)."""
        self._latest: Channel = self.channels.default  # the channel of the latest estimate (the default before one)
        self._retire_check = -math.inf  # DF stamp of the last look for silent channels
        self.estimate: Estimate | None = None
        for name, position in self._fixed_stations.items():
            self._intake.add_station(name, fixed=True)
            if position is not None:
                self._intake.place(name, *position)

    # -- what programs read ------------------------------------------------------------------------
    @property
    def config(self) -> LocalizerConfig:
        """The configuration the Localizer runs with (read-only: a change is a new Localizer, or `reset`)."""
        return self._cfg

    def channel(self, cid: str | None = None) -> Channel | None:
        """The channel `cid` (its id, "default" for readings without a frequency), None if it is not heard; without
        `cid`, the channel of the latest estimate (the default channel before one). A retired channel is found too."""
        return self._latest if cid is None else next((c for c in self.channels.all() if c.id == cid), None)

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
        return self._intake.unknown_quality

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
        base = self._intake.waiting_line if self._intake.waiting_for_gps else self._latest.track.status.words()
        return base + self._rejections.refused_line()

    def track_status(self, channel: Channel | None = None) -> TrackStatus:
        """The state of `channel`'s track (None: the channel of the latest estimate)."""
        return (channel or self._latest).track.summary()

    def recent_points(self, n: int | None = None, channel: str | None = None) -> np.ndarray:
        """The latest `n` (all: None) observation points the filter of `channel` (None: the latest estimate's) uses,
        oldest first, as rows of antenna east, north (m), bearing theta (ENU rad), its sigma (rad) and the antenna
        position's sigma (m); (0, 5) before the start."""
        found = self._latest if channel is None else self.channels.live.get(channel)
        rows = found.track.used_points() if found is not None else np.zeros((0, 5))
        return rows if n is None else rows[len(rows) - min(n, len(rows)):]

    @property
    def start_cloud(self) -> np.ndarray | None:
        """The particles the latest estimate's filter started from (after its latest start or re-start), or None."""
        return self._latest.track.initiator.start_cloud

    @property
    def events(self) -> Counter:
        """Robustness events (alarm, global_restart, emitter_moved, recalibrated) and input events
        (fix_clock_jump, df_clock_jump)."""
        return self._latest.track.events + self._intake.input_events

    def noise_summary(self, channel: Channel | None = None) -> dict:
        """The self-calibrated noise of a channel (default: the latest estimate's): sigma (deg) per quality band with
        data, reading and point outlier rates."""
        cfg = self._cfg
        return (channel or self._latest).track.calibration.noise_summary(lambda q: math.degrees(reading_sigma(q, cfg)))

    def clock_hint_sentence(self) -> str | None:
        """Words for a DF clock offset the bearings point to (from the last global check), or None."""
        hint = self._latest.track.supervisor.clock_hint
        if hint is None:
            return None
        return (f"the bearings fit the track far better with the DF stamps shifted by {hint.shift_s:+.2f} s "
                f"(log-likelihood +{hint.gain:.0f}): a receiver delay or clock offset? try df_time_offset_s = "
                f"{self._cfg.df_time_offset_s + hint.shift_s:.2f}")

    def receiver_noise(self) -> PooledNoise | None:
        """The receiver's noise pooled over the channels that calibrated theirs (receiver_pool.py), when more than
        one frequency was heard (with one, its own calibration says it all); None otherwise."""
        if sum(not math.isnan(c.frequency_hz) for c in self.channels.all()) < 2 or not self._cfg.calibrate_noise:
            return None
        return self.channels.pooled_noise()

    def robustness_lines(self) -> list[str]:
        """Human lines on what the robustness layer saw: the receiver's noise, alternative hypotheses, events."""
        lines = []
        est = self.estimate
        if est is not None and est.algorithm == "survey" and est.noise:
            lines.append(survey_sentence(est.noise))
        elif self._cfg.calibrate_noise:
            line = noise_sentence(self.noise_summary())
            if est is not None and est.transmitters:  # the channel's calibration reads the others' bearings as wild
                line += " (among them the other transmitters' on the frequency: see the count)"
            lines.append(line)
        pooled = self.receiver_noise()
        if pooled is not None:
            lines.append(f"the receiver over its channels: {pooled.sentence()}")
        if est is not None and len(est.modes) > 1:
            lines.append("alternative hypotheses: " + "; ".join(
                f"E {e:.1f} N {n:.1f} ({100 * m:.0f} %)" for e, n, m in est.modes))
        hint = self.clock_hint_sentence()
        if hint:
            lines.append(hint)
        events = {k: v for k, v in self.events.items() if k != "alarm_points"}
        if events:
            lines.append("robustness events: " + ", ".join(f"{k} {v}" for k, v in sorted(events.items())))
        return lines

    def posterior_grid(self, channel: Channel | None = None) -> PosteriorGrid | None:
        """The posterior of `channel`'s track (None: the latest estimate's channel) on a map grid around its
        estimate (engine/outputs/posterior_grid.py); None before its first estimate."""
        channel = channel or self._latest
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
        channel = channel or self._latest
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
        return self._add_points(self._intake.add_fix(stamp, lat, lon, alt, status, sigma_m, station))

    @_one_at_a_time
    def add_heading(self, stamp, yaw_rad, station: str = "", variance_rad2=float("nan")) -> None:
        """The vehicle's heading from an IMU: REP-103 yaw (rad, counter-clockwise from east, ENU at the vehicle), as
        sensor_msgs/Imu gives it, and the yaw's variance (rad^2; NaN, 0 or negative: not known, taken as exact). Used
        with `bearing_reference: vehicle` and `heading_source: imu`."""
        self._intake.add_heading(stamp, yaw_rad, station, variance_rad2)

    @_one_at_a_time
    def add_bearing(self, stamp, azimuth_deg, quality=float("nan"), station: str = "",
                    frequency_hz=float("nan")) -> Estimate | None:
        """A DF record: azimuth (deg) and quality of the carrier at `frequency_hz` (0 or NaN: the default
        channel) seen from `station`. Returns the estimate this reading produced (when it closed an observation
        point), else None."""
        return self._add_bearing(stamp, azimuth_deg, quality, float("nan"), station, frequency_hz)

    @_one_at_a_time
    def add_bearing_enu(self, stamp, yaw_rad, variance_rad2=float("nan"), station: str = "",
                        frequency_hz=float("nan")) -> Estimate | None:
        """A bearing as a REP-103 yaw (rad, counter-clockwise from east at the antenna) with its variance
        (the `pose` encoding). No quality: counted as unknown quality; NaN or non-positive variance
        means the configured sigma."""
        yaw, var = as_float(yaw_rad), as_float(variance_rad2)
        sigma = math.sqrt(var) if var > 0 and math.isfinite(var) else float("nan")
        azimuth = 90.0 - math.degrees(yaw) if math.isfinite(yaw) else yaw
        return self._add_bearing(stamp, azimuth, float("nan"), sigma, station, frequency_hz)

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
                                    frequency_hz=getattr(r, "frequency_hz", nan))
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

    def _add_bearing(self, stamp, azimuth_deg, quality, sigma, station, frequency_hz) -> Estimate | None:
        admitted = self._intake.admit_bearing(stamp, azimuth_deg, quality, sigma, station, frequency_hz)
        room, self._room = self._room, []
        if admitted is None:
            return self._add_points(room) if room else None
        st, now = admitted
        return self._add_points(room + self._retire_silent(now) + self._intake.release(st))

    def _make_room(self, stamp: float) -> bool:
        """A record found every channel taken: the channels silent for channel_timeout_s before its stamp (the
        intake checked it lies on its station's timeline) are retired now, not at the next record admitted, which
        at the limit never comes. Whether any went."""
        before = len(self.channels.live)
        self._room += self._retire_silent(stamp, every_time=True)
        return len(self.channels.live) < before

    def _retire_silent(self, now: float, every_time: bool = False) -> Closed:
        """Once per second of DF time (`every_time`: now): retire the channels silent for channel_timeout_s; their
        open points close."""
        if now - self._retire_check < 1.0 and not every_time:
            return []
        self._retire_check = now
        closed: Closed = []
        for channel in self.channels.retire_silent(now):
            closed += [(channel, group) for group in (b.flush() for b in channel.builders.values()) if group]
            log.info("channel %s (%.0f Hz) silent for %.0f s: retired, its last estimate kept", channel.id,
                     channel.frequency_hz, now - channel.last_heard)
        return closed

    # -- the lifecycle ----------------------------------------------------------------------------
    @_one_at_a_time
    def flush(self) -> Estimate | None:
        """End of data: bearings still waiting for a fix are dropped, the open observation points are used."""
        return self._add_points(self._intake.flush())

    @_one_at_a_time
    def finish(self) -> Estimate | None:
        """After flush(), offline: one last global check over all the data (calibration, modes, moves) on every
        live channel, so the final estimates and their modes reflect everything; those Estimates have
        `end_of_data` set. Returns the last of them (None if no filter runs, or the last points just had a check).
        A live node never sees the end of data and never calls it."""
        estimate = None
        surveyed = self._survey_end() if self._cfg.end_of_data_model == "survey" else {}
        for channel in self.channels.all():  # a survey's channels may have retired between its bearings
            if channel.id in surveyed:
                estimate = self._publish_survey(channel, surveyed[channel.id]) or estimate
            elif not channel.retired and channel.track.finish():
                estimate = self._publish(channel, end_of_data=True) or estimate
        return estimate

    def _survey_end(self) -> dict[str, SurveyFix]:
        """The survey model's fixes of the survey-like channels (survey_log.py), {} without any or a solver."""
        solve = survey_solver.solver()
        if solve is None or self._intake.frame is None:
            return {}
        records = self._intake.survey_log.survey_records(self._intake.frame)
        return solve(records, self._cfg.receiver_class, self._cfg.max_emitters_per_channel) if records else {}

    def _live_survey(self, channel: Channel) -> Estimate | None:
        """A survey-like channel's estimate while the data come (every bearing from a fixed site or a standing
        antenna, from three places on): the survey model's fix of its bearings alone, made again as they grow
        (SurveyLog.due) as a job of the scheduler's (the check worker's, or made in turns at the points that follow:
        a fix that counts transmitters takes up to seconds) and published once it is done; until then the last one,
        restamped; None (the filter's estimate) for any other channel or while the model has no fix for it. The end
        of data pools every survey-like channel (finish)."""
        survey, place = self._intake.survey_log, channel.surveying
        done = self._scheduler.finished(place)
        if done is not None:
            return self._adopt_live_fix(channel, done)
        solve = survey_solver.solver()
        if solve is not None and survey.due(channel.id) and self._scheduler.job(place) is None:
            survey.mark_solved(channel.id)
            records = survey.survey_records(self.datum_frame(), only=channel.id)
            if survey.count_due(channel.id):
                max_k, last = self._cfg.max_emitters_per_channel, None
                survey.counted[channel.id] = (len(records), survey.counted.get(channel.id, (0, None))[1])
            else:
                max_k, last = 1, survey.counted[channel.id][1]
            job = functools.partial(live_fix, solve, records, channel.id, self._cfg.receiver_class, max_k, last)
            self._scheduler.start(place, job, slices.CHECK_BUDGET_US, None, [], first_turn=False)
        last_made = survey.live.get(channel.id)
        if last_made is None:
            return None
        return self._announce(channel, replace(last_made, stamp=channel.track.last_stamp))

    def _adopt_live_fix(self, channel: Channel, done: PendingJob) -> Estimate | None:
        """A live survey fix the scheduler finished, published (and its count kept when it made one)."""
        survey = self._intake.survey_log
        fix = self._scheduler.value(done, "a live survey fix")[1]
        if fix is not None and fix.count is not None and channel.id in survey.counted:
            survey.counted[channel.id] = (survey.counted[channel.id][0], fix.count)
        made = self._publish_survey(channel, fix, end_of_data=False) if fix is not None else None
        if made is None:
            survey.live.pop(channel.id, None)
        else:
            survey.live[channel.id] = made
        return made

    def _publish_survey(self, channel: Channel, fix: SurveyFix, end_of_data: bool = True) -> Estimate | None:
        """A survey-like channel's estimate from the survey model, in the map frame."""
        if not _positive_definite(fix.cov):
            self._rejections(Reason.COVARIANCE_DEGENERATE)
            return None
        frame = self.datum_frame()
        east, north = frame.to_enu(fix.lat, fix.lon)
        track = channel.track
        to_map = ground_to_map(frame.north_angle(fix.lat, fix.lon), LocalFrame.skew(east, north))
        estimate = Estimate(stamp=track.last_stamp, east=float(east), north=float(north), lat=fix.lat, lon=fix.lon,
                            cov=to_map @ fix.cov @ to_map.T, ground_cov=np.array(fix.cov),
                            bearings_used=fix.bearings, points_used=track.points_used,
                            ess=float("nan"), algorithm="survey", modes=[(float(east), float(north), 1.0)],
                            noise=fix.noise, channel=channel.id, frequency_hz=channel.frequency_hz, state=fix.state,
                            warnings=list(fix.warnings), end_of_data=end_of_data, regions=fix.regions,
                            **counted(fix.count, frame))
        return self._announce(channel, estimate)

    @_one_at_a_time
    def idle(self) -> list[Estimate]:
        """Between inputs (`scheduling: realtime`; the node calls it every few ms): the worker's finished results
        applied now rather than at each channel's next point, so a channel whose data paused still gets the start or
        check it was due, and one owed move made, for the channel owing the most, so the points that follow carry
        none. Returns the estimates the results made (each also goes to `on_estimate`)."""
        live = list(self.channels.live.values())
        done = [c for c in live if c.track.apply_job() and c.track.estimating]
        made = [est for est in (self._publish(c) for c in done) if est is not None]
        self._scheduler.move_one(c.track.debtor for c in live)
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
        """Wait until the check worker has finished the live channels' jobs (`scheduling: realtime`; nothing
        otherwise); their results are applied at each channel's next point, or by idle() or catch_up()."""
        self._scheduler.wait(c.track for c in self.channels.live.values())

    def close(self):
        """Stop the background checks' worker (a check running finishes; its result is dropped)."""
        self._scheduler.close()

    def __reduce_ex__(self, protocol):
        """A Localizer holds a worker process, locks and generators mid-run: it is neither pickled nor copied
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
        self._start_tracks()

    @_one_at_a_time
    def adopt_datum(self, frame: LocalFrame | None):
        """Keep the map frame of an earlier Localizer (a datum it took from a fix) so that a restart with new
        settings does not move the map; a configured datum (datum_lat, datum_lon) wins and is kept."""
        if frame is not None and not self._cfg.has_datum and self.frame is None and not self.stations:
            self._intake.frame = frame

    # -- estimates --------------------------------------------------------------------------------
    def _add_points(self, closed: Closed) -> Estimate | None:
        """The channels' tracks take the closed points in order, the points of one track within one call's budget
        for its jobs (slices.py; each track its own, so a channel's run never depends on another's); returns the
        newest estimate they made (a survey-like channel's survey fix also while its filter has not started)."""
        estimate = None
        calls: dict[int, slices.Call] = {}
        for channel, readings in closed:
            track = channel.track
            with slices.one_call(calls.setdefault(id(track), slices.Call())):
                self._scheduler.point_came(channel.surveying)
                took = track.add(readings)
                self._scheduler.take_turn(channel.surveying)  # its live survey fix's turn, after the track's
            if self._intake.observer is not None:
                self._intake.observer.on_point(readings, track.last_kept)
            if took:
                estimate = self._publish(channel) or estimate
            elif self._cfg.end_of_data_model == "survey":  # a survey-like channel's fix needs no started filter
                estimate = self._live_survey(channel) or estimate
        return estimate

    def _publish(self, channel: Channel, end_of_data: bool = False) -> Estimate | None:
        """The channel's new estimate, kept and handed to `on_estimate`; None (counted) when its covariance is not
        positive definite. A survey-like channel's is the survey model's while it has a fix (_live_survey)."""
        if not end_of_data and self._cfg.end_of_data_model == "survey":
            live = self._live_survey(channel)
            if live is not None:
                return live
        track = channel.track
        mean, cov = track.estimate()
        if not _positive_definite(cov):
            self._rejections(Reason.COVARIANCE_DEGENERATE)
            return None
        frame = self.datum_frame()
        lat, lon, _ = frame.to_geodetic(mean[0], mean[1])
        from_map = np.linalg.inv(ground_to_map(frame.north_angle(lat, lon), LocalFrame.skew(mean[0], mean[1])))
        f = track.cloud
        count = track.count_transmitters(final=end_of_data)
        modes, state, warnings = track.assess(np.asarray(mean), np.asarray(cov), others_share(count, np.asarray(mean)))
        transmitters: list[Transmitter] = []
        if count is not None:
            # the antennas only rate the transmitters' ellipses: a single transmitter (most channels) skips them
            antennas = np.array([[g[0].east, g[0].north] for g in track.heard]) if count.transmitters else None
            places, said = co_channel(count, antennas, self._cfg.max_emitters_per_channel)
            warnings = warnings + said
            for place, place_state in places:
                t_lat, t_lon, _ = frame.to_geodetic(place.mean[0], place.mean[1])
                transmitters.append(Transmitter(float(place.mean[0]), float(place.mean[1]), float(t_lat),
                                                float(t_lon), place.cov.copy(), place.share, place_state))
        estimate = Estimate(stamp=track.last_stamp, east=float(mean[0]), north=float(mean[1]), lat=float(lat),
                            lon=float(lon), cov=np.array(cov), ground_cov=from_map @ np.asarray(cov) @ from_map.T,
                            bearings_used=track.bearings_used,
                            points_used=track.points_used, ess=f.ess(), algorithm=self._cfg.algorithm,
                            # the user's own copies: the filter's arrays are read-only and shared
                            particles=f.x.copy(), weights=f.weights.copy(), modes=modes,
                            noise=self.noise_summary(channel) if self._cfg.calibrate_noise else None,
                            channel=channel.id, frequency_hz=channel.frequency_hz, state=state, warnings=warnings,
                            end_of_data=end_of_data, transmitter_count=count.count if count is not None else 1,
                            count_probability=count.probability if count is not None else float("nan"),
                            transmitters=transmitters)
        return self._announce(channel, estimate)

    def _announce(self, channel: Channel, estimate: Estimate) -> Estimate:
        """Keep a channel's new estimate as its and the newest, and hand it to `on_estimate`."""
        channel.published(estimate)
        self.estimate = estimate
        self._latest = channel
        if self.on_estimate is not None:
            self.on_estimate(estimate)
        return estimate
