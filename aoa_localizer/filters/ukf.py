"""An unscented Kalman filter for many Gaussians at once (one per particle): one batched sigma-point pass
for all N means and covariances, additive noise, and angle components handled with wrapped innovations
and circular means (UPF-DE paper sec. 3.3, the proposal of the unscented particle filter)."""
from __future__ import annotations

import numpy as np

_JITTER = 1e-12


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


class BatchedUKF:
    """Sigma points with scaling alpha, beta, kappa (Julier/Wan-van der Merwe); `angles` marks measurement
    components that are angles."""

    def __init__(self, dim: int, alpha: float = 1.0, beta: float = 2.0, kappa: float | None = None):
        self.d = dim
        kappa = 3.0 - dim if kappa is None else kappa
        self.lam = alpha**2 * (dim + kappa) - dim
        n = 2 * dim + 1
        self.wm = np.full(n, 1.0 / (2 * (dim + self.lam)))
        self.wc = self.wm.copy()
        self.wm[0] = self.lam / (dim + self.lam)
        self.wc[0] = self.wm[0] + 1 - alpha**2 + beta

    def sigma_points(self, m: np.ndarray, P: np.ndarray) -> np.ndarray:
        """(N, 2d+1, d) sigma points of N Gaussians (m (N, d), P (N, d, d))."""
        L = np.linalg.cholesky((self.d + self.lam) * P + _JITTER * np.eye(self.d))
        cols = np.swapaxes(L, 1, 2)  # rows of L^T are the columns of L
        return np.concatenate([m[:, None, :], m[:, None, :] + cols, m[:, None, :] - cols], axis=1)

    def predict(self, m, P, f, Q):
        """Time update through f (vectorised over (..., d)) plus additive noise covariance Q."""
        Y = f(self.sigma_points(m, P))
        mean = np.einsum("s,nsd->nd", self.wm, Y)
        dY = Y - mean[:, None, :]
        return mean, np.einsum("s,nsi,nsj->nij", self.wc, dY, dY) + Q

    def update(self, m, P, h, R, z, angles=None):
        """Measurement update with z for every Gaussian; returns the posterior means and covariances."""
        X = self.sigma_points(m, P)
        Z = h(X)  # (N, 2d+1, k)
        k = Z.shape[-1]
        angles = np.zeros(k, bool) if angles is None else np.asarray(angles, bool)
        zhat = np.einsum("s,nsk->nk", self.wm, Z)
        if angles.any():
            circ = np.arctan2(np.einsum("s,nsk->nk", self.wm, np.sin(Z)), np.einsum("s,nsk->nk", self.wm, np.cos(Z)))
            zhat = np.where(angles, circ, zhat)
        dZ = Z - zhat[:, None, :]
        dZ = np.where(angles, _wrap(dZ), dZ)
        dX = X - m[:, None, :]
        S = np.einsum("s,nsi,nsj->nij", self.wc, dZ, dZ) + R
        Pxz = np.einsum("s,nsi,nsj->nij", self.wc, dX, dZ)
        K = np.linalg.solve(np.swapaxes(S, 1, 2), np.swapaxes(Pxz, 1, 2)).swapaxes(1, 2)  # Pxz S^-1
        innov = np.asarray(z, float) - zhat
        innov = np.where(angles, _wrap(innov), innov)
        mean = m + np.einsum("nij,nj->ni", K, innov)
        cov = P - np.einsum("nij,njk,nlk->nil", K, S, K)
        return mean, 0.5 * (cov + np.swapaxes(cov, 1, 2))


def gauss_logpdf(x: np.ndarray, m: np.ndarray, P: np.ndarray) -> np.ndarray:
    """log N(x; m, P) row by row (x, m (N, d); P (N, d, d))."""
    d = x.shape[1]
    L = np.linalg.cholesky(P + _JITTER * np.eye(d))
    sol = np.linalg.solve(L, (x - m)[..., None])[..., 0]
    return (
        -0.5 * np.sum(sol**2, axis=1)
        - np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
        - 0.5 * d * np.log(2 * np.pi)
    )
