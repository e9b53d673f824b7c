"""Localizer: the ROS-free engine the node, the offline replay and the benchmarks all drive.

GPS fixes and DF readings go in as a vehicle gives them (lat/lon, azimuths, qualities, stamps);
estimates come out with ENU metres, lat/lon and a 2x2 covariance. Every input that is not used is
counted under a reason (`rejected`) and logged; no exception escapes for bad data.
"""
from __future__ import annotations

import logging
import math
from collections import Counter, deque
from collections.abc import Callable
from concurrent.futures import wait
from typing import Protocol

import numpy as np

from aoa_localizer.engine.channels import Channel, Channels
from aoa_localizer.engine.checks import CheckWorker
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame, azimuth_to_enu, wrap_pi
from aoa_localizer.engine.gps_track import GpsTrack, Where
from aoa_localizer.engine.heading import ImuHeading, TrackHeading
from aoa_localizer.engine.input_guard import StreamClock, Verdict, confirms, implausible_fix
from aoa_localizer.engine.noise import sentence as noise_sentence
from aoa_localizer.engine.preprocess import PointBuilder, reading_sigma
from aoa_localizer.engine.station import Pending, PendingQueue, Station
from aoa_localizer.engine.track import EmitterTrack
from aoa_localizer.engine.track_report import assess, mode_masses
from aoa_localizer.engine.track_state import TrackStatus
from aoa_localizer.engine.types import Estimate, ObservationPoint, Reading

log = logging.getLogger("aoa_localizer")

_RECENT_INPUTS = 50  # inputs whose fate the status watches ...
_RECENT_MIN = 20  # ... once at least this many came
_MAX_PENDING = 100_000  # bearings waiting for a fix, at most (the age limit normally binds long before)
_CLOCK_REASONS = {Verdict.REPEATED: "repeated", Verdict.OUT_OF_ORDER: "out_of_order", Verdict.AHEAD: "stamp_jump"}

REASONS = {
    "bad_stamp": "stamp is not a finite number",
    "bad_azimuth": "azimuth is NaN or infinite",
    "bad_quality": "quality outside 0..100",
    "low_quality": "quality below quality_min",
    "bearing_out_of_order": "bearing stamp older than the previous bearing",
    "bearing_repeated": "bearing stamp equal to the previous bearing",
    "before_first_fix": "no GPS fix at or before the bearing",
    "gps_gap": "the fixes around the bearing are more than gps_max_gap_s apart",
    "no_fix_after": "no later fix came to bracket the bearing before the end of data",
    "point_outlier": "wild reading inside an observation point (point_gate_sigma)",
    "init_buffer_full": "geometry stayed too poor to start; oldest points dropped (init_max_points)",
    "emitter_moved": "bearings from before the emitter moved, dropped when the track re-started from the recent ones",
    "weights_degenerate": "no particle could explain the point; measurement skipped",
    "internal_error": "an unexpected error in the filter; measurement skipped, state kept",
    "filter_diverged": "the filter's particles or estimate were not finite; not published, the filter restarts",
    "fix_bad_stamp": "fix stamp is not a finite number",
    "fix_no_fix": "NavSatFix status below STATUS_FIX",
    "fix_bad_position": "fix latitude/longitude NaN, infinite or out of range",
    "fix_out_of_order": "fix stamp older than the previous fix",
    "fix_repeated": "fix stamp equal to the previous fix",
    "fix_bad_altitude": "fix altitude outside -1000..20000 m",
    "fix_near_pole": "fix within 0.01 deg of a pole (no local north)",
    "fix_null_island": "fix at exactly 0, 0 (a receiver without a fix)",
    "fix_unconfirmed": "a first fix the next fix contradicts (farther than 100 m + 150 m/s): not taken as the datum",
    "fix_stamp_jump": "fix stamp more than max_stamp_jump_s ahead of the GPS stream: not adopted",
    "bearing_stamp_jump": "bearing stamp more than max_stamp_jump_s ahead of the DF stream: not adopted",
    "clock_jump": "a bearing of the old timeline still waiting for a fix when the DF clock jumped",
    "covariance_degenerate": "the filter's covariance was not positive definite: estimate not published",
    "heading_unknown": "a vehicle-relative bearing with no heading at its stamp: too slow for a course, or no IMU "
    "heading, for longer than heading_hold_s",
    "bad_heading": "heading stamp or yaw is not a finite number",
    "heading_out_of_order": "heading stamp not after the previous heading",
    "heading_ignored": "a heading given while bearing_reference is not `vehicle` or heading_source is not `imu`",
    "bad_frequency": "frequency negative, infinite or above 1 THz (0 or NaN: the default channel)",
    "channel_limit": "a new frequency while max_channels channels are tracked",
    "channel_retired": "a bearing still waiting for a fix when its channel was retired (channel_timeout_s)",
}


class Observer(Protocol):
    """What a program may watch, per input, without reading the engine's internals (reports keep a trace)."""

    def on_fix(self, stamp: float, east: float, north: float, station: str) -> None:
        """An accepted fix, at its ENU position, and its station ("" : the default one)."""

    def on_point(self, readings: list[Reading], kept: np.ndarray) -> None:
        """The readings of a closed observation point, and which of them it kept (False: gated out as wild)."""


def _positive_definite(cov) -> bool:
    """Finite and full rank to working precision (a cloud of 2 particles, or all on one line, is not)."""
    (a, _), (b, c) = np.asarray(cov, float).tolist()  # 2x2 symmetric: its eigenvalues in closed form
    if not all(map(math.isfinite, (a, b, c))):
        return False
    high = 0.5 * (a + c) + math.hypot(0.5 * (a - c), b)
    return high > 0 and (a * c - b * b) / high > 1e-9 * high  # the low eigenvalue as det / high


def _as_float(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


class Localizer:
    """Pairs bearings with the interpolated GPS track, builds observation points, starts and runs a filter; one
    track per emitter (channel, by frequency) and one GPS track per station."""

    def __init__(self, config: LocalizerConfig | None = None, observer: Observer | None = None,
                 on_estimate: Callable[[Estimate], None] | None = None, live: bool = False):
        """`observer`: told of every accepted fix and every closed point (see Observer), for reports.
        `on_estimate`: called with every new estimate, whichever input made it (a fix often closes the point
        that makes it); `estimate` always holds the latest one (None before the first). `live`: a node's
        Localizer, scheduled `realtime` under `scheduling: auto`."""
        self.cfg = config or LocalizerConfig()
        self.observer = observer
        self.on_estimate = on_estimate
        self.rng = np.random.default_rng(self.cfg.seed)
        mode = self.cfg.scheduling
        self.worker = CheckWorker() if mode == "realtime" or (mode == "auto" and live) else None
        self.frame: LocalFrame | None = None
        if self.cfg.datum_lat is not None and self.cfg.datum_lon is not None:
            self.frame = LocalFrame(self.cfg.datum_lat, self.cfg.datum_lon, self.cfg.datum_alt or 0.0)
        self.rejected: Counter = Counter()
        self.input_events: Counter = Counter()  # fix_clock_jump, df_clock_jump
        # Fate of the latest inputs (None: used, else the reason): the status says when most are refused.
        self._recent: deque[str | None] = deque(maxlen=_RECENT_INPUTS)
        self.unknown_quality = 0  # readings used with NaN quality (no correction, default sigma)
        self._fixed_stations: dict[str, tuple[float, float, float, float] | None] = {}  # configured positions
        self._reset_track()

    def _reset_track(self):
        self.stations: dict[str, Station] = {}
        self.channels = Channels(self.cfg, self.rng, self._reject_many, self.worker)
        self.main: Channel = self.channels.default  # the channel of the latest estimate (the default before one)
        self._retire_check = -math.inf  # DF stamp of the last look for silent channels
        self.estimate: Estimate | None = None
        self._status = "waiting for a GPS fix"
        for name, position in self._fixed_stations.items():
            self.add_station(name, fixed=True)
            if position is not None:
                self._place(self.stations[name], *position)

    # -- the default station and the main channel, as single-station, single-emitter programs see them ----------
    @property
    def station(self) -> Station:
        return self._station("")

    @property
    def track(self) -> GpsTrack:
        return self.station.track  # type: ignore[return-value]  # the default station always moves

    @property
    def heading(self) -> TrackHeading | ImuHeading | None:
        return self.station.heading

    @property
    def pending(self) -> PendingQueue:
        """Bearings of the default station waiting for a fix after them."""
        return self.station.pending

    @property
    def builder(self) -> PointBuilder:
        """The main channel's open observation point at the default station."""
        return self.main.builder("")

    @property
    def emitter(self) -> EmitterTrack:
        """The main channel's emitter track (the default channel until a frequency channel makes an estimate)."""
        return self.main.emitter

    # -- what programs read ------------------------------------------------------------------------
    @property
    def filter(self):
        """The running particle filter, or None before the start."""
        return self.emitter.filter

    @property
    def status(self) -> str:
        """One line on the state: waiting for a fix, collecting bearings, waiting for geometry, tracking, checking;
        and, when more than half of the latest inputs were refused, the commonest reason."""
        base = self._status if self._waiting_for_gps else self.emitter.status
        refused = [r for r in self._recent if r is not None]
        if len(self._recent) >= _RECENT_MIN and len(refused) > len(self._recent) / 2:
            reason, n = Counter(refused).most_common(1)[0]
            base += f"; most inputs refused: {reason} ({n} of the last {len(self._recent)})"
        return base

    @property
    def _waiting_for_gps(self) -> bool:
        """Before the datum: no fix yet, or the first one waiting for its confirmation."""
        return self.frame is None or not any(len(st.track) for st in self.stations.values())

    @property
    def init_points(self) -> list[ObservationPoint]:
        """Observation points buffered while waiting to start."""
        return [e.point for e in self.emitter.window] if self.emitter.filter is None else []

    def track_status(self, channel: Channel | None = None) -> TrackStatus:
        """The state of `channel`'s track (None: the main one)."""
        return (channel or self.main).emitter.summary()

    def recent_points(self, n: int | None = None, channel: str | None = None) -> np.ndarray:
        """The latest `n` (all: None) observation points the filter of `channel` (None: the main one) uses, oldest
        first, as rows of antenna east, north (m), bearing theta (ENU rad), its sigma (rad) and the antenna
        position's sigma (m); (0, 5) before the start."""
        found = self.main if channel is None else self.channels.live.get(channel)
        rows = found.emitter.used_points() if found is not None else np.zeros((0, 5))
        return rows if n is None else rows[len(rows) - min(n, len(rows)):]

    @property
    def start_cloud(self) -> np.ndarray | None:
        """The particles the filter started from (after the latest start or re-start), or None before it."""
        return self.emitter.initiator.start_cloud

    @property
    def bearings_used(self) -> int:
        return self.emitter.bearings_used

    @property
    def points_used(self) -> int:
        return self.emitter.points_used

    @property
    def last_update_s(self) -> float:
        return self.emitter.last_update_s

    @property
    def events(self) -> Counter:
        """Robustness events (alarm, global_restart, emitter_moved, recalibrated) and input events
        (fix_clock_jump, df_clock_jump)."""
        return self.emitter.events + self.input_events

    def noise_summary(self, channel: Channel | None = None) -> dict:
        """The self-calibrated noise of a channel (default: the main one): sigma (deg) per quality band with data,
        reading and point outlier rates."""
        cfg = self.cfg
        return (channel or self.main).emitter.calibration.noise_summary(lambda q: math.degrees(reading_sigma(q, cfg)))

    def clock_hint_sentence(self) -> str | None:
        """Words for a DF clock offset the bearings point to (from the last global check), or None."""
        hint = self.emitter.supervisor.clock_hint
        if hint is None:
            return None
        return (f"the bearings fit the track far better with the DF stamps shifted by {hint.shift_s:+.2f} s "
                f"(log-likelihood +{hint.gain:.0f}): a receiver delay or clock offset? try df_time_offset_s = "
                f"{self.cfg.df_time_offset_s + hint.shift_s:.2f}")

    def robustness_lines(self) -> list[str]:
        """Human lines on what the robustness layer saw: the receiver's noise, alternative hypotheses, events."""
        lines = []
        if self.cfg.calibrate_noise:
            lines.append(noise_sentence(self.noise_summary()))
        est = self.estimate
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

    # -- public API -----------------------------------------------------------------------------
    def add_station(self, name: str, fixed: bool = False) -> Station:
        """Declare a station (stations are also made at their first input, moving). `fixed`: a site that does not
        move; its position comes from `set_station_position` or its fixes (the newest wins), not a track."""
        st = self.stations.get(name)
        if st is None or st.fixed != fixed:
            st = self.stations[name] = Station(name, self.cfg, fixed)
        if fixed:
            self._fixed_stations.setdefault(name, None)
        return st

    def set_station_position(self, name: str, lat, lon, alt=float("nan"), sigma_m=0.0) -> bool:
        """A fixed station's position (kept across reset()); it sets the datum when none is set yet. False (the
        reason counted) for a position a fix could not have."""
        lat, lon, alt, sigma_m = map(_as_float, (lat, lon, alt, sigma_m))
        why = self._bad_position(lat, lon, alt)
        if why:
            self._reject(why)
            return False
        self.add_station(name, fixed=True)
        position = (lat, lon, alt, sigma_m if math.isfinite(sigma_m) and sigma_m >= 0 else 0.0)
        self._fixed_stations[name] = position
        self._place(self.stations[name], *position)
        return True

    def _place(self, st: Station, lat: float, lon: float, alt: float, sigma_m: float):
        """A fixed station at lat/lon; its waiting bearings can now be placed."""
        if self.frame is None:
            self._set_datum(lat, lon, alt, f"fixed station {st.name or '(default)'}'s position")
        frame = self.datum_frame()
        east, north = frame.to_enu(lat, lon)
        st.fix_at(float(east), float(north), float(frame.north_angle(lat, lon)), sigma_m)

    def _bad_position(self, lat: float, lon: float, alt: float) -> str | None:
        if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90 and abs(lon) <= 180):
            return "fix_bad_position"
        return implausible_fix(lat, lon, alt)

    def add_fix(self, stamp, lat, lon, alt=float("nan"), status: int = 0, sigma_m=float("nan"),
                station: str = "") -> Estimate | None:
        """A NavSatFix's content; `sigma_m` the horizontal position sigma from its covariance (NaN: unknown);
        `station` the station it places ("": the default one). Returns the newest estimate this fix made
        possible, if any."""
        stamp, lat, lon, alt, sigma_m = map(_as_float, (stamp, lat, lon, alt, sigma_m))
        # gps_sigma_m, when set, overrides the fixes' own covariances (it enters the likelihood as a constant)
        sigma_m = sigma_m if math.isfinite(sigma_m) and sigma_m >= 0 and not self.cfg.gps_sigma_m else 0.0
        if not math.isfinite(stamp):
            self._reject("fix_bad_stamp")
            return None
        if status < 0:
            self._reject("fix_no_fix")
            return None
        why = self._bad_position(lat, lon, alt)
        if why:
            self._reject(why)
            return None
        st = self._station(station)
        verdict = self._admit(st.fix_clock, "fix", "fix_clock_jump", stamp)
        if verdict is None:
            return None
        if verdict is Verdict.CLOCK_JUMP:  # the track starts again on the new timeline
            st.restart_track()  # a first fix on the old timeline confirms nothing now
        if st.fixed:  # a site's fix is its position: trusted like a configured one, no confirmation
            self._place(st, lat, lon, alt, sigma_m)
            self._recent.append(None)
            return self._release_pending(st)
        if self.frame is None:
            candidate = st.datum_candidate
            if candidate is None or not confirms(candidate[:3], (stamp, lat, lon), self.cfg.max_stamp_jump_s):
                if candidate is not None:
                    self._reject("fix_unconfirmed")
                st.datum_candidate = (stamp, lat, lon, alt, sigma_m)
                self._status = "waiting for a second GPS fix to confirm the datum"
                return None
            self._set_datum(*candidate[1:4])
        if st.datum_candidate is not None:  # confirmed now (or another station set the datum meanwhile)
            candidate, st.datum_candidate = st.datum_candidate, None
            self._store_fix(st, *candidate)
        return self._store_fix(st, stamp, lat, lon, alt, sigma_m)

    def _station(self, name: str) -> Station:
        st = self.stations.get(name)
        return st if st is not None else self.add_station(name)

    def _admit(self, clock: StreamClock, kind: str, jump_event: str, stamp: float) -> Verdict | None:
        """The stream clock's verdict on a stamp: None (refused, counted as `<kind>_<reason>`), OK, or
        CLOCK_JUMP (counted under `jump_event`, logged); the caller moves to the new timeline."""
        verdict = clock.admit(stamp)
        if verdict in _CLOCK_REASONS:
            self._reject(f"{kind}_{_CLOCK_REASONS[verdict]}")
            return None
        if verdict is Verdict.CLOCK_JUMP:
            self.input_events[jump_event] += 1
            log.warning("%s: the clock jumped to %.3f; going on on the new timeline", jump_event, stamp)
        return verdict

    def _set_datum(self, lat, lon, alt, source="the first valid fix, confirmed by the next"):
        datum_alt = self.cfg.datum_alt if self.cfg.datum_alt is not None else (alt if math.isfinite(alt) else 0.0)
        self.frame = LocalFrame(lat, lon, datum_alt)
        log.info("datum set from %s: %.7f, %.7f, %.1f m", source, lat, lon, datum_alt)

    def _store_fix(self, st: Station, stamp, lat, lon, alt, sigma_m=0.0) -> Estimate | None:
        frame = self.datum_frame()
        east, north = frame.to_enu(lat, lon)
        track = st.track
        assert isinstance(track, GpsTrack)  # a moving station's
        reason = track.add(stamp, float(east), float(north), float(frame.north_angle(lat, lon)), sigma_m)
        if reason:
            self._reject(reason)
            return None
        self._recent.append(None)
        if isinstance(st.heading, TrackHeading):
            st.heading.note_fix(track)
        if self.observer is not None:
            self.observer.on_fix(stamp, float(east), float(north), st.name)
        estimate = self._release_pending(st)
        # A fix well after an open point's first reading closes it: a vehicle that stopped taking
        # readings still gets its estimate, without waiting for the next reading.
        if not st.pending:
            for channel in list(self.channels.live.values()):
                builder = channel.builders.get(st.name)
                open_point = builder.readings if builder is not None else None
                if open_point and stamp - open_point[0].stamp > self.cfg.obs_max_duration_s:
                    estimate = self._use_points(channel, [builder.flush()]) or estimate
        return estimate

    def add_heading(self, stamp, yaw_rad, station: str = "") -> None:
        """The vehicle's heading from an IMU: REP-103 yaw (rad, counter-clockwise from east, ENU at the vehicle), as
        sensor_msgs/Imu gives it. Used with `bearing_reference: vehicle` and `heading_source: imu`."""
        stamp, yaw = _as_float(stamp), _as_float(yaw_rad)
        heading = self._station(station).heading
        if not isinstance(heading, ImuHeading):  # only with bearing_reference vehicle and heading_source imu
            self._reject("heading_ignored")
        elif not (math.isfinite(stamp) and math.isfinite(yaw)):
            self._reject("bad_heading")
        elif not heading.add(stamp, yaw):
            self._reject("heading_out_of_order")

    def add_bearing(self, stamp, azimuth_deg, quality=float("nan"), station: str = "",
                    frequency_hz=float("nan")) -> Estimate | None:
        """A DF record: azimuth (deg) and quality of the carrier at `frequency_hz` (0 or NaN: the default
        channel) seen from `station`. Returns the estimate this reading produced (when it closed an observation
        point), else None."""
        return self._add_bearing(stamp, azimuth_deg, quality, float("nan"), station, frequency_hz)

    def add_bearing_enu(self, stamp, yaw_rad, variance_rad2=float("nan"), station: str = "",
                        frequency_hz=float("nan")) -> Estimate | None:
        """A bearing as a REP-103 yaw (rad, counter-clockwise from east at the antenna) with its variance
        (the `pose` encoding). No quality: counted as unknown quality; NaN or non-positive variance
        means the configured sigma."""
        yaw, var = _as_float(yaw_rad), _as_float(variance_rad2)
        sigma = math.sqrt(var) if var > 0 and math.isfinite(var) else float("nan")
        azimuth = 90.0 - math.degrees(yaw) if math.isfinite(yaw) else yaw
        return self._add_bearing(stamp, azimuth, float("nan"), sigma, station, frequency_hz)

    def _add_bearing(self, stamp, azimuth_deg, quality, sigma, station, frequency_hz) -> Estimate | None:
        stamp, azimuth, quality, frequency = map(_as_float, (stamp, azimuth_deg, quality, frequency_hz))
        stamp += self.cfg.df_time_offset_s  # on the GPS clock
        if not math.isfinite(stamp):
            self._reject("bad_stamp")
            return None
        if not math.isfinite(azimuth):
            self._reject("bad_azimuth")
            return None
        if not math.isnan(quality) and not 0 <= quality <= 100:
            self._reject("bad_quality")
            return None
        if quality < self.cfg.quality_min:  # False for NaN: unknown quality passes, counted below
            self._reject("low_quality")
            return None
        channel = self.channels.for_frequency(frequency)
        if isinstance(channel, str):
            self._reject(channel)
            return None
        st = self._station(station)
        if channel.id not in st.df_clocks and st.ahead_of_timeline(stamp):
            self._reject("bearing_stamp_jump")
            return None
        verdict = self._admit(st.df_clock(channel.id), "bearing", "df_clock_jump", stamp)
        if verdict is None:
            return None
        if verdict is Verdict.CLOCK_JUMP:  # waiting on the old timeline: no fix will place them in order any more
            self._reject_many("clock_jump", st.pending.drop_channel(channel.id))
        if stamp < st.first_stamp:
            self._reject("before_first_fix")
            return None
        self._recent.append(None)
        channel.last_heard = stamp  # on its clock's timeline (a step back is followed)
        st.pending.push(Pending(stamp, azimuth % 360.0, quality, sigma, channel.id))
        return self._retire_silent(stamp) or self._release_pending(st)

    def _retire_silent(self, now: float) -> Estimate | None:
        """Once per second of DF time: retire the channels silent for channel_timeout_s, using their open points."""
        if now - self._retire_check < 1.0:
            return None
        self._retire_check = now
        estimate = None
        for channel in self.channels.retire_silent(now):
            for builder in channel.builders.values():
                group = builder.flush()
                if group:
                    estimate = self._use_points(channel, [group]) or estimate
            log.info("channel %s (%.0f Hz) silent for %.0f s: retired, its last estimate kept", channel.id,
                     channel.frequency_hz, now - channel.last_heard)
        return estimate

    def flush(self) -> Estimate | None:
        """End of data: bearings still waiting for a fix are dropped, the open observation points are used."""
        for st in self.stations.values():
            self._reject_many("no_fix_after", len(st.pending))
            st.pending.clear()
        estimate = None
        for channel in list(self.channels.live.values()):
            for builder in channel.builders.values():
                group = builder.flush()
                if group:
                    estimate = self._use_points(channel, [group]) or estimate
        return estimate

    def finish(self) -> Estimate | None:
        """After flush(), offline: one last global check over all the data (calibration, modes, moves) on every
        live channel, so the final estimates and their modes reflect everything; those Estimates have
        `end_of_data` set. Returns the last of them (None if no filter runs, or the last points just had a check).
        A live node never sees the end of data and never calls it."""
        estimate = None
        for channel in list(self.channels.live.values()):
            if not channel.emitter.finish():
                continue
            mean, cov = channel.emitter.estimate()
            if not _positive_definite(cov):
                self._reject("covariance_degenerate")
                continue
            made = self._make_estimate(channel, channel.emitter.last_stamp, mean, cov)
            made.end_of_data = True
            self._new_estimate(channel, made)
            estimate = made
        return estimate

    def _new_estimate(self, channel: Channel, estimate: Estimate):
        channel.estimate = self.estimate = estimate
        self.main = channel
        if self.on_estimate is not None:
            self.on_estimate(estimate)

    def poll(self) -> list[Estimate]:
        """Apply the worker's finished results now (`scheduling: realtime`) instead of at each channel's next point:
        a channel whose data paused (a bag's end, a silent carrier) still gets the start or check it was due.
        Returns the estimates they made (each also goes to `on_estimate`)."""
        made = []
        for channel in list(self.channels.live.values()):
            emitter = channel.emitter
            if not emitter.collect() or not emitter.estimating:
                continue
            mean, cov = emitter.estimate()
            if not _positive_definite(cov):
                self._reject("covariance_degenerate")
                continue
            estimate = self._make_estimate(channel, emitter.last_stamp, mean, cov)
            self._new_estimate(channel, estimate)
            made.append(estimate)
        return made

    def pay_owed(self) -> bool:
        """Make one of the moves owed (`scheduling: realtime`: a resampling's sweeps, a worker check's move on its
        modes), for the channel that owes the most: the node calls it when idle, so the points that follow carry no
        move. False when nothing is owed."""
        owing = max(self.channels.live.values(), key=lambda c: c.emitter.owed, default=None)
        if owing is None or not owing.emitter.owed:
            return False
        try:
            return owing.emitter.pay_owed()
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            log.exception("a move sweep between points failed; skipped")
            self._reject("internal_error")
            return False

    def pay_all_owed(self) -> int:
        """Make every owed move now (a replay between inputs, as the node's idle time would); returns how many."""
        made = 0
        while self.pay_owed():
            made += 1
        return made

    def settle(self):
        """Wait until the worker has finished the jobs submitted so far (`scheduling: realtime`; nothing otherwise):
        a replay calls it after each input to run at a receiver's pace, where a job ends before the next point,
        however fast the data is fed. The results are applied at each channel's next point, as live."""
        for channel in self.channels.live.values():
            job = channel.emitter.job
            if job is not None:
                wait([job.future])

    def close(self):
        """Stop the background checks' worker (a check running finishes; its result is dropped)."""
        if self.worker is not None:
            self.worker.close()

    def reset(self, drop_datum: bool = False):
        """Drop the tracks, the points, the filters and the channels; keep the counters and the fixed stations'
        configured positions (the node's ~/reset). The datum is kept, so the map frame stays put, unless
        `drop_datum` and it was not configured: then the next confirmed fix sets a new one (the way out of a datum
        taken from a bad fix)."""
        if drop_datum and not self.cfg.has_datum:
            self.frame = None
        self._reset_track()

    # -- pipeline -------------------------------------------------------------------------------
    def _reject(self, reason: str) -> None:
        self.rejected[reason] += 1
        self._recent.append(reason)
        if self.rejected[reason] == 1:
            log.warning("input not used: %s (%s); further ones are counted", reason, REASONS[reason])
        return None

    def _release_pending(self, st: Station) -> Estimate | None:
        """Pair a station's held bearings with its track in stamp order; stop at the first one still waiting for
        a fix (every later one waits too)."""
        estimate = None
        track = st.track
        while st.pending:
            p = st.pending.head()
            # Waiting is bounded whatever the GPS does: 2 x gps_max_gap_s behind its channel's DF stream, no fix
            # will come (each channel's own stream: a record stamped ahead on another one costs only itself)
            if st.newest_df(p.channel) - p.stamp > 2 * self.cfg.gps_max_gap_s or len(st.pending) > _MAX_PENDING:
                st.pending.pop()
                self._reject("gps_gap" if len(track) else "before_first_fix")
                continue
            if not len(track):
                break  # the datum waits for its confirming fix
            where, at = track.locate(p.stamp)
            if where is Where.WAIT:
                break
            st.pending.pop()
            if where is not Where.OK or at is None:
                self._reject(where.value)
                continue
            channel = self.channels.live.get(p.channel)
            if channel is None:
                self._reject("channel_retired")
                continue
            east, north, north_angle, gps_sigma, v_east, v_north = at
            theta = self._theta(st, p.stamp, p.azimuth, north_angle)
            if theta is None:
                self._reject("heading_unknown")
                continue
            if math.isnan(p.quality):
                self.unknown_quality += 1
            sigma = reading_sigma(p.quality, self.cfg) if math.isnan(p.sigma) else p.sigma
            reading = Reading(p.stamp, theta, p.quality, sigma, east, north, float(gps_sigma), float(v_east),
                              float(v_north))
            closed = channel.builder(st.name).add(reading)
            if closed:
                estimate = self._use_points(channel, closed) or estimate
        return estimate

    def _theta(self, st: Station, stamp: float, azimuth: float, north_angle: float) -> float | None:
        """The reading's ENU angle (rad) from its azimuth as `bearing_reference` defines it; None when a
        vehicle-relative azimuth has no heading at its stamp."""
        cfg = self.cfg
        if cfg.bearing_reference == "true_north":
            return float(azimuth_to_enu(azimuth, north_angle))
        if cfg.bearing_reference == "magnetic_north":
            return float(azimuth_to_enu(azimuth + cfg.magnetic_declination_deg, north_angle))
        track, source = st.track, st.heading
        if isinstance(source, ImuHeading):
            heading = source.at(track, stamp, north_angle)
        elif isinstance(source, TrackHeading) and isinstance(track, GpsTrack):  # a fixed site has no course
            heading = source.at(track, stamp, north_angle)
        else:
            return None  # the forward axis, ENU in the map plane
        if heading is None:
            return None
        return float(wrap_pi(heading - math.radians(azimuth + cfg.mount_offset_deg)))

    def _reject_many(self, reason: str, count: int):
        for _ in range(count):
            self._reject(reason)

    def _use_points(self, channel: Channel, groups: list[list[Reading]]) -> Estimate | None:
        """The channel's filter takes the closed groups; returns the newest estimate they made."""
        estimate = None
        emitter = channel.emitter
        for readings in groups:
            took = emitter.add(readings)
            if self.observer is not None:
                self.observer.on_point(readings, emitter.last_kept)
            if took:
                mean, cov = emitter.estimate()
                if not _positive_definite(cov):
                    self._reject("covariance_degenerate")
                    continue
                estimate = self._make_estimate(channel, emitter.last_stamp, mean, cov)
                self._new_estimate(channel, estimate)
        return estimate

    def adopt_datum(self, frame: LocalFrame | None):
        """Keep the map frame of an earlier Localizer (a datum it took from a fix) so that a restart with new
        settings does not move the map; a configured datum (datum_lat, datum_lon) wins and is kept."""
        if frame is not None and not self.cfg.has_datum and self.frame is None and not self.stations:
            self.frame = frame

    def datum_frame(self) -> LocalFrame:
        """The map frame at the datum (ENU metres); raises RuntimeError before the datum is set."""
        if self.frame is None:
            raise RuntimeError("no datum yet: no fix has been confirmed")
        return self.frame

    def _make_estimate(self, channel: Channel, stamp: float, mean, cov) -> Estimate:
        lat, lon, _ = self.datum_frame().to_geodetic(mean[0], mean[1])
        emitter = channel.emitter
        f = emitter.cloud
        modes = mode_masses(emitter)
        state, warnings = assess(emitter, np.asarray(mean), np.asarray(cov), modes)
        return Estimate(stamp=stamp, east=float(mean[0]), north=float(mean[1]), lat=float(lat), lon=float(lon),
                        cov=np.array(cov), bearings_used=emitter.bearings_used, points_used=emitter.points_used,
                        ess=f.ess(), algorithm=self.cfg.algorithm,
                        # the user's own copies: the filter's arrays are read-only and shared
                        particles=f.x.copy(), weights=f.weights.copy(),
                        modes=modes,
                        noise=self.noise_summary(channel) if self.cfg.calibrate_noise else None,
                        channel=channel.id, frequency_hz=channel.frequency_hz, state=state, warnings=warnings)

