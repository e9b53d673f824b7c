"""What keeps a running filter honest on messy data: the health of each new point (the share the cloud explains
only as outliers, against the calibrated rate); global checks on a growing schedule and on alarm (noise calibration,
global search, then the modes' MH move or a re-start from a far better mode), inline or in the check worker; moves
at every point while in alarm (unless a check is being made in the calls); and the emitter-moved test."""
from __future__ import annotations

import logging
import math
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.inference.checks import CheckResult, check, refined, run_check
from aoa_localizer.engine.inference.global_search import Robust, find_modes, inlier_share, log_posterior
from aoa_localizer.engine.inference.safety import HealthMonitor, ModeProposal, importance_sample
from aoa_localizer.engine.ingest.clock_check import ClockHint
from aoa_localizer.engine.rejections import Reason
from aoa_localizer.engine.scheduling.slices import CHECK_BUDGET_US
from aoa_localizer.engine.track.initiator import MIN_INLIERS, START_SWEEPS
from aoa_localizer.engine.track.state import PendingJob, Phase, Status
from aoa_localizer.engine.types import Reading

if TYPE_CHECKING:
    from aoa_localizer.engine.track.emitter_track import EmitterTrack

log = logging.getLogger("aoa_localizer")

ALARM_SWEEPS = 2  # moves at every point while in alarm
_SEARCH_GROWTH = 2.0  # scheduled global searches when the kept points have grown by this factor ...
_SEARCH_EVERY_MAX = 100  # ... or by this many points
_ALARM_SEARCH_EVERY = 5  # points between global searches while in alarm
_MOVED_MAX_OLD_SHARE = 0.2  # most recent points that may still agree with the old place in a move


class Supervisor:
    """One track's health monitor, global-check schedule and emitter-moved test."""

    def __init__(self, track: EmitterTrack, cfg: LocalizerConfig):
        self.track, self.cfg = track, cfg
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

    def watch(self, logw_before: np.ndarray):
        """Health of the newest point, scheduled and alarm-driven global checks, moves while in alarm and no check is
        being made in the calls."""
        t, cfg = self.track, self.cfg
        f, n = t.running, len(t.window)
        if not cfg.global_safety:
            if cfg.calibrate_noise and n >= self.next_search:
                self.next_search = min(int(math.ceil(n * _SEARCH_GROWTH)), n + _SEARCH_EVERY_MAX)
                best = f.x[np.argmax(f.log_target(f.x))]
                t.calibration.calibrate([refined(best, t.points(), t.robust())], False)
            return
        w = np.exp(logw_before - logw_before.max())
        eps = t.model.lik.outlier_prob
        floor = math.log(max(eps, 1e-300) / (2 * math.pi)) if eps else -np.inf
        outlier_resp = float(w @ np.exp(np.minimum(floor - f.last_ll, 0.0)) / w.sum())
        was = self.alarm
        alarm = self.health.push(outlier_resp > 0.5, t.points_seen, t.calibration.outlier_prob)
        if alarm and not was:
            t.events["alarm"] += 1
            log.warning("the cloud no longer explains the newest points (%d of the last %d look wild); searching",
                        sum(self.health.flags), len(self.health.flags))
        if alarm:
            t.events["alarm_points"] += 1
            t.status = Status(Phase.CHECKING, disagree=sum(self.health.flags), tested=len(self.health.flags))
        elif t.status.phase is Phase.CHECKING:
            t.status = Status(Phase.TRACKING)
        due = n >= self.next_search
        alarm_due = alarm and t.points_seen - self.last_search_point >= _ALARM_SEARCH_EVERY
        if (due or alarm_due) and t.job is None:  # (one still running: due again once it is applied)
            if due:
                self.next_search = min(int(math.ceil(n * _SEARCH_GROWTH)), n + _SEARCH_EVERY_MAX)
            self.global_check()
        elif alarm:
            # (one while a check is made in the calls: two left it a piece a point, and an emitter that moved was
            # noticed late)
            f.rejuvenate(1 if t.job is not None and t.job.in_calls else ALARM_SWEEPS, t.proposal)

    def global_check(self, inline: bool = False):
        """Noise calibration, emitter-moved test, global search, MH move or re-start: whole here (`inline`), or its
        expensive part handed to the worker or made a few pieces per point (applied by the track's collect once
        finished: here when it finished in its first call)."""
        t = self.track
        self.last_search_point = t.points_seen
        snap = t.snapshot()
        if inline:
            self.apply_check(run_check(snap), snap.groups)
            return
        t.job = PendingJob(t.scheduler.start(partial(run_check, snap), check(snap), CHECK_BUDGET_US), t.running,
                           snap.groups)
        t.collect()

    def apply_check(self, res: CheckResult, groups: list[list[Reading]]):
        """The cheap part of a global check, on the current cloud and points: re-weight by the fitted noise,
        emitter-moved test (in alarm), then the modes' MH move or a re-start from a far better mode."""
        t = self.track
        t.apply_fit(res, groups)
        if self.alarm and self._emitter_moved():
            return
        modes = res.modes
        if not modes:
            return
        f = t.running
        t.modes = modes
        self.clock_hint = res.hint
        t.proposal = ModeProposal.over(modes, t.points())
        best_particle = float(np.max(f.log_target(f.x)))
        best_mode = modes[0].log_post
        if res.searched != len(t.window):  # a worker's check: the mode scored over the points held now
            best_mode = float(log_posterior(modes[0].mean, t.points(), t.robust()))
        if best_mode > best_particle + self.cfg.restart_log_odds:
            t.events["global_restart"] += 1
            log.warning("re-start: a mode at E %.1f N %.1f explains the points far better (log odds %.1f) than the "
                        "cloud", modes[0].mean[0], modes[0].mean[1], best_mode - best_particle)
            f.replace_cloud(importance_sample(f.log_target, t.proposal, f.n, t.rng))
            f.rejuvenate(START_SWEEPS, t.proposal)
            self.health.clear()
        elif not t.scheduler.realtime:
            f.rejuvenate(1, t.proposal)
        else:  # realtime: the modes' move is owed, made between points (or at the next point)
            t.scheduler.owe_modes(f)

    def _emitter_moved(self) -> bool:
        """Recent disagreeing points fix a place the older points contradict, and the other way round:
        drop the older points and re-start from the recent ones."""
        t, cfg = self.track, self.cfg
        since = self.health.alarm_since
        m = t.points_seen - since + 1 if since is not None else 0
        if m < cfg.moved_min_points or m >= len(t.window):
            return False
        if cfg.calibrate_noise and not t.calibration.noise.fits:
            return False  # disagreement means nothing before the outlier rate is known
        pts = t.points()
        k = len(pts)
        recent, old = pts.take(np.arange(k - m, k)), pts.take(np.arange(k - m))
        rob = Robust(t.calibration.lik_outlier_prob, cfg.gps_sigma_m)
        modes = find_modes(recent, rob, by_density=True)
        if not modes or modes[0].crossing_deg < cfg.init_min_crossing_deg or modes[0].inliers < MIN_INLIERS:
            return False
        x_new = modes[0].mean
        x_old = t.running.estimate()[0]
        # A moved emitter leaves (almost) no recent point agreeing with the old place; a second, stationary
        # source (a reflection) keeps about its share of them: that is a second mode, not a move.
        if inlier_share(x_old, recent, rob) > _MOVED_MAX_OLD_SHARE:
            return False
        pair = np.stack([x_new, x_old])
        lr_recent = float(np.subtract(*log_posterior(pair, recent, rob)))
        lr_old = -float(np.subtract(*log_posterior(pair, old, rob)))
        if min(lr_recent, lr_old) < cfg.moved_log_odds:
            return False
        dropped = [t.window.popleft() for _ in range(k - m)]
        t.reject(Reason.EMITTER_MOVED, sum(e.used for e in dropped))
        t.events["emitter_moved"] += 1
        log.warning("the emitter moved: the last %d points agree on E %.1f N %.1f, which the older %d contradict "
                    "(log odds %.1f); re-starting from the recent points", m, x_new[0], x_new[1], k - m,
                    min(lr_recent, lr_old))
        t.restart()
        if t.filter is not None:
            t.status = Status(Phase.TRACKING, restarted_from=m)
        return True
