"""Global search of the robust emitter posterior: every mode of p(x | all kept points), not just the nearest.

A static emitter has a 2-D posterior, so it can be searched whole. The robust (mixture) log posterior is
scored on a polar grid around the track, log-spaced in range (metres to hundreds of kilometres); each
bearing's variance is widened by the cell's size as seen from its antenna, so a peak narrower than a
cell is not missed between cell centres. The best local maxima are refined by iteratively re-weighted
Gauss-Newton (the mixture's EM weights, with the widening annealed to zero), and each refined mode gets
its Laplace approximation: mean, covariance, log posterior and log mass. The Localizer starts from these
modes, the safety layer proposes from them, and the benchmark uses the best one as its batch reference.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from aoa_localizer.engine.geodesy import TWO_PI
from aoa_localizer.engine.inference.receiver import NoiseGrid, em_weights, given_log_densities, log_densities, log_sum
from aoa_localizer.engine.scheduling.slices import PIECE_EVALUATIONS, RESIDUALS, metered

_LOG_SQRT_2PI = 0.5 * math.log(TWO_PI)
# Grid: azimuth cells, log-range cells, and the range span relative to the track's extent.
_N_AZ, _N_R = 72, 44
_R_MIN_FACTOR, _R_MAX_FACTOR = 0.01, 200.0
_R_MIN_M, _R_MAX_M = 1.0, 5000.0
_MAX_GRID_POINTS = 120
_MAX_STARTS = 6  # local maxima refined
# Widening of the bearings' variance by the cell size, annealed to zero over the refinement.
_ANNEAL = (1.0, 0.3, 0.1, 0.03, 0.01, 0.0)
_ITER_PER_STAGE = 3
_POLISH_ITERATIONS = 6  # from a start already near its mode
_STEPS = np.array([1.0, 0.5, 0.2])
_MERGE_MAHALANOBIS2 = 9.0
_MIN_STEP_LIMIT_M = 100.0


@dataclass
class Points:
    """Observation points as arrays: antenna east/north (m), bearing theta (ENU rad), its sigma (rad), and the
    antenna position's own sigma (m, from the fixes; 0 when not known)."""

    east: np.ndarray
    north: np.ndarray
    theta: np.ndarray
    sigma: np.ndarray
    gps: np.ndarray = field(default_factory=lambda: np.zeros(()))  # a scalar broadcasts to every point

    def __post_init__(self):
        self.cos, self.sin = np.cos(self.theta), np.sin(self.theta)
        self.gps = np.broadcast_to(np.asarray(self.gps, float), self.east.shape)

    @classmethod
    def of(cls, rows: np.ndarray) -> Points:
        """From a (K, 5) array of east, north, theta, sigma, gps sigma (the emitter model's history)."""
        rows = np.asarray(rows, float).reshape(-1, 5)
        return cls(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4])

    def rows(self) -> np.ndarray:
        """The (K, 5) array `of` reads."""
        return np.column_stack([self.east, self.north, self.theta, self.sigma, self.gps])

    def __len__(self) -> int:
        return self.east.size

    def take(self, idx) -> Points:
        return Points(self.east[idx], self.north[idx], self.theta[idx], self.sigma[idx], self.gps[idx])

    def gps_var(self, rob: Robust) -> np.ndarray:
        """Variance of each antenna position (m^2): configured and per point."""
        return rob.gps_sigma_m**2 + self.gps**2


# The radio-range prior's scale: this many times the antennas' spread, at least this many metres (a transmitter a
# DF receiver hears is often kilometres away; at 100 m a short baseline's posterior kept an emitter 1.4 km out along
# its ray under 3 % of its mass)
REACH_FACTOR, REACH_MIN_M = 2.0, 1000.0


def radio_reach(antennas: np.ndarray) -> tuple[float, float, float]:
    """The radio-range prior (Robust.reach) of antennas at `antennas` (K, 2) east, north: centred on them, its scale
    REACH_FACTOR times their spread, at least REACH_MIN_M."""
    centre = antennas.mean(axis=0)
    spread = float(np.max(np.hypot(*(antennas - centre).T)))
    return float(centre[0]), float(centre[1]), max(REACH_MIN_M, REACH_FACTOR * spread)


@dataclass(frozen=True)
class Robust:
    """What the robust posterior needs besides the points: the outlier share, GPS noise, the prior, and the latent
    noise hypotheses while the receiver's noise is not known (then `outlier_prob` is not used: each hypothesis has
    its own share)."""

    outlier_prob: float
    gps_sigma_m: float = 0.0
    prior_mean: np.ndarray | None = None
    prior_prec: np.ndarray | None = None
    grid: NoiseGrid | None = None
    # The emitter is within radio range of where its bearings were taken: a 2-D Student-t prior (one degree of
    # freedom) at the antennas' centroid, (centre east, centre north, scale m); None: none
    reach: tuple[float, float, float] | None = None


@dataclass
class Mode:
    """One mode of the posterior: Laplace mean and covariance, log posterior at the mean, log mass,
    the number of points it explains (EM weight > 1/2) and the steepest crossing among those points."""

    mean: np.ndarray
    cov: np.ndarray
    log_post: float
    log_mass: float
    inliers: int
    crossing_deg: float


@metered(RESIDUALS, lambda x, pts: math.prod(np.shape(x)[:-1]) * np.size(pts.east))
def _residuals(x: np.ndarray, pts: Points):
    """Residuals theta - bearing(x) in (-pi, pi] (the angle from the antenna->x direction to the measured one,
    no wrapping needed), offsets dx, dy and squared ranges, for x of shape (..., 2) against the K points."""
    dx = x[..., None, 0] - pts.east
    dy = x[..., None, 1] - pts.north
    c, s = pts.cos, pts.sin
    resid = np.arctan2(dx * s - dy * c, dx * c + dy * s)
    return resid, dx, dy, np.maximum(dx * dx + dy * dy, 1e-6)


def cell_widening(cells: np.ndarray, radius: np.ndarray, pts: Points) -> np.ndarray:
    """Each bearing's variance added at a polar grid's cells (A, R, 2) of radius (R,): the cell's radius seen from
    the point's antenna, squared (A, R, K), so a peak narrower than a cell is not missed between centres."""
    dx = cells[..., None, 0] - pts.east
    dy = cells[..., None, 1] - pts.north
    return (radius[None, :, None] ** 2) / np.maximum(dx * dx + dy * dy, 1e-6)


def residuals(x, pts: Points) -> np.ndarray:
    """theta - bearing(x) of every point (rad, in (-pi, pi]) at one place x (2,)."""
    return _residuals(np.asarray(x, float), pts)[0]


def _geometry(x: np.ndarray, pts: Points):
    """Residuals, squared ranges, and the bearing's gradient d bearing / d x (..., K, 2)."""
    resid, dx, dy, r2 = _residuals(x, pts)
    return resid, r2, np.stack([-dy / r2, dx / r2], axis=-1)


def _terms(resid, var, eps: float):
    """Per-point log mixture density and EM inlier weight."""
    g = -0.5 * resid**2 / var - 0.5 * np.log(var) - _LOG_SQRT_2PI + math.log1p(-eps)
    if eps <= 0:
        return g, np.ones_like(g)
    ll = np.logaddexp(g, math.log(eps / TWO_PI))
    return ll, np.exp(g - ll)


def _weights(resid, sigma2, extras: tuple, rob: Robust):
    """EM precision weights (inlier / variance) and inlier weights of each point: under the fixed noise, or as
    expectations over the latent noise's posterior at each place. `extras`: variances added to the points' own
    (antenna position, smoothing), which the noise scale does not multiply."""
    extra = sum(extras[1:], extras[0])
    if rob.grid is not None:
        _, prec, gamma = em_weights(resid, sigma2, extra, rob.grid)
        return prec, gamma
    var = sigma2
    for e in extras:  # in this order: the fixed-noise sums stay the same to the last bit
        var = var + e
    gamma = _terms(resid, var, rob.outlier_prob)[1]
    return gamma / var, gamma


def linearised(x: np.ndarray, pts: Points, rob: Robust):
    """At places x (..., 2): the points' residuals (..., K), the bearings' gradients d bearing / d x (..., K, 2),
    the EM precision weights and the EM inlier weights (..., K): what a Gauss-Newton step and a Laplace
    approximation need."""
    resid, r2, grad = _geometry(x, pts)
    w, gamma = _weights(resid, pts.sigma**2, (pts.gps_var(rob) / np.maximum(r2, 1.0),), rob)
    return resid, grad, w, gamma


def inlier_share(x: np.ndarray, pts: Points, rob: Robust) -> float:
    """Share of the points whose EM inlier weight at the place x (2,) is above one half."""
    return float(np.mean(linearised(np.asarray(x, float), pts, rob)[3] > 0.5))


def reach_log_prior(x: np.ndarray, reach: tuple[float, float, float]) -> np.ndarray:
    """log of the 2-D Student-t (nu = 1) density at x (..., 2) up to a constant: (1 + d^2 / scale^2)^(-3/2)."""
    d2 = np.square(x[..., 0] - reach[0]) + np.square(x[..., 1] - reach[1])
    return -1.5 * np.log1p(d2 / reach[2] ** 2)


def _prior(x: np.ndarray, rob: Robust):
    lp = 0.0 if rob.reach is None else reach_log_prior(x, rob.reach)
    if rob.prior_prec is None:
        return lp
    d = x - rob.prior_mean
    return lp - 0.5 * np.einsum("...i,ij,...j->...", d, rob.prior_prec, d)


def log_posterior(x: np.ndarray, pts: Points, rob: Robust, widen2=0.0) -> np.ndarray:
    """Robust log posterior (up to a constant) at x (..., 2); `widen2` (..., K) adds to each bearing variance."""
    return from_sums(summed_log_densities(x, pts, rob, widen2), x, rob)


def summed_log_densities(x: np.ndarray, pts: Points, rob: Robust, widen2=0.0) -> np.ndarray:
    """The part of the log posterior at x (..., 2) that adds up over the points: their bearings' log densities
    summed, per latent-noise hypothesis (..., H) under rob.grid, else (...). Sums over two sets of points add."""
    if rob.grid is not None:
        return latent_log_densities(x, pts, rob, widen2)
    return point_log_densities(x, pts, rob, widen2).sum(axis=-1)


def point_log_densities(x: np.ndarray, pts: Points, rob: Robust, widen2=0.0) -> np.ndarray:
    """Each point's bearing log density at x (..., K), the noise taken as it is (rob.grid not read)."""
    resid, _, _, r2 = _residuals(x, pts)
    gps_var = pts.gps_var(rob)
    var = pts.sigma**2 + widen2
    if np.any(gps_var):
        var = var + gps_var / np.maximum(r2, 1.0)
    ll, _ = _terms(resid, var, rob.outlier_prob)
    return ll


def from_sums(sums: np.ndarray, x: np.ndarray, rob: Robust) -> np.ndarray:
    """The log posterior at x (..., 2) from summed_log_densities' sums over all the points."""
    return (sums if rob.grid is None else log_sum(sums, rob.grid)) + _prior(x, rob)


def latent_log_densities(x: np.ndarray, pts: Points, rob: Robust, widen2=0.0) -> np.ndarray:
    """Under the latent noise (rob.grid): sum over the points of each bearing's log density per hypothesis at x,
    (..., H) (receiver.log_densities); log_posterior is their log_sum plus the prior on x."""
    assert rob.grid is not None
    resid, extra = _unscaled(x, pts, rob, widen2)
    return log_densities(resid, pts.sigma**2, extra, rob.grid)


def _unscaled(x: np.ndarray, pts: Points, rob: Robust, widen2=0.0) -> tuple[np.ndarray, np.ndarray | float]:
    """The residuals at x (..., K) and the part of each bearing's variance a noise hypothesis does not scale: the
    antenna position's, seen from x, plus `widen2`."""
    resid, _, _, r2 = _residuals(x, pts)
    gps_var = pts.gps_var(rob)
    return resid, (widen2 + gps_var / np.maximum(r2, 1.0) if np.any(gps_var) else widen2)


def hypotheses_log_joint(x: np.ndarray, pts: Points, rob: Robust) -> np.ndarray:
    """Under the latent noise: log p(x, h | points) per hypothesis h, (M, H) for x (M, 2), up to log_posterior's
    constant (its log-sum-exp over h is log_posterior): what a Gibbs draw of each particle's hypothesis needs."""
    assert rob.grid is not None
    return latent_log_densities(x, pts, rob) + rob.grid.log_prior + np.asarray(_prior(x, rob))[..., None]


def log_posterior_given(x: np.ndarray, pts: Points, rob: Robust, h: np.ndarray) -> np.ndarray:
    """hypotheses_log_joint's column h[i] at each row x[i] (M, 2): the posterior of x given its noise hypothesis,
    for moves on the posterior of place and noise together."""
    assert rob.grid is not None
    resid, extra = _unscaled(x, pts, rob)
    return given_log_densities(resid, pts.sigma**2, extra, rob.grid, h) + rob.grid.log_prior[h] + _prior(x, rob)


def extent_from(centre: np.ndarray, pts: Points) -> float:
    """How far the points reach from `centre` (at least 10 m): the scale a polar grid there is laid for."""
    return max(10.0, float(np.max(np.hypot(pts.east - centre[0], pts.north - centre[1]))))


def polar_grid(pts: Points) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """The polar grid a search lays for `pts`: its centre (their mean place), extent (extent_from), cells and cell
    radius (grid_around)."""
    centre = np.array([pts.east.mean(), pts.north.mean()])
    extent = extent_from(centre, pts)
    return (centre, extent, *grid_around(centre, extent))


def grid_around(centre: np.ndarray, extent: float) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres (A, R, 2) and the cell radius (R,) of the polar grid at `centre` for points within `extent`:
    log-spaced in range from a hundredth of the extent to 200 times it (at least _R_MIN_M to _R_MAX_M)."""
    r_lo = max(_R_MIN_M, _R_MIN_FACTOR * extent)
    r_hi = max(_R_MAX_M, _R_MAX_FACTOR * extent)
    log_r = np.linspace(math.log(r_lo), math.log(r_hi), _N_R)
    az = (np.arange(_N_AZ) + 0.5) * TWO_PI / _N_AZ
    d_log = log_r[1] - log_r[0]
    r = np.exp(log_r)
    cells = centre + r[None, :, None] * np.stack([np.cos(az)[:, None] + 0 * r, np.sin(az)[:, None] + 0 * r], axis=-1)
    radius = 0.5 * r * math.hypot(TWO_PI / _N_AZ, d_log)
    return cells, radius


def _local_maxima(score: np.ndarray) -> np.ndarray:
    """Flat indices of cells at least as good as their 8 neighbours (azimuth wraps), best first."""
    padded = np.pad(score, ((1, 1), (0, 0)), mode="wrap")
    padded = np.pad(padded, ((0, 0), (1, 1)), constant_values=-np.inf)
    best = np.ones(score.shape, dtype=bool)
    a, r = score.shape
    for da in (-1, 0, 1):
        for dr in (-1, 0, 1):
            if da or dr:
                best &= score >= padded[1 + da:1 + da + a, 1 + dr:1 + dr + r]
    idx = np.flatnonzero(best & np.isfinite(score))
    return idx[np.argsort(-score.ravel()[idx])]


def refine(starts: np.ndarray, widen: np.ndarray, pts: Points, rob: Robust
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IRLS Gauss-Newton from each start (M, 2), annealing the widening radius (M,) to zero.

    Returns means (M, 2), covariances (M, 2, 2) (the Laplace approximation, inverse of the EM-weighted
    information plus the prior's precision) and EM inlier weights (M, K).
    """
    x = np.array(starts, float)
    widen = np.asarray(widen, float)
    prec = rob.prior_prec if rob.prior_prec is not None else np.zeros((2, 2))
    levels = _ANNEAL if widen.any() else _ANNEAL[-1:]  # nothing to anneal from a start next to its mode
    for level in levels:
        # A start whose step stayed put would stay put again at this level (the same place, the same sums): only
        # the starts still moving take the level's further steps.
        moving = np.arange(x.shape[0])
        for _ in range(_ITER_PER_STAGE if len(levels) > 1 else _POLISH_ITERATIONS):
            stepped = _gn_step(x[moving], pts, rob, level * widen[moving], prec)
            still = np.any(stepped != x[moving], axis=1)
            x[moving] = stepped
            moving = moving[still]
            if not moving.size:
                break
    _, grad, w, gamma = linearised(x, pts, rob)
    info = np.einsum("mk,mki,mkj->mij", w, grad, grad) + prec + 1e-12 * np.eye(2)
    return x, inverse_2x2(info), gamma


def inverse_2x2(a: np.ndarray) -> np.ndarray:
    """Inverses of a stack of symmetric 2x2 matrices in closed form (NaN where singular or not finite): a
    LAPACK call per small batch costs milliseconds here, this costs microseconds (a test checks it against
    numpy.linalg.inv)."""
    det = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
    good = np.isfinite(det) & (det > 0) & np.all(np.isfinite(a), axis=(1, 2))
    out = np.stack([np.stack([a[:, 1, 1], -a[:, 0, 1]], -1), np.stack([-a[:, 1, 0], a[:, 0, 0]], -1)], -2)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = out / det[:, None, None]
    out[~good] = np.nan
    return out


def _gn_step(x, pts: Points, rob: Robust, widen_m, prec):
    """One damped Gauss-Newton step with the EM weights from each place: the best of a few step lengths (or none)."""
    resid, r2, grad = _geometry(x, pts)
    w, _ = _weights(resid, pts.sigma**2, (pts.gps_var(rob) / np.maximum(r2, 1.0), (widen_m[:, None] ** 2) / r2),
                        rob)
    info = np.einsum("mk,mki,mkj->mij", w, grad, grad) + prec + 1e-9 * np.eye(2)
    info = np.where(np.isfinite(info), info, 0.0) + 1e-9 * np.eye(2)
    rhs = np.einsum("mk,mki->mi", w * resid, grad)
    if rob.prior_prec is not None:
        rhs = rhs - (x - rob.prior_mean) @ prec.T
    delta = np.einsum("mij,mj->mi", inverse_2x2(info), rhs)  # NaN where singular: no step (below)
    # Along a ray the bearing-only posterior is nearly flat: never step farther than the distance from the
    # points (plus a margin), so a nearly singular information cannot throw x to 1e150 m.
    reach = np.hypot(x[:, 0] - pts.east.mean(), x[:, 1] - pts.north.mean()) + _MIN_STEP_LIMIT_M
    length = np.linalg.norm(delta, axis=1)
    delta = delta * np.minimum(1.0, reach / np.maximum(length, 1e-300))[:, None]
    delta = np.where(np.isfinite(delta), delta, 0.0)
    trial = x[:, None, :] + _STEPS[None, :, None] * delta[:, None, :]
    cand = np.concatenate([x[:, None, :], trial], axis=1)  # step 0 = stay
    widen2 = (widen_m[:, None, None] ** 2) / _residuals(cand, pts)[3]
    lp = log_posterior(cand, pts, rob, widen2)
    pick = np.argmax(np.where(np.isfinite(lp), lp, -np.inf), axis=1)
    return cand[np.arange(x.shape[0]), pick]


def steepest_crossing_deg(x: np.ndarray, pts: Points, inlier: np.ndarray) -> float:
    """Largest angle (deg, 0-90) between two inlier bearing lines through x: how well x is determined."""
    phi = np.arctan2(x[1] - pts.north[inlier], x[0] - pts.east[inlier])
    if phi.size < 2:
        return 0.0
    c, s = np.cos(2 * phi), np.sin(2 * phi)  # lines: angles mod pi
    # Largest |sin(phi_i - phi_j)| over pairs = half the widest spread of the doubled angles.
    ang = np.sort(np.arctan2(s, c))
    gaps = np.diff(np.concatenate([ang, [ang[0] + TWO_PI]]))
    spread = TWO_PI - gaps.max()  # arc covered by the doubled angles
    return float(math.degrees(min(spread, math.pi) / 2))


def find_modes(pts: Points, rob: Robust, by_density: bool = False) -> list[Mode]:
    """All distinct modes of the robust posterior over `pts`, most massive first (empty for < 2 points).

    `by_density`: highest posterior density first. Under a flat prior (before the start) a far, poorly
    determined mode gains Laplace mass from its sheer size (the bearing-only posterior is improper along the
    rays), so the start ranks by density; once the prior is proper, mass is the right order."""
    if len(pts) < 2:
        return []
    coarse = pts
    if len(pts) > _MAX_GRID_POINTS:  # the coarse score is smoothed anyway: at most this many points, evenly spread
        coarse = pts.take(np.linspace(0, len(pts) - 1, _MAX_GRID_POINTS).round().astype(int))
    _, _, cells, radius = polar_grid(coarse)
    scored = coarse_robust(rob)
    sums = grid_sums(cells, radius, coarse, scored)
    return modes_from_grid(cells, radius, from_sums(sums, cells, scored), pts, rob, by_density)


def grid_sums(cells: np.ndarray, radius: np.ndarray, pts: Points, rob: Robust) -> np.ndarray:
    """summed_log_densities at a polar grid's cells (A, R, 2) of radius (R,) over `pts`, each bearing widened by the
    cell's size: PIECE_EVALUATIONS densities at a time (sums over sets of points add)."""
    per_point = cells.shape[0] * cells.shape[1] * (1 if rob.grid is None else rob.grid.scale.size)
    step = max(1, PIECE_EVALUATIONS // per_point)
    sums: np.ndarray | float = 0.0
    for lo in range(0, len(pts), step):
        part = pts.take(slice(lo, lo + step))
        sums = sums + summed_log_densities(cells, part, rob, cell_widening(cells, radius, part))
    return np.asarray(sums)


def coarse_robust(rob: Robust) -> Robust:
    """The grid's score only picks the starts: under a latent noise, a sixth of its hypotheses do (NoiseGrid.coarse)."""
    return rob if rob.grid is None else replace(rob, grid=rob.grid.coarse())


def modes_from_grid(cells: np.ndarray, radius: np.ndarray, score: np.ndarray, pts: Points, rob: Robust,
                    by_density: bool) -> list[Mode]:
    """find_modes from a polar grid's cells (A, R, 2), radius (R,) and coarse score (A, R): its best local maxima
    refined over `pts`, distinct, ordered as find_modes orders them."""
    top = _local_maxima(score)[:_MAX_STARTS]
    if top.size == 0:
        return []
    a_idx, r_idx = np.unravel_index(top, score.shape)
    means, covs, gamma = refine(cells[a_idx, r_idx], radius[r_idx], pts, rob)
    lp = log_posterior(means, pts, rob)
    modes: list[Mode] = []
    for m in np.argsort(-lp):
        if not (np.isfinite(lp[m]) and np.all(np.isfinite(means[m])) and np.all(np.isfinite(covs[m]))):
            continue
        sign, logdet = np.linalg.slogdet(covs[m])
        if sign <= 0:
            continue
        if any(_same(means[m], o) for o in modes):
            continue
        inlier = gamma[m] > 0.5
        if inlier.sum() < 2:  # a flat far-away "mode" that explains no bearing
            continue
        modes.append(
            Mode(
                means[m].copy(),
                covs[m].copy(),
                float(lp[m]),
                float(lp[m] + 0.5 * (logdet + 2 * math.log(TWO_PI))),
                int(inlier.sum()),
                steepest_crossing_deg(means[m], pts, inlier),
            )
        )
    modes.sort(key=lambda md: -(md.log_post if by_density else md.log_mass))
    return modes


def _same(x: np.ndarray, mode: Mode) -> bool:
    d = x - mode.mean
    return float(d @ np.linalg.solve(mode.cov, d)) < _MERGE_MAHALANOBIS2


def masses(modes: list[Mode]) -> np.ndarray:
    """Laplace masses of the modes, normalised to one."""
    lm = np.array([m.log_mass for m in modes])
    w = np.exp(lm - lm.max())
    return w / w.sum()
