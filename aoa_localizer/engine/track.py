"""One emitter's track: observation points -> start -> filter updates, with the robustness layer around any filter.

The Localizer pairs readings with the GPS track and groups them; this class turns each group into an
observation point and keeps the estimate honest on messy data:

* robust start: a global search of the robust posterior over every buffered point (global_search.py); the
  first cloud is an importance sample of that posterior (every mode in proportion to its mass);
* noise self-calibration: EM on the readings' residuals at the best mode (noise.py); the points are rebuilt
  from their readings with the new sigmas and the cloud re-weighted by the change of posterior;
* global-mode safety: the health monitor watches the outlier share of new points; on alarm, and on a
  growing schedule, the global search runs again and the cloud is moved by independence MH from the modes,
  or re-started from a far better mode; while in alarm the cloud is moved at every point;
* emitter moved: when recent points agree on a place that the older points contradict (and vice versa),
  the older points are dropped and the track re-starts from the recent ones.
"""
from __future__ import annotations

import logging
import math
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import cast

import numpy as np

from aoa_localizer.engine.clock_check import ClockHint, best_shift
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.crlb import ELLIPSE_95
from aoa_localizer.engine.global_search import (
    Mode,
    Points,
    Robust,
    find_modes,
    inlier_share,
    log_posterior,
    refine,
    residuals,
)
from aoa_localizer.engine.noise import NoiseModel, point_outlier_prob
from aoa_localizer.engine.preprocess import columns, make_point
from aoa_localizer.engine.safety import HealthMonitor, ModeProposal, importance_sample
from aoa_localizer.engine.triangulation import initial_particles
from aoa_localizer.engine.types import ObservationPoint, Reading
from aoa_localizer.filters import make_filter
from aoa_localizer.filters.base import ParticleFilter
from aoa_localizer.models.emitter import EmitterModel

log = logging.getLogger("aoa_localizer")

# Broad Gaussian prior after a data-driven start, in multiples of the range to the start: it only keeps the
# bearing-only posterior proper (a flat prior has infinite mass along the rays).
_PRIOR_RANGE_FACTOR = 10.0
_PRIOR_MIN_SIGMA_M = 100.0
_START_SWEEPS = 3  # random-walk MH sweeps that spread the importance sample's duplicates
_ALARM_SWEEPS = 2  # moves at every point while in alarm
_SEARCH_GROWTH = 2.0  # scheduled global searches when the kept points have grown by this factor ...
_SEARCH_EVERY_MAX = 100  # ... or by this many points
_ALARM_SEARCH_EVERY = 5  # points between global searches while in alarm
_MIN_INLIERS = 3  # a start mode must explain at least this many points
_MODE_MIN_MASS = 0.01  # modes reported
_MAX_ELLIPSE_RANGE_SHARE = 0.5  # a start mode's 95 % semi-major axis must be under this share of its range
_START_RETRY_MAX = 5  # most points between two start attempts that found no determined mode
_MOVED_MAX_OLD_SHARE = 0.2  # most recent points that may still agree with the old place in a move


class EmitterTrack:
    """Points, filter and robustness state of one emitter. `reject(reason, count)` counts unused inputs."""

    def __init__(self, cfg: LocalizerConfig, rng: np.random.Generator, reject: Callable[[str, int], None]):
        self.cfg, self.rng, self._reject = cfg, rng, reject
        self.noise = NoiseModel(cfg.outlier_prob)
        self.outlier_prob = cfg.outlier_prob  # point level, in the likelihood
        # (readings, point, readings gated out) per point: the points waiting for a start, then the filter's
        # history
        self.window: deque[tuple[list[Reading], ObservationPoint, int]] = deque()
        self.filter: ParticleFilter | None = None
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

    # -- points -----------------------------------------------------------------------------------
    def sigmas(self, readings: list[Reading]) -> np.ndarray:
        """Each reading's sigma under the calibrated noise model (the configured one until calibrated)."""
        cols = columns(readings)
        if not self.cfg.calibrate_noise:
            return cols.sigma
        return cols.sigma * self.noise.scale(cols.quality)

    def make(self, readings: list[Reading]) -> tuple[ObservationPoint, np.ndarray]:
        return make_point(readings, self.cfg, self.sigmas(readings))

    @property
    def running(self) -> ParticleFilter:
        """The filter, where the code runs only once it started."""
        if self.filter is None:
            raise RuntimeError("no filter running")  # an engine bug, never bad input
        return self.filter

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
        return Points.of(np.array([[p.east, p.north, p.theta, p.sigma, p.gps_sigma] for _, p, _ in self.window]))

    def robust(self, prior: bool = True) -> Robust:
        if prior and self.filter is not None and self.model.prior_prec.any():
            return Robust(self.lik_outlier_prob, self.cfg.gps_sigma_m, self.model.prior_mean, self.model.prior_prec)
        cfg = self.cfg
        if prior and cfg.prior_east is not None and cfg.prior_north is not None and cfg.prior_sigma_m is not None:
            return Robust(self.lik_outlier_prob, cfg.gps_sigma_m, np.array([cfg.prior_east, cfg.prior_north]),
                          np.eye(2) / cfg.prior_sigma_m**2)
        return Robust(self.lik_outlier_prob, self.cfg.gps_sigma_m)

    @property
    def lik_outlier_prob(self) -> float:
        """The outlier share the likelihood uses: the calibrated one for `likelihood: mixture`, 0 for the paper's
        Gaussian (which then stays Gaussian, in the filter and in the searches)."""
        return self.outlier_prob if self.cfg.likelihood == "mixture" else 0.0

    # -- the flow -----------------------------------------------------------------------------------
    def add(self, readings: list[Reading]) -> bool:
        """One closed group of readings; True when the filter took it (or started) and has a new estimate."""
        t0 = time.perf_counter()
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
            took = self._update(readings, point, gated)
        # What this point cost, searches and calibration included.
        self.last_update_s = time.perf_counter() - t0
        return took

    def _try_start(self):
        cfg = self.cfg
        if cfg.has_prior:
            return self._start_from_prior()
        if len(self.window) > cfg.init_max_points:
            _, _, gated = self.window.popleft()
            self._reject("init_buffer_full", 1)
        if len(self.window) < cfg.init_bearings:
            self.status = f"collecting bearings: {len(self.window)} of {cfg.init_bearings} points"
            return False
        if cfg.init_method == "triangulation":
            return self._start_triangulation()
        if len(self.window) < self.next_start_try:
            return False
        modes, why = self._search_start()
        if not modes:
            self.status = f"waiting for geometry: {why}"
            # Search again when the points have grown by a tenth (at most _START_RETRY_MAX points later).
            self.next_start_try = len(self.window) + min(_START_RETRY_MAX, max(1, len(self.window) // 10))
            return False
        best = modes[0]
        last = self.window[-1][1]
        sigma = max(
            _PRIOR_MIN_SIGMA_M, _PRIOR_RANGE_FACTOR * math.hypot(best.mean[0] - last.east, best.mean[1] - last.north)
        )
        self.filter = make_filter(cfg, self.rng, EmitterModel(cfg))
        self.model.set_prior(best.mean, sigma**2 * np.eye(2))
        self.model.lik.outlier_prob = self.lik_outlier_prob
        for _, p, _ in self.window:
            self.model.observe(p)
        self.running.k = len(self.window)
        self.modes, self.proposal = modes, ModeProposal(modes, self._broad_sigma(best.mean))
        particles = importance_sample(self.running.log_target, self.proposal, cfg.num_particles, self.rng)
        self.running.initialise(particles, best.mean, sigma**2 * np.eye(2))
        self.start_cloud = self.running.x.copy()
        self.running.rejuvenate(_START_SWEEPS, self.proposal)
        self._started(f"global search: best of {len(modes)} mode(s), {best.inliers} of {len(self.window)} points agree")
        self.points_used += len(self.window)
        self.bearings_used += sum(len(r) - g for r, _, g in self.window)
        return True

    def _search_start(self) -> tuple[list[Mode], str]:
        """Modes of the robust posterior over the buffered points (with calibration when on); ([], why) if none
        is determined well enough to start from."""
        flat = not self.cfg.has_prior
        modes = find_modes(self.points(), self.robust(), by_density=flat)
        determined = modes and modes[0].crossing_deg >= self.cfg.init_min_crossing_deg
        if determined and self.cfg.calibrate_noise and self._calibrate([m.mean for m in modes[:2]], flat):
            modes = find_modes(self.points(), self.robust(), by_density=flat)
        if not modes:
            return [], "no crossing of bearings in front of the antennas"
        best = modes[0]
        if best.inliers < _MIN_INLIERS:
            return [], f"the best place explains only {best.inliers} points (needs {_MIN_INLIERS})"
        if best.crossing_deg < self.cfg.init_min_crossing_deg:
            return [], (
                f"bearings nearly parallel: best crossing {best.crossing_deg:.1f} deg < "
                f"{self.cfg.init_min_crossing_deg:g} deg"
            )
        size, reach = self._ellipse_and_range(best)
        if size > _MAX_ELLIPSE_RANGE_SHARE * reach:
            return [], (f"position not determined yet: 95 % ellipse {size:.0f} m at {reach:.0f} m from the track")
        return modes, ""

    def _ellipse_and_range(self, mode: Mode) -> tuple[float, float]:
        """Semi-major axis of the mode's 95 % ellipse and its distance to the nearest antenna position (m)."""
        pts = self.points()
        reach = float(np.min(np.hypot(pts.east - mode.mean[0], pts.north - mode.mean[1])))
        return float(np.sqrt(ELLIPSE_95 * np.linalg.eigvalsh(mode.cov)[-1])), max(reach, 1.0)

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
        self.filter = make_filter(self.cfg, self.rng, EmitterModel(self.cfg))
        self.model.lik.outlier_prob = self.lik_outlier_prob
        self.running.initialise(particles, mean, cov)
        self.start_cloud = self.running.x.copy()
        waiting, self.window = list(self.window), deque()
        self._started(how)
        result = False
        for readings, point, gated in waiting:
            result = self._update(readings, point, gated) or result
        return result

    def _started(self, how: str):
        self.status = "tracking"
        self.health.clear()
        self.next_search = max(2 * len(self.window), self.cfg.init_bearings)
        log.info("filter %s started after %d observation points (%s)", self.cfg.algorithm, self.points_seen, how)

    def _update(self, readings, point, gated) -> bool:
        f = self.running
        before = self.model.history.appended
        logw_before = f.logw.copy()
        try:
            ok = f.update(point)
            if ok and self.model.history.appended > before:
                self.window.append((readings, point, gated))
                while len(self.window) > len(self.model.history):
                    self.window.popleft()
            if ok and self._finite():
                self._supervise(logw_before)
            if self.filter is None:  # the emitter moved and the re-start waits for more points
                return False
            f = self.running
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            log.exception("filter update failed; point skipped")
            self._reject("internal_error", 1)
            return False
        if not self._finite():
            self.filter = None
            self.window.clear()
            self.status = "filter diverged: restarting from new bearings"
            log.error("filter %s diverged (non-finite particles or estimate); restarting", self.cfg.algorithm)
            self._reject("filter_diverged", 1)
            return False
        if not ok:
            self._reject("weights_degenerate", 1)
            return False
        self.points_used += 1
        self.bearings_used += point.n_readings
        return True

    def _finite(self) -> bool:
        mean, cov = self.running.estimate()
        return bool(np.all(np.isfinite(self.running.x)) and np.all(np.isfinite(mean)) and np.all(np.isfinite(cov)))

    # -- the safety layer ---------------------------------------------------------------------------
    def _supervise(self, logw_before: np.ndarray):
        """Health of the newest point, scheduled and alarm-driven global searches, moves while in alarm."""
        f, n = self.running, len(self.window)
        if not self.cfg.global_safety:
            if self.cfg.calibrate_noise and n >= self.next_search:
                self.next_search = min(int(math.ceil(n * _SEARCH_GROWTH)), n + _SEARCH_EVERY_MAX)
                best = f.x[np.argmax(f.log_target(f.x))]
                self._calibrate([self._refined(best)], False)
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
        if due or alarm_due:
            if due:
                self.next_search = min(int(math.ceil(n * _SEARCH_GROWTH)), n + _SEARCH_EVERY_MAX)
            self._global_check(alarm)
        elif alarm:
            f.rejuvenate(_ALARM_SWEEPS, self.proposal)

    def finish(self) -> bool:
        """End of data: one more global check over everything kept (unless the last point just had one).
        True when it ran (the estimate changed)."""
        if self.filter is None or not self.cfg.global_safety or self.last_search_point == self.points_seen:
            return False
        t0 = time.perf_counter()
        self._global_check(self.health.alarm_since is not None)
        self.last_update_s = time.perf_counter() - t0
        return self.filter is not None

    def _global_check(self, alarm: bool):
        f = self.running
        self.last_search_point = self.points_seen
        if self.cfg.calibrate_noise:  # the joint fit is safe at any place: it compares several
            best = f.x[np.argmax(f.log_target(f.x))]
            self._calibrate([self._refined(best)] + [m.mean for m in self.modes[:1]], False)
        if alarm and self._emitter_moved():
            return
        modes = find_modes(self.points(), self.robust())
        if not modes:
            return
        self.modes = modes
        self.clock_hint = best_shift(self.points(), self._velocities(), modes[0].mean, self.robust())
        self.proposal = ModeProposal(modes, self._broad_sigma(modes[0].mean))
        best_particle = float(np.max(f.log_target(f.x)))
        if modes[0].log_post > best_particle + self.cfg.restart_log_odds:
            self.events["global_restart"] += 1
            log.warning(
                "re-start: a mode at E %.1f N %.1f explains the points far better (log odds %.1f) than the cloud",
                modes[0].mean[0],
                modes[0].mean[1],
                modes[0].log_post - best_particle,
            )
            f.replace_cloud(importance_sample(f.log_target, self.proposal, f.n, self.rng))
            f.rejuvenate(_START_SWEEPS, self.proposal)
            self.health.clear()
        else:
            f.rejuvenate(1, self.proposal)

    def _refined(self, x: np.ndarray, noise: NoiseModel | None = None) -> np.ndarray:
        """The posterior mode nearest x (Gauss-Newton), under `noise` (default: the current noise model)."""
        pts = self.points() if noise is None else self._rebuilt_points(noise)
        means, _, _ = refine(x[None, :], np.zeros(1), pts, self.robust())
        return means[0]

    def _rebuilt_points(self, noise: NoiseModel | None) -> Points:
        """The kept points rebuilt from their readings with the sigmas of `noise` (None: the configured ones)."""
        rows = []
        for group, _, _ in self.window:
            cols = columns(group)
            sigma = cols.sigma if noise is None else cols.sigma * noise.scale(cols.quality)
            p = make_point(group, self.cfg, sigma)[0]
            rows.append([p.east, p.north, p.theta, p.sigma, p.gps_sigma])
        return Points.of(np.array(rows))

    def _velocities(self) -> np.ndarray:
        """The vehicle's mean velocity (east, north, m/s) over each kept point's readings, (K, 2)."""
        return np.array(
            [[np.mean([r.v_east for r in group]), np.mean([r.v_north for r in group])] for group, _, _ in self.window]
        ).reshape(-1, 2)

    def _broad_sigma(self, centre: np.ndarray) -> float:
        pts = self.points()
        return float(max(_PRIOR_MIN_SIGMA_M, np.max(np.hypot(pts.east - centre[0], pts.north - centre[1]))))

    # -- noise self-calibration -----------------------------------------------------------------------
    def _calibrate(self, candidates: list[np.ndarray], by_density: bool) -> bool:
        """Fit position and noise jointly: at each candidate place, and at the best mode under the configured
        noise, EM fits the noise and Gauss-Newton refines the place; the pair whose readings are likeliest wins
        (a wrong place explained by a wide noise loses to the right place with the right noise). Then the points
        are rebuilt with it and the cloud re-weighted. True if a calibration was applied."""
        readings = [r for group, _, _ in self.window for r in group]
        if len(readings) < 2:
            return False
        quality = np.array([r.quality for r in readings])
        base = np.array([r.sigma for r in readings])
        at_readings = Points(
            np.array([r.east for r in readings]),
            np.array([r.north for r in readings]),
            np.array([r.theta for r in readings]),
            base,
        )
        pts = self._rebuilt_points(None)
        eps = self.cfg.outlier_prob if self.cfg.likelihood == "mixture" else 0.0
        narrow = find_modes(pts, Robust(eps, self.cfg.gps_sigma_m), by_density=by_density)
        best = None
        for x in list(candidates) + [m.mean for m in narrow[:1]]:
            trial = self.noise.copy()
            ll = float("nan")
            for _ in range(2):  # alternate: noise at x, then x under that noise
                ll = trial.fit(residuals(x, at_readings), quality, base)
                if not np.isfinite(ll):
                    return False
                x = self._refined(x, trial)
            if best is None or ll > best[0]:
                best = (ll, trial, x)
        if best is None:
            return False
        _, self.noise, at = best
        f = self.filter  # None while waiting to start: only the points are rebuilt
        old = f.log_target(f.x) if f is not None else None
        rebuilt: deque = deque()
        delta = 0
        for group, _, gated in self.window:
            point, kept = self.make(group)
            now = int((~kept).sum())
            delta += now - gated
            rebuilt.append((group, point, now))
        if delta:
            self._reject("point_outlier", delta)
        self.window = rebuilt
        pts = self.points()
        self.outlier_prob = point_outlier_prob(residuals(at, pts), pts.sigma, self.outlier_prob)
        self.events["recalibrated"] += 1
        if f is not None:
            self.model.history.data = np.column_stack([pts.east, pts.north, pts.theta, pts.sigma, pts.gps])
            self.model.lik.outlier_prob = self.lik_outlier_prob
            f.reweight(f.log_target(f.x) - old)  # old is set whenever f is
            if f.ess() < self.cfg.ess_threshold * f.n:
                f.resample()
                f.rejuvenate(_ALARM_SWEEPS, self.proposal)
        return True

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
    def mode_masses(self) -> list[tuple[float, float, float]]:
        """(east, north, mass) of each mode holding at least 1 % of the cloud's weight, heaviest first."""
        f = self.running
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
