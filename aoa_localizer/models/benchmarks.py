"""The seed papers' benchmark models as state-space models the filters run and the table script simulates.

Time: k = 1, 2, ... is the measurement index; the transition to x_k uses k (the papers' x_{k+1} = f(x_k, k)
is written here as x_k = f(x_{k-1}, k-1) through `k_offset`). Where a paper leaves something out
(initial state, its spread, Gamma parameterisation) the class says what we assume; docs/seed_tables.md
lists the assumptions per table.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .base import StateSpaceModel

_LOG_2PI = math.log(2 * math.pi)


def gauss_loglik(residual, var):
    return -0.5 * (residual**2 / var + math.log(var) + _LOG_2PI)


class BenchmarkModel(StateSpaceModel):
    """A model with a true initial state x0, the filters' initial spread p0, and a simulator."""

    x0: np.ndarray
    p0: np.ndarray  # initial covariance of the filters' particles (diagonal entries)

    def initial(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return self.x0 + np.sqrt(self.p0) * rng.standard_normal((n, self.dim))

    def measure(self, x: np.ndarray, k: int, rng: np.random.Generator):
        """Draw z_k for the true state x (shape (dim,))."""
        raise NotImplementedError

    def simulate(self, steps: int, rng: np.random.Generator, jump: tuple[int, float] | None = None):
        """True states x_0..x_T (T+1, dim) and measurements z_1..z_T; `jump` = (k, size) adds size to x_k."""
        xs, zs = [np.array(self.x0, float)], []
        for k in range(1, steps + 1):
            x = self.transition(xs[-1][None, :], k, rng)[0]
            if jump is not None and k == jump[0]:
                x = x + jump[1]
            xs.append(x)
            zs.append(self.measure(x, k, rng))
        return np.array(xs), zs


@dataclass
class GrowthModel(BenchmarkModel):
    """The univariate non-stationary growth model (UNGM) family:
    x_k = a x + b x/(1+x^2) + c cos(1.2 (k - k_offset)) + w, w ~ N(0, q); z = x^2/kappa + v, v ~ N(0, r)."""

    a: float = 0.5
    b: float = 25.0
    c: float = 8.0
    kappa: float = 20.0
    q: float = 10.0
    r: float = 1.0
    k_offset: int = 1
    x0_value: float = 0.1
    p0_value: float = 2.0

    def __post_init__(self):
        self.dim = 1
        self.x0, self.p0 = np.array([self.x0_value]), np.array([self.p0_value])

    def transition(self, x, k, rng):
        drift = self.a * x + self.b * x / (1 + x * x) + self.c * math.cos(1.2 * (k - self.k_offset))
        return drift + math.sqrt(self.q) * rng.standard_normal(x.shape)

    def loglik(self, x, z, k):
        return gauss_loglik(z - x[..., 0] ** 2 / self.kappa, self.r)

    def measure(self, x, k, rng):
        return float(x[0] ** 2 / self.kappa + math.sqrt(self.r) * rng.standard_normal())


@dataclass
class GammaSineModel(BenchmarkModel):
    """x_k = 1 + sin(omega pi (k - k_offset)) + phi x + w, w ~ Gamma(shape, rate);
    z = c1 x^2 + v for k <= switch_k, c2 x - d + v after it (switch_k None: always c1 x^2), v ~ N(0, r).

    Gamma(a, b) is read as shape a and rate b (scale 1/b), the convention of the unscented-PF
    literature these models come from; with it the state stays around 5, as the papers' figures show.
    """

    omega: float = 0.04
    phi: float = 0.5
    shape: float = 3.0
    rate: float = 2.0
    c1: float = 0.2
    c2: float = 0.5
    d: float = 2.0
    switch_k: int | None = 30
    r: float = 1e-5
    k_offset: int = 1
    x0_value: float = 1.0
    p0_value: float = 0.75

    def __post_init__(self):
        self.dim = 1
        self.x0, self.p0 = np.array([self.x0_value]), np.array([self.p0_value])

    def transition(self, x, k, rng):
        drift = 1.0 + math.sin(self.omega * math.pi * (k - self.k_offset)) + self.phi * x
        return drift + rng.gamma(self.shape, 1.0 / self.rate, size=x.shape)

    def h(self, x, k):
        if self.switch_k is None or k <= self.switch_k:
            return self.c1 * x**2
        return self.c2 * x - self.d

    def loglik(self, x, z, k):
        return gauss_loglik(z - self.h(x[..., 0], k), self.r)

    def measure(self, x, k, rng):
        return float(self.h(x[0], k) + math.sqrt(self.r) * rng.standard_normal())


@dataclass
class CoordinatedTurnModel(BenchmarkModel):
    """ESPF Model 3: state [x, vx, y, vy] (km, km/s), coordinated turn at omega rad/s, period t,
    white acceleration noise with covariance diag(q) through Gamma = [[t^2/2, 0], [t, 0], [0, t^2/2], [0, t]];
    z = [range, bearing atan2(y, x)] + v, v ~ N(0, diag(r)).

    The printed F has sin(omega t) where the standard turn model has sin(omega t)/omega in its first row
    (OCR); we use the standard one. Q = diag(0.3, 0.3) read in km^2 s^-4 would throw the target hundreds of
    km off course in 60 s (errors of kilometres, not the paper's 0.3 km); we read it in m^2 s^-4 against
    the state in km: 0.3e-6. The paper gives no initial spread: p0 below is ours."""

    omega: float = 0.0025
    t: float = 1.0
    q: tuple = (0.3e-6, 0.3e-6)
    r: tuple = (0.02, 0.05)
    start: tuple = (7.0, 0.08, 6.0, 0.05)
    p0_diag: tuple = (0.1, 0.001, 0.1, 0.001)

    def __post_init__(self):
        self.dim = 4
        self.x0, self.p0 = np.array(self.start), np.array(self.p0_diag)
        w, t = self.omega, self.t
        s, c = math.sin(w * t), math.cos(w * t)
        self.F = np.array([[1, s / w, 0, -(1 - c) / w], [0, c, 0, -s], [0, (1 - c) / w, 1, s / w], [0, s, 0, c]])
        self.G = np.array([[t * t / 2, 0], [t, 0], [0, t * t / 2], [0, t]])

    def transition(self, x, k, rng):
        noise = rng.standard_normal((x.shape[0], 2)) * np.sqrt(self.q)
        return x @ self.F.T + noise @ self.G.T

    def h(self, x):
        return np.stack([np.hypot(x[..., 0], x[..., 2]), np.arctan2(x[..., 2], x[..., 0])], axis=-1)

    def loglik(self, x, z, k):
        pred = self.h(x)
        dr = z[0] - pred[..., 0]
        db = (z[1] - pred[..., 1] + math.pi) % (2 * math.pi) - math.pi
        return gauss_loglik(dr, self.r[0]) + gauss_loglik(db, self.r[1])

    def measure(self, x, k, rng):
        return self.h(x) + np.sqrt(self.r) * rng.standard_normal(2)


# The papers' models, by table.
def espf_model1() -> GammaSineModel:
    """ESPF Model 1: x_{k+1} = 1 + sin(0.04 pi k) + 0.5 x_k + Gamma(8, 2); z = x^2/5 + N(0, 0.0045)."""
    return GammaSineModel(omega=0.04, phi=0.5, shape=8.0, rate=2.0, c1=0.2, switch_k=None, r=0.0045)


def espf_model2() -> GrowthModel:
    """ESPF Model 2 (UNGM): x_{k+1} = 0.5 x + 25 x/(1+x^2) + 8 cos(1.2 k) + N(0, 10); z = x^2/20 + N(0, 1)."""
    return GrowthModel(a=0.5, b=25.0, c=8.0, kappa=20.0, q=10.0, r=1.0)


def espf_model3() -> CoordinatedTurnModel:
    return CoordinatedTurnModel()


def gfapf_ungm() -> GrowthModel:
    """GFA-PF's UNGM: x_k = x + 12 x/(1+x^2) + 8 cos(1.2(k-1)) + N(0,1); z = x^2/20 + N(0,1); x0 = 0.5, P0 = 5."""
    return GrowthModel(a=1.0, b=12.0, c=8.0, kappa=20.0, q=1.0, r=1.0, x0_value=0.5, p0_value=5.0)


def gfapf_model1(r: float) -> GammaSineModel:
    """GFA-PF Model 1: Gamma(3, 2) noise, z = 0.2 x^2 (k <= 30), 0.5 x - 2 (k > 30), N(0, r); x0 = 0.5, P0 = 5."""
    return GammaSineModel(shape=3.0, rate=2.0, switch_k=30, r=r, x0_value=0.5, p0_value=5.0)
