"""How many transmitters one channel's bearings come from, and where each is (issue 54; docs/design.md,
"Co-channel transmitters").

Each reading comes from one of K static transmitters, or is wild (a uniform share). Transmitters on one frequency
take turns (push-to-talk, a repeater's users): readings close in time come from the same one. A reflection's ghost
comes with its direct path, reading by reading. So for each K two models are fitted by EM, over time bins of
BIN_S seconds: **in turns** (a bin's readings share one transmitter, the bins independent) and **interleaved**
(every reading its own draw). Each model fits its own scale of the readings' sigmas (per quality band): a receiver
calibrated on two transmitters' bearings reads them as one wide noise. A bearing offset the receiver's calibration
learned is tried beside none (it may come from that confusion too). The count's posterior weighs every model by
its BIC:
K = 1; K in turns (K transmitters); K interleaved (one transmitter and K - 1 ghosts, or carriers on the air at
once, which bearings alone cannot tell apart: counted as one, and said). Where no bin holds two readings the two
models are the same and the count stays at 1 with its probability near a half: the bearings cannot tell.
"""
from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from aoa_localizer.engine.geodesy import wrap_pi
from aoa_localizer.engine.inference.global_search import Mode, Points, Robust, find_modes, radio_reach
from aoa_localizer.engine.scheduling.slices import COUNT_EM, metered

TURNS_SPAN = 0.8  # the share of a transmitter's readings (the middle, in time) whose span is compared ...
TURNS_OVERLAP = 0.25  # ... and the overlap of two such spans, of the shorter, that says they are heard in turns
MIN_READINGS = 30  # a channel's transmitters are counted from this many readings on ...
COUNT_GROWTH = 2.0  # ... and again once they grew by this factor (a count costs 0.01-1 s)
BIN_S = 2.0  # readings within one such bin of time are taken as one transmitter's (in turns)
MIN_SHARE = 0.08  # a transmitter (or a ghost) explains at least this share of the readings
COUNT_SURE = 0.9  # a count this probable is sure: its places may be `tracking`, and they question the estimate
_EM_ITERATIONS = 40
_EM_TOL = 1e-6  # stop when the log-likelihood gains less than this (relative)
_GN_STEPS = 2  # Gauss-Newton steps of each place per EM iteration
_OUTLIER_START, _OUTLIER_MIN = 0.1, 1e-3
_MAX_STARTS = 4  # places (modes) combined into starts for K > 1
_SCALE_RANGE = (0.1, 100.0)  # the fitted scale of the readings' sigmas stays within these
_QUALITY_BANDS = (55.0, 70.0, 85.0)  # the sigmas' scale is fitted per band of quality (and one for unknown quality)
_UNEXPLAINED_MIN = 6  # readings off the one place, from which a second start is sought
_WILD_MADS = 2.5  # a reading this many robust sigmas off the one place is another transmitter's, or wild
_STARTS_OUTLIER_PROB = 0.2  # the modes the count starts from are sought under at least this wild share
_START_APART_M = 30.0  # starts nearer than this to an earlier one are the same start
# One place that explains the readings without widening their sigmas more than this, whose wild readings do not
# meet anywhere with another transmitter's share, is one transmitter (the other fits are skipped: a single
# emitter's count costs one fit and one search of its wild readings); a wider one may be two read as one wide noise
_QUIET_SCALE = 2.0
_LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class Place:
    """One transmitter (or ghost) of a fit: its place (east, north, m), covariance (m^2: Laplace, widened by
    _widened_by_scores) and the share of the readings it explains."""

    mean: np.ndarray
    cov: np.ndarray
    share: float


@dataclass(frozen=True)
class Fit:
    """One model's maximum-likelihood fit."""

    k: int
    in_turns: bool
    places: list[Place]
    scale: np.ndarray  # each reading's, from its quality band's
    shift: np.ndarray  # rad, taken off each reading's bearing: the receiver's offset and its site's bias
    loglik: float
    bic: float
    resp: np.ndarray  # (N, K): each reading's responsibility of each place
    offset: float = 0.0  # rad, the receiver's offset the fit took off (shift without the sites' biases)


@dataclass(frozen=True)
class Count:
    """The count of transmitters and what else the bearings show.

    `count` with its posterior `probability`; `transmitters` (count >= 2: each, the heaviest first; else empty);
    `ghosts`: places whose readings interleave with the transmitter's (a reflection, or a second carrier on at the
    same time), when the interleaved model is the likeliest; `probabilities` by count; `more_than_allowed`: a fit
    with one more transmitter than `max_k` is likelier than every allowed one; `assigned`: each reading's most
    likely transmitter (an index into `transmitters`; empty below two); `fitted`: the count's fit's places (the
    transmitters, or the one and its ghosts), `offset` the bearing offset it took off and `site_bias` each site's
    fitted bias (readings of several stations: a station is a site)."""

    count: int
    probability: float
    transmitters: list[Place]
    ghosts: list[Place]
    probabilities: dict[int, float]
    more_than_allowed: bool
    assigned: np.ndarray
    fitted: list[Place] = field(default_factory=list)  # every place of the fit the count is made from, heaviest first
    offset: float = 0.0  # rad, the receiver's offset that fit took off (the calibration's, or none)
    site_bias: np.ndarray = field(default_factory=lambda: np.zeros(0))  # rad, each site's fitted bias (sites only)
    site_names: tuple[str, ...] = ()  # the sites' names where the caller gave them (its stations)
    # the transmitters are heard in turns over the readings' span, as transmitters sharing a frequency are; False
    # where each holds a stretch of time of its own, as the places one moving transmitter passes through do
    in_turns: bool = True


@dataclass(frozen=True)
class Readings:
    """A channel's readings as arrays: stamp (s), antenna east, north (m), bearing theta (ENU rad), sigma (rad) and
    quality (0-100, NaN unknown: its band is the sigmas' scale's). `site` (a survey's fixed stations: each
    reading's, from 0) gives every site a steady bias of prior sd `site_sd` (rad), fitted in every model: a site's
    readings then weigh as one site, and a biased site cannot pass for a second transmitter (only a site whose own
    readings turn between two places can show one)."""

    stamp: np.ndarray
    east: np.ndarray
    north: np.ndarray
    theta: np.ndarray
    sigma: np.ndarray
    quality: np.ndarray
    site: np.ndarray | None = None
    site_sd: float = 0.0

    def __len__(self) -> int:
        return len(self.stamp)

    @property
    def band(self) -> np.ndarray:
        """Each reading's quality band (len(_QUALITY_BANDS) + 1 for an unknown quality)."""
        q = self.quality
        return np.where(np.isnan(q), len(_QUALITY_BANDS) + 1, np.digitize(np.nan_to_num(q), _QUALITY_BANDS))


def count_transmitters(r: Readings, first: np.ndarray, starts: Callable[[float], list[np.ndarray]], max_k: int,
                       offset: float = 0.0) -> Count | None:
    """The count of transmitters behind `r` (1 to `max_k`): one fitted from `first` (the estimate) and the bearing
    `offset` the receiver's calibration learned (and from no offset), more from the candidate places `starts(scale)`
    gives (the robust posterior's modes with the sigmas scaled, best first), asked only when the one leaves a
    transmitter's share of the readings unexplained; None with fewer than ten readings."""
    if len(r) < 10:
        return None
    bins = np.unique(np.floor((r.stamp - r.stamp.min()) / BIN_S), return_inverse=True)[1]
    first = np.asarray(first, float)
    offsets = sorted({0.0, offset})
    one = max((_best_fit(r, bins, [first], True, _first_scale(r, first, o), o) for o in offsets),
              key=lambda f: f.loglik)
    unexplained = _unexplained(r, one)
    need = max(MIN_SHARE * len(r), _UNEXPLAINED_MIN)  # readings another transmitter would send, at least
    crossings = _wild_crossings(r, one, unexplained) if unexplained.sum() >= _UNEXPLAINED_MIN else []
    if np.median(one.scale) <= _QUIET_SCALE and not any(m.inliers >= need / 2 for m in crossings):
        # One place explains them at their own noise, and the rest do not meet anywhere: no room for another
        return Count(1, 1.0, [], [], {1: 1.0}, False, np.zeros(0, int), list(one.places), one.offset,
                     _site_bias(r, one))
    wide = float(np.median(one.scale))
    candidates = [one.places[0].mean, *(m.mean for m in crossings)]  # the one, then where its wild ones cross
    candidates += [np.asarray(s, float) for s in starts(1.0) + starts(wide)]
    starts_k = _distinct(candidates, _START_APART_M)[:max(_MAX_STARTS, max_k + 1)]
    fits = [one]
    for k in range(2, min(max_k + 1, len(starts_k)) + 1):
        for in_turns in (True, False):
            fit = _best_of(r, bins, [list(c) for c in itertools.combinations(starts_k, k)], in_turns, one.scale,
                           offsets)
            if fit is not None and min(p.share for p in fit.places) >= MIN_SHARE:
                fits.append(fit)
    allowed = [f for f in fits if f.k <= max_k]
    # Errors that repeat along the drive make a stretch of road read as a second place in turns: the evidence is
    # weighed as the one place's residuals say it is worth (a quasi-likelihood's dispersion; 1 for independent ones)
    dispersion = _dependence(r, one, bins) if len(allowed) > 1 else 1.0
    by_count = _by_count(allowed, dispersion)
    count = max(by_count, key=lambda n: (by_count[n], -n))  # a tie goes to fewer transmitters
    born = _births(r, bins, allowed, max_k, need, one.scale) if 2 <= count < max_k else []
    if born:  # where several are on the air, one that no start reached
        fits += born
        allowed += born
        by_count = _by_count(allowed, dispersion)
        count = max(by_count, key=lambda n: (by_count[n], -n))
    best = min((f for f in allowed if (f.k if f.in_turns else 1) == count), key=lambda f: f.bic)
    order = sorted(range(best.k), key=lambda j: -best.places[j].share)
    places = [best.places[j] for j in order]
    transmitters = places if count >= 2 else []
    ghosts = places[1:] if not best.in_turns else []
    assigned = np.argmax(best.resp[:, order], axis=1) if count >= 2 else np.zeros(0, int)
    beyond = min(fits, key=lambda f: f.bic)
    more = (beyond.k > max_k and beyond.in_turns) or (count == max_k and _left_over(r, best, need))
    return Count(count, by_count[count], transmitters, ghosts, by_count, more, assigned, places, best.offset,
                 _site_bias(r, best), in_turns=count < 2 or _heard_in_turns(r.stamp, assigned, count))


def _heard_in_turns(stamp: np.ndarray, assigned: np.ndarray, k: int) -> bool:
    """Whether `k` transmitters (each reading's `assigned`) are heard in turns: some two whose middle
    TURNS_SPAN of readings in time overlap by over TURNS_OVERLAP of the shorter span. Places one after another
    (a mover's) overlap only where a wild reading or an ambiguous crossing falls; readings without times: True."""
    lo, hi = (1.0 - TURNS_SPAN) / 2.0, (1.0 + TURNS_SPAN) / 2.0
    spans = [np.quantile(stamp[assigned == j], [lo, hi]) for j in range(k) if (assigned == j).sum() >= 2]
    if len(spans) < 2 or not np.ptp(stamp) > 0.0:
        return True
    for (a0, a1), (b0, b1) in itertools.combinations(spans, 2):
        shorter = min(a1 - a0, b1 - b0)
        if min(a1, b1) - max(a0, b0) > TURNS_OVERLAP * max(shorter, 0.0):
            return True
    return False


def count_job(r: Readings, first: np.ndarray, max_k: int, offset: float, site_names: tuple[str, ...] = ()
              ) -> Count | None:
    """count_transmitters from the readings' own modes, its sites named `site_names`: a plain function of its
    inputs, as the scheduler runs it (in the check worker, or in turns within the calls)."""
    count = count_transmitters(r, first, mode_starts(r), max_k, offset)
    return replace(count, site_names=site_names) if count is not None and site_names else count


def mode_starts(r: Readings) -> Callable[[float], list[np.ndarray]]:
    """The candidate places of `count_transmitters`: the robust posterior's modes of the readings with their sigmas
    scaled by the given factor, best first."""
    def modes(scale: float) -> list[np.ndarray]:
        rows = np.column_stack([r.east, r.north, r.theta, scale * r.sigma, np.zeros(len(r))])
        return [m.mean for m in find_modes(Points.of(rows), Robust(_STARTS_OUTLIER_PROB), by_density=True)]
    return modes


def _dependence(r: Readings, fit: Fit, bins: np.ndarray) -> float:
    """How many times the readings' log-likelihood overstates its evidence under `fit`, where their errors repeat
    along the drive (a site error a stretch of road shares): the long-run variance of the inliers' standardised
    residuals (summed per time bin, the bins' sums' autocovariances to lag L with Bartlett weights) over their
    plain variance; 1 for independent errors (and where the excess is within its chance spread)."""
    order = np.argsort(r.stamp, kind="stable")
    turned = _turned(r, fit.shift)
    by_place = np.column_stack([_jacobian(turned, p.mean)[0] for p in fit.places])
    resid = np.take_along_axis(by_place, np.argmax(fit.resp, axis=1)[:, None], axis=1)[:, 0]  # at its own place
    z = resid / (fit.scale * r.sigma)
    z = np.where(np.abs(z) <= 3.0, z, 0.0)[order]  # the wild ones say nothing of the others' dependence
    b = bins[order]
    _, which = np.unique(b, return_inverse=True)
    sums = np.bincount(which, z)
    plain = float(np.sum(z * z))
    n = sums.size
    if plain <= 0.0 or n < 8:
        return 1.0
    weighted, spread = _bartlett(n)
    long_run = float(sums @ sums) + 2.0 * sum(w * float(sums[lag:] @ sums[:-lag]) for lag, w in weighted)
    factor = long_run / plain
    return factor if factor > 1.0 + 3.0 * spread else 1.0


def _bartlett(n: int) -> tuple[list[tuple[int, float]], float]:
    """Newey and West's lags for a series of n bins' sums: each lag up to n^(1/3) (at most n - 1) with its Bartlett
    weight, and the chance spread of a long-run variance over the plain one for independent terms, roughly."""
    lags = int(math.ceil(n ** (1.0 / 3.0)))
    return ([(lag, 1.0 - lag / (lags + 1)) for lag in range(1, min(lags, n - 1) + 1)],
            math.sqrt(2.0 * (2 * lags + 1) / n))


def _site_bias(r: Readings, fit: Fit) -> np.ndarray:
    """Each site's bias (rad) in `fit` (its shift without the common offset); empty without sites."""
    if r.site is None:
        return np.zeros(0)
    sites = int(r.site.max()) + 1
    return np.bincount(r.site, fit.shift - fit.offset, minlength=sites) / np.maximum(
        np.bincount(r.site, minlength=sites), 1)


def _tempered_bic(fit: Fit, dispersion: float) -> float:
    """The fit's BIC with its log-likelihood divided by `dispersion` (its penalty as it was)."""
    return fit.bic + 2.0 * fit.loglik * (1.0 - 1.0 / dispersion)


def _bic_weights(bics: list[float]) -> np.ndarray:
    b = np.array(bics)
    w = np.exp(-0.5 * (b - b.min()))
    return w / w.sum()


def _turned(r: Readings, shift: np.ndarray | float) -> Readings:
    """The readings with `shift` (rad: one for all, or each reading's) taken off their bearings."""
    return replace(r, theta=wrap_pi(r.theta - shift)) if np.any(shift) else r


def _first_scale(r: Readings, x: np.ndarray, offset: float) -> np.ndarray:
    """The sigmas' scale the residuals at place x suggest (their median absolute value, robustly), every reading's."""
    resid, _ = _jacobian(_turned(r, offset), x)
    return np.full(len(r), float(np.clip(np.median(np.abs(resid) / r.sigma) / 0.6745, 1.0, _SCALE_RANGE[1])))


def _by_count(fits: list[Fit], dispersion: float) -> dict[int, float]:
    """Each count's posterior probability: its fits' BIC weights (tempered by `dispersion`) summed, an interleaved
    fit counting one transmitter."""
    by_count: dict[int, float] = {}
    for f, w in zip(fits, _bic_weights([_tempered_bic(f, dispersion) for f in fits]), strict=True):
        n = f.k if f.in_turns else 1
        by_count[n] = by_count.get(n, 0.0) + float(w)
    return dict(sorted(by_count.items()))


def _births(r: Readings, bins: np.ndarray, fits: list[Fit], max_k: int, need: float, scale: np.ndarray) -> list[Fit]:
    """Fits with one more transmitter, each started from the likeliest fit in turns so far and the place where the
    readings it leaves over meet (with half a transmitter's share): a transmitter that no start reached, its
    crossing drowned among the others' (five on the air read as four, p = 1.00). Each is kept while it is likelier
    (BIC) than the fit it grew from, up to the limit. Asked only where the count already says several: a lone
    transmitter's biased or wild readings grow no fits (and cost no time)."""
    born: list[Fit] = []
    turns = [f for f in fits if f.in_turns and f.k <= max_k]
    top = min(turns, key=lambda f: f.bic) if turns else None
    while top is not None and top.k < max_k:
        unexplained = _unexplained(r, top)
        if unexplained.sum() < _UNEXPLAINED_MIN:
            break
        where = [m.mean for m in _wild_crossings(r, top, unexplained) if m.inliers >= need / 2]
        if not where:
            break
        fit = _best_fit(r, bins, [p.mean for p in top.places] + [where[0]], True, scale, top.offset)
        if min(p.share for p in fit.places) < MIN_SHARE or fit.bic >= top.bic:
            break
        born.append(fit)
        top = fit
    return born


def _left_over(r: Readings, fit: Fit, need: float) -> bool:
    """Whether the readings that none of `fit`'s places explains still meet at a place of their own, with a third
    of a transmitter's share (places at the limit absorb some of the others' readings): one more transmitter than
    the fit has."""
    unexplained = _unexplained(r, fit)
    if unexplained.sum() < _UNEXPLAINED_MIN:
        return False
    return any(m.inliers >= need / 3 for m in _wild_crossings(r, fit, unexplained))


def _unexplained(r: Readings, fit: Fit) -> np.ndarray:
    """Which readings lie off every place of `fit`: more than _WILD_MADS robust sigmas from each (the median
    absolute residual of their quality band at their nearest place, which another transmitter's readings cannot
    widen as they widen the fit's own scale)."""
    turned = _turned(r, fit.shift)
    z = np.min([np.abs(_jacobian(turned, p.mean)[0]) for p in fit.places], axis=0) / r.sigma
    band = r.band
    mad = np.array([np.median(z[band == b]) if np.any(band == b) else 1.0 for b in range(band.max() + 1)]) / 0.6745
    return z > _WILD_MADS * np.maximum(mad, 1e-9)[band]


def _wild_crossings(r: Readings, fit: Fit, wild: np.ndarray) -> list[Mode]:
    """Where the readings `fit` calls wild cross (the best two modes, with the readings each explains): a further
    transmitter's start that the modes of all the readings missed (its crossing drowned in the others')."""
    turned = _turned(r, fit.shift)
    rows = np.column_stack([r.east, r.north, turned.theta, fit.scale * r.sigma, np.zeros(len(r))])[wild]
    return find_modes(Points.of(rows), Robust(0.2), by_density=True)[:2]


def _distinct(places: list[np.ndarray], apart_m: float) -> list[np.ndarray]:
    """`places` without those within `apart_m` of one before them."""
    out: list[np.ndarray] = []
    for p in places:
        if all(np.hypot(*(p - q)) > apart_m for q in out):
            out.append(p)
    return out


def _best_of(r: Readings, bins: np.ndarray, combos: list[list[np.ndarray]], in_turns: bool, scale: np.ndarray,
             offsets: list[float]) -> Fit | None:
    fits = [_best_fit(r, bins, c, in_turns, scale, o) for c in combos for o in offsets]
    fits = [f for f in fits if f is not None]
    return max(fits, key=lambda f: f.loglik) if fits else None


def _best_fit(r: Readings, bins: np.ndarray, places: list[np.ndarray], in_turns: bool, scale: np.ndarray,
              offset: float) -> Fit:
    """EM from `places` and the sigmas' `scale`, with the bearing `offset` taken off: the responsibilities of each
    transmitter (per bin in turns, per reading interleaved) and the wild share; each place by weighted Gauss-Newton;
    the shares, the scales and the sites' biases; then BIC (the biases, a prior's random effects, enter the
    log-likelihood with their prior's density, not as parameters)."""
    band = r.band
    base = _turned(r, offset)
    k = len(places)
    x = np.array(places, float)
    share = np.full(k, 1.0 / k)
    bias = np.zeros(int(r.site.max()) + 1 if r.site is not None else 0)
    eps = _OUTLIER_START
    previous = -np.inf
    loglik = -np.inf
    for _ in range(_EM_ITERATIONS):
        shifted = _biased(base, bias)
        log_in, log_e = _emissions(shifted, x, eps, scale)  # (N, K) log of the inlier part, of the whole emission
        resp, loglik = _responsibilities(log_e, share, bins, in_turns)
        loglik += _bias_prior(r, bias)
        inlier = resp * np.exp(log_in - log_e)  # each reading's weight for each place as an inlier
        share = np.maximum(resp.mean(axis=0), 1e-12)
        share /= share.sum()
        eps = float(np.clip(1.0 - inlier.sum() / len(r), _OUTLIER_MIN, 0.5))
        for j in range(k):
            x[j] = _gauss_newton(shifted, x[j], inlier[:, j], scale)
        scale = _scale(shifted, x, inlier, band)
        bias = _site_biases(base, x, inlier, scale, len(bias))
        if abs(loglik - previous) <= _EM_TOL * abs(loglik):
            break
        previous = loglik
    shifted = _biased(base, bias)
    log_in, log_e = _emissions(shifted, x, eps, scale)
    resp, loglik = _responsibilities(log_e, share, bins, in_turns)
    loglik += _bias_prior(r, bias)
    inlier = resp * np.exp(log_in - log_e)
    out = [Place(x[j].copy(), _widened_by_scores(
        _covariance(shifted, x[j], inlier[:, j], scale) * _own_dispersion(shifted, x[j], inlier[:, j], scale),
        shifted, x[j], inlier[:, j], scale, bins), float(resp[:, j].mean())) for j in range(k)]
    params = 2 * k + (k - 1) + 1 + len(np.unique(band))  # places, shares, the wild share, the scales
    shift = offset + (bias[r.site] if r.site is not None else np.zeros(len(r)))
    return Fit(k, in_turns, out, scale, shift, loglik, -2.0 * loglik + params * math.log(len(r)), resp, offset)


def _own_dispersion(r: Readings, x: np.ndarray, w: np.ndarray, scale: np.ndarray) -> float:
    """How much wider than its quality bands' scale a place's own readings scatter about it (their weighted mean
    squared residual in scaled sigmas, at least 1): a place that holds another transmitter's readings too, or whose
    readings the bands' scale understates, widens its own ellipse rather than claim the bands' precision."""
    resid, _ = _jacobian(r, x)
    total = float(w.sum())
    if total <= 2.0:
        return 1.0
    return max(1.0, float(w @ (resid / (scale * r.sigma)) ** 2) / total)


def _widened_by_scores(cov: np.ndarray, r: Readings, x: np.ndarray, w: np.ndarray, scale: np.ndarray,
                       bins: np.ndarray) -> np.ndarray:
    """A place's covariance widened where its own readings' scores vary more than it says, along the drive: the
    sandwich cov M cov, its meat the place's score sums per time bin with their autocovariances (_bartlett, as
    _dependence's), so errors a stretch of its bins repeat (a stretch of road's site error, bursts of
    another transmitter held by it) count as what they are worth. Kept in each direction where it exceeds `cov`
    beyond its chance spread (as _dependence keeps its factor), never narrower: for independent errors the meat
    is at most the information. Sites (a survey's stations) weigh their biases in _covariance already."""
    if r.site is not None or not np.all(np.isfinite(cov)):
        return cov
    resid, jac = _jacobian(r, x)
    score = (w * resid / (scale * r.sigma) ** 2)[:, None] * jac  # each reading's part of the log-likelihood's gradient
    nbins = int(bins.max()) + 1
    heard = np.bincount(bins, w, minlength=nbins) > 0.5  # the place's own bins, in time order
    sums = np.column_stack([np.bincount(bins, score[:, i], minlength=nbins) for i in (0, 1)])[heard]
    n = sums.shape[0]
    if n < 8:
        return cov
    weighted, spread = _bartlett(n)
    meat: np.ndarray = sums.T @ sums
    for lag, bartlett in weighted:
        cross = sums[lag:].T @ sums[:-lag]
        meat = meat + bartlett * (cross + cross.T)
    sandwich = cov @ meat @ cov
    try:
        root = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return cov
    inv_root = np.linalg.inv(root)
    excess, turn = np.linalg.eigh(inv_root @ sandwich @ inv_root.T)  # the sandwich in cov's own units
    grown = root @ turn @ np.diag(np.where(excess > 1.0 + 3.0 * spread, excess, 1.0)) @ turn.T @ root.T
    return 0.5 * (grown + grown.T)


def _biased(r: Readings, bias: np.ndarray) -> Readings:
    """The readings with their sites' biases taken off (as they are without sites)."""
    return _turned(r, bias[r.site]) if r.site is not None else r


def _bias_prior(r: Readings, bias: np.ndarray) -> float:
    """The log density of the sites' biases under their prior (0 without sites)."""
    if r.site is None:
        return 0.0
    sd = max(r.site_sd, 1e-6)
    return float(np.sum(-0.5 * (bias / sd) ** 2 - math.log(sd) - 0.5 * _LOG_2PI))


def _site_biases(r: Readings, x: np.ndarray, inlier: np.ndarray, scale: np.ndarray, sites: int) -> np.ndarray:
    """Each site's bias: its readings' inlier-weighted mean residual at the places `x`, shrunk by the prior (the
    maximum of the posterior of a Gaussian bias); none without sites."""
    if r.site is None:
        return np.zeros(0)
    num, den = np.zeros(len(r)), np.zeros(len(r))
    for j in range(len(x)):
        resid, _ = _jacobian(r, x[j])
        a = inlier[:, j] / (scale * r.sigma) ** 2
        num += a * resid
        den += a
    prec = 1.0 / max(r.site_sd, 1e-6) ** 2
    return np.bincount(r.site, num, minlength=sites) / (np.bincount(r.site, den, minlength=sites) + prec)


def _scale(r: Readings, x: np.ndarray, inlier: np.ndarray, band: np.ndarray) -> np.ndarray:
    """Each reading's sigma scale: its quality band's inliers' weighted RMS residual in sigmas at the places `x`."""
    z2 = np.zeros(len(r))
    for j in range(len(x)):
        resid, _ = _jacobian(r, x[j])
        z2 += inlier[:, j] * (resid / r.sigma) ** 2
    weight = inlier.sum(axis=1)
    sums = np.bincount(band, z2, minlength=band.max() + 1)
    counts = np.bincount(band, weight, minlength=band.max() + 1)
    scales = np.sqrt(np.divide(sums, counts, out=np.ones_like(sums), where=counts > 1.0))
    return np.clip(scales, *_SCALE_RANGE)[band]


@metered(COUNT_EM, lambda r, x, eps, scale: len(r) * len(x))
def _emissions(r: Readings, x: np.ndarray, eps: float, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """log((1 - eps) N(residual; scale sigma)) and log of it plus the wild share's eps / 2 pi, (N, K)."""
    bearing = np.arctan2(x[None, :, 1] - r.north[:, None], x[None, :, 0] - r.east[:, None])
    resid = wrap_pi(r.theta[:, None] - bearing)
    s = (scale * r.sigma)[:, None]
    log_in = math.log1p(-eps) - 0.5 * (resid / s) ** 2 - np.log(s) - 0.5 * _LOG_2PI
    return log_in, np.logaddexp(log_in, math.log(eps) - _LOG_2PI)


def _responsibilities(log_e: np.ndarray, share: np.ndarray, bins: np.ndarray, in_turns: bool
                      ) -> tuple[np.ndarray, float]:
    """Each reading's responsibility of each place (N, K) and the model's log-likelihood: in turns, a bin's
    readings share one place (their log emissions summed per bin); interleaved, each reading its own."""
    log_share = np.log(share)[None, :]
    if not in_turns:
        joint = log_e + log_share
        norm = np.logaddexp.reduce(joint, axis=1)
        return np.exp(joint - norm[:, None]), float(norm.sum())
    per_bin = np.zeros((bins.max() + 1, log_e.shape[1]))
    np.add.at(per_bin, bins, log_e)
    joint = per_bin + log_share
    norm = np.logaddexp.reduce(joint, axis=1)
    return np.exp(joint - norm[:, None])[bins], float(norm.sum())


def _jacobian(r: Readings, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (theta - bearing) and d bearing / d x (N, 2) at place x."""
    dx, dy = x[0] - r.east, x[1] - r.north
    r2 = np.maximum(dx * dx + dy * dy, 1e-6)
    resid = wrap_pi(r.theta - np.arctan2(dy, dx))
    return resid, np.column_stack([-dy / r2, dx / r2])


def _reach(r: Readings) -> tuple[np.ndarray, float]:
    """The places keep to the antennas' radio range (global_search.radio_reach) as a Gaussian, so a transmitter
    heard from one side is not fitted at infinity along its rays: its centre and its information (1 / scale^2)."""
    east, north, scale = radio_reach(np.column_stack([r.east, r.north]))
    return np.array([east, north]), 1.0 / scale**2


def _gauss_newton(r: Readings, x: np.ndarray, w: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """x moved to raise the weighted bearings' likelihood under the radio-range prior, a few steps (unchanged when
    they cannot fix it)."""
    centre, prior = _reach(r)
    for _ in range(_GN_STEPS):
        resid, jac = _jacobian(r, x)
        a = w / (scale * r.sigma) ** 2
        info = (jac * a[:, None]).T @ jac + prior * np.eye(2)
        grad = jac.T @ (a * resid) + prior * (centre - x)
        try:
            step = np.linalg.solve(info, grad)
        except np.linalg.LinAlgError:
            return x
        if not np.all(np.isfinite(step)):
            return x
        x = x + step
    return x


def _covariance(r: Readings, x: np.ndarray, w: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The Laplace covariance of a place from the readings it explains and the radio-range prior (the inverse of
    their information); with sites, each site's readings inform as one bearing whose bias is unknown (their
    information on the bias marginalised under its prior), so a place heard by few sites keeps their biases' spread."""
    _, jac = _jacobian(r, x)
    a = w / (scale * r.sigma) ** 2
    prior = _reach(r)[1] * np.eye(2)
    if r.site is None:
        info = (jac * a[:, None]).T @ jac + prior
    else:
        sites = int(r.site.max()) + 1
        weight = np.bincount(r.site, a, minlength=sites)
        mean_jac = np.column_stack([np.bincount(r.site, a * jac[:, i], minlength=sites) for i in (0, 1)]
                                   ) / np.maximum(weight, 1e-300)[:, None]
        kept = weight / (1.0 + weight * r.site_sd**2)  # a site's information once its bias is unknown
        info = (mean_jac * kept[:, None]).T @ mean_jac + prior
    try:
        return np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return np.full((2, 2), np.inf)
