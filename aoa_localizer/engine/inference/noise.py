"""Self-calibrated bearing noise: what the receiver's sigma(Q) and outlier rate really are, learned from its data.

The configured sigma model is the starting guess. Given the readings' residuals at the current estimate,
EM on the mixture (Gaussian inliers, uniform outliers on the circle) fits a scale factor k per quality
band (40-50, ..., 90-100, and one for unknown quality), so sigma(Q) = k(Q) x configured sigma(Q), with k
interpolated between band centres. Each band is shrunk towards a straight line in Q fitted across the bands
(weighted by their readings; the pooled scale when fewer than two bands have data), so a thin band borrows
from its neighbours without flattening a real slope. This
covers a receiver whose sigma is mis-stated by a constant factor, one whose noise depends on quality
while the config says constant, and one that reports no quality at all. EM starts from a robust scale
(1.4826 x median |residual|), from above, where it cannot lock onto a narrow core and call the rest wild.
"""
from __future__ import annotations

import bisect
import math

import numpy as np

from aoa_localizer.engine.geodesy import TWO_PI
from aoa_localizer.engine.scheduling.slices import EM_STEP, metered

BAND_EDGES = np.arange(40.0, 101.0, 10.0)  # quality bands; below 40 joins the first, NaN has its own
N_BANDS = BAND_EDGES.size - 1
UNKNOWN = N_BANDS  # index of the unknown-quality band
_CENTRES = 0.5 * (BAND_EDGES[:-1] + BAND_EDGES[1:])
_SHRINK_READINGS = 10.0  # pseudo-readings at the shrinkage target in every band
_MIN_READINGS = 40  # fewer readings: keep the current calibration
_EM_ITERATIONS = 25
_EM_TOL = 1e-7  # EM has converged once no log k^2 or outlier rate moves by more than this ...
_EM_MERGE = 1e-4  # ... and two runs this close go on as one
_K_RANGE = (0.05, 50.0)
HEADING_SCALES = (1.0, 0.5, 0.25, 0.0)  # shares of the stated heading variance tried; the best likelihood is kept
_HEADING_EVIDENCE = 3.0  # nats a share other than the whole must gain over it
OUTLIER_RANGE = (0.01, 0.6)
_MIDDLE_HALF_Z = 0.6745  # half of a Gaussian lies within this many sigmas
_HOLLOW_SHARE, _HOLLOW_MIN_WEIGHT = 0.25, 20.0  # a core with less than half its expected share is hollow


def band_of(quality: np.ndarray) -> np.ndarray:
    """Band index of each quality (UNKNOWN for NaN)."""
    q = np.asarray(quality, float)
    band = np.clip(((np.nan_to_num(q, nan=40.0) - 40.0) // 10.0).astype(int), 0, N_BANDS - 1)
    return np.where(np.isnan(q), UNKNOWN, band)


_CENTRE_LIST = _CENTRES.tolist()


def _interp_band(q: float, k: list[float]) -> float:
    """numpy.interp(q, band centres, k) for one quality, the same formula; the unknown band's k for NaN."""
    if q != q:
        return k[UNKNOWN]
    c = _CENTRE_LIST
    if q <= c[0]:
        return k[0]
    if q >= c[-1]:
        return k[N_BANDS - 1]
    j = bisect.bisect_right(c, q) - 1
    if q == c[j]:
        return k[j]
    return (k[j + 1] - k[j]) / (c[j + 1] - c[j]) * (q - c[j]) + k[j]


class NoiseModel:
    """Scale factors on the configured reading sigma, per quality band, and the reading outlier rate."""

    def __init__(self, outlier_prob: float):
        self.k = np.ones(N_BANDS + 1)
        self.reading_outlier_prob = outlier_prob
        self.fits = 0  # calibrations made
        self.readings = np.zeros(N_BANDS + 1)  # EM inlier weight per band at the last fit
        # The last fit's core is hollow: its inliers avoid the middle of their own Gaussian (a wide noise that
        # swallows two clusters of bearings either side of a place between two sources)
        self.hollow = False
        # The share of the heading's stated variance (the course over ground's, from the fixes) that the residuals
        # bear out: the course's sigma is a model's claim (its drift term a floor), and where it overstates the
        # heading's error the receiver's own scale would be driven to its floor to make room for it
        self.heading_scale = 1.0

    def scale(self, quality: np.ndarray) -> np.ndarray:
        """k(Q): interpolated between band centres for known quality, the unknown band's for NaN."""
        q = np.asarray(quality, float)
        unknown = np.isnan(q)
        known = np.interp(np.where(unknown, 40.0, q), _CENTRES, self.k[:N_BANDS])
        return np.where(unknown, self.k[UNKNOWN], known)

    def scales(self, quality: list[float]) -> list[float]:
        """scale() for a few readings in plain floats (a point's, per point); scale() is the reference."""
        k = self.k.tolist()
        return [_interp_band(q, k) for q in quality]

    def fit(self, resid: np.ndarray, quality: np.ndarray, base_sigma: np.ndarray,
            known_var: np.ndarray | None = None) -> float:
        """EM on reading residuals (rad) at a candidate emitter position; `known_var` (rad^2) is variance each
        residual has besides the receiver's (the heading a relative bearing was turned by), so it is not
        blamed on the receiver. Returns the log likelihood of the readings under the fitted model (NaN, nothing
        changed, with too few readings)."""
        resid, base_sigma = np.asarray(resid, float), np.asarray(base_sigma, float)
        known = np.zeros(resid.size) if known_var is None else np.asarray(known_var, float)
        ok = np.isfinite(resid) & np.isfinite(base_sigma) & (base_sigma > 0) & np.isfinite(known)
        if ok.sum() < _MIN_READINGS:
            return float("nan")
        resid, base_sigma, band = resid[ok], base_sigma[ok], band_of(np.asarray(quality, float)[ok])
        starts = self._starts(resid / base_sigma)
        best = (1.0, _em(resid, base_sigma, known[ok], band, starts))
        if _floored(*best[1][1:4:2]):
            # the statement left most readings no receiver noise of their own: how much of it do they bear out?
            for scale in HEADING_SCALES[1:]:
                fit = _em(resid, base_sigma, scale * known[ok], band, starts)
                if fit[0] > best[1][0] + (_HEADING_EVIDENCE if best[0] == 1.0 else 0.0):
                    best = (scale, fit)
        self.heading_scale, (ll, k2, eps, w, self.hollow) = best
        self.k = np.sqrt(k2)
        self.reading_outlier_prob = eps
        self.readings = w
        self.fits += 1
        return ll

    def copy(self) -> NoiseModel:
        other = NoiseModel(self.reading_outlier_prob)
        other.k, other.readings, other.fits, other.hollow = self.k.copy(), self.readings.copy(), self.fits, self.hollow
        other.heading_scale = self.heading_scale
        return other

    def _starts(self, z: np.ndarray) -> np.ndarray:
        """EM starting scales: the current one, the robust scale of the residuals, and a ladder from 1/4 to 32:
        the mixture's likelihood has local optima (a wide core that swallows a ghost's bearings, or a narrow one
        that calls good bearings wild), so the best of several runs is kept."""
        robust = 1.4826 * float(np.median(np.abs(z)))
        return np.array([float(np.median(self.k[:N_BANDS])), robust] + [2.0**e for e in range(-2, 6)])

    def summary(self, base_sigma_deg) -> dict:
        """Calibrated sigma (deg) per band that has data, keyed by the band's centre quality ("nan" for unknown),
        and the reading outlier rate. `base_sigma_deg(q)` is the configured sigma at quality q."""
        sig = {}
        for b in range(N_BANDS + 1):
            if self.readings[b] >= 1.0:
                q = float("nan") if b == UNKNOWN else float(_CENTRES[b])
                key = "nan" if b == UNKNOWN else f"{q:g}"
                sig[key] = round(float(self.k[b] * base_sigma_deg(q)), 3)
        out = {"sigma_deg": sig, "reading_outlier_prob": round(self.reading_outlier_prob, 4), "fits": self.fits}
        if self.heading_scale != 1.0:
            out["heading_variance_share"] = self.heading_scale
        return out


def _floored(k2: np.ndarray, weights: np.ndarray) -> bool:
    """Whether the bands holding most of the readings' weight have their scale at the floor."""
    low = k2 <= (2.0 * _K_RANGE[0]) ** 2
    return float(weights[low].sum()) > 0.5 * float(weights.sum())


def _em(resid: np.ndarray, base_sigma: np.ndarray, known_var: np.ndarray, band: np.ndarray, k0: np.ndarray,
        tol: float = _EM_TOL) -> tuple[float, np.ndarray, float, np.ndarray, bool]:
    """EM from each starting scale in k0 (S,), all at once. Returns the best run's (log likelihood, k^2 per band,
    outlier rate, inlier weight per band, whether its core is hollow); a run with a hollow core is the best only
    when every run's is. A residual's variance is k^2 base_sigma^2 + known_var; the M-step takes the known part
    off each squared residual (a moment step: unbiased, and exact EM when it is 0). Runs that reach one another
    (within _EM_MERGE) go on as one, and EM stops once no parameter moves by more than `tol` (0: every iteration,
    every run): the starts mostly meet within a few iterations, and the rest would repeat the same run."""
    z2_all, z2_known = (resid / base_sigma) ** 2, known_var / base_sigma**2
    z2 = z2_all - z2_known
    onehot = np.zeros((resid.size, N_BANDS + 1))
    onehot[np.arange(resid.size), band] = 1.0
    k2 = np.repeat(np.clip(k0, *_K_RANGE)[:, None] ** 2, N_BANDS + 1, axis=1)  # (S, B)
    eps = np.full((k0.size, 1), 0.2)
    for _ in range(_EM_ITERATIONS):
        gamma, _ = _responsibilities(resid, base_sigma, known_var, k2[:, band], eps)
        # the known variance taken off may leave a band's sum below 0: no receiver noise seen there
        w, s = gamma @ onehot, np.maximum((gamma * z2) @ onehot, 0.0)
        new_k2 = np.clip((s + _SHRINK_READINGS * _shrink_target(w, s)) / (w + _SHRINK_READINGS), _K_RANGE[0] ** 2,
                         _K_RANGE[1] ** 2)
        new_eps = np.clip(1.0 - gamma.mean(axis=1, keepdims=True), *OUTLIER_RANGE)
        moved = max(float(np.max(np.abs(np.log(new_k2 / k2)))), float(np.max(np.abs(new_eps - eps))))
        k2, eps = new_k2, new_eps
        if moved <= tol:
            break
        if tol > 0.0:
            k2, eps = _distinct_runs(k2, eps)
    gamma, dens = _responsibilities(resid, base_sigma, known_var, k2[:, band], eps)
    ll = np.log(dens).sum(axis=1)
    hollow = _hollow(gamma, z2_all / (k2[:, band] + z2_known))
    b = int(np.argmax(np.where(hollow & ~hollow.all(), -np.inf, ll)))
    return float(ll[b]), k2[b], float(eps[b, 0]), gamma[b] @ onehot, bool(hollow[b])


def _distinct_runs(k2: np.ndarray, eps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The runs that no earlier run has reached: every log k^2 and the outlier rate within _EM_MERGE of it."""
    close = (np.max(np.abs(np.log(k2[:, None, :] / k2[None, :, :])), axis=2) <= _EM_MERGE) & (
        np.abs(eps - eps.T) <= _EM_MERGE)
    keep = ~np.tril(close, -1).any(axis=1)
    return k2[keep], eps[keep]


def _hollow(gamma: np.ndarray, z2: np.ndarray) -> np.ndarray:
    """Per run (S,): whether the inliers avoid their Gaussian's middle half (|z| < 0.674 holds half of a Gaussian):
    fewer than _HOLLOW_SHARE of the inlier weight there, with at least _HOLLOW_MIN_WEIGHT of it."""
    weight = gamma.sum(axis=1)
    core = (gamma * (z2 < _MIDDLE_HALF_Z**2)).sum(axis=1)
    return (weight >= _HOLLOW_MIN_WEIGHT) & (core < _HOLLOW_SHARE * weight)


@metered(EM_STEP, lambda resid, base_sigma, known_var, k2_per_reading, eps: math.prod(np.broadcast_shapes(
    np.shape(resid), np.shape(base_sigma), np.shape(known_var), np.shape(k2_per_reading), np.shape(eps))))
def _responsibilities(resid, base_sigma, known_var, k2_per_reading, eps):
    """Inlier weights and mixture densities of the readings (S, n) under each run's scales and outlier rate."""
    var = k2_per_reading * base_sigma**2 + known_var
    g = (1 - eps) * np.exp(-0.5 * resid**2 / var) / np.sqrt(TWO_PI * var)
    dens = g + eps / TWO_PI
    return g / dens, dens


def _shrink_target(w: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Per run and band (S, B), the k^2 a thin band is shrunk towards: a line k(Q) over the quality bands weighted
    by their readings, pooled for the unknown band (and for all when fewer than two quality bands have readings)."""
    pooled = s.sum(axis=1, keepdims=True) / np.maximum(w.sum(axis=1, keepdims=True), 1e-12)
    target = np.repeat(pooled, N_BANDS + 1, axis=1)
    wq, sq = w[:, :N_BANDS], s[:, :N_BANDS]
    has = wq >= 1.0
    k = np.sqrt(np.where(has, sq / np.maximum(wq, 1e-12), 0.0))
    ww = np.where(has, np.sqrt(wq), 0.0)  # weights of the line fit
    sw, sx, sy = ww.sum(1), ww @ _CENTRES, (ww * k).sum(1)
    sxx, sxy = ww @ _CENTRES**2, (ww * k * _CENTRES).sum(1)
    det = sw * sxx - sx**2
    line = (has.sum(axis=1) >= 2) & (det > 1e-9)
    slope = np.where(line, (sw * sxy - sx * sy) / np.where(line, det, 1.0), 0.0)
    icpt = np.where(line, (sy - slope * sx) / np.maximum(sw, 1e-12), 0.0)
    fitted = np.maximum(icpt[:, None] + slope[:, None] * _CENTRES, _K_RANGE[0]) ** 2
    target[:, :N_BANDS] = np.where(line[:, None], fitted, target[:, :N_BANDS])
    unknown = w[:, UNKNOWN] >= 1.0
    target[:, UNKNOWN] = np.where(unknown, s[:, UNKNOWN] / np.maximum(w[:, UNKNOWN], 1e-12), target[:, UNKNOWN])
    return target


def point_outlier_prob(resid: np.ndarray, sigma: np.ndarray, current: float) -> float:
    """EM estimate of the share of observation points the likelihood should treat as wild (sigma fixed)."""
    resid, sigma = np.asarray(resid, float), np.asarray(sigma, float)
    if resid.size < 10:
        return current
    eps = max(current, 0.1)
    for _ in range(_EM_ITERATIONS):
        g = (1 - eps) * np.exp(-0.5 * (resid / sigma) ** 2) / (np.sqrt(TWO_PI) * sigma)
        gamma = g / (g + eps / TWO_PI)
        eps = float(np.clip(1.0 - gamma.mean(), *OUTLIER_RANGE))
    return eps


def sentence(summary: dict) -> str:
    """'your receiver's sigma looks like 3.1 deg at Q 95, ...; 12 % of readings look wild'."""
    parts = [f"{v:.2g} deg at {'unknown quality' if k == 'nan' else 'Q ' + k}" for k, v in summary["sigma_deg"].items()]
    if not parts:
        return "noise not calibrated yet"
    return (f"your receiver's sigma looks like {', '.join(parts)}; "
            f"{100 * summary['reading_outlier_prob']:.0f} % of readings look wild")
