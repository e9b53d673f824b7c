"""Each paper operator made a Metropolis-Hastings move leaves its target invariant: a cloud drawn from a known
law is still that law after many sweeps (mean and covariance within sampling error), and the moves do move."""
import numpy as np
import pytest

from aoa_localizer.filters import moves
from aoa_localizer.filters.espf import sbx_scale

MEAN = np.array([3.0, -2.0])
COV = np.array([[4.0, 2.4], [2.4, 2.25]])
PREC = np.linalg.inv(COV)
N, SWEEPS = 4000, 25


def log_target(x, of=None):
    d = x - MEAN
    return -0.5 * np.einsum("ni,ij,nj->n", d, PREC, d)


def arithmetic_scale(rng):
    """The arithmetic crossover's s = 2a - 1 with its inverse added: s ~ U(-1, 1) or 1/s, half and half."""
    def draw(m):
        s = rng.uniform(-1.0, 1.0, m)
        return np.where(rng.random(m) < 0.5, s, 1.0 / s)
    return draw


def swarm_mean(step, visual):
    """Towards the centre of the fixed half's members within `visual` of the particle (itself excluded)."""
    def mean_of(xs, others, _others_target):
        others = others[:200]  # a fixed subset of the fixed half: cheaper, and still independent of xs
        d2 = np.sum((xs[:, None, :] - others[None, :, :]) ** 2, axis=-1)
        near = d2 < visual**2
        count = near.sum(axis=1)
        centre = np.where(count[:, None] > 0, (near @ others) / np.maximum(count, 1)[:, None], xs)
        return xs + step * (centre - xs)
    return mean_of


def run(move, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.multivariate_normal(MEAN, COV, N)
    target = log_target(x)
    accepted = 0
    for _ in range(SWEEPS):
        x, target, a = move(x, target, rng)
        accepted += a
    assert np.allclose(target, log_target(x))
    return x, accepted / (N * SWEEPS)


CHOL = np.linalg.cholesky(0.5 * COV)
MOVES = {
    "de_mc": lambda x, t, rng: moves.de_mc(x, t, log_target, rng, gamma=1.19, cr=0.9, jitter=0.01 * np.eye(2)),
    "sbx_pairs": lambda x, t, rng: moves.pair_scale(x, t, log_target, rng, lambda m: sbx_scale(rng, m, 2.0)),
    "arithmetic_pairs": lambda x, t, rng: moves.pair_scale(x, t, log_target, rng, arithmetic_scale(rng)),
    "swarm_drift": lambda x, t, rng: moves.drift(x, t, log_target, rng, swarm_mean(0.5, 1.5), CHOL),
    "multiple_try": lambda x, t, rng: moves.multiple_try(x, t, log_target, rng, 5, CHOL),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(MOVES))
def test_the_move_keeps_its_target(name):
    x, acceptance = run(MOVES[name])
    assert 0.05 < acceptance < 1.0, acceptance
    # standard errors of the mean about sqrt(4 / 4000) = 0.03 (correlated chains: a few times more)
    assert np.allclose(x.mean(axis=0), MEAN, atol=0.15), x.mean(axis=0)
    assert np.allclose(np.cov(x.T), COV, rtol=0.12, atol=0.12), np.cov(x.T)


def test_a_pair_move_without_its_jacobian_drifts_off_the_target():
    """The check above can fail: the same SBX pair move without the |s|^d factor does not keep the target."""
    rng = np.random.default_rng(1)
    x = rng.multivariate_normal(MEAN, COV, N)
    target = log_target(x)
    for _ in range(SWEEPS):
        order = rng.permutation(N)
        i, j = order[0::2], order[1::2]
        s = sbx_scale(rng, i.size, 2.0)
        m, half = 0.5 * (x[i] + x[j]), 0.5 * (x[i] - x[j])
        c1, c2 = m + s[:, None] * half, m - s[:, None] * half
        log_ratio = log_target(c1) + log_target(c2) - target[i] - target[j]  # d log|s| left out
        take = np.log(rng.random(i.size)) < log_ratio
        x[i[take]], x[j[take]] = c1[take], c2[take]
        target = log_target(x)
    assert not np.allclose(np.cov(x.T), COV, rtol=0.12, atol=0.12)


@pytest.mark.parametrize("d", [2, 3])
def test_whiten_is_the_triangular_solve(d):
    """The 2-D substitution (and the general path) give L^-1 v row by row, as LAPACK's solve does."""
    rng = np.random.default_rng(4)
    a = rng.standard_normal((d, d))
    chol = np.linalg.cholesky(a @ a.T + d * np.eye(d))
    v = rng.standard_normal((7, d)) * 50.0
    assert np.allclose(moves.whiten(v, chol), np.linalg.solve(chol, v.T).T, rtol=1e-12, atol=1e-12)
    assert np.allclose(moves.whiten(v[:, None, :], chol)[:, 0], np.linalg.solve(chol, v.T).T, rtol=1e-12)


def test_one_acceptance_rule_for_every_move():
    """log U < log_ratio row by row: a possible place proposed from an impossible one (+inf) is always taken, two
    impossible places (NaN) never, an impossible proposal (-inf) never; the independence move from modes and the
    pair moves decide with the same rule as the rest."""
    rng = np.random.default_rng(0)
    ratio = np.array([np.inf, np.nan, -np.inf, 0.0, -1e9])
    for _ in range(20):
        assert moves.accepted(ratio, rng).tolist() == [True, False, False, True, False]
    x, prop = np.zeros((2, 2)), np.ones((2, 2))
    target, prop_target = np.array([-np.inf, 0.0]), np.array([0.0, -np.inf])
    kept, kept_target, n = moves.accept(x, target, prop, prop_target, prop_target - target, rng)
    assert kept.tolist() == [[1.0, 1.0], [0.0, 0.0]] and kept_target.tolist() == [0.0, 0.0] and n == 1


SCALES = np.array([0.5, 1.5])  # each particle's own target: N(MEAN, s^2 COV) with s by its label


def labelled_target(labels):
    def target(x, of=None):
        s = SCALES[labels if of is None else labels[of]]
        return log_target(x) / s**2
    return target


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(MOVES))
def test_each_particle_keeps_its_own_target_when_the_targets_differ(name):
    """A target per particle (a noise hypothesis drawn for each before a sweep): every move asks for the target
    of the particle whose move each row is, so each labelled half of the cloud keeps its own law; a move that
    mixed up whose row is whose would pull both halves to something in between."""
    rng = np.random.default_rng(3)
    labels = np.arange(N) % 2
    x = MEAN + (rng.multivariate_normal(np.zeros(2), COV, N) * SCALES[labels][:, None])
    target = labelled_target(labels)
    t = target(x)
    for _ in range(SWEEPS):
        x, t, _ = LABELLED[name](x, t, rng, target)
    assert np.allclose(t, target(x))
    for label, s in enumerate(SCALES):
        part = x[labels == label]
        assert np.allclose(part.mean(axis=0), MEAN, atol=0.2 * s), (label, part.mean(axis=0))
        assert np.allclose(np.cov(part.T), s**2 * COV, rtol=0.15, atol=0.05), (label, np.cov(part.T))


LABELLED = {
    "de_mc": lambda x, t, rng, lt: moves.de_mc(x, t, lt, rng, gamma=1.19, cr=0.9, jitter=0.01 * np.eye(2)),
    "sbx_pairs": lambda x, t, rng, lt: moves.pair_scale(x, t, lt, rng, lambda m: sbx_scale(rng, m, 2.0)),
    "arithmetic_pairs": lambda x, t, rng, lt: moves.pair_scale(x, t, lt, rng, arithmetic_scale(rng)),
    "swarm_drift": lambda x, t, rng, lt: moves.drift(x, t, lt, rng, swarm_mean(0.5, 1.5), CHOL),
    "multiple_try": lambda x, t, rng, lt: moves.multiple_try(x, t, lt, rng, 5, CHOL),
}


def test_a_categorical_draw_per_row_follows_its_weights():
    """The Gibbs draw of a noise hypothesis: each row's index in proportion to exp(row); a row with no finite
    weight draws uniformly, and an impossible index is never drawn."""
    rng = np.random.default_rng(8)
    with np.errstate(divide="ignore"):
        logw = np.log(np.array([[0.2, 0.5, 0.3], [0.0, 1.0, 0.0]])) + np.array([[-800.0], [5.0]])
    drawn = moves.categorical(np.repeat(logw, 20000, axis=0), rng)
    first = np.bincount(drawn[:20000], minlength=3) / 20000
    assert np.allclose(first, [0.2, 0.5, 0.3], atol=0.015), first
    assert set(drawn[20000:].tolist()) == {1}
    none = moves.categorical(np.full((9000, 3), -np.inf), rng)
    assert np.allclose(np.bincount(none, minlength=3) / 9000, 1 / 3, atol=0.02)
