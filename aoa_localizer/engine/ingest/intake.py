"""The Localizer's input side: the stations (their clocks, GPS tracks, headings and held bearings) and the datum.

Fixes, headings and bearings come in as a vehicle gives them; each bearing is held by its station (station.py)
until a fix after it lets the station's track place the antenna at its stamp, and the pairing (pairing.py) makes it
a Reading in ENU in its channel's open observation point. What comes out is the points that closed: (channel,
readings) pairs, returned to the Localizer for the channels' tracks.
"""
from __future__ import annotations

import logging
import math
import numbers
from collections import Counter

from aoa_localizer.engine.channels import Channels, Closed
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.ingest.gps_track import GpsTrack
from aoa_localizer.engine.ingest.heading import ImuHeading, TrackHeading
from aoa_localizer.engine.ingest.input_guard import Verdict, beyond_map, confirms, implausible_fix
from aoa_localizer.engine.ingest.pairing import Pairing
from aoa_localizer.engine.ingest.station import Station
from aoa_localizer.engine.rejections import Reason, Rejections
from aoa_localizer.engine.types import SIGMA_RANGE_RAD

log = logging.getLogger("aoa_localizer")

_CLOCK_REASONS = {  # (the fix's, the bearing's) reason for each refusing verdict of a stream clock
    Verdict.REPEATED: (Reason.FIX_REPEATED, Reason.BEARING_REPEATED),
    Verdict.OUT_OF_ORDER: (Reason.FIX_OUT_OF_ORDER, Reason.BEARING_OUT_OF_ORDER),
    Verdict.AHEAD: (Reason.FIX_STAMP_JUMP, Reason.BEARING_STAMP_JUMP),
}


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
        self.other_band = 0  # DF records outside frequency_band_hz, left to the node of their band
        self.waiting_line = "waiting for a GPS fix"
        self.pairing = Pairing(cfg, channels, reject)

    def reset(self, channels: Channels):
        """Drop the stations (their tracks, clocks and held bearings) for new `channels`; the datum and the counters
        stay."""
        self.channels = channels
        self.stations = {}
        self.waiting_line = "waiting for a GPS fix"
        self.pairing.reset(channels)

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
        verdict = st.fix_clock.admit(stamp)
        if not self._clock_said(verdict, "fix", "fix_clock_jump", stamp):
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
            return self.pairing.pair_held(st)
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

    def take_bearing(self, stamp, azimuth_deg, quality, sigma_deg, station: str, frequency_hz) -> Closed:
        """A DF record, checked, found its channel and handed to its station, which holds it until a fix places it;
        returns the observation points it closed: the points of channels retired as silent by its stamp, then
        those its station's held bearings close now that they can be placed (Pairing). A refused record is
        counted under its reason and closes only what retiring made room for."""
        stamp, azimuth, quality, frequency = map(as_float, (stamp, azimuth_deg, quality, frequency_hz))
        # a reading's own sigma: NaN or None when it has none; what is given must lie in SIGMA_RANGE_DEG
        given = sigma_deg is not None and not (isinstance(sigma_deg, numbers.Real) and math.isnan(sigma_deg))
        sigma = math.radians(as_float(sigma_deg)) if given else math.nan
        if not self.cfg.in_band(frequency):  # another node's (frequency_band_hz): not ours, not an error
            self.other_band += 1
            return []
        stamp += self.cfg.df_time_offset_s  # on the GPS clock
        why = (Reason.BAD_STAMP if not math.isfinite(stamp) else Reason.BAD_AZIMUTH if not math.isfinite(azimuth)
               else Reason.BAD_SIGMA if given and not SIGMA_RANGE_RAD[0] <= sigma <= SIGMA_RANGE_RAD[1]
               else Reason.BAD_QUALITY if not math.isnan(quality) and not 0 <= quality <= 100
               else Reason.LOW_QUALITY if quality < self.cfg.quality_min  # False for NaN: unknown quality passes
               else None)
        if why is not None:
            self.reject(why)
            return []
        room: Closed = []
        channel = self.channels.for_frequency(frequency)
        # with every channel taken, the silent ones are retired as of the record's stamp first, when that lies on
        # its station's timeline (a stamp from nowhere must not retire them)
        if channel is Reason.CHANNEL_LIMIT:
            st = self.station(station)
            if not (st.ahead_of_timeline(stamp) or st.fix_clock.future(stamp)):
                before = len(self.channels.live)
                room = self.channels.retire_silent(stamp, every_time=True)
                if len(self.channels.live) < before:
                    channel = self.channels.for_frequency(frequency)
        if isinstance(channel, Reason):
            self.reject(channel)
            return room
        st = self.station(station)
        hold = st.hold(channel.id, stamp, azimuth % 360.0, quality, sigma)
        admitted = hold.verdict is None or self._clock_said(hold.verdict, "bearing", "df_clock_jump", stamp)
        if admitted and hold.verdict is Verdict.CLOCK_JUMP:
            self.reject(Reason.CLOCK_JUMP, hold.dropped)
        if not admitted or hold.refused is not None:
            # a record refused here never opened its channel: one left open would hold a place among max_channels
            # that no bearing ever fills (a scanning receiver before its first fix filled them all)
            if hold.refused is not None:
                self.reject(hold.refused)
            self.channels.discard_unheard(channel)
            return room
        self.reject.used()
        channel.last_heard = stamp  # on its clock's timeline (a step back is followed)
        return room + self.channels.retire_silent(stamp) + self.pairing.pair_held(st)

    def flush(self) -> Closed:
        """End of data: bearings waiting only for the later fixes of their course are paired with the fixes there
        are, those still waiting for a fix are dropped, the open observation points close."""
        closed: Closed = []
        for st in self.stations.values():
            if st.held_fix is not None:  # the last stretch's first fix: nothing after it to say it was a glitch
                held, st.held_fix = st.held_fix, None
                st.fix_clock.resume(held[0])
                closed += self._use_fix(st, *held)
            closed += self.pairing.pair_held(st, final=True)  # those only waiting for their course's later fixes
            self.reject(Reason.NO_FIX_AFTER, len(st.pending))
            st.pending.clear()
        return closed + [(channel, group) for channel in list(self.channels.live.values())
                         for group in (builder.flush() for builder in channel.builders.values()) if group]

    # -- the steps ------------------------------------------------------------------------------------
    def _clock_said(self, verdict: Verdict, kind: str, jump_event: str, stamp: float) -> bool:
        """Count a stream clock's verdict on a stamp of a `kind` of input: False when it refuses it (counted under its
        reason); a CLOCK_JUMP is counted under `jump_event` and logged (the caller moves to the new timeline)."""
        if verdict in _CLOCK_REASONS:
            self.reject(_CLOCK_REASONS[verdict][kind == "bearing"])
            return False
        if verdict is Verdict.CLOCK_JUMP:
            self.input_events[jump_event] += 1
            log.warning("%s: the clock jumped to %.3f; going on on the new timeline", jump_event, stamp)
        return True

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
        closed = self.pairing.pair_held(st)
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
