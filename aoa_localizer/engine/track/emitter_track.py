"""One emitter's track: observation points -> start -> filter updates, with the robustness layer around any filter.

The Localizer pairs readings with the GPS track and groups them; a track turns each group into an observation
point and keeps the estimate honest on messy data, with three parts:

* the initiator (initiator.py) starts the filter: a global search of the robust posterior over every buffered point,
  the first cloud an importance sample of it (every mode in proportion to its mass); or triangulation, or the prior;
* the supervisor (supervisor.py) watches each new point's health, runs global checks on a growing schedule and on
  alarm (inline, or their expensive part in a worker process: checks.py), moves the cloud from the modes or
  re-starts it, and drops the older points when the emitter moved;
* the calibrator (calibrator.py) holds the receiver as the data show it (noise, outlier share, latent noise, bearing
  offset): points are made with it, and a new calibration rebuilds them and re-weights the cloud.
"""
from __future__ import annotations

import logging
import math
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable
from typing import cast

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.inference.checks import CheckResult, Snapshot
from aoa_localizer.engine.inference.emitter_model import EmitterModel
from aoa_localizer.engine.inference.global_search import Mode, Points, Robust, find_modes
from aoa_localizer.engine.inference.offset import marginalise, prior_sd
from aoa_localizer.engine.inference.safety import ModeProposal
from aoa_localizer.engine.ingest.point_batch import Built, points_of, rows_of
from aoa_localizer.engine.rejections import Reason
from aoa_localizer.engine.scheduling.scheduler import Scheduler
from aoa_localizer.engine.track.calibrator import Calibrator
from aoa_localizer.engine.track.initiator import Initiator
from aoa_localizer.engine.track.report import cloud_estimate, spatial_median, wide_for_range
from aoa_localizer.engine.track.state import PendingJob, Phase, Status, TrackState, TrackStatus, WindowEntry
from aoa_localizer.engine.track.supervisor import Supervisor
from aoa_localizer.engine.types import Reading
from aoa_localizer.filters.base import ParticleFilter

log = logging.getLogger("aoa_localizer")

# The radio-range prior's scale: this many times the antennas' spread, at least this many metres (a transmitter a
# DF receiver hears is often kilometres away; at 100 m a short baseline's posterior kept an emitter 1.4 km out along
# its ray under 3 % of its mass)
_REACH_FACTOR, _REACH_MIN_M = 2.0, 1000.0
_CURRENT_SHARE = 0.9  # a provisional sample's share of the points held for it to count as current


class EmitterTrack:
    """Points, filter and robustness state of one emitter. `reject(reason, count)` counts unused inputs."""

    def __init__(self, cfg: LocalizerConfig, rng: np.random.Generator, reject: Callable[[Reason, int], None],
                 scheduler: Scheduler):
        """`scheduler`: where the start searches and global checks run (inline, or beside the filter)."""
        self.cfg, self.rng, self.reject, self.scheduler = cfg, rng, reject, scheduler
        self.calibration = Calibrator(self, cfg)
        self.initiator = Initiator(self, cfg)
        self.supervisor = Supervisor(self, cfg)
        self.job: PendingJob | None = None  # a start search or global check running in the worker
        # The points waiting for a start, then the filter's history
        self.window: deque[WindowEntry] = deque()
        self.filter: ParticleFilter | None = None
        # A sample of the posterior while it is proper but not determined enough to start the filter from: the
        # estimate (state `poorly_determined`) until the filter starts
        self.provisional: ParticleFilter | None = None
        self.modes: list[Mode] = []
        self.proposal: ModeProposal | None = None
        self.events: Counter = Counter()  # global_restart, emitter_moved, recalibrated, alarm, offset_learned
        self.status = Status(Phase.COLLECTING)
        self.points_seen = 0
        self.points_used = 0
        self.bearings_used = 0
        self.last_update_s = float("nan")
        self.last_stamp = float("nan")  # stamp of the newest observation point
        self.last_kept = np.zeros(0, bool)  # which readings the newest point kept (the report's trace)

    @property
    def state(self) -> TrackState:
        if self.filter is not None:
            return TrackState.TRACKING
        return TrackState.COLLECTING if self.provisional is None else TrackState.PROVISIONAL

    def summary(self) -> TrackStatus:
        """The track as programs read it (Localizer.track_status)."""
        sup = self.supervisor
        return TrackStatus(self.state, self.status, sup.alarm, sup.health.share, self.points_used, self.bearings_used,
                           self.last_update_s)

    # -- the flow -----------------------------------------------------------------------------------
    def add(self, readings: list[Reading]) -> bool:
        """One closed group of readings; True when the filter took it (or started) and has a new estimate. Its
        job's pieces come after the filter's step, within what the step left of the call's budget (the Localizer
        opens it: slices.one_call)."""
        t0 = time.perf_counter()
        owed_before = self.scheduler.debt(self.filter).modes
        if self.job is not None:
            self.job.release()
        applied = self.collect()  # a job's findings first: they may change the noise the point is made with
        point, kept = self.calibration.make(readings)
        self.last_stamp, self.last_kept = point.stamp, kept
        entry = WindowEntry(readings, point, int((~kept).sum()))
        if entry.gated:
            self.reject(Reason.POINT_OUTLIER, entry.gated)
        self.points_seen += 1
        if self.filter is None:
            self.window.append(entry)
            # (a provisional sample applied above is a new estimate even when no search finishes now)
            took = self.initiator.try_start() or (applied and self.estimating)
        else:
            took = self.update(entry, owed_before)
        if self.job is not None:
            self.job.advance()
            if self.collect():  # one that finished now is applied now, as at a point
                took = self.estimating
        self.last_update_s = time.perf_counter() - t0  # what this point cost, searches and calibration included
        return took

    def update(self, entry: WindowEntry, owed_before: bool = False) -> bool:
        """The running filter's update with one point (and the moves it owes the scheduler), then the supervisor's
        watch; False when it did not take it. `owed_before`: a check's move on the modes was owed before the point
        came (and was not made between points): made now."""
        f = self.running
        before = self.model.history.appended
        logw_before = f.logw  # replaced by the update, never changed in place
        try:
            ok = f.update(entry.point)
            if ok:
                self.scheduler.stepped(f)
            if ok and self.model.history.appended > before:
                self.window.append(entry)
                while len(self.window) > len(self.model.history):
                    self.window.popleft()
            if ok and f.finite():
                self.supervisor.watch(logw_before)
                if owed_before:
                    self.scheduler.pay_modes(self.filter, self.proposal)
            if self.filter is None:  # the emitter moved and the re-start waits for more points
                return False
            f = self.running
        except (ArithmeticError, ValueError, np.linalg.LinAlgError, MemoryError):
            log.exception("filter update failed; point skipped")
            self.reject(Reason.INTERNAL_ERROR, 1)
            return False
        if not f.finite():
            self._diverged()
            return False
        if not ok:
            self.reject(Reason.WEIGHTS_DEGENERATE, 1)
            return False
        self.points_used += 1
        self.bearings_used += entry.point.n_readings
        return True

    def restart(self):
        """Drop the filter (the emitter moved) and start again from the points kept."""
        self.filter = None
        self.modes, self.proposal = [], None
        self.points_used = 0
        self.bearings_used = 0
        self.initiator.try_start()

    def _diverged(self):
        self.filter = None
        self.window.clear()
        self.status = Status(Phase.DIVERGED)
        log.error("filter %s diverged (non-finite particles or estimate); restarting", self.cfg.algorithm)
        self.reject(Reason.FILTER_DIVERGED, 1)

    def finish(self) -> bool:
        """End of data: the worker's job still running is applied (and a start the worker lagged behind is tried
        inline), then one more global check over everything kept runs inline (unless the last point just had
        one). True when the estimate changed."""
        t0 = time.perf_counter()
        changed = False
        while self.job is not None:  # a stale start search is run again, over all the points: wait for that too
            changed = self.collect(wait=True) or changed
        self.scheduler.settle(self.filter)
        if self.filter is None:  # the end of data: the best estimate the points allow, never "collecting"
            self.initiator.next_start_try = 0
            changed = self.initiator.try_start(inline=True, final=True) or changed
        if self.filter is not None and self.cfg.global_safety and self.supervisor.last_search_point != self.points_seen:
            self.supervisor.global_check(inline=True)
            self.collect(wait=True)  # the start search of an emitter-moved re-start
            changed = True
        self.last_update_s = time.perf_counter() - t0
        return changed and self.estimating

    # -- the check worker -----------------------------------------------------------------------------
    def snapshot(self) -> Snapshot:
        """What a start search or global check needs, copied: it may run in the worker while the track goes on."""
        f = self.filter
        best = f.x[np.argmax(f.log_target(f.x))].copy() if f is not None and self.cfg.calibrate_noise else None
        c = self.calibration
        return Snapshot(self.cfg, [e.readings for e in self.window], rows_of([e.point for e in self.window]),
                        c.noise.copy(), c.outlier_prob, self.robust(), best, [m.mean.copy() for m in self.modes[:1]],
                        c.offset, c.course)

    def collect(self, wait: bool = False) -> bool:
        """Apply the worker's result once it is ready (`wait`: wait for it); True when one was applied. A result for
        a filter that has since been replaced (re-start, divergence) is dropped."""
        job = self.job
        if job is None or not (wait or job.future.done()):
            return False
        self.job = None
        try:
            result = job.future.result()
        except Exception:  # the worker's boundary: a failed check never stops the track
            if self.scheduler.failures <= 1:
                log.exception("global check failed in the worker; skipped (further failures are counted)")
            self.reject(Reason.INTERNAL_ERROR, 1)
            return False
        if self.filter is not job.filter:
            return False
        try:
            if job.is_start:
                return self.initiator.apply_start(result, job.groups)
            self.supervisor.apply_check(result, job.groups)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            log.exception("applying a global check failed; skipped")
            self.reject(Reason.INTERNAL_ERROR, 1)
            return False
        if self.filter is not None and not self.filter.finite():
            self._diverged()
        return True

    def apply_fit(self, res: CheckResult, groups: list[list[Reading]]):
        """A search's noise and offset fit, if it made one, adopted by the calibrator."""
        if res.noise is not None and res.at is not None:
            self.calibration.apply(res.noise, res.at, _by_group(groups, res.built), res.offset, res.course)

    # -- what the track holds -------------------------------------------------------------------------
    @property
    def debtor(self) -> tuple[ParticleFilter | None, ModeProposal | None]:
        """What the scheduler's owed moves are made with: the filter, and the proposal of its last check's modes."""
        return self.filter, self.proposal

    @property
    def running(self) -> ParticleFilter:
        """The filter, where the code runs only once it started."""
        if self.filter is None:
            raise RuntimeError("no filter running")  # an engine bug, never bad input
        return self.filter

    @property
    def cloud(self) -> ParticleFilter:
        """The particles the estimate comes from: the running filter, or the provisional sample before it."""
        if self.filter is not None:
            return self.filter
        if self.provisional is None:
            raise RuntimeError("no estimate yet")  # an engine bug, never bad input
        return self.provisional

    @property
    def cloud_is_current(self) -> bool:
        """Whether the cloud describes the points held now: a running filter's always; a provisional sample's while it
        holds all but a tenth of them (a start search that finds no place leaves the last sample standing)."""
        if self.filter is not None:
            return True
        return self.provisional is not None and self.provisional.k >= _CURRENT_SHARE * len(self.window)

    @property
    def estimating(self) -> bool:
        """Whether there is an estimate: a running filter or a provisional sample."""
        return self.state is not TrackState.COLLECTING

    @property
    def model(self) -> EmitterModel:
        """The running filter's emitter model (the track always builds one)."""
        return cast(EmitterModel, self.running.model)

    def used_points(self) -> np.ndarray:
        """(K, 5) rows east, north, theta, sigma, gps sigma of the points the running filter keeps; (0, 5) before."""
        if self.filter is None:
            return np.zeros((0, 5))
        return np.array(self.model.history.data, float).reshape(-1, 5)

    def points(self) -> Points:
        return points_of([e.point for e in self.window])

    def posterior_points(self) -> Points:
        """The points the estimate's posterior is over: the running filter's, else the ones held."""
        return Points.of(self.model.history.data) if self.filter is not None else self.points()

    def robust(self, prior: bool = True) -> Robust:
        """The robust posterior's settings the searches use: the calibrated outlier share and latent noise, with the
        filter's prior, the configured one, or (before a start) the radio-range prior of the points held."""
        c, cfg = self.calibration, self.cfg
        if prior and self.filter is not None and self.model.prior_prec.any():
            return Robust(c.lik_outlier_prob, cfg.gps_sigma_m, self.model.prior_mean, self.model.prior_prec,
                          c.noise_prior(), self.model.reach)
        if prior and cfg.prior_east is not None and cfg.prior_north is not None and cfg.prior_sigma_m is not None:
            return Robust(c.lik_outlier_prob, cfg.gps_sigma_m, np.array([cfg.prior_east, cfg.prior_north]),
                          np.eye(2) / cfg.prior_sigma_m**2, c.noise_prior())
        reach = (self.reach() if self.filter is None else self.model.reach) if prior else None
        return Robust(c.lik_outlier_prob, cfg.gps_sigma_m, grid=c.noise_prior(), reach=reach)

    def reach(self) -> tuple[float, float, float] | None:
        """The radio-range prior of the points held (global_search.Robust.reach): centred on their antennas, its
        scale twice their spread (at least _REACH_MIN_M)."""
        if not self.window:
            return None
        pos = np.array([[e.point.east, e.point.north] for e in self.window])
        centre = pos.mean(axis=0)
        spread = float(np.max(np.hypot(*(pos - centre).T)))
        return float(centre[0]), float(centre[1]), max(_REACH_MIN_M, _REACH_FACTOR * spread)

    # -- estimates ------------------------------------------------------------------------------------
    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """The published place and covariance, marginalised over the residual bearing offset the points cannot tell
        from a place (offset.marginalise): a running filter's mean and covariance, or where its ellipse is wide for
        the range (its tails along the rays drag the mean out), its spatial median with the ellipse holding 95 % of
        the cloud; a provisional sample's highest-density place (its best mode) with that ellipse."""
        if self.filter is None:
            mean, cov = cloud_estimate(self.cloud, self.modes[0].mean)
        else:
            mean, cov = self.filter.estimate()
            if wide_for_range(self, mean, cov)[0]:
                mean, cov = cloud_estimate(self.filter, spatial_median(self.filter.x, self.filter.weights))
        sd = math.inf if self.calibration.offset else prior_sd(self.cfg)
        if sd == 0.0:
            return mean, cov
        pts = self.posterior_points()
        shift, spread = marginalise(pts, mean, self.robust(), sd)
        return mean + shift, cov + spread

    def batch_estimate(self) -> Mode | None:
        """Robust batch maximum likelihood over every point held (no filter): global search, joint noise
        calibration, Gauss-Newton; the best mode with its Laplace covariance. The benchmark's reference."""
        modes = find_modes(self.points(), self.robust(), by_density=True)
        if modes and self.cfg.calibrate_noise and self.calibration.calibrate([m.mean for m in modes[:2]], True):
            modes = find_modes(self.points(), self.robust(), by_density=True)
        return modes[0] if modes else None


def _by_group(groups: Iterable[list[Reading]], built: list[Built]) -> dict[int, tuple[list[Reading], Built]]:
    """A check's points rebuilt with its noise, by their group's identity (empty when the check made none)."""
    return {id(g): (g, b) for g, b in zip(groups, built, strict=True)} if built else {}
