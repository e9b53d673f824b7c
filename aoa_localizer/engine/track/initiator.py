"""How a track's filter starts: from the global search's modes over every buffered point (an importance sample of
the robust posterior, every mode in proportion to its mass), from crossings of the bearings (the paper's start), or
from the configured prior; or a provisional sample while the posterior is proper but not determined enough. The
initiator says when to search and what a search's result means, and makes the filters; the track adopts them."""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from enum import Enum
from functools import partial
from typing import cast

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.inference.checks import CheckResult, Snapshot, search_start
from aoa_localizer.engine.inference.emitter_model import EmitterModel
from aoa_localizer.engine.inference.global_search import Mode
from aoa_localizer.engine.inference.point_batch import points_of
from aoa_localizer.engine.inference.receiver import NoiseGrid
from aoa_localizer.engine.inference.safety import ModeProposal, importance_sample
from aoa_localizer.engine.inference.start_grid import StartGrid
from aoa_localizer.engine.inference.triangulation import initial_particles
from aoa_localizer.engine.scheduling.scheduler import Scheduler
from aoa_localizer.engine.types import ObservationPoint
from aoa_localizer.filters import make_filter
from aoa_localizer.filters.base import ParticleFilter

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


class Outcome(Enum):
    """What a start search's result means for a track holding its points now: search again over all of them (it
    was stale), start the filter from its modes, or wait (holding a provisional sample when it drew one)."""

    SEARCH_AGAIN = "search again"
    START = "start"
    WAIT = "wait"


@dataclass(frozen=True)
class Holding:
    """What a filter made over a track's held points needs of the track: the points, the radio-range prior
    (global_search.Robust.reach), the likelihood's outlier share and the latent noise (None: calibrated)."""

    points: list[ObservationPoint]
    reach: tuple[float, float, float] | None
    outlier_prob: float
    noise: NoiseGrid | None


class Initiator:
    """When one track's start searches run and what their results mean, and the filters a start makes."""

    def __init__(self, cfg: LocalizerConfig, rng: np.random.Generator, scheduler: Scheduler):
        """`rng`: the track's generator (the filters' and the starts' draws); `scheduler`: it takes each new
        filter (its moves owed)."""
        self.cfg, self.rng, self.scheduler = cfg, rng, scheduler
        self.next_start_try = 0  # points the window must hold before the next start search
        self.start_cloud: np.ndarray | None = None  # the particles of the latest start
        self.searched_again = False  # the pending start search was made again because the one before was stale
        self.start_grid: StartGrid | None = None  # the last start search's grid and sums (start_grid.py)
        # The provisional samples' seeds: a stream of their own, so drawing them leaves the filter's stream as it is
        self.sample_seeds = rng.spawn(1)[0]

    def search_due(self, held: int, searching: bool) -> bool:
        """Whether a start search over `held` points is due now (not while one is `searching`)."""
        return held >= self.next_start_try and not searching

    def search_now(self):
        """The next start search is due at once, whatever the points held (the end of data)."""
        self.next_start_try = 0

    def search_job(self, snap: Snapshot, final: bool) -> partial[CheckResult]:
        """A start search of `snap` (`final`: the end of data, with whatever points there are), for the scheduler."""
        snap.start_grid, snap.sample_seed = self.start_grid, int(self.sample_seeds.integers(2**63))
        return partial(search_start, snap, MIN_INLIERS, MAX_ELLIPSE_RANGE_SHARE, final)

    def outcome(self, res: CheckResult, held: int) -> Outcome:
        """What `res` means with `held` points held now. Points may come far faster than the worker searched (a bag
        replayed at full speed): a mode of the few points searched is no start for the many held now, so a stale
        result is searched again, over all of them, once; when that search is stale too, the worker is the
        bottleneck (hundreds of channels queue behind it), and searching again would never end: its modes still
        propose for every point held now."""
        self.start_grid = res.start_grid
        stale = held > res.searched + max(_STALE_MIN, res.searched // _STALE_SHARE)
        if stale and not self.searched_again:
            self.next_start_try, self.searched_again = 0, True
            return Outcome.SEARCH_AGAIN
        self.searched_again = False
        if res.modes and res.determined:
            self.start_grid = None
            return Outcome.START
        # Search again when the points searched have grown by a tenth (at most _START_RETRY_MAX points later); at
        # once when enough came while the worker searched: the stream may have ended, and no later point would ask
        # again (the live node kept emitters of its last seconds without an estimate).
        self.next_start_try = res.searched + min(_START_RETRY_MAX, max(1, res.searched // 10))
        return Outcome.WAIT

    def _holding_points(self, modes: list[Mode], held: Holding, particles: int | None = None
                        ) -> tuple[ParticleFilter, ModeProposal]:
        """A new filter whose model holds every point waiting for a start, on the posterior the start search scored:
        the likelihood under the radio-range prior (no Gaussian at the best mode: at a mode by the track, ten times
        its few metres of range held the cloud there and cut off the far end of its ray); and the modes' proposal,
        the track's from now on."""
        f = self.new_filter(held.noise, particles, held.outlier_prob, held.reach)
        model = cast(EmitterModel, f.model)
        for point in held.points:
            model.observe(point)
        return f, ModeProposal.over(modes, points_of(held.points))

    def sample_posterior(self, modes: list[Mode], held: Holding) -> tuple[ParticleFilter, ModeProposal]:
        """The filter's start: an importance sample of the posterior from the modes, resampled, then MH sweeps (kept
        as `start_cloud`); with the modes' proposal."""
        f, proposal = self._holding_points(modes, held)
        f.initialise(importance_sample(f.log_target, proposal, f.n, self.rng), taken=len(held.points))
        self.start_cloud = f.x.copy()
        f.rejuvenate(START_SWEEPS, proposal)
        return f, proposal

    def provisional(self, modes: list[Mode], sample: tuple[np.ndarray, np.ndarray], searched: int, held: Holding
                    ) -> tuple[ParticleFilter, ModeProposal]:
        """A provisional sample: the start search's weighted draws (provisional.py), read, never stepped (no
        resampling and no moves to spread duplicates), over the `searched` points it drew them for."""
        particles, logw = sample
        f, proposal = self._holding_points(modes, held, max(self.cfg.num_particles, len(particles)))
        f.initialise(particles, logw=logw - logw.max() if np.isfinite(logw.max()) else None, taken=searched)
        return f, proposal

    def triangulation(self, pts: list[ObservationPoint]) -> tuple[np.ndarray, np.ndarray, np.ndarray] | str:
        """The paper's start (sec. 3.3): particles from crossings of sorted pairs, with the broad prior's mean and
        covariance; or why the geometry allows none yet."""
        cfg = self.cfg
        particles, why = initial_particles(pts, cfg.num_particles, cfg.init_min_crossing_deg, cfg.init_min_support,
                                           self.rng)
        if particles is None:
            return why
        mean = particles.mean(axis=0)
        sigma = _prior_sigma(mean, pts[-1])
        return particles, mean, sigma**2 * np.eye(2)

    def prior(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Particles from the configured prior, with its mean and covariance."""
        cfg = self.cfg
        mean = np.array([cfg.prior_east, cfg.prior_north])
        sigma = cast(float, cfg.prior_sigma_m)  # set, as has_prior says
        particles = mean + sigma * self.rng.standard_normal((cfg.num_particles, 2))
        return particles, mean, sigma**2 * np.eye(2)

    def replayed_filter(self, particles: np.ndarray, mean: np.ndarray, cov: np.ndarray, noise: NoiseGrid | None,
                        outlier_prob: float) -> ParticleFilter:
        """A filter started from `particles` under a Gaussian prior, to take the points held one by one (kept as
        `start_cloud`)."""
        f = self.new_filter(noise, outlier_prob=outlier_prob)
        f.initialise(particles, mean, cov)
        self.start_cloud = f.x.copy()
        return f

    def new_filter(self, noise: NoiseGrid | None, particles: int | None = None, outlier_prob: float | None = None,
                   reach: tuple[float, float, float] | None = None) -> ParticleFilter:
        """A filter on a new emitter model (with the latent `noise` while it is latent, the learned point
        `outlier_prob`, the radio-range prior's `reach`); `particles`: N if not the configured one. Its resamplings'
        sweeps are owed to the scheduler (a bounded step)."""
        model = EmitterModel(self.cfg, noise, reach, outlier_prob)
        cfg = self.cfg if particles is None else self.cfg.with_changes(num_particles=particles)
        return make_filter(cfg, self.rng, model, deferred=True)


def _prior_sigma(start: np.ndarray, last: ObservationPoint) -> float:
    """The broad prior's sigma at a data-driven start: PRIOR_RANGE_FACTOR times the range from the newest point."""
    return max(PRIOR_MIN_SIGMA_M, PRIOR_RANGE_FACTOR * math.hypot(start[0] - last.east, start[1] - last.north))
