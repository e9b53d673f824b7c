"""One emitter's track: observation points -> start -> filter updates, with the robustness layer around any filter.

The Localizer pairs readings with the GPS track and groups them; this class turns each group into an
observation point and keeps the estimate honest on messy data:

* robust start: a global search of the robust posterior over every buffered point (global_search.py); the
  first cloud is an importance sample of that posterior (every mode in proportion to its mass);
* noise self-calibration: EM on the readings' residuals at the best mode (noise.py); the points are rebuilt
  from their readings with the new sigmas and the cloud re-weighted by the change of posterior;
* global-mode safety: the health monitor watches the outlier share of new points; on alarm, and on a
  growing schedule, the global search runs again and the cloud is moved by independence MH from the modes,
  or re-started from a far better mode; while in alarm the cloud is moved at every point. The check's search
  and noise fit run inline or in a worker process (checks.py), its result applied at the next point;
* emitter moved: when recent points agree on a place that the older points contradict (and vice versa),
  the older points are dropped and the track re-starts from the recent ones.
"""
from __future__ import annotations

import logging
import math
import time
from collections import Counter, deque
from collections.abc import Callable
from concurrent.futures import Future
from functools import partial
from typing import cast

import numpy as np

from aoa_localizer.engine.checks import (
    Built,
    CheckResult,
    CheckWorker,
    Snapshot,
    ellipse_and_reach,
    fit_noise,
    offset_point,
    points_of,
    refined,
    rows_of,
    run_check,
    search_start,
    sigmas,
)
from aoa_localizer.engine.clock_check import ClockHint
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.crlb import ELLIPSE_95
from aoa_localizer.engine.emitter_model import EmitterModel
from aoa_localizer.engine.global_search import (
    Mode,
    Points,
    Robust,
    find_modes,
    inlier_share,
    log_posterior,
    residuals,
)
from aoa_localizer.engine.noise import NoiseModel, point_outlier_prob
from aoa_localizer.engine.offset import marginalise, prior_sd
from aoa_localizer.engine.preprocess import make_point
from aoa_localizer.engine.receiver import NoiseGrid
from aoa_localizer.engine.safety import HealthMonitor, ModeProposal, importance_sample
from aoa_localizer.engine.triangulation import initial_particles
from aoa_localizer.engine.types import ObservationPoint, Reading
from aoa_localizer.filters import make_filter
from aoa_localizer.filters.base import ParticleFilter
from aoa_localizer.filters.resample_move import ResampleMove

log = logging.getLogger("aoa_localizer")

# Broad Gaussian prior after a data-driven start, in multiples of the range to the start: it only keeps the
# bearing-only posterior proper (a flat prior has infinite mass along the rays).
_PRIOR_RANGE_FACTOR = 10.0
_PRIOR_MIN_SIGMA_M = 100.0
_PROVISIONAL_PARTICLES = 1000
_ELLIPSE_MASS = 0.95  # the share of the posterior a provisional estimate's ELLIPSE_95 ellipse holds
# The radio-range prior's scale: this many times the antennas' spread, at least this many metres.
_REACH_FACTOR, _REACH_MIN_M = 2.0, 100.0
_START_SWEEPS = 3  # random-walk MH sweeps that spread the importance sample's duplicates
_ALARM_SWEEPS = 2  # moves at every point while in alarm
_SEARCH_GROWTH = 2.0  # scheduled global searches when the kept points have grown by this factor ...
_SEARCH_EVERY_MAX = 100  # ... or by this many points
_ALARM_SEARCH_EVERY = 5  # points between global searches while in alarm
_MIN_INLIERS = 3  # a start mode must explain at least this many points
_MODE_MIN_MASS = 0.01  # modes reported
_MAX_ELLIPSE_RANGE_SHARE = 0.5  # a start mode's 95 % semi-major axis must be under this share of its range
_START_RETRY_MAX = 5  # most points between two start attempts that found no determined mode
_SUSPECT_WILD_SHARE = 0.4  # more bearings than this unexplained: the model does not fit (state `suspect`)
_AMBIGUOUS_MASS = 0.2  # a second mode this heavy leaves the estimate poorly determined
_MOVED_MAX_OLD_SHARE = 0.2  # most recent points that may still agree with the old place in a move
_STALE_MIN, _STALE_SHARE = 2, 5  # a start search's result is stale once the points grew by more than max(2, 1/5)


class EmitterTrack:
    """Points, filter and robustness state of one emitter. `reject(reason, count)` counts unused inputs."""

    def __init__(self, cfg: LocalizerConfig, rng: np.random.Generator, reject: Callable[[str, int], None],
                 worker: CheckWorker | None = None):
        """`worker`: runs the global checks' expensive part beside the filter (None: inline)."""
        self.cfg, self.rng, self._reject, self.worker = cfg, rng, reject, worker
        # A job running in the worker: a global check for this filter, or a start search (None: before the start),
        # and the groups of its snapshot (the originals: the worker's copies come back as points in their order).
        self.check: tuple[Future, ParticleFilter | None, list[list[Reading]]] | None = None
        self.noise = NoiseModel(cfg.outlier_prob)
        self.outlier_prob = cfg.outlier_prob  # point level, in the likelihood
        # The receiver's noise as latent hypotheses, marginalised with the position until the readings calibrate it
        # (None: known, or calibrated)
        self.grid: NoiseGrid | None = None
        self.offset = 0.0  # a constant bearing offset the data determined (ENU rad, offset.py), taken off every point
        if cfg.noise == "unknown" and cfg.likelihood == "mixture":
            self.grid = NoiseGrid.for_config(cfg)
        # (readings, point, readings gated out) per point: the points waiting for a start, then the filter's
        # history
        self.window: deque[tuple[list[Reading], ObservationPoint, int]] = deque()
        self.filter: ParticleFilter | None = None
        # A sample of the posterior while it is proper but not determined enough to start the filter from: the
        # estimate (state `poorly_determined`) until the filter starts
        self.provisional: ParticleFilter | None = None
        self.health = HealthMonitor(cfg.health_window, cfg.health_p_value)
        self.modes: list[Mode] = []
        self.proposal: ModeProposal | None = None
        self.events: Counter = Counter()  # global_restart, emitter_moved, recalibrated, alarm
        self.status = "collecting bearings"
        self.points_seen = 0
        self.points_used = 0
        self.bearings_used = 0
        self.last_update_s = float("nan")
        self.last_stamp = float("nan")  # stamp of the newest observation point
        self.next_search = 0
        self.next_start_try = 0
        self.last_search_point = -1
        self.start_cloud: np.ndarray | None = None  # the particles of the latest start
        self.clock_hint: ClockHint | None = None  # a DF stamp shift the bearings prefer, from the last global check
        self.move_owed = False  # realtime: the last check's move on the modes, not made yet
        self._noise_summary: tuple[NoiseModel, int, float, dict] | None = None  # (model, fits, share, summary)

    # -- points -----------------------------------------------------------------------------------
    def sigmas(self, readings: list[Reading]) -> np.ndarray:
        """Each reading's sigma under the calibrated noise model (the configured one until calibrated)."""
        return sigmas(readings, self.noise if self.cfg.calibrate_noise else None)

    def noise_summary(self, base_sigma_deg: Callable[[float], float]) -> dict:
        """The calibrated noise's summary (NoiseModel.summary) with the point outlier share; every estimate carries
        one, so it is made again only for another model, a new fit (a model changes only by fit(), which counts
        them) or another share. The caller gets its own dicts."""
        n, cached = self.noise, self._noise_summary
        if cached is None or cached[0] is not n or cached[1:3] != (n.fits, self.outlier_prob):
            summary = n.summary(base_sigma_deg)
            summary["point_outlier_prob"] = round(self.outlier_prob, 4)
            cached = self._noise_summary = (n, n.fits, self.outlier_prob, summary)
        summary = cached[3]
        return {**summary, "sigma_deg": dict(summary["sigma_deg"])}

    def make(self, readings: list[Reading]) -> tuple[ObservationPoint, np.ndarray]:
        """The point of `readings` under the calibrated noise model (the readings' own sigmas until calibrated)."""
        made = make_point(readings, self.cfg, self.sigmas(readings) if self.cfg.calibrate_noise else None)
        return offset_point(made, self.offset)

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

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """The published mean and covariance: the cloud's (_cloud_estimate), marginalised over the residual bearing
        offset the points cannot tell from a place (offset.marginalise)."""
        mean, cov = self._cloud_estimate()
        sd = math.inf if self.offset else prior_sd(self.cfg)
        if sd == 0.0:
            return mean, cov
        pts = Points.of(self.model.history.data) if self.filter is not None else self.points()
        shift, spread = marginalise(pts, mean, self.robust(), sd)
        return mean + shift, cov + spread

    def _cloud_estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """The filter's mean and covariance; or, for a provisional sample, the posterior's highest-density place (the
        best mode: with few bearings the posterior's tails along the rays drag its mean far out) with the cloud's
        second moment about it, scaled so the 95 % ellipse holds 95 % of the cloud."""
        if self.filter is not None:
            return self.filter.estimate()
        f = self.cloud
        centre = self.modes[0].mean.copy()
        w, d = f.weights, f.x - centre
        cov = (w[:, None] * d).T @ d
        try:
            d2 = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)
        except np.linalg.LinAlgError:
            return centre, cov
        order = np.argsort(d2)
        at = min(int(np.searchsorted(np.cumsum(w[order]), _ELLIPSE_MASS)), len(order) - 1)
        return centre, cov * max(float(d2[order][at]), 1e-12) / ELLIPSE_95

    @property
    def estimating(self) -> bool:
        """Whether there is an estimate: a running filter or a provisional sample."""
        return self.filter is not None or self.provisional is not None

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
        return points_of([p for _, p, _ in self.window])

    def robust(self, prior: bool = True) -> Robust:
        if prior and self.filter is not None and self.model.prior_prec.any():
            return Robust(self.lik_outlier_prob, self.cfg.gps_sigma_m, self.model.prior_mean, self.model.prior_prec,
                          self.grid, self.model.reach)
        cfg = self.cfg
        if prior and cfg.prior_east is not None and cfg.prior_north is not None and cfg.prior_sigma_m is not None:
            return Robust(self.lik_outlier_prob, cfg.gps_sigma_m, np.array([cfg.prior_east, cfg.prior_north]),
                          np.eye(2) / cfg.prior_sigma_m**2, self.grid)
        reach = self.reach() if self.filter is None and prior else None
        return Robust(self.lik_outlier_prob, self.cfg.gps_sigma_m, grid=self.grid, reach=reach)

    def reach(self) -> tuple[float, float, float] | None:
        """The radio-range prior of the points held (global_search.Robust.reach): centred on their antennas, its
        scale twice their spread (at least _REACH_MIN_M)."""
        if not self.window:
            return None
        pos = np.array([[p.east, p.north] for _, p, _ in self.window])
        centre = pos.mean(axis=0)
        spread = float(np.max(np.hypot(*(pos - centre).T)))
        return float(centre[0]), float(centre[1]), max(_REACH_MIN_M, _REACH_FACTOR * spread)

    @property
    def lik_outlier_prob(self) -> float:
        """The outlier share the likelihood uses: the calibrated one for `likelihood: mixture`, 0 for the paper's
        Gaussian (which then stays Gaussian, in the filter and in the searches)."""
        return self.outlier_prob if self.cfg.likelihood == "mixture" else 0.0

    # -- the flow -----------------------------------------------------------------------------------
    def add(self, readings: list[Reading]) -> bool:
        """One closed group of readings; True when the filter took it (or started) and has a new estimate."""
        t0 = time.perf_counter()
        owed_before = self.move_owed
        self._collect_check()  # a background check's findings first: they may change the noise the point is made with
        point, kept = self.make(readings)
        self.last_stamp = point.stamp
        self.last_kept = kept  # which readings the point kept (the report's trace)
        gated = int((~kept).sum())
        if gated:
            self._reject("point_outlier", gated)
        self.points_seen += 1
        if self.filter is None:
            self.window.append((readings, point, gated))
            took = self._try_start()
        else:
            took = self._update(readings, point, gated, owed_before)
        # What this point cost, searches and calibration included.
        self.last_update_s = time.perf_counter() - t0
        return took

    def _try_start(self, inline: bool = False, final: bool = False):
        """Start the filter once the points allow (`inline`: the start search here, even with a worker; `final`: the
        end of data, with whatever points there are)."""
        cfg = self.cfg
        if cfg.has_prior:
            return self._start_from_prior()
        if len(self.window) > cfg.init_max_points:
            _, _, gated = self.window.popleft()
            self._reject("init_buffer_full", 1)
        if len(self.window) < (min(2, cfg.init_bearings) if final else cfg.init_bearings):
            self.status = f"collecting bearings: {len(self.window)} of {cfg.init_bearings} points"
            return False
        if cfg.init_method == "triangulation":
            return self._start_triangulation()
        if not final and (len(self.window) < self.next_start_try or self.check is not None):
            return False
        snap = self._snapshot()
        job = partial(search_start, snap, _MIN_INLIERS, _MAX_ELLIPSE_RANGE_SHARE, final)
        future = None if inline else self._submit(job)
        if future is None:
            return self._apply_start(job(), snap.groups)
        self.check = (future, None, snap.groups)
        return False

    def _apply_start(self, res: CheckResult, groups: list[list[Reading]]) -> bool:
        """Start the filter from a start search's modes over the points held now (a background search's snapshot
        may have fewer): an importance sample of the posterior, then MH sweeps; or wait for more points."""
        if len(self.window) > res.searched + max(_STALE_MIN, res.searched // _STALE_SHARE):
            # Points came far faster than the worker searched (a bag replayed at full speed): a mode of the few
            # points searched is no start for the many held now. Search again, over all of them.
            self.next_start_try = 0
            return self._try_start()
        if res.noise is not None and res.at is not None:
            self._apply_calibration(res.noise, res.at, _by_group(groups, res.built), res.offset)
        modes = res.modes
        if not modes or not res.determined:
            self.status = f"waiting for geometry: {res.why}"
            # Search again when the points searched have grown by a tenth (at most _START_RETRY_MAX points later).
            self.next_start_try = res.searched + min(_START_RETRY_MAX, max(1, res.searched // 10))
            if not modes:
                return False
            # Proper but not determined: publish a sample of the posterior (wide, honest), not nothing.
            self.provisional = self._sample_posterior(modes)
            self.status = f"poorly determined: {res.why}"
        else:
            self.provisional = None
            self.filter = self._sample_posterior(modes, start=True)
            self._started(f"global search: best of {len(modes)} mode(s), {modes[0].inliers} of {len(self.window)} "
                          "points agree")
        self.modes = modes
        self.points_used = len(self.window)  # (none before: a start, or a provisional sample, holds all)
        self.bearings_used = sum(len(r) - g for r, _, g in self.window)
        return True

    def _sample_posterior(self, modes: list[Mode], start: bool = False) -> ParticleFilter:
        """A filter holding every point waiting for a start and an importance sample of their posterior from the
        modes (MH sweeps after it), with a broad Gaussian prior at the best mode that keeps the posterior proper.
        `start`: the filter's start (its importance sample kept as `start_cloud`)."""
        best = modes[0]
        last = self.window[-1][1]
        sigma = max(
            _PRIOR_MIN_SIGMA_M, _PRIOR_RANGE_FACTOR * math.hypot(best.mean[0] - last.east, best.mean[1] - last.north)
        )
        # A provisional sample's ellipse is read off its tails: at least _PROVISIONAL_PARTICLES (few points: cheap)
        f = self._new_filter(None if start else max(self.cfg.num_particles, _PROVISIONAL_PARTICLES))
        model = cast(EmitterModel, f.model)
        model.set_prior(best.mean, sigma**2 * np.eye(2))
        model.reach = self.reach()
        model.lik.outlier_prob = self.lik_outlier_prob
        for _, p, _ in self.window:
            model.observe(p)
        f.k = len(self.window)
        self.proposal = ModeProposal(modes, self._broad_sigma(best.mean))
        particles = importance_sample(f.log_target, self.proposal, f.n, self.rng)
        f.initialise(particles, best.mean, sigma**2 * np.eye(2))
        if start:
            self.start_cloud = f.x.copy()
        f.rejuvenate(_START_SWEEPS, self.proposal)
        return f

    def _start_triangulation(self):
        """The paper's start (sec. 3.3): crossings of sorted pairs; then every buffered point updates the filter."""
        cfg = self.cfg
        pts = [p for _, p, _ in self.window]
        particles, why = initial_particles(
            pts, cfg.num_particles, cfg.init_min_crossing_deg, cfg.init_min_support, self.rng
        )
        if particles is None:
            self.status = f"waiting for geometry: {why}"
            return False
        mean = particles.mean(axis=0)
        sigma = max(
            _PRIOR_MIN_SIGMA_M, _PRIOR_RANGE_FACTOR * math.hypot(mean[0] - pts[-1].east, mean[1] - pts[-1].north)
        )
        return self._start_then_replay(particles, mean, sigma**2 * np.eye(2), "triangulation")

    def _start_from_prior(self):
        cfg = self.cfg
        mean = np.array([cfg.prior_east, cfg.prior_north])
        particles = mean + cfg.prior_sigma_m * self.rng.standard_normal((cfg.num_particles, 2))
        return self._start_then_replay(particles, mean, cfg.prior_sigma_m**2 * np.eye(2), "prior")

    def _start_then_replay(self, particles, mean, cov, how: str):
        self.filter = self._new_filter()
        self.model.lik.outlier_prob = self.lik_outlier_prob
        self.running.initialise(particles, mean, cov)
        self.start_cloud = self.running.x.copy()
        waiting, self.window = list(self.window), deque()
        self._started(how)
        result = False
        for readings, point, gated in waiting:
            result = self._update(readings, point, gated) or result
        return result

    def _new_filter(self, particles: int | None = None) -> ParticleFilter:
        """A filter on a new emitter model (with the latent noise while it is latent); `particles`: N if not the
        configured one."""
        model = EmitterModel(self.cfg)
        model.grid = self.grid
        cfg = self.cfg if particles is None else self.cfg.with_changes(num_particles=particles)
        f = make_filter(cfg, self.rng, model)
        if self.worker is not None and isinstance(f, ResampleMove):  # realtime: a bounded step
            f.sweeps_per_point = 1
        return f

    def _started(self, how: str):
        self.status = "tracking"
        self.health.clear()
        self.next_search = max(2 * len(self.window), self.cfg.init_bearings)
        log.info("filter %s started after %d observation points (%s)", self.cfg.algorithm, self.points_seen, how)

    def _update(self, readings, point, gated, owed_before: bool = False) -> bool:
        f = self.running
        before = self.model.history.appended
        logw_before = f.logw  # replaced by the update, never changed in place
        try:
            ok = f.update(point)
            if ok and self.model.history.appended > before:
                self.window.append((readings, point, gated))
                while len(self.window) > len(self.model.history):
                    self.window.popleft()
            if ok and self._finite():
                self._supervise(logw_before)
                if owed_before:
                    self._pay_move()  # owed before this point came and not made in idle time: now
            if self.filter is None:  # the emitter moved and the re-start waits for more points
                return False
            f = self.running
        except (ArithmeticError, ValueError, np.linalg.LinAlgError, MemoryError):
            log.exception("filter update failed; point skipped")
            self._reject("internal_error", 1)
            return False
        if not self._finite():
            self._diverged()
            return False
        if not ok:
            self._reject("weights_degenerate", 1)
            return False
        self.points_used += 1
        self.bearings_used += point.n_readings
        return True

    def _diverged(self):
        self.filter = None
        self.window.clear()
        self.status = "filter diverged: restarting from new bearings"
        log.error("filter %s diverged (non-finite particles or estimate); restarting", self.cfg.algorithm)
        self._reject("filter_diverged", 1)

    def _finite(self) -> bool:
        return self.running.finite()

    # -- the safety layer ---------------------------------------------------------------------------
    def _supervise(self, logw_before: np.ndarray):
        """Health of the newest point, scheduled and alarm-driven global searches, moves while in alarm."""
        f, n = self.running, len(self.window)
        if not self.cfg.global_safety:
            if self.cfg.calibrate_noise and n >= self.next_search:
                self.next_search = min(int(math.ceil(n * _SEARCH_GROWTH)), n + _SEARCH_EVERY_MAX)
                best = f.x[np.argmax(f.log_target(f.x))]
                self._calibrate([refined(best, self.points(), self.robust())], False)
            return
        w = np.exp(logw_before - logw_before.max())
        eps = self.model.lik.outlier_prob
        floor = math.log(max(eps, 1e-300) / (2 * math.pi)) if eps else -np.inf
        outlier_resp = float(w @ np.exp(np.minimum(floor - f.last_ll, 0.0)) / w.sum())
        was = self.health.alarm_since is not None
        alarm = self.health.push(outlier_resp > 0.5, self.points_seen, self.outlier_prob)
        if alarm and not was:
            self.events["alarm"] += 1
            log.warning(
                "the cloud no longer explains the newest points (%d of the last %d look wild); searching",
                sum(self.health.flags),
                len(self.health.flags),
            )
        if alarm:
            self.events["alarm_points"] += 1
            self.status = f"checking: {sum(self.health.flags)} of the last {len(self.health.flags)} points disagree"
        elif self.status.startswith("checking"):
            self.status = "tracking"
        due = n >= self.next_search
        alarm_due = alarm and self.points_seen - self.last_search_point >= _ALARM_SEARCH_EVERY
        if (due or alarm_due) and self.check is None:  # (one still running: due again once it is applied)
            if due:
                self.next_search = min(int(math.ceil(n * _SEARCH_GROWTH)), n + _SEARCH_EVERY_MAX)
            self._global_check(alarm)
        elif alarm:
            f.rejuvenate(_ALARM_SWEEPS, self.proposal)

    def finish(self) -> bool:
        """End of data: the worker's job still running is applied (and a start the worker lagged behind is tried
        inline), then one more global check over everything kept runs inline (unless the last point just had
        one). True when the estimate changed."""
        t0 = time.perf_counter()
        changed = False
        while self.check is not None:  # a stale start search is run again, over all the points: wait for that too
            changed = self._collect_check(wait=True) or changed
        if self.filter is None:  # the end of data: the best estimate the points allow, never "collecting"
            self.next_start_try = 0
            changed = self._try_start(inline=True, final=True) or changed
        if self.filter is not None and self.cfg.global_safety and self.last_search_point != self.points_seen:
            self._global_check(inline=True)
            self._collect_check(wait=True)  # the start search of an emitter-moved re-start
            changed = True
        self.last_update_s = time.perf_counter() - t0
        return changed and (self.filter is not None or self.provisional is not None)

    def _global_check(self, inline: bool = False):
        """Noise calibration, emitter-moved test, global search, MH move or re-start: inline, or its expensive part
        handed to the worker (applied at a later point by _collect_check)."""
        self.last_search_point = self.points_seen
        snap = self._snapshot()
        future = None if inline else self._submit(partial(run_check, snap))
        if future is None:
            self._apply_check(run_check(snap), snap.groups)
        else:
            self.check = (future, self.running, snap.groups)

    def _submit(self, job) -> Future | None:
        """The job handed to the worker; None without one, or when it cannot take it (then the caller runs it)."""
        return None if self.worker is None else self.worker.submit(job)

    def _snapshot(self) -> Snapshot:
        f = self.filter
        best = f.x[np.argmax(f.log_target(f.x))].copy() if f is not None and self.cfg.calibrate_noise else None
        groups, rows = [g for g, _, _ in self.window], rows_of([p for _, p, _ in self.window])
        return Snapshot(self.cfg, groups, rows, self.noise.copy(), self.outlier_prob,
                        self.robust(), best, [m.mean.copy() for m in self.modes[:1]], self.offset)

    def pay_owed(self) -> bool:
        """One move owed (`scheduling: realtime`: a global check's move on the modes, then the filter's sweeps),
        made between points; False if none is owed."""
        f = self.filter
        if f is None or not self._finite():
            return False
        return self._pay_move() or (isinstance(f, ResampleMove) and f.pay_owed())

    def _pay_move(self) -> bool:
        """The owed move on the last check's modes, if any (an MH move: made late, it keeps the posterior)."""
        if not self.move_owed:
            return False
        self.move_owed = False
        if self.filter is None or self.proposal is None:
            return False
        self.filter.rejuvenate(1, self.proposal)
        return True

    @property
    def owed(self) -> int:
        return int(self.move_owed) + (self.filter.owed if isinstance(self.filter, ResampleMove) else 0)

    def collect(self) -> bool:
        """Apply the worker's result if it is ready (without waiting for the next point); True when applied."""
        return self._collect_check()

    def _collect_check(self, wait: bool = False) -> bool:
        """Apply the background check's result once it is ready (`wait`: wait for it); True when one was applied.
        A result for a filter that has since been replaced (re-start, divergence) is dropped."""
        if self.check is None or not (wait or self.check[0].done()):
            return False
        future, filt, groups = self.check
        self.check = None
        try:
            result = future.result()
        except Exception:  # the worker's boundary: a failed check never stops the track
            if self.worker is None or self.worker.failures <= 1:
                log.exception("global check failed in the worker; skipped (further failures are counted)")
            self._reject("internal_error", 1)
            return False
        if self.filter is not filt:
            return False
        try:
            if filt is None:
                return self._apply_start(result, groups)
            self._apply_check(result, groups)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            log.exception("applying a global check failed; skipped")
            self._reject("internal_error", 1)
            return False
        if self.filter is not None and not self._finite():
            self._diverged()
        return True

    def _apply_check(self, res: CheckResult, groups: list[list[Reading]]):
        """The cheap part of a global check, on the current cloud and points: re-weight by the fitted noise,
        emitter-moved test (in alarm), then the modes' MH move or a re-start from a far better mode."""
        if res.noise is not None and res.at is not None:
            self._apply_calibration(res.noise, res.at, _by_group(groups, res.built), res.offset)
        if self.health.alarm_since is not None and self._emitter_moved():
            return
        modes = res.modes
        if not modes:
            return
        f = self.running
        self.modes = modes
        self.clock_hint = res.hint
        self.proposal = ModeProposal(modes, self._broad_sigma(modes[0].mean))
        best_particle = float(np.max(f.log_target(f.x)))
        best_mode = modes[0].log_post
        if res.searched != len(self.window):  # a worker's check: the mode scored over the points held now
            best_mode = float(log_posterior(modes[0].mean, self.points(), self.robust()))
        if best_mode > best_particle + self.cfg.restart_log_odds:
            self.events["global_restart"] += 1
            log.warning(
                "re-start: a mode at E %.1f N %.1f explains the points far better (log odds %.1f) than the cloud",
                modes[0].mean[0],
                modes[0].mean[1],
                best_mode - best_particle,
            )
            f.replace_cloud(importance_sample(f.log_target, self.proposal, f.n, self.rng))
            f.rejuvenate(_START_SWEEPS, self.proposal)
            self.health.clear()
        elif self.worker is None:
            f.rejuvenate(1, self.proposal)
        else:  # realtime: the modes' move is owed, made in idle time (or at the next point)
            self.move_owed = True

    def _broad_sigma(self, centre: np.ndarray) -> float:
        pts = self.points()
        return float(max(_PRIOR_MIN_SIGMA_M, np.max(np.hypot(pts.east - centre[0], pts.north - centre[1]))))

    # -- noise self-calibration -----------------------------------------------------------------------
    def _calibrate(self, candidates: list[np.ndarray], by_density: bool) -> bool:
        """Fit position and noise jointly (checks.fit_noise) from the candidate places, then rebuild the points with
        the fitted noise and re-weight the cloud. True if a calibration was applied."""
        fit = fit_noise([g for g, _, _ in self.window], self.cfg, self.noise, self.robust(), candidates, by_density)
        if fit is None:
            return False
        noise, at, offset = fit
        self._apply_calibration(noise, at, {}, offset)
        return True

    def _apply_calibration(self, noise: NoiseModel, at: np.ndarray, built: dict[int, tuple[list[Reading], Built]],
                           offset: float):
        """Adopt `noise` and the bearing `offset` (fitted at the place `at`): rebuild the kept points with them
        (`built`: points already made with them, by their group's identity), re-estimate the point outlier share,
        re-weight the cloud by the change of posterior (a changed offset moves the posterior: the check's re-start
        test that follows finds the new place)."""
        self.noise = noise
        if offset != self.offset:
            self.offset = offset
            self.events["offset_learned"] += 1
            log.warning("the bearings look %+.1f deg off the true bearings: learned, and taken off every bearing (%s)",
                        self.offset_deg, self._offset_advice())
        f = self.filter  # None while waiting to start: only the points are rebuilt
        old = f.log_target(f.x) if f is not None else None
        rebuilt: deque = deque()
        delta = 0
        for group, _, gated in self.window:
            made = built.get(id(group))
            point, kept = made[1] if made is not None and made[0] is group else self.make(group)
            now = int((~kept).sum())
            delta += now - gated
            rebuilt.append((group, point, now))
        if delta:
            self._reject("point_outlier", delta)
        self.window = rebuilt
        pts = self.points()
        self.outlier_prob = point_outlier_prob(residuals(at, pts), pts.sigma, self.outlier_prob)
        self.events["recalibrated"] += 1
        self.grid = None  # the readings calibrated the noise: from now on it is taken as fitted
        if f is not None:
            self.model.history.data = np.column_stack([pts.east, pts.north, pts.theta, pts.sigma, pts.gps])
            self.model.lik.outlier_prob = self.lik_outlier_prob
            self.model.grid = None
            f.reweight(f.log_target(f.x) - old)  # old is set whenever f is
            if f.ess() < self.cfg.ess_threshold * f.n:
                f.resample()
                f.rejuvenate(_ALARM_SWEEPS, self.proposal)

    # -- emitter moved ------------------------------------------------------------------------------
    def _emitter_moved(self) -> bool:
        """Recent disagreeing points fix a place the older points contradict, and the other way round:
        drop the older points and re-start from the recent ones."""
        since = self.health.alarm_since
        m = self.points_seen - since + 1 if since is not None else 0
        if m < self.cfg.moved_min_points or m >= len(self.window):
            return False
        if self.cfg.calibrate_noise and not self.noise.fits:
            return False  # disagreement means nothing before the outlier rate is known
        pts = self.points()
        k = len(pts)
        recent, old = pts.take(np.arange(k - m, k)), pts.take(np.arange(k - m))
        rob = Robust(self.lik_outlier_prob, self.cfg.gps_sigma_m)
        modes = find_modes(recent, rob, by_density=True)
        if not modes or modes[0].crossing_deg < self.cfg.init_min_crossing_deg or modes[0].inliers < _MIN_INLIERS:
            return False
        x_new = modes[0].mean
        x_old = self.running.estimate()[0]
        # A moved emitter leaves (almost) no recent point agreeing with the old place; a second, stationary
        # source (a reflection) keeps about its share of them: that is a second mode, not a move.
        still = inlier_share(x_old, recent, rob)
        if still > _MOVED_MAX_OLD_SHARE:
            return False
        pair = np.stack([x_new, x_old])
        lr_recent = float(np.subtract(*log_posterior(pair, recent, rob)))
        lr_old = -float(np.subtract(*log_posterior(pair, old, rob)))
        if min(lr_recent, lr_old) < self.cfg.moved_log_odds:
            return False
        dropped = [self.window.popleft() for _ in range(k - m)]
        self._reject("emitter_moved", sum(len(r) - g for r, _, g in dropped))
        self.events["emitter_moved"] += 1
        log.warning(
            "the emitter moved: the last %d points agree on E %.1f N %.1f, which the older %d contradict "
            "(log odds %.1f); re-starting from the recent points",
            m,
            x_new[0],
            x_new[1],
            k - m,
            min(lr_recent, lr_old),
        )
        self.filter = None
        self.modes, self.proposal = [], None
        self.points_used = 0
        self.bearings_used = 0
        self._try_start()
        if self.filter is not None:
            self.status = f"tracking (emitter moved: re-started from the last {m} points)"
        return True

    # -- the batch reference -----------------------------------------------------------------------
    def batch_estimate(self) -> Mode | None:
        """Robust batch maximum likelihood over every point held (no filter): global search, joint noise
        calibration, Gauss-Newton; the best mode with its Laplace covariance. The benchmark's reference."""
        modes = find_modes(self.points(), self.robust(), by_density=True)
        if modes and self.cfg.calibrate_noise and self._calibrate([m.mean for m in modes[:2]], True):
            modes = find_modes(self.points(), self.robust(), by_density=True)
        return modes[0] if modes else None

    # -- what the estimate reports -----------------------------------------------------------------------
    @property
    def offset_deg(self) -> float:
        """The learned offset as azimuth degrees: true azimuth = read azimuth + this."""
        return math.degrees(self.offset)

    def _offset_advice(self) -> str:
        cfg = self.cfg
        if cfg.bearing_reference == "vehicle":
            return f"set mount_offset_deg to {cfg.mount_offset_deg + self.offset_deg:.1f}?"
        if cfg.bearing_reference == "magnetic_north":
            return f"set magnetic_declination_deg to {cfg.magnetic_declination_deg + self.offset_deg:.1f}?"
        return ("a magnetic declination or mount offset not applied, or the DF's north reference set wrong "
                "(bearing_reference, magnetic_declination_deg, mount_offset_deg)?")

    def assess(self, mean: np.ndarray, cov: np.ndarray, modes: list) -> tuple[str, list[str]]:
        """The estimate's state and the warnings behind it (docs/interface.md, "Estimate states"): `suspect` when
        the model does not fit the bearings, `poorly_determined` when the posterior is proper but wide or
        multi-modal (or only a provisional sample), else `tracking`."""
        warnings = []
        if self.health.alarm_since is not None:
            warnings.append(f"the estimate no longer explains the newest bearings ({sum(self.health.flags)} of the "
                            f"last {len(self.health.flags)} points disagree): multipath, an emitter that moved, or a "
                            "bearing reference or offset set wrong (bearing_reference, mount_offset_deg, "
                            "magnetic_declination_deg)")
        wild = max(self.outlier_prob if self.grid is None else 0.0,
                   self.noise.reading_outlier_prob if self.noise.fits else 0.0)
        if wild > _SUSPECT_WILD_SHARE:
            warnings.append(f"{100 * wild:.0f} % of the bearings look wild: a bearing offset or reference set wrong "
                            "(bearing_reference, mount_offset_deg, magnetic_declination_deg), or heavy multipath")
        if self.offset:
            warnings.append(f"the bearings look {self.offset_deg:+.1f} deg off the true bearings (true azimuth = read "
                            f"azimuth {self.offset_deg:+.1f} deg), learned and corrected: {self._offset_advice()}")
        if warnings:
            return "suspect", warnings
        if self.filter is None:
            why = self.status.removeprefix("poorly determined: ").removeprefix("waiting for geometry: ")
            return "poorly_determined", [f"few or poorly crossing bearings: {why}"]
        h = self.model.history.data
        size, reach = ellipse_and_reach(mean, cov, h[:, 0], h[:, 1])
        if size > _MAX_ELLIPSE_RANGE_SHARE * reach:
            return "poorly_determined", [f"the 95 % ellipse ({size:.0f} m) is wide for the range ({reach:.0f} m)"]
        if len(modes) > 1 and modes[1][2] >= _AMBIGUOUS_MASS:
            return "poorly_determined", [f"a second place holds {100 * modes[1][2]:.0f} % of the posterior"]
        return "tracking", []

    def mode_masses(self) -> list[tuple[float, float, float]]:
        """(east, north, mass) of each mode holding at least 1 % of the cloud's weight, heaviest first."""
        f = self.cloud
        w = f.weights
        if len(self.modes) < 2:
            mean = w @ f.x
            return [(float(mean[0]), float(mean[1]), 1.0)]
        d2 = np.stack([np.einsum("ni,ij,nj->n", f.x - m.mean, np.linalg.inv(m.cov), f.x - m.mean) for m in self.modes])
        nearest = np.argmin(d2, axis=0)
        out = []
        for j in range(len(self.modes)):
            sel = nearest == j
            mass = float(w[sel].sum())
            if mass >= _MODE_MIN_MASS:
                c = (w[sel] @ f.x[sel]) / mass
                out.append((float(c[0]), float(c[1]), mass))
        return sorted(out, key=lambda t: -t[2])


def _by_group(groups: list[list[Reading]], built: list[Built]) -> dict[int, tuple[list[Reading], Built]]:
    """A check's points rebuilt with its noise, by their group's identity (empty when the check made none)."""
    return {id(g): (g, b) for g, b in zip(groups, built, strict=True)} if built else {}

