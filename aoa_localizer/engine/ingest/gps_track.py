"""The vehicle's GPS track in ENU: interpolation at a bearing's stamp, never across a gap or past the last fix."""
from __future__ import annotations

import bisect
import math
from enum import Enum
from typing import NamedTuple

import numpy as np

from aoa_localizer.engine.rejections import Reason

# Fixes kept: enough to bracket any bearing still pending (bearings arrive within gps_max_gap_s).
_KEEP_FIXES = 512
_VELOCITY_SPAN = 3  # fix-to-fix segments a velocity is measured over
STILL_MPS = 0.5  # an antenna slower than this at an isolated fix stood still (its position may be held) ...
_HELD_MAX_M = 2.0  # ... if it cannot have gone farther than this from it at its mean speed across the gap


class MotionFit(NamedTuple):
    """A straight-line fit to fixes: velocity (m/s), the spread of the stamps (sum of squared deviations from
    their mean, s^2), and the residual sum of squares across the direction of travel (m^2) with its degrees of
    freedom."""

    v_east: float
    v_north: float
    sxx: float
    rss_across: float
    dof: int


class Where(Enum):
    """What the track can say about a stamp."""

    OK = "ok"  # bracketed by two fixes close enough in time (or on a fix)
    WAIT = "wait"  # after the newest fix but within the gap: a later fix may still bracket it
    GAP = Reason.GPS_GAP  # the fixes around it are farther apart than gps_max_gap_s
    BEFORE = Reason.BEFORE_FIRST_FIX  # older than every fix kept


class GpsTrack:
    """Time-ordered ENU fixes with linear interpolation between neighbours at most `max_gap_s` apart."""

    def __init__(self, max_gap_s: float):
        self.max_gap_s = max_gap_s
        self.t: list[float] = []
        self.e: list[float] = []
        self.n: list[float] = []
        self.north: list[float] = []  # ENU angle of true north at each fix
        self.sigma: list[float] = []  # horizontal position sigma of each fix (m; 0: not known)
        self._fits: dict[tuple[int, int], MotionFit] = {}  # fitted_motion by fix range, until the next fix

    def __len__(self):
        return len(self.t)

    def add(self, stamp: float, east: float, north: float, north_angle: float, sigma: float = 0.0) -> Reason | None:
        """Append a fix; returns a rejection reason if its stamp is not after the newest one."""
        if self.t and stamp <= self.t[-1]:
            return Reason.FIX_REPEATED if stamp == self.t[-1] else Reason.FIX_OUT_OF_ORDER
        self._fits.clear()
        for column, value in ((self.t, stamp), (self.e, east), (self.n, north), (self.north, north_angle),
                              (self.sigma, sigma)):
            column.append(value)
            if len(column) > 2 * _KEEP_FIXES:
                del column[:-_KEEP_FIXES]
        return None

    def locate(self, stamp: float) -> tuple[Where, tuple[float, ...] | None]:
        """(east, north, north angle, position sigma, east and north velocity) at `stamp` if the track brackets it
        closely enough, else the reason it does not. The velocity is that of the segment holding the stamp."""
        if not self.t or stamp < self.t[0]:
            return Where.BEFORE, None
        k = bisect.bisect_left(self.t, stamp)
        if k < len(self.t) and self.t[k] == stamp:
            return Where.OK, (self.e[k], self.n[k], self.north[k], self.sigma[k], *self._velocity(k))
        if k == len(self.t):
            return (Where.GAP if stamp - self.t[-1] > self.max_gap_s else Where.WAIT), None
        t0, t1 = self.t[k - 1], self.t[k]
        if t1 - t0 > self.max_gap_s:
            return self._held(stamp, k)
        f = (stamp - t0) / (t1 - t0)
        e, n, north, sigma, j = self.e, self.n, self.north, self.sigma, k - 1  # written out: runs per reading
        return Where.OK, (e[j] + f * (e[k] - e[j]), n[j] + f * (n[k] - n[j]), north[j] + f * (north[k] - north[j]),
                          sigma[j] + f * (sigma[k] - sigma[j]), *self._velocity(k))

    def _held(self, stamp: float, k: int) -> tuple[Where, tuple[float, ...] | None]:
        """Across a gap: the nearer of fixes k - 1 and k if it is within max_gap_s of the stamp and the antenna stood
        still there (no segment within the gap, or slower than STILL_MPS: a surveyor's fix at each bearing, minutes
        apart) and cannot have moved more than _HELD_MAX_M from it by the stamp; else a gap. A moving vehicle's fixes
        around a drop-out are never held."""
        j = k - 1 if stamp - self.t[k - 1] <= self.t[k] - stamp else k
        v_e, v_n = self._velocity(j)
        # how far the antenna can have gone from the held fix, at its mean speed across the gap
        across = math.hypot(self.e[k] - self.e[k - 1], self.n[k] - self.n[k - 1]) / (self.t[k] - self.t[k - 1])
        if (abs(stamp - self.t[j]) > self.max_gap_s or v_e * v_e + v_n * v_n > STILL_MPS**2
                or across * abs(stamp - self.t[j]) > _HELD_MAX_M):
            return Where.GAP, None
        return Where.OK, (self.e[j], self.n[j], self.north[j], self.sigma[j], 0.0, 0.0)

    def fitted_motion(self, t0: float, t1: float) -> MotionFit | None:
        """The least-squares straight-line motion of the fixes stamped in [t0, t1] (None with fewer than two).
        Centred on a reading, its velocity is the course over ground at the reading without the lag of a
        one-sided difference. The readings between two fixes share their windows' fixes: each range is fitted once."""
        lo, hi = bisect.bisect_left(self.t, t0), bisect.bisect_right(self.t, t1)
        if hi - lo < 2:
            return None
        fit = self._fits.get((lo, hi))
        if fit is None:
            fit = self._fits[lo, hi] = self._fit(lo, hi)
        return fit

    def _fit(self, lo: int, hi: int) -> MotionFit:
        t = np.asarray(self.t[lo:hi])
        dt = t - t.mean()
        sxx = float(dt @ dt)  # > 0: the track's stamps increase
        east, north = np.asarray(self.e[lo:hi]), np.asarray(self.n[lo:hi])
        v_east, v_north = float(dt @ east) / sxx, float(dt @ north) / sxx
        speed = math.hypot(v_east, v_north)
        if speed == 0:
            return MotionFit(0.0, 0.0, sxx, 0.0, 0)
        # residuals across the direction of travel: a turn, or noise (a change of speed leaves the course alone)
        across = ((north - north.mean() - v_north * dt) * v_east - (east - east.mean() - v_east * dt) * v_north) / speed
        return MotionFit(v_east, v_north, sxx, float(across @ across), hi - lo - 2)

    def line_residual(self) -> tuple[float, float] | None:
        """How far the middle one of the newest three fixes lies across the line through its neighbours (squared,
        m^2), and the multiple of one fix's variance per axis that this has for white position noise; None with
        fewer than three fixes, across a gap or with the neighbours on one place. A straight drive gives 0 whatever
        its speed does: it measures the fixes' jitter across the track, which is what turns into course noise."""
        if len(self.t) < 3:
            return None
        (t0, t1, t2), (e0, e1, e2), (n0, n1, n2) = self.t[-3:], self.e[-3:], self.n[-3:]
        chord = math.hypot(e2 - e0, n2 - n0)
        if t2 - t0 > 2 * self.max_gap_s or chord == 0:
            return None
        f = (t1 - t0) / (t2 - t0)
        across = ((n1 - n0) * (e2 - e0) - (e1 - e0) * (n2 - n0)) / chord
        return across * across, 1.0 + f * f + (1.0 - f) ** 2

    def _velocity(self, k: int) -> tuple[float, float]:
        """East and north velocity (m/s) over the fixes up to `_VELOCITY_SPAN` segments before fix k (after it for
        the first fixes), within gaps of at most max_gap_s; 0 without such a segment. Several segments, because a
        one-second difference of noisy fixes is mostly noise."""
        hi = max(k, min(_VELOCITY_SPAN, len(self.t) - 1))
        lo = hi
        while lo > max(0, hi - _VELOCITY_SPAN) and self.t[lo] - self.t[lo - 1] <= self.max_gap_s:
            lo -= 1
        if lo == hi:
            return 0.0, 0.0
        dt = self.t[hi] - self.t[lo]
        return (self.e[hi] - self.e[lo]) / dt, (self.n[hi] - self.n[lo]) / dt
