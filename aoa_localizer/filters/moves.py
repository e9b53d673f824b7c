"""The papers' operators as Metropolis-Hastings moves that leave the posterior pi (a filter's `log_target`)
invariant, so a cloud moved by them is still a weighted sample of pi and the published ellipse stays honest.

Population moves (a DE difference, a swarm's centre, a central dust) read other particles. They move one half
of the cloud at a time while the other half stays fixed: for the moving half the fixed half is a constant, so
each kernel is an ordinary MH kernel on a particle and the sweep keeps the joint law of independent draws of
pi (the red-black scheme of ensemble samplers). Every function returns (x, target, accepted count).

A target may differ per particle (a particle's own noise hypothesis, drawn before the sweep): every move tells
`log_target` whose move each row it asks about is (`of`: particle indices; None: the particles in order), and
each particle's kernel keeps its own target.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

RW_SCALE = 2.38 / 2**0.5  # the optimal random-walk scale in 2-D (Roberts, Gelman, Gilks 1997), in cloud sigmas
SPREAD_FLOOR_M2 = 1e-2  # added to a cloud's covariance before its Cholesky factor: moves stay alive in a collapse


class LogTarget(Protocol):
    """The log target at rows y (M, d), row i being a move of particle of[i] (None: the particles in order)."""

    def __call__(self, y: np.ndarray, of: np.ndarray | None = None, /) -> np.ndarray: ...


def cloud_chol(cov: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Cholesky factor of scale^2 times a cloud's covariance, floored: the scale of every move built on the cloud."""
    return scale * np.linalg.cholesky(cov + SPREAD_FLOOR_M2 * np.eye(len(cov)))


def categorical(log_weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One index per row of log_weights (M, H), drawn in proportion to exp(row); a row with no finite weight draws
    uniformly (its particle is impossible whatever it draws)."""
    top = np.max(log_weights, axis=1, keepdims=True)
    finite = np.isfinite(top)
    w = np.exp(log_weights - np.where(finite, top, 0.0))
    w[~finite[:, 0]] = 1.0
    cum = np.cumsum(w, axis=1)
    u = rng.random(log_weights.shape[0]) * cum[:, -1]
    return np.minimum((cum <= u[:, None]).sum(axis=1), log_weights.shape[1] - 1)


def halves(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random split of the particle indices into two halves (the moving one first)."""
    order = rng.permutation(n)
    return order[: n // 2], order[n // 2:]


def accepted(log_ratio: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The Metropolis-Hastings decision per row, log U < log_ratio: a NaN ratio (two impossible places) rejects,
    +inf (a possible place proposed from an impossible one) accepts. Every move decides with it."""
    return np.log(rng.random(log_ratio.shape[0])) < log_ratio


def accept(x, target, prop, prop_target, log_ratio, rng: np.random.Generator):
    """Keep prop where the MH decision (`accepted`) takes it."""
    take = accepted(log_ratio, rng)
    return np.where(take[:, None], prop, x), np.where(take, prop_target, target), int(take.sum())


def whiten(v: np.ndarray, chol: np.ndarray) -> np.ndarray:
    """L^-1 v for each row v (L lower triangular, a Cholesky factor): by substitution in 2-D, since LAPACK's solve
    with many right-hand sides waited milliseconds for its second thread while the check worker had the other core."""
    if chol.shape == (2, 2):
        d0 = v[..., 0] / chol[0, 0]
        return np.stack([d0, (v[..., 1] - chol[1, 0] * d0) / chol[1, 1]], axis=-1)
    return np.linalg.solve(chol, v[..., None])[..., 0]


def gauss_log_kernel(to: np.ndarray, mean: np.ndarray, chol: np.ndarray) -> np.ndarray:
    """log N(to; mean, L L^T) up to the constant (the same L both ways, so it cancels in a ratio)."""
    d = whiten(to - mean, chol)
    return -0.5 * np.sum(d * d, axis=-1)


def random_walk(x, target, log_target: LogTarget, rng: np.random.Generator, chol: np.ndarray, log_attempt=None):
    """A Gaussian random-walk move per particle (Cholesky factor `chol`). With `log_attempt(target)`, the move is
    tried only with that probability (AGA-PF's adaptive mutation) and the ratio carries attempt(y) / attempt(x)."""
    prop = x + rng.standard_normal(x.shape) @ chol.T
    prop_target = log_target(prop)
    log_ratio = prop_target - target
    if log_attempt is not None:
        forward = log_attempt(target)
        tried = np.log(rng.random(x.shape[0])) < forward
        log_ratio = np.where(tried, log_ratio + log_attempt(prop_target) - forward, -np.inf)
    return accept(x, target, prop, prop_target, log_ratio, rng)


def independence(x, target, log_target: LogTarget, rng: np.random.Generator, mean: np.ndarray, chol: np.ndarray):
    """An independence move from the Gaussian N(mean, L L^T): accept with pi(y) q(x) / (pi(x) q(y))."""
    prop = mean + rng.standard_normal(x.shape) @ chol.T
    prop_target = log_target(prop)
    log_ratio = prop_target - target + gauss_log_kernel(x, mean, chol) - gauss_log_kernel(prop, mean, chol)
    return accept(x, target, prop, prop_target, log_ratio, rng)


class Proposal(Protocol):
    """A proposal with an exact density (the safety layer's mode mixture): draws and their log density."""

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray: ...

    def logpdf(self, x: np.ndarray) -> np.ndarray: ...


def independence_from(x, target, log_target: LogTarget, rng: np.random.Generator, proposal: Proposal):
    """An independence move from `proposal`: accept with pi(y) q(x) / (pi(x) q(y))."""
    prop = proposal.sample(x.shape[0], rng)
    prop_target = log_target(prop)
    log_ratio = (prop_target - proposal.logpdf(prop)) - (target - proposal.logpdf(x))
    return accept(x, target, prop, prop_target, log_ratio, rng)


def de_mc(x, target, log_target: LogTarget, rng: np.random.Generator, gamma: float, cr: float, jitter: np.ndarray):
    """DE-MC (ter Braak 2006) on each half: x_i + gamma (x_r1 - x_r2) on a binomial crossover mask (rate cr, at
    least one coordinate) plus a small Gaussian jitter (Cholesky factor `jitter`), r1 != r2 from the other half.
    The proposal is symmetric (swapping r1 and r2 reverses it), so the ratio is pi(y) / pi(x)."""
    n, d = x.shape
    x, target, accepted = x.copy(), target.copy(), 0
    if n < 6:
        return x, target, 0
    moving, fixed = halves(n, rng)
    for part, other in ((moving, fixed), (fixed, moving)):
        # two distinct members of the other half per particle: r1 uniform, r2 uniform among the rest
        r1 = rng.integers(0, other.size, size=part.size)
        r2 = (r1 + rng.integers(1, other.size, size=part.size)) % other.size
        mask = rng.random((part.size, d)) < cr
        mask[np.arange(part.size), rng.integers(0, d, size=part.size)] = True
        step = np.where(mask, gamma * (x[other[r1]] - x[other[r2]]), 0.0)
        prop = x[part] + step + rng.standard_normal((part.size, d)) @ jitter.T
        prop_target = log_target(prop, part)
        x[part], target[part], a = accept(x[part], target[part], prop, prop_target, prop_target - target[part], rng)
        accepted += a
    return x, target, accepted


def drift(x, target, log_target: LogTarget, rng: np.random.Generator, mean_of: Callable, chol: np.ndarray):
    """A Gaussian proposal N(m(x), L L^T) whose mean `mean_of(x_moving, x_fixed, target_fixed)` is drawn from the
    fixed half (a swarm's centre, the central dust's pull), with the Hastings ratio q(x | y) / q(y | x) computed
    through m(y): each half in turn."""
    n, _ = x.shape
    x, target, accepted = x.copy(), target.copy(), 0
    moving, fixed = halves(n, rng)
    for part, other in ((moving, fixed), (fixed, moving)):
        xs, others = x[part], x[other]
        mean = mean_of(xs, others, target[other])
        prop = mean + rng.standard_normal(xs.shape) @ chol.T
        back = mean_of(prop, others, target[other])
        prop_target = log_target(prop, part)
        log_ratio = (prop_target - target[part] + gauss_log_kernel(xs, back, chol)
                     - gauss_log_kernel(prop, mean, chol))
        x[part], target[part], a = accept(xs, target[part], prop, prop_target, log_ratio, rng)
        accepted += a
    return x, target, accepted


def pair_scale(x, target, log_target: LogTarget, rng: np.random.Generator, draw_scale: Callable, log_attempt=None):
    """Disjoint random pairs (x_i, x_j) keep their midpoint m and scale their half-difference by s:
    c1 = m + s (x_i - x_j) / 2, c2 = m - s (x_i - x_j) / 2 (simulated binary crossover with s = beta, the
    arithmetic crossover with s = 2a - 1). For a law of s with p(1/s) = s^2 p(s) (SBX's; the arithmetic one
    with its inverse added), the Hastings ratio is |s|^d pi(c1) pi(c2) / (pi(x_i) pi(x_j)). With
    `log_attempt(target_a, target_b)`, a pair is crossed only with that probability (AGA-PF's adaptive
    crossover) and the ratio carries attempt(children) / attempt(parents)."""
    n, d = x.shape
    x, target = x.copy(), target.copy()
    order = rng.permutation(n)
    i, j = order[0: 2 * (n // 2): 2], order[1: 2 * (n // 2): 2]
    s = draw_scale(i.size)
    half = 0.5 * (x[i] - x[j])
    m = 0.5 * (x[i] + x[j])
    c1, c2 = m + s[:, None] * half, m - s[:, None] * half
    t1, t2 = log_target(c1, i), log_target(c2, j)
    log_ratio = d * np.log(np.abs(s)) + t1 + t2 - target[i] - target[j]
    if log_attempt is not None:
        forward = log_attempt(target[i], target[j])
        tried = np.log(rng.random(i.size)) < forward
        log_ratio = np.where(tried, log_ratio + log_attempt(t1, t2) - forward, -np.inf)
    take = accepted(log_ratio, rng)
    x[i[take]], x[j[take]] = c1[take], c2[take]
    target[i[take]], target[j[take]] = t1[take], t2[take]
    return x, target, 2 * int(take.sum())


def multiple_try(x, target, log_target: LogTarget, rng: np.random.Generator, tries: int, chol: np.ndarray):
    """Multiple-try Metropolis (Liu, Liang, Wong 2000) with a symmetric Gaussian look: `tries` looks around each
    particle, one picked in proportion to pi, `tries - 1` reference looks around the pick plus the particle
    itself; accept with sum pi(looks) / sum pi(references)."""
    n, d = x.shape
    looks = x[:, None, :] + rng.standard_normal((n, tries, d)) @ chol.T
    look_t = log_target(looks.reshape(-1, d), np.repeat(np.arange(n), tries)).reshape(n, tries)
    finite = np.isfinite(look_t).any(axis=1)
    top = np.where(finite, np.max(np.where(np.isfinite(look_t), look_t, -np.inf), axis=1), 0.0)
    w = np.exp(np.where(np.isfinite(look_t), look_t, -np.inf) - top[:, None])
    w_sum = w.sum(axis=1)
    cum = np.cumsum(w, axis=1) / np.where(w_sum > 0, w_sum, 1.0)[:, None]
    pick = np.minimum((cum < rng.random(n)[:, None]).sum(axis=1), tries - 1)
    y, y_t = looks[np.arange(n), pick], look_t[np.arange(n), pick]
    refs = y[:, None, :] + rng.standard_normal((n, tries - 1, d)) @ chol.T
    ref_t = log_target(refs.reshape(-1, d), np.repeat(np.arange(n), tries - 1)).reshape(n, tries - 1)
    ref_all = np.concatenate([ref_t, target[:, None]], axis=1)
    ref_all = np.where(np.isfinite(ref_all), ref_all, -np.inf)
    # each side's sum about its own top: the references may lie far above the looks (all looks poor), where one
    # shared top overflowed exp
    ref_top = np.max(ref_all, axis=1)
    ref_top = np.where(np.isfinite(ref_top), ref_top, 0.0)
    ref_w = np.exp(ref_all - ref_top[:, None]).sum(axis=1)
    with np.errstate(divide="ignore"):
        log_ratio = np.where(finite & (w_sum > 0), top + np.log(w_sum) - ref_top - np.log(ref_w), -np.inf)
    return accept(x, target, y, y_t, log_ratio, rng)
