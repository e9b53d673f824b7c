"""The start search's polar grid, kept from one search to the next with each cell's sums over the points.

Until the filter starts, a track searches its posterior again at nearly every new point, over all the points it
holds: scored afresh, the grid costs cells x points x hypotheses at each search. The part of the score that adds
up over the points (global_search.summed_log_densities) is kept per cell instead, so a search adds only the points
that came since the last one (and takes off the oldest ones a window dropped); the prior, which is not a sum over
points, is added at each search. The grid stays where it was laid while the points stay within twice its extent,
and the sums are made again from all the points when the points held are not the ones summed plus new ones (points
remade by a calibration) or the noise they were summed under changed.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from aoa_localizer.engine.inference.global_search import (
    Mode,
    Points,
    Robust,
    coarse_robust,
    extent_from,
    from_sums,
    grid_sums,
    modes_from_grid,
    polar_grid,
)
from aoa_localizer.engine.inference.grid_proposal import GridProposal

_REGRID = 2.0  # points this many times farther from the grid's centre than when it was laid: a new grid


@dataclass
class StartGrid:
    """A polar grid laid around the points of a first search (cells (A, R, 2), radius (R,); none before it), with
    the sums of the points scored on it (`rows`: those points as (K, 5) rows; `key`: the noise they were scored
    under)."""

    centre: np.ndarray = field(default_factory=lambda: np.zeros(2))
    extent: float = 0.0
    cells: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 2)))
    radius: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rows: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    key: tuple = ()
    sums: np.ndarray | float = 0.0
    last_score: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # the last search's score (A, R)

    def covers(self, pts: Points) -> bool:
        """Whether the grid is laid and the points stay close enough to its centre for its cells (else lay a new
        one)."""
        return self.cells.size > 0 and extent_from(self.centre, pts) <= _REGRID * self.extent

    def modes(self, pts: Points, rob: Robust) -> list[Mode]:
        """find_modes(pts, rob, by_density=True) on this grid, its score made from the kept sums plus the points that
        came since; the grid laid (again) around the points first when they are not within it."""
        if not self.covers(pts):
            self.centre, self.extent, self.cells, self.radius = polar_grid(pts)
            self.rows, self.key, self.sums = np.zeros((0, 5)), (), 0.0
        score = self.score(pts, rob)
        return modes_from_grid(self.cells, self.radius, score, pts, rob, by_density=True)

    def score(self, pts: Points, rob: Robust) -> np.ndarray:
        """The coarse log posterior (A, R) over `pts` at the cells, each bearing widened by the cell's size."""
        coarse = coarse_robust(rob)
        rows = pts.rows()
        key = _key(coarse)
        sums: np.ndarray | float = 0.0
        done = 0
        dropped = _dropped(self.rows, rows) if key == self.key else None
        if dropped is not None:
            sums, done = self.sums, len(self.rows) - dropped
            if dropped:
                sums = sums - grid_sums(self.cells, self.radius, Points.of(self.rows[:dropped]), coarse)
        if done < len(rows):
            sums = sums + grid_sums(self.cells, self.radius, pts.take(slice(done, None)), coarse)
        self.rows, self.key, self.sums = rows, key, sums  # together: a search that failed leaves the last ones
        self.last_score = from_sums(np.asarray(sums), self.cells, coarse)
        return self.last_score

    def proposal(self) -> GridProposal | None:
        """An importance proposal from the last search's score (grid_proposal.py); None before a search."""
        if self.last_score.shape != self.cells.shape[:2] or not self.last_score.size:
            return None
        log_r = np.log(np.hypot(*(self.cells[0] - self.centre).T))
        return GridProposal.usable(self.centre, log_r, self.last_score)


def _dropped(summed: np.ndarray, rows: np.ndarray) -> int | None:
    """How many of the points summed (rows) lead the ones held now, which are the rest of them followed by new ones
    (a window that dropped its oldest points); None when the points held are not (points remade, or most of the
    sums would go: summing afresh costs less)."""
    if not len(summed):
        return 0
    if not len(rows):
        return None
    first = np.flatnonzero((summed == rows[0]).all(axis=1))
    dropped = int(first[0]) if first.size else len(summed)
    kept = len(summed) - dropped
    if dropped > kept or len(rows) < kept or not np.array_equal(rows[:kept], summed[dropped:]):
        return None
    return dropped


def _key(rob: Robust) -> tuple:
    """What the per-point sums depend on besides the points: the noise (fixed share or latent hypotheses) and the
    GPS sigma (the prior and the radio-range prior are added at each search)."""
    grid = rob.grid
    hyp = None if grid is None else (grid.scale.tobytes(), grid.outlier.tobytes(), grid.log_prior.tobytes())
    return rob.outlier_prob, rob.gps_sigma_m, hyp
