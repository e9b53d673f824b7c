import numpy as np
import pytest

from aoa_localizer.engine.crlb import crlb_rmse, fisher_information, inside_ellipse, nees


def test_two_perpendicular_bearings_by_hand():
    # Emitter at the origin; one sensor 100 m south (bearing north), one 200 m west (bearing east).
    sigma = 0.01
    j = fisher_information([0.0, 0.0], [[0.0, -100.0], [-200.0, 0.0]], [sigma, sigma])
    # The south sensor measures east error with std sigma * 100; the west one north error with sigma * 200.
    assert j == pytest.approx(np.diag([1 / (sigma * 100) ** 2, 1 / (sigma * 200) ** 2]))
    assert crlb_rmse([0.0, 0.0], [[0.0, -100.0], [-200.0, 0.0]], [sigma, sigma]) == pytest.approx(np.hypot(1.0, 2.0))


def test_collinear_bearings_have_no_bound():
    assert crlb_rmse([0.0, 0.0], [[0.0, -100.0], [0.0, -200.0]], [0.01, 0.01]) == float("inf")


def test_nees_and_ellipse():
    cov = np.diag([4.0, 1.0])
    assert nees([2.0, 1.0], cov) == pytest.approx(2.0)
    assert inside_ellipse([2.0, 1.0], cov) and not inside_ellipse([5.0, 0.0], cov)


def test_a_collapsed_covariance_scores_infinite_nees():
    assert nees([1.0, 0.0], np.zeros((2, 2))) == float("inf") and not inside_ellipse([1.0, 0.0], np.zeros((2, 2)))


def test_crlb_so_far_grows_into_the_batch_bound():
    from aoa_localizer.engine.crlb import crlb_so_far

    sensors = np.array([[0.0, -100.0], [0.0, -150.0], [-200.0, 0.0], [-250.0, 10.0]])
    sigmas = np.full(4, 0.01)
    stamps = np.array([1.0, 2.0, 3.0, 4.0])
    bound = crlb_so_far([0.0, 0.0], sensors, sigmas, stamps, [0.5, 2.5, 4.0])
    assert bound[0] == float("inf") and bound[1] == float("inf")  # nothing yet; then two collinear rays only
    assert bound[2] == pytest.approx(crlb_rmse([0.0, 0.0], sensors, sigmas))


def test_the_circular_error_holds_its_share_of_a_gaussian():
    """CE90 (CoT's `ce`): sqrt(2 ln 10) sigma for a circle, 1.645 sigma for a line, and 90 % of draws otherwise."""
    import math

    from aoa_localizer.engine.crlb import circular_error

    assert circular_error(np.eye(2) * 4.0) == pytest.approx(2.0 * math.sqrt(2.0 * math.log(10.0)), rel=1e-5)
    assert circular_error(np.diag([9.0, 0.0])) == pytest.approx(3.0 * 1.6448536, rel=1e-6)
    cov = np.array([[9.0, 2.0], [2.0, 1.0]])
    draws = np.random.default_rng(1).multivariate_normal([0.0, 0.0], cov, 200_000)
    assert np.mean(np.hypot(*draws.T) <= circular_error(cov)) == pytest.approx(0.9, abs=0.004)
    assert circular_error(cov, 0.5) < circular_error(cov, 0.9) < circular_error(cov, 0.99)
