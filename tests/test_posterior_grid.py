"""The posterior on a map grid (emitter/posterior): the density the global checks use, evaluated per cell."""
import math

import numpy as np
import pytest

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.outputs.posterior_grid import CELLS, REGION, PosteriorGrid
from aoa_localizer.simulation.evaluation import run
from aoa_localizer.simulation.scenarios import simulate


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["seed", "straight"])
def test_the_grids_95_percent_region_holds_95_percent_of_the_cloud(scenario):
    """Two pictures of one posterior: the density on the grid and the filter's particles. The cells the grid shows
    (its 95 % highest-density region) hold about 95 % of the particles' weight (N = 100: within Monte Carlo
    error); the most probable cell is 100, and a more probable cell never has a lower value."""
    res = run(simulate(scenario, 1), LocalizerConfig(seed=1))
    grid, est = res.localizer.posterior().grid(), res.localizer.view().estimate
    assert grid.value.shape == (CELLS, CELLS) and grid.prob.sum() == pytest.approx(1.0)
    assert abs(region_mass(grid, est.particles, est.weights) - REGION) < 0.06
    order = np.argsort(grid.prob, axis=None)
    assert np.all(np.diff(grid.value.ravel()[order].astype(int)) >= 0) and grid.value.max() == 100
    shown = grid.prob[grid.value > 0].sum()
    assert REGION <= shown < REGION + grid.prob.max() + 1e-12  # the region and the one cell that crosses it
    rows, cols = grid.cell_of(est.particles[:, 0], est.particles[:, 1])
    assert rows.min() >= 0 and cols.min() >= 0 and max(rows.max(), cols.max()) < CELLS  # the window holds them


def test_no_grid_before_the_first_estimate():
    from aoa_localizer import Localizer

    assert Localizer(LocalizerConfig(seed=1)).posterior() is None


def region_mass(grid: PosteriorGrid, particles: np.ndarray, weights: np.ndarray) -> float:
    """The weighted share of `particles` in the cells the grid shows (value > 0): about REGION when the grid and
    the cloud describe the same posterior."""
    rows, cols = grid.cell_of(particles[:, 0], particles[:, 1])
    n = grid.value.shape[0]
    inside = (rows >= 0) & (rows < n) & (cols >= 0) & (cols < n)
    shown = np.zeros(len(particles), bool)
    shown[inside] = grid.value[rows[inside], cols[inside]] > 0
    return float(np.sum(weights[shown]) / np.sum(weights)) if math.isfinite(np.sum(weights)) else 0.0
