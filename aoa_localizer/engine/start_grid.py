"""The start search's polar grid, kept from one search to the next with each cell's sums over the points.

Until the filter starts, a track searches its posterior again at nearly every new point, over all the points it
holds: scored afresh, the grid costs cells x points x hypotheses at each search. The part of the score that adds
up over the points (global_search.summed_log_densities) is kept per cell instead, so a search adds only the points
that came since the last one; the prior, which is not a sum over points, is added at each search. The grid stays
where it was laid while the points stay within twice its extent, and the sums are made again from all the points
when the points held are not the ones summed plus new ones (a point dropped, points remade by a calibration) or
the noise they were summed under changed.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from aoa_localizer.engine.global_search import (
    Mode,
    Points,
    Robust,
    cell_widening,
    coarse_robust,
    extent_from,
    from_sums,
    grid_around,
    modes_from_grid,
    summed_log_densities,
)

_REGRID = 2.0  # points this many times farther from the grid's centre than when it was laid: a new grid


@dataclass
class StartGrid:
    """A polar grid laid around the points of a first search (cells (A, R, 2), radius (R,)), with the sums of the
    points scored on it (`rows`: those points as (K, 5) rows; `key`: the noise they were scored under)."""

    centre: np.ndarray
    extent: float
    cells: np.ndarray
    radius: np.ndarray
    rows: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    key: tuple = ()
    sums: np.ndarray | float = 0.0

    @classmethod
    def around(cls, pts: Points) -> StartGrid:
        """A grid laid for `pts`, as find_modes lays one (nothing summed yet)."""
        centre = np.array([pts.east.mean(), pts.north.mean()])
        extent = extent_from(centre, pts)
        return cls(centre, extent, *grid_around(centre, extent))

    def covers(self, pts: Points) -> bool:
        """Whether the points stay close enough to the grid's centre for its cells (else lay a new one)."""
        return extent_from(self.centre, pts) <= _REGRID * self.extent

    def modes(self, pts: Points, rob: Robust) -> list[Mode]:
        """find_modes(pts, rob, by_density=True) on this grid, its score made from the kept sums plus the points
        that came since."""
        return modes_from_grid(self.cells, self.radius, self.score(pts, rob), pts, rob, by_density=True)

    def score(self, pts: Points, rob: Robust) -> np.ndarray:
        """The coarse log posterior (A, R) over `pts` at the cells, each bearing widened by the cell's size."""
        coarse = coarse_robust(rob)
        rows = np.column_stack([pts.east, pts.north, pts.theta, pts.sigma, pts.gps])
        key = _key(coarse)
        sums, done = self.sums, len(self.rows)
        if key != self.key or len(rows) < done or not np.array_equal(rows[:done], self.rows):
            sums, done = 0.0, 0
        if done < len(rows):
            new = pts.take(slice(done, None))
            sums = sums + summed_log_densities(self.cells, new, coarse, cell_widening(self.cells, self.radius, new))
        self.rows, self.key, self.sums = rows, key, sums  # together: a search that failed leaves the last ones
        return from_sums(np.asarray(sums), self.cells, coarse)


def _key(rob: Robust) -> tuple:
    """What the per-point sums depend on besides the points: the noise (fixed share or latent hypotheses) and the
    GPS sigma (the prior and the radio-range prior are added at each search)."""
    grid = rob.grid
    hyp = None if grid is None else (grid.scale.tobytes(), grid.outlier.tobytes(), grid.log_prior.tobytes())
    return rob.outlier_prob, rob.gps_sigma_m, hyp
