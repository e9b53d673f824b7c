"""The station errors' family and prior: each station's own Gaussian error, and a share of wild stations.

A station's centre bearing is off by its own error, Gaussian with a scale tau (plus its readings' scatter),
independently of the other stations, or it is wild (uniform on the circle) with probability w. tau and w lie on a
grid whose prior is what receivers of a class do, and their posterior pools every emitter of a receiver, so three
bearings that happen to cross well cannot prove a sharp receiver while a survey of many emitters learns its own
(docs/design.md, "Honest on real bearings", compares this family by evidence with a plain Gaussian and with a
part shared by a receiver's stations, on real and simulated bearings).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ReceiverClass:
    """What receivers of a kind do: the independent station error's scale (median deg, sd of its log), and the
    hypotheses for one receiver's shared, place-like error as a share of the truth's range, with their weights."""

    scale_deg: float
    log_sd: float
    shared_place: tuple
    shared_weight: tuple = (1.0,)


# A hand-held survey's place-like error: the two-scale mixture fitted (maximum likelihood against the surveyed
# truth) to two real observers' 46 collars, docs/design.md "Honest on real bearings"
_HAND_HELD_PLACE = {"shared_place": (0.2, 0.6), "shared_weight": (0.75, 0.25)}
# An unknown receiver's scale: a few degrees, but wide (a factor e^2 a standard deviation), so that a handful of
# stations whose readings agree to a fraction of a degree can show it; an observer's survey pools its ids anyway
RECEIVER_CLASSES: dict[str, ReceiverClass] = {
    "unknown": ReceiverClass(6.0, 2.0, **_HAND_HELD_PLACE),
    "handheld": ReceiverClass(15.0, 0.6, **_HAND_HELD_PLACE),
    "electronic": ReceiverClass(3.0, 0.8, (0.0,)),
    "mast": ReceiverClass(2.0, 0.8, (0.0,)),
    "indoor": ReceiverClass(10.0, 0.7, (0.0, 0.1), (0.5, 0.5)),
}
TAU_DEG = np.geomspace(0.05, 50.0, 17)  # a site part of nearly none (below a lab array's) to barely a direction
WILD = np.array([0.02, 0.12])  # a station's chance of being wild
SCALE_BANDS = 3  # each band of scales is zoomed onto its own posterior, so a sharp one is resolved
_LOG_2PI = math.log(2 * math.pi)


@dataclass(frozen=True)
class NoiseGrid:
    """The (tau, w) hypotheses, flattened, with their log prior."""

    tau: np.ndarray  # (H,) rad
    wild: np.ndarray  # (H,)
    log_prior: np.ndarray  # (H,)
    shared_place: np.ndarray  # (L,) the place-like error's hypotheses, shares of the truth's range
    shared_weight: np.ndarray  # (L,) their prior weights
    repeated: bool = False  # the stations' readings repeat: tau is a site part that may be absent

    @property
    def size(self) -> int:
        return int(self.tau.size)

    @functools.cached_property
    def scales(self) -> tuple[np.ndarray, np.ndarray]:
        """The distinct scales (U,) and each hypothesis's index among them (H,): a scale's densities serve each of
        its wild shares."""
        tau, which = np.unique(self.tau, return_inverse=True)
        return tau, which

    def bands(self, count: int = SCALE_BANDS) -> list[np.ndarray]:
        """The hypotheses' indices in `count` bands of neighbouring scales."""
        edges = np.quantile(np.unique(self.tau), np.linspace(0, 1, count + 1)[1:-1])
        band = np.searchsorted(edges, self.tau)
        return [np.flatnonzero(band == b) for b in range(count)]

    def subset(self, index: np.ndarray) -> NoiseGrid:
        return NoiseGrid(self.tau[index], self.wild[index], self.log_prior[index], self.shared_place,
                         self.shared_weight, self.repeated)


def noise_grid(receiver_class: str, repeated: bool = False) -> NoiseGrid:
    """The hypotheses and their prior for a receiver class (a ValueError names the classes for any other).

    With one reading a station, tau is the whole of a station's error and the class's prior holds it (three
    bearings that cross well cannot prove a sharp receiver). With `repeated` readings at the stations, their own
    scatter is measured apart and tau is only the steady site part on top of it, which may be absent: half the
    prior is then spread evenly over log tau, so the readings decide (a precise instrument's site part of nearly
    nothing is not held up by a prior made for people with Yagis)."""
    if receiver_class not in RECEIVER_CLASSES:
        raise ValueError(f"receiver_class {receiver_class!r} is not one of {', '.join(RECEIVER_CLASSES)}")
    cls = RECEIVER_CLASSES[receiver_class]
    median, log_sd = cls.scale_deg, cls.log_sd
    tau_deg, wild = (a.ravel() for a in np.meshgrid(TAU_DEG, WILD, indexing="ij"))
    log_prior = -0.5 * ((np.log(tau_deg) - math.log(median)) / log_sd) ** 2
    log_prior -= logsumexp(log_prior, axis=0)
    if repeated:
        even = np.full(tau_deg.size, -math.log(tau_deg.size))
        log_prior = np.logaddexp(log_prior, even) - math.log(2.0)
    return NoiseGrid(np.radians(tau_deg), wild, log_prior, np.array(cls.shared_place), np.array(cls.shared_weight),
                     repeated)


def logsumexp(x: np.ndarray, axis: int) -> np.ndarray:
    """log(sum(exp(x))) along an axis, stable; -inf where every term is (scipy's is several times slower on the
    grid's sizes)."""
    m = np.max(x, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        return np.squeeze(m, axis=axis) + np.log(np.sum(np.exp(x - m), axis=axis))


def log_likelihood(resid: np.ndarray, own_var: np.ndarray, noise: NoiseGrid) -> np.ndarray:
    """log p(station residuals | hypothesis) for residuals (K, C) rad and each station's own variance besides tau^2,
    (K,) or per place (K, C) rad^2: (H, C). Sums over no wild station and each single one (with three or more
    stations; two wild stations of a handful are left to the scale's mixture).

    The densities depend on the scale alone, so they are made once per distinct tau and shared by its wild shares;
    the sum over which single station is wild is the all-kept term times 1 + sum_k w / (1 - w) / (2 pi) / N_k."""
    k = resid.shape[0]
    own = own_var if own_var.ndim == 2 else own_var[:, None]
    tau, which = noise.scales
    # single precision for the per-station densities (a grid's log likelihoods need a millionth of a nat at most)
    d = (tau[:, None, None] ** 2 + own[None, :, :]).astype(np.float32)  # (U, K, C or 1)
    minus = 0.5 * (np.square(resid, dtype=np.float32)[None, :, :] / d + np.log(d) + np.float32(_LOG_2PI))
    log_keep = np.log1p(-noise.wild)[:, None]
    total = -minus.sum(axis=1, dtype=float)[which] + k * log_keep  # (H, C)
    if k < 3:
        return total
    top = minus.max(axis=1)  # (U, C): the station least explained under each scale
    spread = np.log(np.exp(minus - top[:, None, :]).sum(axis=1, dtype=float))  # log sum_k exp(-log N_k - top)
    b = (np.log(noise.wild)[:, None] - log_keep - _LOG_2PI) + (top + spread)[which]  # log of the wild terms' sum
    return total + np.logaddexp(0.0, b)


def expected_error(noise: NoiseGrid, weights: np.ndarray) -> float:
    """The posterior root-mean-square scale (rad) of one station's error."""
    return float(np.sqrt(weights @ noise.tau**2))


def quantile_of(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    """The q-quantile of a positive per-hypothesis value under posterior weights, each grid value standing for the
    bin around it in log scale (to the midpoints with its neighbours): a posterior on one value of the grid gives
    that bin's interval, never a point (`5.8-5.8 deg at 90 %` said more than the grid knows)."""
    v, inverse = np.unique(values, return_inverse=True)
    if v.size == 1:
        return float(v[0])
    w = np.bincount(inverse, weights=weights)
    log_v = np.log(v)
    mid = 0.5 * (log_v[1:] + log_v[:-1])
    edges = np.concatenate([[2.0 * log_v[0] - mid[0]], mid, [2.0 * log_v[-1] - mid[-1]]])
    cdf = np.concatenate([[0.0], np.cumsum(w)]) / w.sum()
    return float(np.exp(np.interp(q, cdf, edges)))
