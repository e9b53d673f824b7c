"""The vehicle's heading at a reading's stamp, for DF arrays that measure bearings from the vehicle's forward axis
(`bearing_reference: vehicle`): the course over ground fitted to the GPS fixes around the reading, or an IMU's
yaw interpolated at it. Unknown for a while (a stopped vehicle has no course, an IMU may pause), the last good
heading is held up to `heading_hold_s`; after that the reading is refused (`heading_unknown`). Headings are ENU
angles of the forward axis (rad, counter-clockwise from east) in the map plane, each with its sigma (rad), which
the reading's observation point adds to its bearing's variance."""
from __future__ import annotations

import bisect
import functools
import math
from collections import deque

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.distributions import chi2_cdf, chi2_ppf
from aoa_localizer.engine.geodesy import Skew, turn, wrap_pi
from aoa_localizer.engine.ingest.gps_track import GpsTrack

_KEEP = 4096  # headings kept (IMU samples, or good courses at fixes): minutes at 20-50 Hz
_WIDEN = (1, 2, 4)  # multiples of heading_window_s tried in turn for a course good enough
_JITTER_SAMPLES = 256  # recent fixes the GPS jitter is measured over (minutes at 1 Hz: it changes slowly)
_JITTER_SAMPLES_MIN = 4  # fixes' jitter samples before any course is trusted
_JITTER_KEEP = 0.9  # the share of the smallest samples the jitter is measured from
_TRIMMED_MEAN = float(chi2_cdf(chi2_ppf(_JITTER_KEEP, 1), 3)) / _JITTER_KEEP  # E[X | X < its 90 % point], X chi2(1)
_JITTER_FLOOR_M = 0.02  # the least jitter a window's fit is tested against (RTK's centimetres)
# The velocity error that the fixes' jitter does not show: their slow errors (multipath, atmosphere) drift, which
# a velocity from positions takes for motion; a receiver's own velocity is seldom better than this (m/s).
_DRIFT_MPS = 0.1


@functools.lru_cache(maxsize=1024)
def _chi2_quantile(p: float, dof: float) -> float:
    """chi2.ppf, cached: every fix's jitter bound and every window's lack-of-fit test ask again for the same few
    hundred values."""
    return float(chi2_ppf(p, dof))


class _Samples:
    """Stamped headings (with their sigmas) in stamp order (bounded), with a lookup of the newest one at or before a
    stamp."""

    def __init__(self):
        self.t: list[float] = []
        self.h: list[float] = []
        self.sd: list[float] = []

    def add(self, stamp: float, heading: float, sd: float) -> bool:
        if self.t and stamp <= self.t[-1]:
            return False
        self.t.append(stamp)
        self.h.append(heading)
        self.sd.append(sd)
        if len(self.t) > 2 * _KEEP:  # lists (bisect needs fast indexing), trimmed now and then
            del self.t[:-_KEEP], self.h[:-_KEEP], self.sd[:-_KEEP]
        return True

    def held(self, stamp: float, hold_s: float) -> tuple[float, float] | None:
        """The newest heading and its sigma at or before `stamp`, if it is at most `hold_s` old."""
        k = bisect.bisect_right(self.t, stamp)
        if k == 0 or stamp - self.t[k - 1] > hold_s:
            return None
        return self.h[k - 1], self.sd[k - 1]


class _Jitter:
    """The GPS fixes' own noise (per axis) from how far each fix lies across the line through its neighbours: the
    noise that turns into course noise, which a receiver's declared accuracy (an absolute error, mostly slow)
    overstates. A 95 % upper bound from the mean of the recent samples without their largest tenth (so a turn does
    not lift it), counting two neighbouring samples as one (they share fixes); few samples give a wide bound, so a
    noisy track is not trusted before its noise is known."""

    def __init__(self):
        self.samples: deque[float] = deque(maxlen=_JITTER_SAMPLES)  # distance across^2 / its multiple of sigma^2
        self.variance: float | None = None  # per-axis variance of one fix (m^2); None before _JITTER_SAMPLES_MIN

    def add(self, residual: tuple[float, float] | None):
        if residual is None:
            return
        self.samples.append(residual[0] / residual[1])
        n = len(self.samples)
        if n < _JITTER_SAMPLES_MIN:
            return
        kept = sorted(self.samples)[:max(1, round(_JITTER_KEEP * n))]
        # each sample is sigma^2 chi2(1); the kept ones' mean is sigma^2 _TRIMMED_MEAN on average
        dof = _JITTER_KEEP * n / 2
        self.variance = sum(kept) / len(kept) / _TRIMMED_MEAN * dof / _chi2_quantile(0.05, dof)


class TrackHeading:
    """Course over ground from the GPS track, with its sigma from the fixes' jitter: the least-squares velocity of
    the fixes within `heading_window_s` centred on the reading, widened (x2, x4) while the course is too uncertain,
    used when the vehicle moves at least `heading_min_speed_mps` and the course's sigma is at most
    `heading_max_sigma_deg`; for a vehicle not seen moving, the last good course (checked at every fix over the
    window before it) is held."""

    def __init__(self, cfg: LocalizerConfig):
        self.cfg = cfg
        self.good = _Samples()
        self.jitter = _Jitter()

    def note_fix(self, track: GpsTrack):
        """After a fix: its jitter sample, and the course over the window ending at it, remembered when good."""
        self.jitter.add(track.line_residual())
        t, w = track.t[-1], self.cfg.heading_window_s
        course, _ = self._course(track, [(t - k * w, t) for k in _WIDEN])
        if course is not None:
            self.good.add(t, *course)

    def at(self, track: GpsTrack, stamp: float, _north_angle: float, _skew: Skew) -> tuple[float, float] | None:
        """The heading (ENU rad) at `stamp` and its sigma (rad), or None. The last good course is held only for a
        vehicle not seen moving: one that moves (faster than three sigmas of its fixes' noise) on a course too
        uncertain, or bent (turning), may have turned away from it."""
        half = 0.5 * self.cfg.heading_window_s
        course, moving = self._course(track, [(stamp - k * half, stamp + k * half) for k in _WIDEN])
        if course is not None or moving:
            return course
        return self.good.held(stamp, self.cfg.heading_hold_s)

    def _course(self, track: GpsTrack, windows: list[tuple[float, float]]) -> tuple[tuple[float, float] | None, bool]:
        """The course and its sigma over the first window where it is good enough (else None), and whether the
        vehicle was seen moving. The course's variance is the velocity's across the direction of travel over the
        speed^2: the fixes' jitter over the stamps' spread, and the slow errors' drift (sd_v^2). A window whose fixes
        lie farther across the line than the jitter explains (a lack-of-fit test at 1 %) holds a turn, whose course no
        sigma describes: none."""
        variance = self.jitter.variance
        if variance is None:
            return None, False
        moving = False
        for t0, t1 in windows:
            fit = track.fitted_motion(t0, t1)
            if fit is None:
                continue
            speed, sd_v = math.hypot(fit.v_east, fit.v_north), math.sqrt(variance / fit.sxx + _DRIFT_MPS**2)
            if speed < self.cfg.heading_min_speed_mps:
                return None, False  # a longer window would only average the stop in
            if speed < 3.0 * sd_v:
                continue  # the fixes' noise alone could give this speed: a longer window tells
            moving = True
            if fit.dof and fit.rss_across > max(variance, _JITTER_FLOOR_M**2) * _chi2_quantile(0.99, fit.dof):
                break  # the fixes bend away from a line (a turn): a longer window bends more
            if sd_v <= speed * math.radians(self.cfg.heading_max_sigma_deg):
                return (math.atan2(fit.v_north, fit.v_east), sd_v / speed), True
        return None, moving


class ImuHeading:
    """REP-103 yaw samples (ENU at the vehicle, counter-clockwise from east) interpolated at the reading's stamp
    (the shorter way round), turned into the map plane by the meridian convergence at the antenna; a reading past
    the newest sample holds it up to `heading_hold_s`."""

    def __init__(self, cfg: LocalizerConfig):
        self.cfg = cfg
        self.samples = _Samples()

    def add(self, stamp: float, yaw_rad: float, sd: float) -> bool:
        """False (not used) for a stamp not after the newest one. `sd`: the yaw's sigma (rad; 0: exact)."""
        return self.samples.add(stamp, yaw_rad, sd)

    def at(self, _track: object, stamp: float, north_angle: float, skew: Skew) -> tuple[float, float] | None:
        """The heading (ENU rad) at `stamp` and its sigma (the larger of its samples'), or None."""
        t, h, sd = self.samples.t, self.samples.h, self.samples.sd
        k = bisect.bisect_left(t, stamp)
        if 0 < k < len(t) and t[k] - t[k - 1] <= self.cfg.heading_hold_s:
            f = (stamp - t[k - 1]) / (t[k] - t[k - 1])
            yaw, sigma = h[k - 1] + f * wrap_pi(h[k] - h[k - 1]), max(sd[k - 1], sd[k])
        elif k < len(t) and t[k] == stamp:
            yaw, sigma = h[k], sd[k]
        else:
            held = self.samples.held(stamp, self.cfg.heading_hold_s)
            if held is None:
                return None
            yaw, sigma = held
        return turn(north_angle, yaw - math.pi / 2, skew), sigma
