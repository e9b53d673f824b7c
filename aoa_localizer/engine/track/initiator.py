"""How a track's filter starts: from the global search's modes over every buffered point (an importance sample of
the robust posterior, every mode in proportion to its mass), from crossings of the bearings (the paper's start), or
from the configured prior; or a provisional sample while the posterior is proper but not determined enough."""
from __future__ import annotations

import logging
import math
from collections import deque
from functools import partial
from typing import TYPE_CHECKING, cast

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.inference.checks import CheckResult, search_start, start_search
from aoa_localizer.engine.inference.emitter_model import EmitterModel
from aoa_localizer.engine.inference.global_search import Mode
from aoa_localizer.engine.inference.safety import ModeProposal, importance_sample
from aoa_localizer.engine.inference.start_grid import StartGrid
from aoa_localizer.engine.inference.triangulation import initial_particles
from aoa_localizer.engine.rejections import Reason
from aoa_localizer.engine.scheduling.slices import START_BUDGET_US
from aoa_localizer.engine.track.state import PendingJob, Phase, Status
from aoa_localizer.engine.types import ObservationPoint, Reading
from aoa_localizer.filters import make_filter
from aoa_localizer.filters.base import ParticleFilter

if TYPE_CHECKING:
    from aoa_localizer.engine.track.emitter_track import EmitterTrack

log = logging.getLogger("aoa_localizer")

# Broad Gaussian prior after the paper's start (triangulation), in multiples of the range to the start: it only
# keeps the bearing-only posterior proper (a flat prior has infinite mass along the rays); the global search's start
# has the radio-range prior instead.
PRIOR_RANGE_FACTOR = 10.0
PRIOR_MIN_SIGMA_M = 100.0
START_SWEEPS = 3  # random-walk MH sweeps that spread the importance sample's duplicates
MIN_INLIERS = 3  # a start mode must explain at least this many points
MAX_ELLIPSE_RANGE_SHARE = 0.5  # a start mode's 95 % semi-major axis must be under this share of its range
_START_RETRY_MAX = 5  # most points between two start attempts that found no determined mode
# A start search's result is stale once the points grew by more than max(4, a half) while it ran: its modes still
# propose for a few more points (the importance weights are over all held), not for many times its points
_STALE_MIN, _STALE_SHARE = 4, 2


class Initiator:
    """Starts one track's filter once its points allow (`try_start`), and makes the filters the track runs."""

    def __init__(self, track: EmitterTrack, cfg: LocalizerConfig):
        self.track, self.cfg = track, cfg
        self.next_start_try = 0  # points the window must hold before the next start search
        self.start_cloud: np.ndarray | None = None  # the particles of the latest start
        self.searched_again = False  # the pending start search was made again because the one before was stale
        self.start_grid: StartGrid | None = None  # the last start search's grid and sums (start_grid.py)
        # The provisional samples' seeds: a stream of their own, so drawing them leaves the filter's stream as it is
        self.sample_seeds = track.rng.spawn(1)[0]

    def try_start(self, inline: bool = False, final: bool = False) -> bool:
        """Start the filter once the points allow (`inline`: the start search here, even with a worker; `final`: the
        end of data, with whatever points there are)."""
        t, cfg = self.track, self.cfg
        if cfg.has_prior:
            return self._from_prior()
        if len(t.window) > cfg.init_max_points:
            t.window.popleft()
            t.reject(Reason.INIT_BUFFER_FULL, 1)
        if len(t.window) < (min(2, cfg.init_bearings) if final else cfg.init_bearings):
            t.status = Status(Phase.COLLECTING, held=len(t.window), needed=cfg.init_bearings)
            return False
        if cfg.init_method == "triangulation":
            return self._from_triangulation()
        if not final and (len(t.window) < self.next_start_try or t.job is not None):
            return False
        snap = t.snapshot()
        snap.start_grid, snap.sample_seed = self.start_grid, int(self.sample_seeds.integers(2**63))
        job = partial(search_start, snap, MIN_INLIERS, MAX_ELLIPSE_RANGE_SHARE, final)
        if inline:
            return self.apply_start(job(), snap.groups)
        steps = start_search(snap, MIN_INLIERS, MAX_ELLIPSE_RANGE_SHARE, final)
        t.job = PendingJob(t.scheduler.start(job, steps, START_BUDGET_US), None, snap.groups)
        return t.collect()  # a sliced search small enough to finish in its first call starts the filter now

    def apply_start(self, res: CheckResult, groups: list[list[Reading]]) -> bool:
        """Start the filter from a start search's modes over the points held now (a background search's snapshot
        may have fewer): an importance sample of the posterior, then MH sweeps; or wait for more points."""
        t = self.track
        self.start_grid = res.start_grid
        stale = len(t.window) > res.searched + max(_STALE_MIN, res.searched // _STALE_SHARE)
        if stale and not self.searched_again:
            # Points came far faster than the worker searched (a bag replayed at full speed): a mode of the few
            # points searched is no start for the many held now. Search again, over all of them, once: when that
            # search is stale too, the worker is the bottleneck (hundreds of channels queue behind it), and
            # searching again would never end; its modes still propose for every point held now.
            self.next_start_try, self.searched_again = 0, True
            return self.try_start()
        self.searched_again = False
        t.apply_fit(res, groups)
        modes = res.modes
        if modes and res.determined:
            t.provisional, self.start_grid = None, None
            t.filter = self._sample_posterior(modes)
            self._started(f"global search: best of {len(modes)} mode(s), {modes[0].inliers} of {len(t.window)} "
                          "points agree")
            self._hold(modes)
            return True
        t.status = Status(Phase.WAITING_FOR_GEOMETRY, res.why)
        if modes and res.sample is not None:
            # Proper but not determined: publish the search's sample of the posterior (wide, honest), not nothing
            t.provisional = self._provisional(modes, res.sample, res.searched)
            t.status = Status(Phase.POORLY_DETERMINED, res.why)
            self._hold(modes, groups)
        # Search again when the points searched have grown by a tenth (at most _START_RETRY_MAX points later); at
        # once when enough came while the worker searched: the stream may have ended, and no later point would ask
        # again (the live node kept emitters of its last seconds without an estimate).
        self.next_start_try = res.searched + min(_START_RETRY_MAX, max(1, res.searched // 10))
        searched_again = len(t.window) >= self.next_start_try and self.try_start()
        return searched_again or bool(modes)

    def _hold(self, modes: list[Mode], searched: list[list[Reading]] | None = None):
        """The track's modes and its estimate's points: every point waiting (none before: a start holds all), or
        those of them the search drew a provisional sample over (`searched`: their readings)."""
        t = self.track
        t.modes = modes
        held = list(t.window)
        if searched is not None:
            ids = {id(g) for g in searched}
            held = [e for e in held if id(e.readings) in ids]
        t.points_used = len(held)
        t.bearings_used = sum(e.used for e in held)

    def _holding_points(self, modes: list[Mode], particles: int | None = None
                        ) -> tuple[ParticleFilter, ModeProposal]:
        """A new filter whose model holds every point waiting for a start, on the posterior the start search scored:
        the likelihood under the radio-range prior (no Gaussian at the best mode: at a mode by the track, ten times
        its few metres of range held the cloud there and cut off the far end of its ray); and the modes' proposal,
        the track's from now on."""
        t = self.track
        f = self.new_filter(particles)
        model = cast(EmitterModel, f.model)
        model.reach = t.reach()
        model.lik.outlier_prob = t.calibration.lik_outlier_prob
        for e in t.window:
            model.observe(e.point)
        f.k = len(t.window)
        t.proposal = proposal = ModeProposal.over(modes, t.points())
        return f, proposal

    def _sample_posterior(self, modes: list[Mode]) -> ParticleFilter:
        """The filter's start: an importance sample of the posterior from the modes, resampled, then MH sweeps (kept
        as `start_cloud`)."""
        t = self.track
        f, proposal = self._holding_points(modes)
        f.initialise(importance_sample(f.log_target, proposal, f.n, t.rng))
        self.start_cloud = f.x.copy()
        f.rejuvenate(START_SWEEPS, proposal)
        return f

    def _provisional(self, modes: list[Mode], sample: tuple[np.ndarray, np.ndarray], searched: int) -> ParticleFilter:
        """A provisional sample: the start search's weighted draws (provisional.py), read, never stepped (no
        resampling and no moves to spread duplicates), over the `searched` points it drew them for."""
        particles, logw = sample
        f, _ = self._holding_points(modes, max(self.cfg.num_particles, len(particles)))
        f.initialise(particles)
        if np.isfinite(logw.max()):
            f.logw = logw - logw.max()
        f.k = searched
        return f

    def _from_triangulation(self) -> bool:
        """The paper's start (sec. 3.3): crossings of sorted pairs; then every buffered point updates the filter."""
        t, cfg = self.track, self.cfg
        pts = [e.point for e in t.window]
        particles, why = initial_particles(pts, cfg.num_particles, cfg.init_min_crossing_deg, cfg.init_min_support,
                                           t.rng)
        if particles is None:
            t.status = Status(Phase.WAITING_FOR_GEOMETRY, why)
            return False
        mean = particles.mean(axis=0)
        sigma = _prior_sigma(mean, pts[-1])
        return self._start_then_replay(particles, mean, sigma**2 * np.eye(2), "triangulation")

    def _from_prior(self) -> bool:
        cfg = self.cfg
        mean = np.array([cfg.prior_east, cfg.prior_north])
        sigma = cast(float, cfg.prior_sigma_m)  # set, as has_prior says
        particles = mean + sigma * self.track.rng.standard_normal((cfg.num_particles, 2))
        return self._start_then_replay(particles, mean, sigma**2 * np.eye(2), "prior")

    def _start_then_replay(self, particles, mean, cov, how: str) -> bool:
        t = self.track
        f = t.filter = self.new_filter()
        t.model.lik.outlier_prob = t.calibration.lik_outlier_prob
        f.initialise(particles, mean, cov)
        self.start_cloud = f.x.copy()
        waiting, t.window = list(t.window), deque()
        self._started(how)
        result = False
        for entry in waiting:
            result = t.update(entry) or result
        return result

    def new_filter(self, particles: int | None = None) -> ParticleFilter:
        """A filter on a new emitter model (with the latent noise while it is latent); `particles`: N if not the
        configured one."""
        t = self.track
        model = EmitterModel(self.cfg)
        model.grid = t.calibration.noise_prior()
        cfg = self.cfg if particles is None else self.cfg.with_changes(num_particles=particles)
        f = make_filter(cfg, t.rng, model)
        t.scheduler.take(f)
        return f

    def _started(self, how: str):
        t = self.track
        t.status = Status(Phase.TRACKING)
        t.supervisor.started(len(t.window))
        log.info("filter %s started after %d observation points (%s)", self.cfg.algorithm, t.points_seen, how)


def _prior_sigma(start: np.ndarray, last: ObservationPoint) -> float:
    """The broad prior's sigma at a data-driven start: PRIOR_RANGE_FACTOR times the range from the newest point."""
    return max(PRIOR_MIN_SIGMA_M, PRIOR_RANGE_FACTOR * math.hypot(start[0] - last.east, start[1] - last.north))
