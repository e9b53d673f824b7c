"""Peers from the `particles` package (N. Chopin) on exactly the measurements our filter saw.

Both get our observation points (antenna position, corrected bearing, its sigma) and our likelihood
(Gaussian + uniform outliers), and the prior our run used: the scenario's prior where it has one,
else a Gaussian fitted to our triangulated start cloud with its covariance doubled. So the
comparison is filter against filter, not pre-processing against none.
"""
from __future__ import annotations

import functools
import time

import numpy as np

try:
    import particles
    from particles import distributions as dists
    from particles import smc_samplers as ssp
    from particles import state_space_models as ssm
except ImportError:  # the `bench` extra is not installed
    particles = None

from aoa_localizer.engine.geodesy import wrap_pi
from aoa_localizer.engine.inference.likelihood import mixture_loglik

AVAILABLE = particles is not None


def _loglik(east_of, north_of, p, outlier_prob):
    """Log-likelihood of point p = (east, north, theta, sigma) for emitter coordinates."""
    predicted = np.arctan2(north_of - p[1], east_of - p[0])
    return mixture_loglik(wrap_pi(p[2] - predicted), p[3], outlier_prob)


if AVAILABLE:

    class BearingDist(dists.ProbDist):
        """A bearing around `mu` (per particle) with the engine's mixture likelihood."""

        def __init__(self, mu, sigma, outlier_prob):
            self.mu, self.sigma, self.outlier_prob = mu, sigma, outlier_prob

        def logpdf(self, z):
            return mixture_loglik(wrap_pi(z - self.mu), self.sigma, self.outlier_prob)

    class RandomWalkEmitter(ssm.StateSpaceModel):
        """The AFSA paper's state model for the bootstrap peer: X_k = X_{k-1} + N(0, q^2 I)."""

        def PX0(self):
            return dists.MvNormal(loc=self.m0, cov=self.P0)

        def PX(self, t, xp):
            return dists.MvNormal(loc=xp, cov=self.q**2 * np.eye(2))

        def PY(self, t, xp, x):
            p = self.points[t]
            mu = np.arctan2(x[:, 1] - p[1], x[:, 0] - p[0])
            return BearingDist(mu, p[3], self.outlier_prob)

    class StaticEmitter(ssp.StaticModel):
        """A static emitter for IBIS: theta = (x, y)."""

        def logpyt(self, theta, t):
            return _loglik(theta["x"], theta["y"], self.data[t], self.outlier_prob)


def _run(alg, get_estimate) -> tuple[list[np.ndarray], list[float]]:
    estimates, step_s = [], []
    while True:
        t0 = time.perf_counter()
        try:
            next(alg)
        except StopIteration:
            break
        step_s.append(time.perf_counter() - t0)
        estimates.append(get_estimate(alg))
    return estimates, step_s


@functools.cache
def _warm_up() -> None:
    """Once per process, untimed: a small IBIS run, which resamples and moves. The first resample-move step of a
    process takes about half a second (first calls into the MCMC code); timed, that one step swamped the mean."""
    rng = np.random.default_rng(0)
    east, north = rng.uniform(0, 1000, 30), rng.uniform(0, 500, 30)
    theta = np.arctan2(800.0 - north, 1200.0 - east) + rng.normal(0.0, 0.02, 30)
    points = np.column_stack([east, north, theta, np.full(30, 0.02)])
    _ibis(points, np.array([1100.0, 700.0]), 1e4 * np.eye(2), 100, 0.05, 0)


def run_bootstrap(points, prior_mean, prior_cov, n, q, outlier_prob, seed):
    """particles' bootstrap filter with the paper's random walk; returns (estimates, step times)."""
    _warm_up()
    np.random.seed(seed)  # particles draws from numpy's global generator
    model = RandomWalkEmitter(m0=np.asarray(prior_mean), P0=np.asarray(prior_cov), q=q,
                              points=points, outlier_prob=outlier_prob)
    fk = ssm.Bootstrap(ssm=model, data=points[:, 2])
    alg = particles.SMC(fk=fk, N=n, resampling="systematic", ESSrmin=0.5)
    return _run(alg, lambda a: a.W @ a.X)


def run_ibis(points, prior_mean, prior_cov, n, outlier_prob, seed):
    """particles' IBIS sampler (resample-move with random-walk MCMC on the full posterior)."""
    _warm_up()
    return _ibis(points, prior_mean, prior_cov, n, outlier_prob, seed)


def _ibis(points, prior_mean, prior_cov, n, outlier_prob, seed):
    np.random.seed(seed)
    sd = np.sqrt(np.diag(prior_cov))
    prior = dists.StructDist({"x": dists.Normal(loc=prior_mean[0], scale=sd[0]),
                              "y": dists.Normal(loc=prior_mean[1], scale=sd[1])})
    model = StaticEmitter(data=points, prior=prior)
    model.outlier_prob = outlier_prob
    alg = particles.SMC(fk=ssp.IBIS(model, wastefree=False, len_chain=5), N=n, ESSrmin=0.5)
    return _run(alg, lambda a: np.array([a.W @ a.X.theta["x"], a.W @ a.X.theta["y"]]))
