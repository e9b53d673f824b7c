"""GFA-PF: the particle filter based on the gravitation field algorithm (Chen Shiming et al. 2017, sec. 2).

After prediction and weighting, D times: the highest-weight particle is the central dust; every other
particle moves by x <- x + P + Q (eq. 12), attraction P = M dis (eq. 10), off closer than `attract_min`,
and rotation repulsion Q = f cbrt(dis) (eq. 11), pointing away from the centre, off farther than
`repel_max`; the weights are recomputed and the centre found again. Then the weights are w_prev L(z|x),
resampling only when N_eff falls under the threshold.

Readings: dis is the offset to the centre (a vector in 2-D, its length compared with the thresholds);
the repulsion points away from the centre (the text calls it a repulsion; as printed eq. 12 adds it
with the attraction's sign); f, "the probability of rotation", is drawn U(0, rotation_max) per dust and
iteration. Scaling: with `scale: spread` the thresholds are in standard deviations s of the cloud and
the repulsion is s f cbrt(|dis|/s), so the whole move scales with the problem (a test checks it); with
`absolute`, s = 1: the paper's 1-D models. This is `gfapf.variant: paper`: the re-weight after the move lacks
the move's density (the paper's own flaw), which collapses the cloud on the emitter.

`gfapf.variant: mcmc` (default, the emitter): resample-move; attraction and repulsion towards the central
dust (the best particle of the other half, fixed for the half's move; f drawn once per sweep) are the mean of
a Gaussian proposal (half a standard deviation of the cloud), accepted with the Hastings ratio computed
through the reverse move's mean (moves.drift); `iterations` sweeps.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aoa_localizer.core.spec import choice, param, variant_choice
from aoa_localizer.filters import moves
from aoa_localizer.filters.algorithm import Algorithm
from aoa_localizer.filters.base import ParticleFilter
from aoa_localizer.filters.resample_move import MoveKernel

NOISE_SCALE = 0.5  # the proposal's spread around the gravitation move, in standard deviations of the cloud


@dataclass(frozen=True)
class GfapfConfig:
    """GFA-PF settings (paper sec. 2): attraction M, rotation factor maximum, D iterations, the dead zone of the
    attraction and the range of the repulsion. `scale`: `absolute` reads the two distances in state units (the
    paper's 1-D models); `spread` in standard deviations of the cloud (the emitter problem, any scale)."""

    variant: str = variant_choice("GFA-PF")
    attraction: float = param(0.0618, "GFA-PF: attraction weight M towards the central dust", low=0.0, high=10.0)
    rotation_max: float = param(0.3, "GFA-PF: largest rotation factor f of the repulsion", low=0.0, high=10.0)
    iterations: int = param(8, "GFA-PF: gravitation iterations D per measurement",
                            low=0, high=100)
    attract_min: float = param(0.5, "GFA-PF: no attraction closer than this to the centre (scale units)", low=0.0,
                               high=1e4)
    repel_max: float = param(0.2, "GFA-PF: no repulsion farther than this from the centre (scale units)", low=0.0,
                             high=1e4)
    scale: str = choice("spread", ("spread", "absolute"), "GFA-PF: `spread` (standard deviations of the cloud) or "
                        "`absolute` (state units) for the two distances")


def gravitation_step(x: np.ndarray, centre: int, scale: float, attraction: float, attract_min: float,
                     repel_max: float, f: np.ndarray) -> np.ndarray:
    """One move of every dust towards (attraction) and away from (repulsion) the centre dust."""
    dis = x[centre] - x
    d = np.linalg.norm(dis, axis=1)
    attract = np.where((d >= attract_min * scale)[:, None], attraction * dis, 0.0)
    unit = np.divide(dis, d[:, None], out=np.zeros_like(dis), where=d[:, None] > 0)
    push = scale * f * np.cbrt(d / scale)
    repel = np.where(((d <= repel_max * scale) & (d > 0))[:, None], -push[:, None] * unit, 0.0)
    return x + attract + repel


class GfapfFilter(ParticleFilter):
    name = "gfapf"

    def cloud_scale(self) -> float:
        """s: 1 for `absolute`, else the cloud's RMS standard deviation per axis (weighted)."""
        if self.cfg.gfapf.scale == "absolute":
            return 1.0
        _, cov = self.estimate()
        return float(np.sqrt(max(np.trace(cov) / cov.shape[0], 1e-12)))

    def after_weight(self, z):
        g, rng = self.cfg.gfapf, self.rng
        scale = self.cloud_scale()
        x, ll = self.x, self.last_ll
        for _ in range(g.iterations):
            centre = int(np.argmax(self.prev_logw + ll))
            x = gravitation_step(x, centre, scale, g.attraction, g.attract_min, g.repel_max,
                                 g.rotation_max * rng.random(x.shape[0]))
            ll = self.loglik(x, z)
        new = self.prev_logw + ll
        if np.isfinite(new.max()):
            self.x, self.last_ll = x, ll
            self.logw = new - new.max()


class GfapfMoves(MoveKernel):
    """`gfapf.variant: mcmc`: the gravitation step as the mean of an MH proposal on the posterior."""

    name = "gfapf"

    def sweeps(self, settings) -> int:
        return settings.gfapf.iterations or 1

    def sweep(self, f, target, z):
        g = f.cfg.gfapf
        scale = 1.0 if g.scale == "absolute" else float(np.sqrt(max(np.trace(f.spread) / f.model.dim, 1e-12)))
        rotation = g.rotation_max * f.rng.random()

        def pulled(xs, others, others_target):
            centre = others[int(np.argmax(others_target))]
            pool = np.vstack([centre[None, :], xs])  # the centre dust first, then the moving dusts
            turn = np.full(len(pool), rotation)
            return gravitation_step(pool, 0, scale, g.attraction, g.attract_min, g.repel_max, turn)[1:]

        x, target, accepted = moves.drift(f.x, target, f.log_target, f.rng, pulled, f.chol(NOISE_SCALE))
        return x, target, accepted, f.n


ALGORITHMS = (Algorithm("gfapf", "gravitation field", "gfapf", GfapfConfig, GfapfFilter, GfapfMoves),)
