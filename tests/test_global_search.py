"""The global search's shortcuts against what they stand for: the Gauss-Newton refinement's against its plain
schedule, the start grid's kept sums against a score made afresh."""
from dataclasses import replace

import numpy as np
import pytest

from aoa_localizer.engine.inference import global_search, start_grid
from aoa_localizer.engine.inference.global_search import Points, Robust, find_modes, log_posterior, refine
from aoa_localizer.engine.inference.receiver import NoiseGrid
from aoa_localizer.engine.inference.start_grid import StartGrid


def _points(rng: np.random.Generator) -> Points:
    """A drive along a road east of two sources (a ghost takes a third of the bearings), 2 deg noise."""
    east = np.linspace(-800.0, 800.0, 30)
    north = np.zeros_like(east)
    source = np.where(np.arange(30) % 3 == 0, 1, 0)
    target = np.array([[150.0, 900.0], [-600.0, 400.0]])[source]
    theta = np.arctan2(target[:, 1] - north, target[:, 0] - east) + np.radians(2.0) * rng.standard_normal(30)
    return Points(east, north, theta, np.full(30, np.radians(2.0)), np.full(30, 3.0))


def _plain_refine(starts, widen, pts, rob):
    """refine as the annealing schedule reads: every step at every level for every start."""
    x = np.array(starts, float)
    prec = rob.prior_prec if rob.prior_prec is not None else np.zeros((2, 2))
    levels = global_search._ANNEAL if widen.any() else global_search._ANNEAL[-1:]
    for level in levels:
        for _ in range(global_search._ITER_PER_STAGE if len(levels) > 1 else global_search._POLISH_ITERATIONS):
            x = global_search._gn_step(x, pts, rob, level * widen, prec)
    _, grad, w, gamma = global_search.linearised(x, pts, rob)
    info = np.einsum("mk,mki,mkj->mij", w, grad, grad) + prec + 1e-12 * np.eye(2)
    return x, global_search.inverse_2x2(info), gamma


@pytest.mark.parametrize("latent", [False, True])
@pytest.mark.parametrize("annealed", [False, True])
def test_refine_skips_the_steps_of_starts_that_stopped_and_ends_where_every_step_would(monkeypatch, latent, annealed):
    """A start whose step stayed put stays put at that level, so refine takes no more steps from it: the places,
    covariances and inlier weights are those of the plain schedule to the last bit, with fewer places stepped."""
    rng = np.random.default_rng(3)
    pts = _points(rng)
    rob = Robust(0.05, 3.0, grid=NoiseGrid.weak(2.0) if latent else None)
    starts = np.array([[100.0, 1000.0], [-500.0, 300.0], [2000.0, 5000.0], [0.0, -700.0], [149.0, 901.0]])
    widen = np.array([300.0, 200.0, 2000.0, 500.0, 1.0]) if annealed else np.zeros(5)
    expected = _plain_refine(starts, widen, pts, rob)
    stepped = []
    step = global_search._gn_step
    monkeypatch.setattr(global_search, "_gn_step", lambda x, *a: stepped.append(len(x)) or step(x, *a))
    got = refine(starts, widen, pts, rob)
    for g, e in zip(got, expected, strict=True):
        np.testing.assert_array_equal(g, e)
    steps = global_search._ITER_PER_STAGE * len(global_search._ANNEAL) if annealed else global_search._POLISH_ITERATIONS
    plain = steps * len(starts)
    assert sum(stepped) < plain if annealed else sum(stepped) <= plain  # polishing, starts tend to creep on
    assert np.hypot(*(got[0][4] - [150.0, 900.0])) < 50.0  # the start next to the source ends at it


def counting(monkeypatch) -> list[int]:
    """How many points each of the start grid's sums is made over, in the order made."""
    scored: list[int] = []
    real = start_grid.grid_sums

    def grid_sums(cells, radius, pts, rob):
        scored.append(len(pts))
        return real(cells, radius, pts, rob)

    monkeypatch.setattr(start_grid, "grid_sums", grid_sums)
    return scored


@pytest.mark.parametrize("latent", [False, True])
def test_a_start_grid_adds_new_points_to_its_sums_and_scores_as_a_fresh_grid_does(monkeypatch, latent):
    """The start grid's score made from its kept sums plus the points that came since matches the score of all the
    points made at once to 1e-9, scoring only the new points; points remade (a calibration) or another noise are
    summed again from all of them, and on a grid laid for the same points the modes are find_modes'."""
    pts = _points(np.random.default_rng(5))
    rob = Robust(0.05, 3.0, grid=NoiseGrid.weak(2.0) if latent else None)
    grid = StartGrid(*global_search.polar_grid(pts.take(slice(0, 10))))  # laid as find_modes lays one
    scored = counting(monkeypatch)
    for k in (10, 11, 20, 30):
        held = pts.take(slice(0, k))
        score = grid.score(held, rob)
        fresh = replace(grid, rows=np.zeros((0, 5)), key=(), sums=0.0).score(held, rob)
        np.testing.assert_allclose(score, fresh, rtol=0.0, atol=1e-9)
        coarse = global_search.coarse_robust(rob)  # all the points in one piece, as find_modes scored before pieces
        whole = log_posterior(grid.cells, held, coarse, global_search.cell_widening(grid.cells, grid.radius, held))
        np.testing.assert_allclose(score, whole, rtol=0.0, atol=1e-9)
    assert scored[::2] == [10, 1, 9, 10]  # each fresh score took all k points
    remade = replace(pts, sigma=2.0 * pts.sigma)
    grid.score(remade, rob)
    grid.score(pts, replace(rob, gps_sigma_m=10.0))
    assert scored[-2:] == [30, 30]
    assert grid.covers(pts.take(slice(0, 13))) and not grid.covers(pts)  # laid for 10 points: twice their reach
    laid = StartGrid(*global_search.polar_grid(pts))
    assert [m.mean.tolist() for m in laid.modes(pts, rob)] == \
        [m.mean.tolist() for m in find_modes(pts, rob, by_density=True)]


def test_a_start_grid_takes_off_the_points_a_window_dropped(monkeypatch):
    """Points held as a window that dropped its oldest and took new ones: the kept sums lose the dropped points and
    gain the new ones (scoring only those) and match a fresh score to 1e-9; a window that dropped more than it kept
    is summed afresh. An empty grid lays itself around the points, and again when they leave it."""
    pts = _points(np.random.default_rng(6))
    rob = Robust(0.05, 3.0, grid=NoiseGrid.weak(2.0))
    grid = StartGrid()
    assert not grid.covers(pts)
    grid.modes(pts.take(slice(0, 20)), rob)
    assert grid.covers(pts.take(slice(0, 20)))
    scored = counting(monkeypatch)
    window = pts.take(slice(5, 24))  # 5 dropped, 4 new
    score = grid.score(window, rob)
    assert scored == [5, 4]
    fresh = StartGrid.score(replace(grid, rows=np.zeros((0, 5)), key=(), sums=0.0), window, rob)
    np.testing.assert_allclose(score, fresh, rtol=0.0, atol=1e-9)
    scored.clear()
    grid.score(pts.take(slice(16, 26)), rob)  # 11 of 19 dropped: afresh
    assert scored == [10]
