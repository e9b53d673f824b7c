"""The scipy.special forms of the laws the engine asks for agree with scipy.stats, the reference."""
import numpy as np
import pytest
from scipy import stats

from aoa_localizer.engine import distributions as d


@pytest.mark.parametrize("df", [1, 2, 3, 5, 17.5, 200])
def test_chi_square_quantiles_and_tails_are_scipy_stats(df):
    q = np.array([1e-6, 0.01, 0.05, 0.25, 0.5, 0.625, 0.9, 0.95, 0.99, 1 - 1e-9])
    np.testing.assert_allclose(d.chi2_ppf(q, df), stats.chi2.ppf(q, df), rtol=1e-10)
    x = np.array([0.0, 1e-3, 0.5, 1.0, 3.0, 9.21, 40.0, 400.0])
    np.testing.assert_allclose(d.chi2_cdf(x, df), stats.chi2.cdf(x, df), rtol=1e-10, atol=1e-300)
    np.testing.assert_allclose(d.chi2_sf(x, df), stats.chi2.sf(x, df), rtol=1e-9, atol=1e-300)


def test_normal_quantiles_and_tails_are_scipy_stats():
    q = np.array([1e-12, 0.025, 0.5, 0.625, 0.975, 1 - 1e-12])
    np.testing.assert_allclose(d.norm_ppf(q), stats.norm.ppf(q), rtol=1e-12)
    x = np.array([-40.0, -3.0, 0.0, 1.0, 8.0, 38.0])
    np.testing.assert_allclose(d.norm_sf(x), stats.norm.sf(x), rtol=1e-12, atol=1e-300)


@pytest.mark.parametrize("n, p", [(1, 0.3), (10, 0.05), (10, 0.99), (30, 0.2), (500, 0.5)])
def test_binomial_tails_are_scipy_stats_from_below_zero_to_past_n(n, p):
    k = np.arange(-2, n + 3)
    np.testing.assert_allclose(d.binom_sf(k, n, p), stats.binom.sf(k, n, p), rtol=1e-9, atol=1e-300)
