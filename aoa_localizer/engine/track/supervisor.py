"""What keeps a running filter honest on messy data: the health of each new point (the share the cloud explains
only as outliers, against the calibrated rate); global checks on a growing schedule and on alarm (noise calibration,
global search, then the modes' MH move or a re-start from a far better mode), inline or in the check worker; moves
at every point while in alarm (unless a check is being made in the calls); and the emitter-moved test. The
supervisor decides; the track acts on its decisions."""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from enum import Enum
from functools import partial
from typing import cast

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.inference.checks import CheckResult, Snapshot, run_check
from aoa_localizer.engine.inference.clock_check import ClockHint
from aoa_localizer.engine.inference.emitter_model import EmitterModel
from aoa_localizer.engine.inference.global_search import Points, Robust, find_modes, inlier_share, log_posterior
from aoa_localizer.engine.inference.safety import HealthMonitor
from aoa_localizer.engine.scheduling.scheduler import PendingJob
from aoa_localizer.engine.track.initiator import MIN_INLIERS
from aoa_localizer.filters.base import ParticleFilter

log = logging.getLogger("aoa_localizer")

ALARM_SWEEPS = 2  # moves at every point while in alarm
_SEARCH_GROWTH = 2.0  # scheduled global searches when the kept points have grown by this factor ...
_SEARCH_EVERY_MAX = 100  # ... or by this many points
_ALARM_SEARCH_EVERY = 5  # points between global searches while in alarm
_MOVED_MAX_OLD_SHARE = 0.2  # most recent points that may still agree with the old place in a move


@dataclass(frozen=True)
class Watch:
    """What a new point's health asks of the track: `alarm` (the cloud no longer explains the newest points;
    `alarm_began` at this point), a calibration now (the filters alone: `calibrate`), a global check now (`check`),
    or `sweeps` moves now (in alarm, no check due)."""

    alarm: bool = False
    alarm_began: bool = False
    calibrate: bool = False
    check: bool = False
    sweeps: int = 0


class CheckVerdict(Enum):
    """What a global check's modes make of the cloud: a re-start from the best mode (far better than any particle),
    one move on the modes now, or that move owed (made between points)."""

    RESTART = "restart"
    MOVE = "move"
    OWE = "owe"


@dataclass(frozen=True)
class Moved:
    """The emitter moved: the last `recent` points agree on `place`, which the older ones contradict by `log_odds`."""

    recent: int
    place: np.ndarray
    log_odds: float


class Supervisor:
    """One track's health monitor, global-check schedule, re-start test and emitter-moved test."""

    def __init__(self, cfg: LocalizerConfig):
        self.cfg = cfg
        self.health = HealthMonitor(cfg.health_window, cfg.health_p_value)
        self.next_search = 0  # kept points at which the next scheduled global check is due
        self.last_search_point = -1  # the point (points_seen) of the last global check
        self.clock_hint: ClockHint | None = None  # a DF stamp shift the bearings prefer, from the last global check

    @property
    def alarm(self) -> bool:
        """The cloud no longer explains the newest points."""
        return self.health.alarm_since is not None

    def started(self, points: int):
        """A filter started over `points` points: a fresh health record, the first scheduled check at twice them."""
        self.health.clear()
        self.next_search = max(2 * points, self.cfg.init_bearings)

    def watch(self, f: ParticleFilter, logw_before: np.ndarray, held: int, seen: int, outlier_prob: float,
              job: PendingJob | None) -> Watch:
        """The newest point's health (`f` has just taken it; `logw_before`: its log weights before) with `held`
        points kept of `seen`, against the calibrated `outlier_prob`; whether a scheduled or alarm-driven global
        check is due (not while `job` runs: due again once it is applied), else the moves while in alarm (one while
        a check is made in the calls: two left it one kernel a point, and an emitter that moved was noticed late)."""
        cfg = self.cfg
        if not cfg.global_safety:
            if cfg.calibrate_noise and held >= self.next_search:
                self._schedule(held)
                return Watch(calibrate=True)
            return Watch()
        w = np.exp(logw_before - logw_before.max())
        eps = cast(EmitterModel, f.model).lik.outlier_prob
        floor = math.log(max(eps, 1e-300) / (2 * math.pi)) if eps else -np.inf
        outlier_resp = float(w @ np.exp(np.minimum(floor - f.last_ll, 0.0)) / w.sum())
        was = self.alarm
        alarm = self.health.push(outlier_resp > 0.5, seen, outlier_prob)
        if alarm and not was:
            log.warning("the cloud no longer explains the newest points (%d of the last %d look wild); searching",
                        sum(self.health.flags), len(self.health.flags))
        due = held >= self.next_search
        alarm_due = alarm and seen - self.last_search_point >= _ALARM_SEARCH_EVERY
        if (due or alarm_due) and job is None:
            if due:
                self._schedule(held)
            return Watch(alarm, alarm and not was, check=True)
        sweeps = (1 if job is not None and job.in_calls else ALARM_SWEEPS) if alarm else 0
        return Watch(alarm, alarm and not was, sweeps=sweeps)

    def _schedule(self, held: int):
        self.next_search = min(int(math.ceil(held * _SEARCH_GROWTH)), held + _SEARCH_EVERY_MAX)

    def check_job(self, snap: Snapshot, seen: int) -> partial[CheckResult]:
        """A global check of `snap` at point `seen`, for the scheduler."""
        self.last_search_point = seen
        return partial(run_check, snap)

    def verdict(self, res: CheckResult, f: ParticleFilter, pts: Points, robust: Robust, realtime: bool
                ) -> CheckVerdict:
        """A check's modes against the cloud over the points held now (`pts`): a re-start when the best mode beats
        every particle by restart_log_odds (a worker's check scored again over the points held now)."""
        self.clock_hint = res.hint
        best_particle = float(np.max(f.log_target(f.x)))
        best_mode = res.modes[0].log_post
        if res.searched != len(pts):
            best_mode = float(log_posterior(res.modes[0].mean, pts, robust))
        if best_mode > best_particle + self.cfg.restart_log_odds:
            log.warning("re-start: a mode at E %.1f N %.1f explains the points far better (log odds %.1f) than the "
                        "cloud", res.modes[0].mean[0], res.modes[0].mean[1], best_mode - best_particle)
            self.health.clear()
            return CheckVerdict.RESTART
        return CheckVerdict.OWE if realtime else CheckVerdict.MOVE

    def moved(self, pts: Points, seen: int, f: ParticleFilter, outlier_prob: float, noise_fits: bool
              ) -> Moved | None:
        """In alarm: whether recent disagreeing points fix a place the older points of `pts` contradict, and the
        other way round (`outlier_prob`: the likelihood's; `noise_fits`: the noise was calibrated)."""
        cfg = self.cfg
        since = self.health.alarm_since
        m = seen - since + 1 if since is not None else 0
        if m < cfg.moved_min_points or m >= len(pts):
            return None
        if cfg.calibrate_noise and not noise_fits:
            return None  # disagreement means nothing before the outlier rate is known
        k = len(pts)
        recent, old = pts.take(np.arange(k - m, k)), pts.take(np.arange(k - m))
        rob = Robust(outlier_prob, cfg.gps_sigma_m)
        modes = find_modes(recent, rob, by_density=True)
        if not modes or modes[0].crossing_deg < cfg.init_min_crossing_deg or modes[0].inliers < MIN_INLIERS:
            return None
        x_new = modes[0].mean
        x_old = f.estimate()[0]
        # A moved emitter leaves (almost) no recent point agreeing with the old place; a second, stationary
        # source (a reflection) keeps about its share of them: that is a second mode, not a move.
        if inlier_share(x_old, recent, rob) > _MOVED_MAX_OLD_SHARE:
            return None
        pair = np.stack([x_new, x_old])
        lr_recent = float(np.subtract(*log_posterior(pair, recent, rob)))
        lr_old = -float(np.subtract(*log_posterior(pair, old, rob)))
        if min(lr_recent, lr_old) < cfg.moved_log_odds:
            return None
        log.warning("the emitter moved: the last %d points agree on E %.1f N %.1f, which the older %d contradict "
                    "(log odds %.1f); re-starting from the recent points", m, x_new[0], x_new[1], k - m,
                    min(lr_recent, lr_old))
        return Moved(m, x_new, min(lr_recent, lr_old))
