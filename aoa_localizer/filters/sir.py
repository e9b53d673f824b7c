"""The bootstrap SIR filter: the skeleton as it is (prior proposal, resampling when ESS falls), and its emitter
variant, resample-move with Gaussian random-walk Metropolis moves (the IBIS sampler's kernel)."""
from dataclasses import dataclass

from aoa_localizer.core.spec import variant_choice
from aoa_localizer.filters import moves
from aoa_localizer.filters.algorithm import Algorithm
from aoa_localizer.filters.base import ParticleFilter
from aoa_localizer.filters.moves import RW_SCALE
from aoa_localizer.filters.resample_move import MoveKernel


@dataclass(frozen=True)
class SirConfig:
    """The bootstrap filter on the emitter: `mcmc` resample-move (Gaussian random-walk MH) or `paper` (the plain
    bootstrap with the random-walk process noise: the papers' PF baseline)."""

    variant: str = variant_choice("SIR")


class SirFilter(ParticleFilter):
    """`sir.variant: paper`: sampling-importance-resampling with the state model (its random walk) as proposal;
    the papers' PF baseline."""

    name = "sir"


class SirMoves(MoveKernel):
    """`sir.variant: mcmc`: resample-move with random-walk MH moves scaled by the cloud."""

    name = "sir"

    def sweep(self, f, target, z):
        x, target, accepted = moves.random_walk(f.x, target, f.log_target, f.rng, f.chol(RW_SCALE))
        return x, target, accepted, f.n


ALGORITHMS = (Algorithm("sir", "bootstrap", "sir", SirConfig, SirFilter, SirMoves),)
