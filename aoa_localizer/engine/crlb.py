"""Cramer-Rao lower bound of a static emitter seen through bearings (docs/benchmarks.md), and consistency scores."""
from __future__ import annotations

import numpy as np

from aoa_localizer.engine.distributions import chi2_ppf, norm_ppf

# Scale of the 95 % error ellipse for 2 degrees of freedom: x^T P^-1 x <= 5.991.
ELLIPSE_95 = float(chi2_ppf(0.95, 2))
ELLIPSE_50 = float(chi2_ppf(0.5, 2))


def fisher_information(emitter, sensors, sigmas) -> np.ndarray:
    """J = sum_k 1/(sigma_k^2 r_k^2) [sin^2 t, -sin t cos t; -sin t cos t, cos^2 t] over the bearings used."""
    d = np.asarray(emitter, float) - np.asarray(sensors, float)
    r2 = np.sum(d * d, axis=1)
    t = np.arctan2(d[:, 1], d[:, 0])
    g = np.stack([-np.sin(t), np.cos(t)], axis=1) / np.sqrt(r2)[:, None]  # gradient of the bearing
    w = 1.0 / np.asarray(sigmas, float) ** 2
    return (g * w[:, None]).T @ g


def crlb_rmse(emitter, sensors, sigmas) -> float:
    """sqrt(trace(J^-1)): the RMSE no unbiased estimator beats (inf when J is singular)."""
    j = fisher_information(emitter, sensors, sigmas)
    if np.linalg.cond(j) > 1e12:
        return float("inf")
    return float(np.sqrt(np.trace(np.linalg.inv(j))))


def crlb_so_far(truth, sensors, sigmas, stamps, at) -> np.ndarray:
    """CRLB of the readings stamped up to each time in `at` (stamps sorted; cumulative Fisher information,
    inf while it is singular)."""
    d = np.asarray(truth, float) - np.asarray(sensors, float)
    r2 = np.sum(d * d, axis=1)
    t = np.arctan2(d[:, 1], d[:, 0])
    g = np.stack([-np.sin(t), np.cos(t)], axis=1) / np.sqrt(r2)[:, None]
    cum = np.cumsum(np.einsum("ki,kj->kij", g / np.asarray(sigmas)[:, None] ** 2, g), axis=0)
    out = np.full(len(at), np.inf)
    idx = np.searchsorted(np.asarray(stamps), np.asarray(at), side="right") - 1
    for i, k in enumerate(idx):
        if k >= 0 and np.linalg.cond(cum[k]) < 1e12:
            out[i] = float(np.sqrt(np.trace(np.linalg.inv(cum[k]))))
    return out


def nees(error, cov) -> float:
    """Normalised estimation error squared e^T P^-1 e (mean 2 for an honest 2-D filter); inf for a collapsed
    (singular) covariance that does not hold the error."""
    e = np.asarray(error, float)
    try:
        return float(e @ np.linalg.solve(np.asarray(cov, float), e))
    except np.linalg.LinAlgError:
        return 0.0 if not e.any() else float("inf")


def inside_ellipse(error, cov, level_chi2: float = ELLIPSE_95) -> bool:
    """Whether the truth lies inside the published ellipse."""
    return nees(error, cov) <= level_chi2


def ellipse_points(mean, cov, scale: float = ELLIPSE_95, n: int = 64) -> np.ndarray:
    """Closed polygon (n+1, 2) of the ellipse x^T cov^-1 x = scale around mean (the 95 % ellipse by default)."""
    vals, vecs = np.linalg.eigh(np.asarray(cov, float))
    a = np.linspace(0.0, 2 * np.pi, n + 1)
    unit = np.stack([np.cos(a), np.sin(a)], axis=1) * np.sqrt(scale * np.maximum(vals, 0.0))
    ring = np.asarray(mean, float) + unit @ vecs.T
    ring[-1] = ring[0]  # exactly closed
    return ring


def ellipse_axes(cov, scale: float = ELLIPSE_95) -> tuple[float, float, float]:
    """Semi-major and semi-minor axes (m) and the major axis's azimuth (deg from north, 0-180) of the ellipse."""
    vals, vecs = np.linalg.eigh(np.asarray(cov, float))
    major = vecs[:, 1]
    azimuth = float(np.degrees(np.arctan2(major[0], major[1])) % 180.0)
    return float(np.sqrt(scale * max(vals[1], 0.0))), float(np.sqrt(scale * max(vals[0], 0.0))), azimuth


_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(64)


def circular_error(cov, p: float = 0.9) -> float:
    """The radius (m) of the circle about the estimate that holds probability `p` of a Gaussian with covariance
    `cov` (CE90 for p = 0.9, CoT's `ce`): the root of P(l1 z1^2 + l2 z2^2 <= r^2) = p over the eigenvalues l1 >= l2,
    by Gauss-Legendre over z1. A circle's sigma gives sqrt(2 ln 10) sigma = 2.146 sigma; a line's 1.645 sigma."""
    from scipy.optimize import brentq
    from scipy.special import erf

    l2, l1 = (max(float(v), 0.0) for v in np.linalg.eigvalsh(np.asarray(cov, float)))
    if l1 <= 0.0:
        return 0.0
    if l2 <= 1e-12 * l1:  # a line: its two-sided quantile
        return float(norm_ppf(0.5 + p / 2.0) * np.sqrt(l1))

    def held(r: float) -> float:
        top = r / np.sqrt(l1)
        z1 = 0.5 * top * (_NODES + 1.0)
        inner = np.sqrt(np.maximum(r * r - l1 * z1 * z1, 0.0) / (2.0 * l2))
        return float(top * np.sum(_WEIGHTS * np.exp(-0.5 * z1 * z1) * erf(inner)) / np.sqrt(2.0 * np.pi)) - p

    return float(brentq(held, 0.0, 10.0 * np.sqrt(l1 + l2)))


def ou_transition(dt: float, speed: float, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) of a state [east, north, v_east, v_north] over dt when the velocity is an Ornstein-Uhlenbeck process
    (stationary sd `speed` per axis, correlation time `tau`) and the place its integral: the exact discretisation."""
    a = np.exp(-dt / tau)
    b = tau * (1.0 - a)
    s2 = speed * speed
    qvv = s2 * (1.0 - a * a)
    qxv = s2 * tau * (1.0 - a) ** 2
    qxx = s2 * tau * tau * (2.0 * dt / tau - 3.0 + 4.0 * a - a * a)
    eye = np.eye(2)
    f = np.block([[eye, b * eye], [np.zeros((2, 2)), a * eye]])
    q = np.block([[qxx * eye, qxv * eye], [qxv * eye, qvv * eye]])
    return f, q


def pcrb_moving(truth, sensors, sigmas, stamps, speed: float, tau: float, prior_sd_m: float = 1000.0) -> np.ndarray:
    """The posterior Cramer-Rao bound (Tichavsky, Muravchik and Nehorai 1998, the recursive information form) of a
    moving transmitter's place after each reading: `truth` (K, 2) its place at each reading's stamp, the readings'
    antennas, sigmas (rad) and stamps, the motion an OU velocity (ou_transition); the measurement's information
    taken at the true state. Returns the bound's RMSE (m) of the place after each reading."""
    truth, sensors = np.asarray(truth, float), np.asarray(sensors, float)
    sigmas, stamps = np.asarray(sigmas, float), np.asarray(stamps, float)
    info = np.diag([prior_sd_m ** -2, prior_sd_m ** -2, speed ** -2, speed ** -2])
    out = np.empty(len(stamps))
    for k in range(len(stamps)):
        if k:
            f, q = ou_transition(max(0.0, stamps[k] - stamps[k - 1]), speed, tau)
            info = np.linalg.inv(q + f @ np.linalg.solve(info, f.T))
        d = truth[k] - sensors[k]
        r2 = float(d @ d)
        h = np.array([-d[1] / r2, d[0] / r2, 0.0, 0.0])
        info = info + np.outer(h, h) / sigmas[k] ** 2
        out[k] = float(np.sqrt(np.trace(np.linalg.inv(info)[:2, :2])))
    return out
