"""The Localizer's input side: the stations (their clocks, GPS tracks, headings and held bearings) and the datum.

Fixes, headings and bearings come in as a vehicle gives them; each bearing waits until a fix after it lets its
station's track place the antenna at its stamp, becomes a Reading in ENU, and joins its channel's open observation
point. What comes out is the points that closed: (channel, readings) pairs for the channels' tracks.
"""
from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable

from aoa_localizer.engine.channels import Channel, Channels
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame, Skew, turn
from aoa_localizer.engine.ingest.gps_track import STILL_MPS, GpsTrack, Where
from aoa_localizer.engine.ingest.heading import ImuHeading, TrackHeading
from aoa_localizer.engine.ingest.input_guard import StreamClock, Verdict, beyond_map, confirms, implausible_fix
from aoa_localizer.engine.ingest.preprocess import reading_sigma
from aoa_localizer.engine.ingest.station import Pending, Station
from aoa_localizer.engine.outputs.survey_log import SurveyLog
from aoa_localizer.engine.rejections import Reason, Rejections
from aoa_localizer.engine.types import Reading

log = logging.getLogger("aoa_localizer")

_MAX_PENDING = 100_000  # bearings waiting for a fix, at most (the age limit normally binds long before)
_CLOCK_REASONS = {  # (the fix's, the bearing's) reason for each refusing verdict of a stream clock
    Verdict.REPEATED: (Reason.FIX_REPEATED, Reason.BEARING_REPEATED),
    Verdict.OUT_OF_ORDER: (Reason.FIX_OUT_OF_ORDER, Reason.BEARING_OUT_OF_ORDER),
    Verdict.AHEAD: (Reason.FIX_STAMP_JUMP, Reason.BEARING_STAMP_JUMP),
}

Closed = list[tuple[Channel, list[Reading]]]  # the observation points an input closed, with their channels


def as_float(value) -> float:
    """`value` as a float; NaN for what is not a number (bad input is refused by its reason, never raised)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


class Intake:
    """Stations and the datum; turns fixes and bearings into closed observation points of `channels`. Every input
    it does not use goes to `reject` with its reason."""

    def __init__(self, cfg: LocalizerConfig, channels: Channels, reject: Rejections, frame: LocalFrame | None,
                 observer=None):
        self.cfg, self.channels, self.reject, self.frame, self.observer = cfg, channels, reject, frame, observer
        self.stations: dict[str, Station] = {}
        self.input_events: Counter = Counter()  # fix_clock_jump, df_clock_jump, fix_pause
        self.unknown_quality = 0  # readings used with NaN quality (no correction, default sigma)
        self.other_band = 0  # DF records outside frequency_band_hz, left to the node of their band
        self.waiting_line = "waiting for a GPS fix"
        self.survey_log = SurveyLog()
        # called with a record's stamp when every channel is taken: retires the silent ones, says whether any went
        self.make_room: Callable[[float], bool] | None = None

    def reset(self, channels: Channels):
        """Drop the stations (their tracks, clocks and held bearings) for new `channels`; the datum and the counters
        stay."""
        self.channels = channels
        self.stations = {}
        self.waiting_line = "waiting for a GPS fix"
        self.survey_log = SurveyLog()

    @property
    def waiting_for_gps(self) -> bool:
        """Before the datum: no fix yet, or the first one waiting for its confirmation."""
        return self.frame is None or not any(len(st.gps) for st in self.stations.values())

    def datum_frame(self) -> LocalFrame:
        """The map frame at the datum (ENU metres); raises RuntimeError before the datum is set."""
        if self.frame is None:
            raise RuntimeError("no datum yet: no fix has been confirmed")
        return self.frame

    # -- stations -------------------------------------------------------------------------------------
    def add_station(self, name: str, fixed: bool = False) -> Station:
        st = self.stations.get(name)
        if st is None or st.fixed != fixed:
            st = self.stations[name] = Station(name, self.cfg, fixed)
        return st

    def station(self, name: str) -> Station:
        st = self.stations.get(name)
        return st if st is not None else self.add_station(name)

    def place(self, name: str, lat: float, lon: float, alt: float, sigma_m: float):
        """A fixed station at lat/lon; its waiting bearings can now be placed."""
        st = self.stations[name]
        if self.frame is None:
            self._set_datum(lat, lon, alt, f"fixed station {name or '(default)'}'s position")
        frame = self.datum_frame()
        east, north = frame.to_enu(lat, lon)
        st.fix_at(float(east), float(north), float(frame.north_angle(lat, lon)), sigma_m)

    def bad_position(self, lat: float, lon: float, alt: float) -> Reason | None:
        """Why a position cannot be used, or None: out of range, implausible, or beyond the map plane's reach."""
        if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90 and abs(lon) <= 180):
            return Reason.FIX_BAD_POSITION
        why = implausible_fix(lat, lon, alt)
        if why is None and self.frame is not None and beyond_map((self.frame.lat0, self.frame.lon0), lat, lon):
            return Reason.FIX_BEYOND_MAP
        return why

    # -- inputs ---------------------------------------------------------------------------------------
    def add_fix(self, stamp, lat, lon, alt, status: int, sigma_m, station: str) -> Closed:
        stamp, lat, lon, alt, sigma_m = map(as_float, (stamp, lat, lon, alt, sigma_m))
        # gps_sigma_m, when set, overrides the fixes' own covariances (it enters the likelihood as a constant)
        sigma_m = sigma_m if math.isfinite(sigma_m) and sigma_m >= 0 and not self.cfg.gps_sigma_m else 0.0
        if not math.isfinite(stamp):
            self.reject(Reason.FIX_BAD_STAMP)
            return []
        if status < 0:
            self.reject(Reason.FIX_NO_FIX)
            return []
        why = self.bad_position(lat, lon, alt)
        if why:
            self.reject(why)
            return []
        st = self.station(station)
        fix = (stamp, lat, lon, alt, sigma_m)
        held, st.held_fix = st.held_fix, None
        # the next fix goes on from the held one (later, and where a vehicle or a walker can have got to): the
        # stream paused (a surveyor's next stop), it was no glitch
        if held is not None and not st.fix_clock.future(stamp) and confirms(held[:3], fix[:3], math.inf):
            gap = held[0] - (st.fix_clock.last if st.fix_clock.last is not None else held[0])
            st.fix_clock.resume(stamp)
            self.input_events["fix_pause"] += 1
            log.info("fix_pause: the fixes went on %.0f s after the one before, confirmed by the next", gap)
            return self._use_fix(st, *held) + self._use_fix(st, *fix)
        if held is not None:
            self.reject(Reason.FIX_STAMP_JUMP)  # the held fix was a glitch: the stream did not go on from it
        if not st.fix_clock.future(stamp) and st.fix_clock.far_ahead(stamp):
            st.held_fix = fix
            return []
        verdict = self._admit(st.fix_clock, "fix", "fix_clock_jump", stamp)
        if verdict is None:
            return []
        if verdict is Verdict.CLOCK_JUMP:  # the track starts again on the new timeline
            st.restart_gps()  # a first fix on the old timeline confirms nothing now
        return self._use_fix(st, *fix)

    def _use_fix(self, st: Station, stamp, lat, lon, alt, sigma_m) -> Closed:
        """An admitted fix: a site's position, the datum's confirmation, or a point of the track."""
        station = st.name
        if st.fixed:  # a site's fix is its position: trusted like a configured one, no confirmation
            self.place(station, lat, lon, alt, sigma_m)
            self.reject.used()
            return self.release(st)
        if self.frame is None:
            candidate = st.datum_candidate
            # a sparse stream's next fix (a surveyor's, minutes after the last) confirms across its pause
            within = math.inf if st.fix_clock.sparse() else self.cfg.max_stamp_jump_s
            if candidate is None or not confirms(candidate[:3], (stamp, lat, lon), within):
                if candidate is not None:
                    self.reject(Reason.FIX_UNCONFIRMED)
                st.datum_candidate = (stamp, lat, lon, alt, sigma_m)
                self.waiting_line = "waiting for a second GPS fix to confirm the datum"
                return []
            self._set_datum(*candidate[1:4])
        closed: Closed = []
        if st.datum_candidate is not None:  # confirmed now (or another station set the datum meanwhile)
            candidate, st.datum_candidate = st.datum_candidate, None
            closed += self._store_fix(st, *candidate)
        return closed + self._store_fix(st, stamp, lat, lon, alt, sigma_m)

    def add_heading(self, stamp, yaw_rad, station: str, variance_rad2=math.nan) -> None:
        stamp, yaw, variance = as_float(stamp), as_float(yaw_rad), as_float(variance_rad2)
        heading = self.station(station).heading
        if not isinstance(heading, ImuHeading):  # only with bearing_reference vehicle and heading_source imu
            self.reject(Reason.HEADING_IGNORED)
        elif not (math.isfinite(stamp) and math.isfinite(yaw)):
            self.reject(Reason.BAD_HEADING)
        elif not heading.add(stamp, yaw, math.sqrt(variance) if 0 < variance < math.inf else 0.0):
            self.reject(Reason.HEADING_OUT_OF_ORDER)

    def _channel(self, frequency: float, stamp: float, station: str) -> Channel | Reason:
        """The record's channel; with every channel taken, the silent ones are retired as of its stamp first, when
        that lies on its station's timeline (a stamp from nowhere must not retire them)."""
        channel = self.channels.for_frequency(frequency)
        if channel is Reason.CHANNEL_LIMIT and self.make_room is not None:
            st = self.station(station)
            if not st.ahead_of_timeline(stamp) and not st.fix_clock.future(stamp) and self.make_room(stamp):
                channel = self.channels.for_frequency(frequency)
        return channel

    def admit_bearing(self, stamp, azimuth_deg, quality, sigma, station: str,
                      frequency_hz) -> tuple[Station, float] | None:
        """Check a DF record and hold it at its station until a fix places it (release): its station and its stamp on
        the GPS clock, or None when refused."""
        stamp, azimuth, quality, frequency = map(as_float, (stamp, azimuth_deg, quality, frequency_hz))
        if not self.cfg.in_band(frequency):  # another node's (frequency_band_hz): not ours, not an error
            self.other_band += 1
            return None
        stamp += self.cfg.df_time_offset_s  # on the GPS clock
        if not math.isfinite(stamp):
            self.reject(Reason.BAD_STAMP)
            return None
        if not math.isfinite(azimuth):
            self.reject(Reason.BAD_AZIMUTH)
            return None
        if not math.isnan(quality) and not 0 <= quality <= 100:
            self.reject(Reason.BAD_QUALITY)
            return None
        if quality < self.cfg.quality_min:  # False for NaN: unknown quality passes, counted below
            self.reject(Reason.LOW_QUALITY)
            return None
        channel = self._channel(frequency, stamp, station)
        if isinstance(channel, Reason):
            self.reject(channel)
            return None
        st = self.station(station)
        # a record refused here never opened its channel: one left open would hold a place among max_channels
        # that no bearing ever fills (a scanning receiver before its first fix filled them all)
        if channel.id not in st.df_clocks and st.ahead_of_timeline(stamp):
            self.reject(Reason.BEARING_STAMP_JUMP)
            self.channels.discard_unheard(channel)
            return None
        verdict = self._admit(st.df_clock(channel.id), "bearing", "df_clock_jump", stamp)
        if verdict is None:
            self.channels.discard_unheard(channel)
            return None
        if verdict is Verdict.CLOCK_JUMP:  # waiting on the old timeline: no fix will place them in order any more
            self.reject(Reason.CLOCK_JUMP, st.pending.drop_channel(channel.id))
        if stamp < st.first_stamp:
            self.reject(Reason.BEFORE_FIRST_FIX)
            self.channels.discard_unheard(channel)
            return None
        self.reject.used()
        channel.last_heard = stamp  # on its clock's timeline (a step back is followed)
        st.pending.push(Pending(stamp, azimuth % 360.0, quality, sigma, channel.id))
        return st, stamp

    def flush(self) -> Closed:
        """End of data: bearings waiting only for the later fixes of their course are paired with the fixes there
        are, those still waiting for a fix are dropped, the open observation points close."""
        closed: Closed = []
        for st in self.stations.values():
            if st.held_fix is not None:  # the last stretch's first fix: nothing after it to say it was a glitch
                held, st.held_fix = st.held_fix, None
                st.fix_clock.resume(held[0])
                closed += self._use_fix(st, *held)
            closed += self.release(st, final=True)  # those only waiting for their course's later fixes
            self.reject(Reason.NO_FIX_AFTER, len(st.pending))
            st.pending.clear()
        return closed + [(channel, group) for channel in list(self.channels.live.values())
                         for group in (builder.flush() for builder in channel.builders.values()) if group]

    # -- the steps ------------------------------------------------------------------------------------
    def _admit(self, clock: StreamClock, kind: str, jump_event: str, stamp: float) -> Verdict | None:
        """The stream clock's verdict on a stamp: None (refused, counted under its reason for a `kind` of input), OK,
        or CLOCK_JUMP (counted under `jump_event`, logged); the caller moves to the new timeline."""
        verdict = clock.admit(stamp)
        if verdict in _CLOCK_REASONS:
            self.reject(_CLOCK_REASONS[verdict][kind == "bearing"])
            return None
        if verdict is Verdict.CLOCK_JUMP:
            self.input_events[jump_event] += 1
            log.warning("%s: the clock jumped to %.3f; going on on the new timeline", jump_event, stamp)
        return verdict

    def _set_datum(self, lat, lon, alt, source="the first valid fix, confirmed by the next"):
        datum_alt = self.cfg.datum_alt if self.cfg.datum_alt is not None else (alt if math.isfinite(alt) else 0.0)
        self.frame = LocalFrame(lat, lon, datum_alt)
        log.info("datum set from %s: %.7f, %.7f, %.1f m", source, lat, lon, datum_alt)

    def _store_fix(self, st: Station, stamp, lat, lon, alt, sigma_m=0.0) -> Closed:
        frame = self.datum_frame()
        east, north = frame.to_enu(lat, lon)
        gps = st.gps
        assert isinstance(gps, GpsTrack)  # a moving station's
        reason = gps.add(stamp, float(east), float(north), float(frame.north_angle(lat, lon)), sigma_m)
        if reason:
            self.reject(reason)
            return []
        self.reject.used()
        if isinstance(st.heading, TrackHeading):
            st.heading.note_fix(gps)
        if self.observer is not None:
            self.observer.on_fix(stamp, float(east), float(north), st.name)
        closed = self.release(st)
        # A fix well after an open point's first reading closes it: a vehicle that stopped taking
        # readings still gets its estimate, without waiting for the next reading.
        if not st.pending:
            for channel in list(self.channels.live.values()):
                builder = channel.builders.get(st.name)
                if builder is None or not builder.readings:
                    continue
                if stamp - builder.readings[0].stamp > self.cfg.obs_max_duration_s:
                    closed.append((channel, builder.flush() or []))
        return closed

    def release(self, st: Station, final: bool = False) -> Closed:
        """Pair a station's held bearings with its track in stamp order; stop at the first one still waiting for
        a fix (every later one waits too). A bearing turned by the course over ground also waits for the fixes of
        `heading_window_s` after it (its course is fitted centred on it: a trailing one lags a turn), except at the
        end of data (`final`)."""
        closed: Closed = []
        gps = st.gps
        lead = self.cfg.heading_window_s if st.course_source() else 0.0
        while st.pending:
            p = st.pending.head()
            # Waiting is bounded whatever the GPS does: 2 x gps_max_gap_s (and the course's lead) behind its
            # channel's DF stream, no fix will come (each channel's own stream: a record stamped ahead on another one
            # costs only itself)
            if (st.newest_df(p.channel) - p.stamp > 2 * self.cfg.gps_max_gap_s + lead
                    or len(st.pending) > _MAX_PENDING):
                st.pending.pop()
                self.reject(Reason.GPS_GAP if len(gps) else Reason.BEFORE_FIRST_FIX)
                continue
            if not len(gps):
                break  # the datum waits for its confirming fix
            where, at = gps.locate(p.stamp)
            if where is Where.WAIT or (lead and not final and where is Where.OK and gps.t[-1] < p.stamp + lead):
                break
            if where is Where.GAP and st.held_fix is not None and p.stamp > gps.t[-1]:
                break  # a held fix may be the start of the stream's next stretch: the next fix says
            st.pending.pop()
            if where is not Where.OK or at is None:
                self.reject(where.value)
                continue
            channel = self.channels.live.get(p.channel)
            if channel is None:
                self.reject(Reason.CHANNEL_RETIRED)
                continue
            east, north, north_angle, gps_sigma, v_east, v_north = at
            turned = self._theta(st, p.stamp, p.azimuth, north_angle, LocalFrame.skew(east, north))
            if turned is None:
                self.reject(Reason.HEADING_UNKNOWN)
                continue
            theta, heading_sigma = turned
            if math.isnan(p.quality):
                self.unknown_quality += 1
            sigma = reading_sigma(p.quality, self.cfg) if math.isnan(p.sigma) else p.sigma
            reading = Reading(p.stamp, theta, p.quality, sigma, east, north, float(gps_sigma), float(v_east),
                              float(v_north), heading_sigma)
            if channel.id not in self.survey_log.not_survey:  # a drive's channel costs a set look-up a reading
                # a survey's: from a fixed site, or from an antenna standing still (a surveyor's stop)
                still = math.hypot(v_east, v_north) < STILL_MPS
                self.survey_log.add(channel.id, st.fixed or still,
                                    (st.name, p.stamp, east, north, theta, north_angle,
                                     math.degrees(p.sigma) if math.isfinite(p.sigma) else math.nan))
            closed += [(channel, group) for group in channel.builder(st.name).add(reading)]
        return closed

    def _theta(self, st: Station, stamp: float, azimuth: float, north_angle: float,
               skew: Skew) -> tuple[float, float] | None:
        """The reading's map angle (rad) from its azimuth as `bearing_reference` defines it, and the sigma of the
        heading it was turned by (rad); None when a vehicle-relative azimuth has no heading at its stamp. The
        azimuth turns from north (or the heading) on the ground, and the plane's skew far from the datum says
        what that turn is on the map (geodesy.turn)."""
        cfg = self.cfg
        if cfg.bearing_reference == "true_north":
            return turn(north_angle, -math.radians(azimuth), skew), 0.0
        if cfg.bearing_reference == "magnetic_north":
            return turn(north_angle, -math.radians(azimuth + cfg.magnetic_declination_deg), skew), 0.0
        course = st.course_source()
        if isinstance(st.heading, ImuHeading):
            at = st.heading.at(st.gps, stamp, north_angle, skew)
        elif course is not None:
            at = course[0].at(course[1], stamp, north_angle, skew)
        else:
            return None  # the forward axis, ENU in the map plane
        if at is None:
            return None
        heading, sigma = at
        return turn(heading, -math.radians(azimuth + cfg.mount_offset_deg), skew), sigma
