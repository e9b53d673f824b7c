"""What a track's estimate reports beside its mean: a provisional sample's mean and ellipse, the posterior's modes
and their masses, and the estimate's state with the warnings behind it (docs/interface.md, "Estimate states")."""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from aoa_localizer.engine.crlb import ELLIPSE_95
from aoa_localizer.engine.inference.checks import ellipse_and_reach
from aoa_localizer.engine.inference.co_channel import COUNT_SURE, Count, Place
from aoa_localizer.engine.inference.global_search import Mode
from aoa_localizer.engine.inference.safety import HealthMonitor
from aoa_localizer.engine.track.calibrator import Calibrator
from aoa_localizer.engine.track.initiator import MAX_ELLIPSE_RANGE_SHARE
from aoa_localizer.engine.track.state import Status
from aoa_localizer.engine.types import EstimateState
from aoa_localizer.filters.base import ParticleFilter

_ELLIPSE_MASS = 0.95  # the share of the posterior a provisional estimate's ELLIPSE_95 ellipse holds
_MODE_MIN_MASS = 0.01  # modes reported
_SUSPECT_WILD_SHARE = 0.4  # more bearings than this unexplained: the model does not fit (state `suspect`)
_AMBIGUOUS_MASS = 0.2  # a second mode this heavy leaves the estimate poorly determined
_MEDIAN_MAX_STEPS, _MEDIAN_TOL_M = 100, 1e-3  # Weiszfeld's iteration: it stops when a step is under a millimetre
_MEDIAN_MIN_DISTANCE_M = 1e-6  # a particle at the iterate weighs as if this far (its own weight is then dominant)


def cloud_estimate(f: ParticleFilter, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A wide posterior's estimate: `centre` (a place its tails along the rays do not drag out, as they drag its mean)
    with the cloud's second moment about it, scaled so the 95 % ellipse holds 95 % of the cloud."""
    centre = np.array(centre, float)
    w, d = f.weights, f.x - centre
    cov = (w[:, None] * d).T @ d
    try:
        d2 = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)
    except np.linalg.LinAlgError:
        return centre, cov
    order = np.argsort(d2)
    at = min(int(np.searchsorted(np.cumsum(w[order]), _ELLIPSE_MASS)), len(order) - 1)
    return centre, cov * max(float(d2[order][at]), 1e-12) / ELLIPSE_95


def spatial_median(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The weighted cloud's spatial (geometric) median, the place of least expected distance to the emitter
    (Weiszfeld's iteration from the mean): the mean for a symmetric cloud, and unmoved by a tail along a ray."""
    m = w @ x
    for _ in range(_MEDIAN_MAX_STEPS):
        inv = w / np.maximum(np.hypot(x[:, 0] - m[0], x[:, 1] - m[1]), _MEDIAN_MIN_DISTANCE_M)
        step = (inv @ x) / inv.sum() - m
        m = m + step
        if math.hypot(step[0], step[1]) < _MEDIAN_TOL_M:
            break
    return m


def wide_for_range(history: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> tuple[bool, float, float]:
    """(whether the 95 % ellipse's semi-major axis is over MAX_ELLIPSE_RANGE_SHARE of the range from the antennas of
    the filter's `history` rows, the semi-major axis, the range)."""
    h = history
    size, reach = ellipse_and_reach(mean, cov, h[:, 0], h[:, 1])
    return size > MAX_ELLIPSE_RANGE_SHARE * reach, size, reach


def mode_masses(f: ParticleFilter, modes: list[Mode]) -> list[tuple[float, float, float]]:
    """(east, north, mass) of each of the search's `modes` holding at least 1 % of the cloud's weight, heaviest
    first; the particles go to their nearest mode, and modes whose centres lie inside each other's 95 % ellipse are
    one place."""
    w = f.weights
    if len(modes) < 2:
        mean = w @ f.x
        return [(float(mean[0]), float(mean[1]), 1.0)]
    d2 = np.stack([np.einsum("ni,ij,nj->n", f.x - m.mean, np.linalg.inv(m.cov), f.x - m.mean) for m in modes])
    clusters = merge_overlapping(f.x, w, np.argmin(d2, axis=0))
    out = [(float(c[0]), float(c[1]), mass) for c, _, mass in clusters if mass >= _MODE_MIN_MASS]
    return sorted(out, key=lambda t: -t[2])


def merge_overlapping(x: np.ndarray, w: np.ndarray, label: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Weighted particles `x`, `w` in the clusters `label` gives, as (centre, covariance, mass) each, after joining
    any two clusters whose centres lie inside either one's 95 % ellipse (two hypotheses a metre apart are one)."""
    label = label.copy()
    while True:
        stats = {}
        for j in np.unique(label):
            sel = label == j
            mass = float(w[sel].sum())
            if mass <= 0:
                continue
            c = (w[sel] @ x[sel]) / mass
            d = x[sel] - c
            stats[j] = (c, (w[sel, None] * d).T @ d / mass, mass)
        pair = next(((i, j) for i in stats for j in stats if i < j
                     and min(_inside(stats[i], stats[j][0]), _inside(stats[j], stats[i][0])) <= ELLIPSE_95), None)
        if pair is None:
            return list(stats.values())
        label[label == pair[1]] = pair[0]


def _inside(cluster: tuple[np.ndarray, np.ndarray, float], place: np.ndarray) -> float:
    """The squared Mahalanobis distance of `place` from a cluster (inf for a cluster with no spread)."""
    centre, cov, _ = cluster
    try:
        return float((place - centre) @ np.linalg.solve(cov, place - centre))
    except np.linalg.LinAlgError:
        return math.inf


def wild_share(c: Calibrator) -> float:
    """The share of the bearings the calibration reads as wild."""
    return max(c.outlier_prob if c.grid is None else 0.0, c.noise.reading_outlier_prob if c.noise.fits else 0.0)


def looks_wild(c: Calibrator, others_share: float = 0.0) -> bool:
    """More of the bearings look wild than the model allows, beyond the `others_share` that other transmitters on
    the frequency explain."""
    return wild_share(c) - others_share > _SUSPECT_WILD_SHARE


def _misfits(health: HealthMonitor, c: Calibrator, others_share: float, counting: bool
             ) -> tuple[list[str], str | None]:
    """What says the model does not fit (the supervisor's `health` in alarm, many wild bearings beyond the
    `others_share` other transmitters explain), and the one finding that keeps the estimate `poorly_determined`
    instead: another transmitter's turn, or a count asked for by these under way (`counting`)."""
    warnings, keyed = [], None
    if health.alarm_since is not None:
        disagree = f"({sum(health.flags)} of the last {len(health.flags)} points disagree)"
        if counting:
            keyed = (f"the estimate does not explain the newest bearings {disagree}: another transmitter on this "
                     "frequency, multipath or an emitter that moved; the transmitters on it are being counted")
        elif others_share > 0.0:
            # the newest bearings are another transmitter's turn: the model fits, which one the track follows is open
            keyed = (f"the estimate does not explain the newest bearings {disagree}: another transmitter on this "
                     "frequency has its turn (see the count), and the track may move to it")
        else:
            warnings.append(f"the estimate no longer explains the newest bearings {disagree}: multipath, an emitter "
                            "that moved, or a bearing reference or offset set wrong (bearing_reference, "
                            "mount_offset_deg, magnetic_declination_deg)")
    if looks_wild(c, others_share):
        wild = f"{100 * wild_share(c):.0f} % of the bearings look wild"
        if counting:
            keyed = keyed or (f"{wild}: another transmitter on this frequency, or a model that does not fit; the "
                              "transmitters on it are being counted")
        else:
            warnings.append(f"{wild}: a bearing offset or reference set wrong (bearing_reference, mount_offset_deg, "
                            "magnetic_declination_deg), or heavy multipath")
    return warnings, keyed


def assess(mean: np.ndarray, cov: np.ndarray, modes: list, health: HealthMonitor, c: Calibrator, status: Status,
           history: np.ndarray | None, others_share: float = 0.0, counting: bool = False
           ) -> tuple[EstimateState, list[str]]:
    """The estimate's state and the warnings behind it: `suspect` when the model does not fit the bearings
    (_misfits; the calibration `c` turning them by an offset or the course), `poorly_determined` when the posterior
    is proper but wide or multi-modal, or only a provisional sample (no filter `history`: the track's `status` says
    why), or when a misfit is another transmitter's turn or is being counted (`counting`), else `tracking`."""
    warnings, keyed = _misfits(health, c, others_share, counting)
    if c.course:
        warnings.append("the bearings turn with the vehicle: they look measured from its forward axis, not from north; "
                        f"learned, and each is turned by the vehicle's course: {c.offset_advice()}")
    elif c.offset:
        warnings.append(f"the bearings look {c.offset_deg:+.1f} deg off the true bearings (true azimuth = read "
                        f"azimuth {c.offset_deg:+.1f} deg), learned and corrected: {c.offset_advice()}")
    if warnings:
        return EstimateState.SUSPECT, warnings
    if keyed is not None:
        return EstimateState.POORLY_DETERMINED, [keyed]
    if history is None:
        why = status.why or status.words()
        return EstimateState.POORLY_DETERMINED, [f"few or poorly crossing bearings: {why}"]
    wide, size, reach = wide_for_range(history, mean, cov)
    if wide:
        return EstimateState.POORLY_DETERMINED, [
            f"the 95 % ellipse ({size:.0f} m) is wide for the range ({reach:.0f} m)"]
    if len(modes) > 1 and modes[1][2] >= _AMBIGUOUS_MASS:
        return EstimateState.POORLY_DETERMINED, [f"a second place holds {100 * modes[1][2]:.0f} % of the posterior"]
    return EstimateState.TRACKING, []


def others_share(count: Count | None, mean: np.ndarray) -> float:
    """The share of a channel's readings that its other transmitters explain (the track follows the one nearest its
    estimate `mean`); 0 with one transmitter."""
    if count is None or count.count < 2:
        return 0.0
    nearest = min(count.transmitters, key=lambda p: float(np.hypot(*(p.mean - mean))))
    return sum(p.share for p in count.transmitters) - nearest.share


def between_transmitters(count: Count | None, mean: np.ndarray, cov: np.ndarray) -> str | None:
    """Why a channel's estimate is at none of the places its count found (the filter followed the bearings of two
    transmitters, or of one and its interleaved ghost, mixed: a place between them), or None: it lies within the
    95 % region of one place (their covariances summed), or the count found one place."""
    if count is None or (count.count < 2 and not count.ghosts) or count.probability < COUNT_SURE:
        return None  # an unsure count's places do not question the estimate
    places = count.transmitters if count.count >= 2 else count.fitted
    def d2(p: Place) -> float:
        diff = np.asarray(mean, float) - p.mean
        try:
            return float(diff @ np.linalg.solve(np.asarray(cov) + p.cov, diff))
        except np.linalg.LinAlgError:
            return math.inf
    nearest = min(places, key=d2)
    if d2(nearest) <= ELLIPSE_95:
        return None
    far = float(np.hypot(*(np.asarray(mean, float) - nearest.mean)))
    if count.count >= 2:
        return (f"this estimate is at none of the {count.count} transmitters ({far:.0f} m from the nearest, outside "
                "both their ellipses): the bearings of several are mixed in it; each transmitter's place is in "
                "`transmitters`")
    return (f"this estimate is at neither place whose bearings interleave ({far:.0f} m from the nearer, outside both "
            "their ellipses): the bearings of both are mixed in it")


STATIONS_DISAGREE_DEG = 3.0  # stations' fitted biases further apart than this are said


def stations_disagree(count: Count | None) -> str | None:
    """What a count over several stations' readings found of their steady biases, when they are further apart than
    STATIONS_DISAGREE_DEG (one receiver's bias or north reference, which the channel's filter, taking the stations
    as one receiver, cannot learn); None otherwise."""
    if count is None or count.site_bias.size < 2 or len(count.site_names) != count.site_bias.size:
        return None
    deg = -np.degrees(count.site_bias)  # as azimuths read them (clockwise): the site's map-angle bias turned
    if float(deg.max() - deg.min()) <= STATIONS_DISAGREE_DEG:
        return None
    each = ", ".join(f"{name} {d:+.1f} deg" for name, d in zip(count.site_names, deg, strict=True))
    return (f"the stations' bearings disagree by {float(deg.max() - deg.min()):.1f} deg ({each} against the "
            "place): a receiver's steady bias or north reference (bearing_reference, mount_offset_deg); the "
            "estimate mixes them")


def co_channel(count: Count, antennas: np.ndarray | None, max_k: int,
               name: Callable[[np.ndarray], str] | None = None, estimate_is: str = "the track's"
               ) -> tuple[list[tuple[Place, EstimateState]], list[str]]:
    """The transmitters of a channel's count with their states (`tracking` when the count is sure and the place's
    95 % ellipse is narrow for its range from the `antennas` (N, 2), given whenever there are transmitters), and
    the warnings the count makes: several transmitters; a place whose bearings interleave with the estimate's; more
    transmitters than `max_k`. `name` words a place (default: its east and north), `estimate_is` what the
    channel's own estimate is."""
    name = name or (lambda x: f"E {x[0]:.0f} N {x[1]:.0f}")
    out, warnings = [], []
    for place in count.transmitters:
        assert antennas is not None  # given whenever there are transmitters
        size, reach = ellipse_and_reach(place.mean, place.cov, antennas[:, 0], antennas[:, 1])
        # more on the air than allowed: a place may hold another's readings too, so none is sure
        sure = (count.probability >= COUNT_SURE and size <= MAX_ELLIPSE_RANGE_SHARE * reach
                and not count.more_than_allowed)
        out.append((place, EstimateState.TRACKING if sure else EstimateState.POORLY_DETERMINED))
    if count.count >= 2:
        places = ", ".join(f"{name(p.mean)} ({100 * p.share:.0f} %)" for p in count.transmitters)
        warnings.append(f"{count.count} transmitters on this frequency (p = {count.probability:.2f}), taking turns: "
                        f"{places}; each is in `transmitters`, this estimate is {estimate_is} (a reflection heard "
                        "alone while the direct path was blocked looks the same)")
    for ghost in count.ghosts:
        where = f"a second place, {name(ghost.mean)}, explains {100 * ghost.share:.0f} %"
        if count.probabilities.get(2, 0.0) >= 1.0 - COUNT_SURE:  # the turns and the interleaving fit alike
            warnings.append(f"{where} of the bearings: a second transmitter taking turns, or a reflection; the "
                            f"readings are too far apart in time to tell (p = {count.probabilities[2]:.2f} for two)")
        else:
            warnings.append(f"{where} of the bearings, interleaved with this one's: a reflection, or another carrier "
                            "on the air at the same time (bearings alone cannot tell which)")
    if count.more_than_allowed:
        warnings.append(f"more transmitters than max_emitters_per_channel ({max_k}) seem to be on this frequency: "
                        "each place given may hold another's readings too (raise the limit to see them)")
    return out, warnings
