"""The vehicle's heading at a reading's stamp, for DF arrays that measure bearings from the vehicle's forward axis
(`bearing_reference: vehicle`): the course over ground fitted to the GPS fixes around the reading, or an IMU's
yaw interpolated at it. Unknown for a while (a stopped vehicle has no course, an IMU may pause), the last good
heading is held up to `heading_hold_s`; after that the reading is refused (`heading_unknown`). Headings are ENU
angles of the forward axis (rad, counter-clockwise from east) in the map plane."""
from __future__ import annotations

import bisect
import math

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import wrap_pi
from aoa_localizer.engine.gps_track import GpsTrack

_KEEP = 4096  # headings kept (IMU samples, or good courses at fixes): minutes at 20-50 Hz


class _Samples:
    """Stamped headings in stamp order (bounded), with a lookup of the newest one at or before a stamp."""

    def __init__(self):
        self.t: list[float] = []
        self.h: list[float] = []

    def add(self, stamp: float, heading: float) -> bool:
        if self.t and stamp <= self.t[-1]:
            return False
        self.t.append(stamp)
        self.h.append(heading)
        if len(self.t) > 2 * _KEEP:  # lists (bisect needs fast indexing), trimmed now and then
            del self.t[:-_KEEP], self.h[:-_KEEP]
        return True

    def held(self, stamp: float, hold_s: float) -> float | None:
        """The newest heading at or before `stamp`, if it is at most `hold_s` old."""
        k = bisect.bisect_right(self.t, stamp)
        if k == 0 or stamp - self.t[k - 1] > hold_s:
            return None
        return self.h[k - 1]


class TrackHeading:
    """Course over ground from the GPS track: fitted over `heading_window_s` centred on the reading when the
    vehicle moves at least `heading_min_speed_mps`, else the last good course (checked at every fix) held."""

    def __init__(self, cfg: LocalizerConfig):
        self.cfg = cfg
        self.good = _Samples()

    def note_fix(self, track: GpsTrack):
        """After a fix: the course over the window ending at it, remembered when fast enough."""
        t = track.t[-1]
        heading = self._course(track, t - self.cfg.heading_window_s, t)
        if heading is not None:
            self.good.add(t, heading)

    def at(self, track: GpsTrack, stamp: float, _north_angle: float) -> float | None:
        half = 0.5 * self.cfg.heading_window_s
        heading = self._course(track, stamp - half, stamp + half)
        return heading if heading is not None else self.good.held(stamp, self.cfg.heading_hold_s)

    def _course(self, track: GpsTrack, t0: float, t1: float) -> float | None:
        v = track.fitted_velocity(t0, t1)
        if v is None or math.hypot(*v) < self.cfg.heading_min_speed_mps:
            return None
        return math.atan2(v[1], v[0])


class ImuHeading:
    """REP-103 yaw samples (ENU at the vehicle, counter-clockwise from east) interpolated at the reading's stamp
    (the shorter way round), turned into the map plane by the meridian convergence at the antenna; a reading past
    the newest sample holds it up to `heading_hold_s`."""

    def __init__(self, cfg: LocalizerConfig):
        self.cfg = cfg
        self.samples = _Samples()

    def add(self, stamp: float, yaw_rad: float) -> bool:
        """False (not used) for a stamp not after the newest one."""
        return self.samples.add(stamp, yaw_rad)

    def at(self, _track: object, stamp: float, north_angle: float) -> float | None:
        t, h = self.samples.t, self.samples.h
        k = bisect.bisect_left(t, stamp)
        if 0 < k < len(t) and t[k] - t[k - 1] <= self.cfg.heading_hold_s:
            f = (stamp - t[k - 1]) / (t[k] - t[k - 1])
            yaw = h[k - 1] + f * wrap_pi(h[k] - h[k - 1])
        elif k < len(t) and t[k] == stamp:
            yaw = h[k]
        else:
            held = self.samples.held(stamp, self.cfg.heading_hold_s)
            if held is None:
                return None
            yaw = held
        return float(wrap_pi(yaw + north_angle - math.pi / 2))
