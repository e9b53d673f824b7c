"""A provisional sample: the weighted importance sample published while the posterior is proper but its best place is
not determined enough to start the filter. Made by the start search that found it not determined, as the search's
last part (in the worker, or in the search's turns), over the points it searched, so that its looks under the
latent noise never fall into the call that applies the search (the node's callback, under `realtime`)."""
from __future__ import annotations

import numpy as np

from aoa_localizer.engine.inference.global_search import Mode, Points, Robust, log_posterior
from aoa_localizer.engine.inference.grid_proposal import Blend
from aoa_localizer.engine.inference.safety import ModeProposal, Proposal, log_weights
from aoa_localizer.engine.inference.start_grid import StartGrid

DRAWS = 2000  # at least this many draws, one look each: the ellipse is read off the sample's tails
_DRAWS_AT_ONCE = 250  # draws whose posterior one look makes (a look of 2000 would take a call's budget alone)


def provisional_sample(modes: list[Mode], pts: Points, rob: Robust, grid: StartGrid | None, draws: int,
                       rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """`draws` places and their log importance weights (unnormalised; -inf where the posterior is not finite) under
    the robust posterior over `pts`: half from the modes' Student-t laws with a broad one, half from the search's
    grid, which reaches the far end of rays that the modes' Laplace laws do not (grid_proposal.py). The draws keep
    their weights: a provisional sample is read, never stepped."""
    modal = ModeProposal.over(modes, pts)
    cells = grid.proposal() if grid is not None else None
    proposal: Proposal = modal if cells is None else Blend([modal, cells], [0.5, 0.5])
    x = proposal.sample(draws, rng)
    logw = np.empty(draws)
    for lo in range(0, draws, _DRAWS_AT_ONCE):
        logw[lo:lo + _DRAWS_AT_ONCE] = log_weights(lambda y: log_posterior(y, pts, rob), proposal,
                                                 x[lo:lo + _DRAWS_AT_ONCE])
    return x, logw
