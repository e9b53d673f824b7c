"""The reference's residual offset marginalised into the estimate (offset.marginalise, `offset_sigma_deg`)."""
import math

import numpy as np
import pytest

from aoa_localizer import LocalizerConfig
from aoa_localizer.engine.inference.global_search import Points, Robust, linearised
from aoa_localizer.engine.inference.offset import marginalise, prior_sd
from aoa_localizer.simulation.evaluation import run
from aoa_localizer.simulation.scenarios import SCENARIOS, simulate

GAUSSIAN = Robust(0.0)  # no wild share: the EM weights are 1 / sigma^2
SIGMA = math.radians(1.0)


def _points(stations: np.ndarray, emitter: np.ndarray, offset: float) -> Points:
    d = emitter - stations
    theta = np.arctan2(d[:, 1], d[:, 0]) + offset
    return Points(stations[:, 0], stations[:, 1], theta, np.full(len(stations), SIGMA))


def _road(n: int = 25) -> np.ndarray:
    return np.column_stack([np.linspace(-600.0, 600.0, n), np.zeros(n)])


def _fit_at_zero_offset(pts: Points, x: np.ndarray) -> np.ndarray:
    """Gauss-Newton in the place alone: what a filter that takes the offset as 0 converges to."""
    for _ in range(50):
        r, grad, w, _ = linearised(x, pts, GAUSSIAN)
        x = x + np.linalg.solve((grad * w[:, None]).T @ grad, grad.T @ (w * r))
    return x


def test_the_added_covariance_is_the_schur_complement_by_hand():
    """The bearing from (e, n) to (x, y) has gradient (-(y - n), x - e) / r^2 and the offset's derivative is 1;
    with weights 1 / sigma^2 the place's marginal covariance is the xy block of the inverse of the joint
    information with the prior 1 / sd^2 on the offset, and the function adds exactly its excess over I_xx^-1."""
    stations = _road()
    x = np.array([150.0, 500.0])
    pts = _points(stations, x, 0.0)
    d = x - stations
    r2 = np.sum(d * d, axis=1)
    jac = np.column_stack([-d[:, 1] / r2, d[:, 0] / r2, np.ones(len(d))])
    info = jac.T @ jac / SIGMA**2
    sd = math.radians(2.0)
    with_prior = info + np.diag([0.0, 0.0, 1.0 / sd**2])
    expected = np.linalg.inv(with_prior)[:2, :2] - np.linalg.inv(info[:2, :2])
    shift, spread = marginalise(pts, x, GAUSSIAN, sd)
    assert spread == pytest.approx(expected, rel=1e-9, abs=1e-9)
    assert shift == pytest.approx(np.zeros(2), abs=1e-9)  # no residuals: no offset to move the place by


def test_no_prior_spread_means_nothing_added():
    pts = _points(_road(), np.array([150.0, 500.0]), math.radians(2.0))
    shift, spread = marginalise(pts, np.array([150.0, 500.0]), GAUSSIAN, 0.0)
    assert not shift.any() and not spread.any()


def test_the_shift_takes_the_zero_offset_fit_most_of_the_way_to_the_truth():
    """Noiseless bearings 2 deg off from one straight road: the fit that takes the offset as 0 lands tens of metres
    away along the road; with a flat offset prior, one Gauss-Newton step in the offset from its residuals brings it
    back to within a tenth of that (first order), and the added covariance's long axis lies along the shift."""
    truth = np.array([150.0, 500.0])
    pts = _points(_road(), truth, math.radians(2.0))
    x0 = _fit_at_zero_offset(pts, truth.copy())
    miss = float(np.hypot(*(x0 - truth)))
    assert miss > 10.0
    shift, spread = marginalise(pts, x0, GAUSSIAN, math.inf)
    assert np.hypot(*(x0 + shift - truth)) < 0.1 * miss
    major = np.linalg.eigh(spread)[1][:, -1]
    assert abs(major @ shift) / np.hypot(*shift) > 0.99


def test_the_reference_sets_the_prior():
    assert prior_sd(LocalizerConfig()) == 0.0
    assert prior_sd(LocalizerConfig(bearing_reference="magnetic_north")) == pytest.approx(math.radians(2.0))
    assert prior_sd(LocalizerConfig(bearing_reference="vehicle")) == pytest.approx(math.radians(10.0))
    assert prior_sd(LocalizerConfig(bearing_reference="vehicle", mount_offset_deg=90.0)) == pytest.approx(
        math.radians(3.0))
    assert prior_sd(LocalizerConfig(bearing_reference="vehicle", offset_sigma_deg=0.5)) == pytest.approx(
        math.radians(0.5))


@pytest.mark.slow
def test_a_compass_a_few_degrees_off_on_a_straight_drive_stays_inside_the_ellipse():
    """The public `straight` drive read by a compass 3 deg off (`magnetic_north`, declination right), the learned
    offset off so that only the residual one differs: with the offset taken as known the filter's own ellipse
    misses the truth, and only the site part (a steady 3 deg is a site error every point shares) brings it inside
    (the motion watch off: it reads the steady error as a probable motion and widens the ellipse too); with the
    default residual offset (2 deg for a compass) it is inside, and nearer."""
    from aoa_localizer.engine.crlb import inside_ellipse

    data = simulate(SCENARIOS["straight"], 0)
    data.bearings[:, 1] = (data.bearings[:, 1] + 3.0) % 360.0
    cfg = LocalizerConfig(seed=10000, bearing_reference="magnetic_north", learn_offset=False)
    known = run(data, cfg.with_changes(offset_sigma_deg=0.0, motion_model="static"))
    final = known.estimates[-1]
    err = np.array([final.east, final.north]) - data.emitter_enu
    track = next(iter(known.localizer._channels.all())).track
    assert not inside_ellipse(err, final.cov - track.site_spread) and known.scores["inside95"]
    default = run(data, cfg)
    assert default.scores["inside95"]
    assert default.scores["error"] < known.scores["error"]
