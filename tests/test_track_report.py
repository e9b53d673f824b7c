"""The published place and ellipse of a wide posterior: the cloud's spatial median (scipy's minimiser as the
reference) and the ellipse that holds 95 % of the cloud."""
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.optimize import minimize

from aoa_localizer import LocalizerConfig
from aoa_localizer.engine.crlb import ELLIPSE_95
from aoa_localizer.engine.track.report import cloud_estimate, spatial_median, wide_for_range
from aoa_localizer.simulation.surveys import hand_held, locate_survey_with


def _reference_median(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The place of least weighted distance sum, by a general minimiser."""
    res = minimize(lambda m: float(w @ np.hypot(x[:, 0] - m[0], x[:, 1] - m[1])), w @ x, method="Nelder-Mead",
                   options={"xatol": 1e-6, "fatol": 1e-12, "maxiter": 20000})
    return res.x


@pytest.mark.parametrize("seed", range(5))
def test_the_spatial_median_is_the_place_of_least_weighted_distance(seed):
    """Random weighted clouds, some with a tail along a ray: Weiszfeld's iterate is the minimiser's place (1 cm),
    and its distance sum is not beaten by it."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((300, 2)) * [40.0, 15.0]
    if seed % 2:
        x[:40] = np.column_stack([rng.uniform(100.0, 5000.0, 40), rng.normal(0.0, 20.0, 40)])
    w = rng.random(300)
    w /= w.sum()
    ours, ref = spatial_median(x, w), _reference_median(x, w)
    assert np.hypot(*(ours - ref)) < 0.01

    def total(m):
        return float(w @ np.hypot(x[:, 0] - m[0], x[:, 1] - m[1]))

    assert total(ours) <= total(ref) + 1e-6


def test_a_symmetric_cloud_s_median_is_its_mean_and_a_tail_does_not_drag_it():
    """A cloud symmetric about (10, -20) has its median there; with 10 % of the mass 5 km out along a ray, the mean
    moves 500 m and the median a few metres."""
    rng = np.random.default_rng(1)
    half = rng.standard_normal((200, 2)) * [30.0, 10.0]
    x = np.vstack([half, -half]) + [10.0, -20.0]
    w = np.full(400, 1 / 400)
    np.testing.assert_allclose(spatial_median(x, w), [10.0, -20.0], atol=1e-6)
    x[:40] = [5010.0, -20.0]
    assert (w @ x)[0] - 10.0 == pytest.approx(500.0, rel=0.02)
    assert abs(spatial_median(x, w)[0] - 10.0) < 10.0


def test_the_cloud_ellipse_holds_95_percent_of_the_weight_about_its_centre():
    """The ellipse about the given centre holds at least 95 % of the weight, and one a hair narrower holds less."""
    rng = np.random.default_rng(2)
    x = rng.standard_t(1.5, (500, 2)) * [50.0, 5.0]
    w = rng.random(500)
    w /= w.sum()
    centre = np.array([3.0, -1.0])
    place, cov = cloud_estimate(SimpleNamespace(x=x, weights=w), centre)
    np.testing.assert_array_equal(place, centre)
    d = x - centre
    d2 = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)
    assert w[d2 <= ELLIPSE_95 * (1 + 1e-9)].sum() >= 0.95
    assert w[d2 <= ELLIPSE_95 * (1 - 1e-6)].sum() < 0.95


@pytest.mark.slow
def test_a_survey_whose_filter_is_wide_for_its_range_publishes_the_spatial_median():
    """Hand-held survey 2 of seed 3 (3 bearings at 20-30 deg) ends on a running filter whose moment ellipse is wide
    for the range: the estimate is the cloud's spatial median, nearer the truth than the cloud's mean, which the
    tails along the rays drag out (48 m against 176 m)."""
    rng = np.random.default_rng(3)
    survey = [hand_held(rng) for _ in range(3)][-1]
    # the filter's end of data; no offset marginalised: the place is the cloud's own
    cfg = LocalizerConfig(seed=0, offset_sigma_deg=0.0, end_of_data_model="filter")
    est, loc = locate_survey_with(survey, cfg)
    track = loc._channels.default.track
    f = track.filter
    assert est is not None and f is not None
    mean, cov = f.estimate()
    assert wide_for_range(track.model.history.data, mean, cov)[0]
    np.testing.assert_allclose([est.east, est.north], spatial_median(f.x, f.weights), atol=1e-6)
    assert np.hypot(est.east, est.north) < np.hypot(*mean)
