"""A station's held bearings placed on its track: each becomes a Reading in the map frame (its antenna's interpolated
place, its azimuth turned to a map angle, its sigma) and joins its channel's open observation point; the points that
close are handed on. The intake holds one Pairing; it is the last step of a bearing's way in."""
from __future__ import annotations

import math

from aoa_localizer.engine.channels import Channels, Closed
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame, Skew, turn
from aoa_localizer.engine.ingest.gps_track import STILL_MPS, Where
from aoa_localizer.engine.ingest.heading import ImuHeading
from aoa_localizer.engine.ingest.station import Station
from aoa_localizer.engine.points.preprocess import reading_sigma
from aoa_localizer.engine.rejections import Reason, Rejections
from aoa_localizer.engine.survey.survey_log import SurveyLog
from aoa_localizer.engine.types import Reading

MAX_PENDING = 100_000  # bearings waiting for a fix, at most (the age limit normally binds long before)


class Pairing:
    """Pairs held bearings with their station's track into readings of `channels`; keeps the survey-like bearings
    (`survey_log`) and counts the readings used with unknown quality. A bearing it cannot place goes to `reject`
    with its reason."""

    def __init__(self, cfg: LocalizerConfig, channels: Channels, reject: Rejections):
        self.cfg, self.channels, self.reject = cfg, channels, reject
        self.survey_log = SurveyLog()
        self.unknown_quality = 0  # readings used with NaN quality (no correction, default sigma)

    def reset(self, channels: Channels):
        """New `channels` and a new survey log (the counter stays)."""
        self.channels = channels
        self.survey_log = SurveyLog()

    def pair_held(self, st: Station, final: bool = False) -> Closed:
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
                    or len(st.pending) > MAX_PENDING):
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
                              float(v_north), heading_sigma, st.name)
            if channel.id not in self.survey_log.not_survey:  # a drive's channel costs a set look-up a reading
                # a survey's: from a fixed site, or from an antenna standing still (a surveyor's stop)
                still = math.hypot(v_east, v_north) < STILL_MPS
                self.survey_log.add(channel.id, st.fixed, still,
                                    (st.name, p.stamp, east, north, theta, north_angle,
                                     math.degrees(p.sigma) if math.isfinite(p.sigma) else math.nan, sigma))
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
