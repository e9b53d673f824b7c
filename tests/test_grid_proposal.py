"""The start grid's importance proposal: its density by hand, its draws against it, and what it buys on a ray."""
import math

import numpy as np
import pytest

from aoa_localizer.engine.inference.global_search import Points, Robust, log_posterior
from aoa_localizer.engine.inference.grid_proposal import Blend, GridProposal
from aoa_localizer.engine.inference.safety import ModeProposal, weighted_sample
from aoa_localizer.engine.inference.start_grid import StartGrid


def _small_grid() -> GridProposal:
    """4 azimuth cells by 3 ranges (1, e, e^2 m) at (10, 20), score 0 but one cell 2 nats better."""
    score = np.zeros((4, 3))
    score[1, 2] = 2.0
    return GridProposal(np.array([10.0, 20.0]), np.log([1.0, math.e, math.e**2]), score)


def test_the_density_of_a_cell_is_its_mass_over_its_polar_area():
    q = _small_grid()
    # masses: exp(score + 2 log r); az cell 1 spans 90-180 deg, range cell 2 log r in [1.5, 2.5]
    mass = np.exp(np.zeros((4, 3)) + 2 * np.log([1.0, math.e, math.e**2]))
    mass[1, 2] *= math.e**2
    p = mass / mass.sum()
    r = math.exp(2.2)
    x = np.array([10.0 + r * math.cos(math.radians(120)), 20.0 + r * math.sin(math.radians(120))])
    expected = math.log(p[1, 2]) - math.log((math.pi / 2) * 1.0) - 2 * math.log(r)
    assert float(q.logpdf(x[None])[0]) == pytest.approx(expected, rel=1e-12)
    # outside the ranges (log r < -0.5 or > 2.5): no density
    assert np.all(np.isneginf(q.logpdf(np.array([[10.2, 20.0], [10.0 + math.exp(2.6), 20.0]]))))


def test_the_density_integrates_to_one_and_the_draws_follow_it():
    q = _small_grid()
    # integrate exp(logpdf) over the plane in polar coordinates around the centre (dx dy = r^2 dlog r daz)
    az = (np.arange(720) + 0.5) * 2 * math.pi / 720
    log_r = np.linspace(-0.5, 2.5, 601)[:-1] + 0.0025
    a, lr = np.meshgrid(az, log_r, indexing="ij")
    r = np.exp(lr)
    x = np.stack([10.0 + r * np.cos(a), 20.0 + r * np.sin(a)], axis=-1)
    integral = float(np.sum(np.exp(q.logpdf(x)) * r**2) * (2 * math.pi / 720) * 0.005)
    assert integral == pytest.approx(1.0, abs=1e-3)
    # the draws fall in the cells in proportion to their masses
    y = q.sample(40_000, np.random.default_rng(1))
    d = y - q.centre
    cell_a = np.floor(np.arctan2(d[:, 1], d[:, 0]) % (2 * math.pi) / (math.pi / 2)).astype(int)
    cell_r = np.rint(0.5 * np.log(np.sum(d * d, axis=1))).astype(int)
    counts = np.zeros((4, 3))
    np.add.at(counts, (cell_a, cell_r), 1)
    assert counts.ravel() / 40_000 == pytest.approx(q.p, abs=0.01)


def test_a_blend_is_the_weighted_mixture_of_its_parts():
    q = _small_grid()
    other = GridProposal(np.array([0.0, 0.0]), np.log([1.0, math.e, math.e**2]), np.zeros((4, 3)))
    blend = Blend([q, other], [3.0, 1.0])
    x = np.array([[12.0, 21.0], [1.5, -1.0], [500.0, 0.0]])
    with np.errstate(divide="ignore"):
        expected = np.log(0.75 * np.exp(q.logpdf(x)) + 0.25 * np.exp(other.logpdf(x)))
    assert blend.logpdf(x) == pytest.approx(expected, rel=1e-12)
    # drawn from itself, a sample's importance weights are all equal
    _, logw = weighted_sample(blend.logpdf, blend, 500, np.random.default_rng(2))
    assert np.ptp(logw) == pytest.approx(0.0, abs=1e-9)


def _parallel_bearings():
    """Five antennas 10 m apart on a line, bearings to an emitter 3 km away at 2 deg noise: the range is not
    determined, so the posterior (under the radio-range prior) is a ray from the track out to kilometres."""
    rng = np.random.default_rng(3)
    east, north = np.arange(5) * 10.0, np.zeros(5)
    truth = np.array([3000.0, 1500.0])
    theta = np.arctan2(truth[1] - north, truth[0] - east) + np.radians(2.0) * rng.standard_normal(5)
    pts = Points(east, north, theta, np.full(5, np.radians(2.0)))
    return pts, Robust(0.05, reach=(20.0, 0.0, 100.0))


def _share_beyond(pts, rob, radius: float) -> float:
    """The posterior's mass farther than `radius` from (20, 0), by integration on a fine polar grid out to 100 km."""
    az = (np.arange(720) + 0.5) * 2 * math.pi / 720
    a, log_r = np.meshgrid(az, np.linspace(math.log(0.5), math.log(1e5), 600), indexing="ij")
    r = np.exp(log_r)
    lp = log_posterior(np.stack([20.0 + r * np.cos(a), r * np.sin(a)], axis=-1), pts, rob)
    w = np.exp(lp - lp.max()) * r**2  # dx dy = r^2 dlog r daz
    return float(w[r > radius].sum() / w.sum())


@pytest.mark.slow
def test_on_a_ray_the_grid_keeps_more_draws_and_the_sample_reaches_the_far_end():
    pts, rob = _parallel_bearings()
    grid = StartGrid()
    modes = grid.modes(pts, rob)
    assert modes
    mode_q = ModeProposal(modes, 100.0)
    grid_q = grid.proposal()
    assert grid_q is not None

    def sample(q):
        y, logw = weighted_sample(lambda x: log_posterior(x, pts, rob), q, 4000, np.random.default_rng(4))
        w = np.exp(logw - logw.max())
        far = np.hypot(y[:, 0] - 20.0, y[:, 1]) > 1000.0
        return float(w.sum() ** 2 / np.sum(w * w)), float(w[far].sum() / w.sum())

    ess_modes, _ = sample(mode_q)
    ess_blend, far_blend = sample(Blend([mode_q, grid_q], [0.5, 0.5]))
    assert ess_blend > 2 * ess_modes
    # over 40 % of the posterior lies beyond 1 km (the grid reaches 8 km of it: its tail beyond is not drawn)
    assert far_blend == pytest.approx(_share_beyond(pts, rob, 1000.0), abs=0.1)

