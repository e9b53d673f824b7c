"""The posterior on a map grid (the node's `emitter/posterior`, an OccupancyGrid): what the ellipse cannot show, such
as a ghost mode or the banana-shaped posterior of the first bearings.

The robust posterior the global checks use is evaluated for every cell (its likelihood with the cell's width seen
from each antenna added to the bearing variances), each mode of the last global search puts at least its Laplace
mass into the cells it covers (a mode narrower than a cell can fall between the centres), and the cells are
normalised over the window (each cell's probability). The
window is centred on the estimate and spans WINDOW_SIGMAS times the 95 % ellipse's major semi-axis, widened to hold
every mode and every particle; it has CELLS cells a side, so the resolution follows the ellipse. A cell's value is
100 x (1 - the mass of the cells more probable than it), rounded up, so the most probable cell is 100, the cells of
the 95 % highest-density region are 5 or more, and the rest are 0.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from aoa_localizer.engine.crlb import ellipse_axes
from aoa_localizer.engine.inference.global_search import Mode, Points, Robust, log_posterior

CELLS = 64  # cells a side: the evaluation costs cells^2 x points (docs/interface.md gives the times)
WINDOW_SIGMAS = 3.0  # the window's half-width, in 95 % ellipse major semi-axes
MIN_RESOLUTION_M = 0.1
REGION = 0.95  # the highest-density region the values show


@dataclass(frozen=True)
class PosteriorGrid:
    """Cells of `resolution` metres from the lower-left corner (`east0`, `north0`), rows going north; `prob` each
    cell's posterior probability (rows x columns, summing to 1), `value` its 0-100 occupancy value."""

    east0: float
    north0: float
    resolution: float
    prob: np.ndarray
    value: np.ndarray

    def cell_of(self, east, north) -> tuple[np.ndarray, np.ndarray]:
        """(row, column) of places (east, north); outside the grid they fall off its edges."""
        return (np.floor((np.asarray(north) - self.north0) / self.resolution).astype(int),
                np.floor((np.asarray(east) - self.east0) / self.resolution).astype(int))


def window(mean: np.ndarray, cov: np.ndarray, places: np.ndarray) -> tuple[float, float, float]:
    """(east0, north0, resolution) of a square window centred on `mean`: WINDOW_SIGMAS 95 % ellipse semi-axes each
    way, widened to hold `places` (modes, particles)."""
    half = WINDOW_SIGMAS * float(ellipse_axes(cov)[0])
    if len(places):
        half = max(half, float(np.max(np.abs(places - mean))) * 1.05)
    resolution = max(2.0 * half / CELLS, MIN_RESOLUTION_M)
    half = 0.5 * resolution * CELLS
    return float(mean[0]) - half, float(mean[1]) - half, resolution


def posterior_grid(pts: Points, rob: Robust, mean: np.ndarray, cov: np.ndarray, places: np.ndarray,
                   modes: Sequence[Mode] = ()) -> PosteriorGrid:
    """The posterior over the points `pts` on the window around `mean` (see `window`); `modes`, the posterior's
    modes as the last global search found them, make sure a mode narrower than a cell keeps its mass."""
    east0, north0, res = window(np.asarray(mean, float), np.asarray(cov, float), np.asarray(places, float))
    centres = (np.arange(CELLS) + 0.5) * res
    grid = np.stack(np.meshgrid(east0 + centres, north0 + centres), axis=-1).reshape(-1, 2)  # rows go north
    # A cell's likelihood as a whole, not its centre's: its width seen from each antenna joins the bearing's
    # variance (a uniform cell's cross-range variance, res^2 / 12, over the range squared). Centres alone miss a
    # posterior narrower than a cell, such as one of two modes far apart.
    range2 = (grid[:, 0, None] - pts.east) ** 2 + (grid[:, 1, None] - pts.north) ** 2
    widen2 = res**2 / 12.0 / np.maximum(range2, res**2)
    logp = log_posterior(grid, pts, rob, widen2).reshape(CELLS, CELLS) + 2.0 * math.log(res)
    logp = np.maximum(logp, _mode_masses(modes, pts, rob, east0, north0, res))
    finite = np.isfinite(logp)
    top = float(np.max(logp[finite])) if finite.any() else 0.0
    p = np.where(finite, np.exp(logp - top), 0.0)
    total = p.sum()
    prob = p / total if total > 0 else np.full_like(p, 1.0 / p.size)
    order = np.argsort(prob, axis=None)[::-1]
    above = np.empty(prob.size)
    above[order] = np.cumsum(prob.ravel()[order])  # mass of the cells at least as probable
    value = np.where(above - prob.ravel() < REGION, np.ceil(100.0 * (1.0 - above + prob.ravel())), 0.0)
    return PosteriorGrid(east0, north0, res, prob, np.clip(value, 0, 100).astype(np.int8).reshape(prob.shape))


def _mode_masses(modes: Sequence[Mode], pts: Points, rob: Robust, east0: float, north0: float,
                 res: float) -> np.ndarray:
    """Each cell's log mass from the modes' Laplace approximations (the mode's log posterior now, over the points
    held, with its covariance), spread over the cells by its east and north marginals: the widened centres alone
    lose a mode narrower than a cell when their bearings, widened one by one, still cross far from the centre."""
    out = np.full((CELLS, CELLS), -np.inf)
    edges = np.arange(CELLS + 1) * res
    for m in modes:
        # the mode's Laplace mass with its log posterior over the points held now (its covariance's term kept)
        log_mass = m.log_mass - m.log_post + float(log_posterior(m.mean, pts, rob))
        sd = np.sqrt(np.diag(m.cov))
        if not (math.isfinite(log_mass) and np.all(sd > 0)):
            continue
        east = np.diff(ndtr((east0 + edges - m.mean[0]) / sd[0]))
        north = np.diff(ndtr((north0 + edges - m.mean[1]) / sd[1]))
        with np.errstate(divide="ignore"):
            out = np.logaddexp(out, log_mass + np.log(np.outer(north, east)))  # rows go north
    return out


