"""Locate every emitter of a survey at once, the receivers calibrated jointly over the emitters they heard.

The model (docs/design.md, "Honest on real bearings"): a station's centre bearing of an emitter is the true
bearing plus its receiver's bias plus an error of the family in noise_family.py, whose scale and wild share are
hypotheses on a grid. Emitters linked by a common receiver form a group: the hypotheses'
posterior pools the group's evidence, and each emitter's posterior is the mixture of its own posteriors under
them. A receiver heard over three or more emitters learns its bias (bias.py) and every fix is made again with
it; an emitter heard mostly by one receiver gets that receiver's shared, place-like error, a prior no crossing
can check.
"""
from __future__ import annotations

import math
from collections import Counter, defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from aoa_localizer.engine.crlb import ellipse_axes
from aoa_localizer.engine.distributions import chi2_sf
from aoa_localizer.engine.geodesy import LocalFrame, centroid, wrap_pi
from aoa_localizer.engine.survey.survey_log import SurveyCount, SurveyTransmitter
from aoa_localizer.engine.types import EstimateState
from aoa_localizer.pooled.bias import BIAS_MIN_EMITTERS, Bias, learn_biases, residuals
from aoa_localizer.pooled.grid import (
    CELLS,
    Geometry,
    displaced,
    evidence,
    log_joint,
    median_range,
    mixture,
    prior_scale,
    rebinned,
    refined_mode,
    widened,
    zoom,
)
from aoa_localizer.pooled.noise_family import NoiseGrid, expected_error, logsumexp, noise_grid, quantile_of
from aoa_localizer.pooled.region import LEVELS, Region, mode, moment, size_text, summarise
from aoa_localizer.pooled.stations import Station, SurveyReading, make_stations, pooled_scatter, station_variance
from aoa_localizer.pooled.transmitters import count_id

_ROUNDS = 2  # fixes made without biases, then again with the biases the first fixes showed
_OFF_Z = 3.0  # a station further off than this many of its expected errors is named
_HELD_LOW, _HELD_HIGH = 0.90, 0.99  # a 95 % ellipse holding mass outside this range is said to mislead
_FIT_P = 0.05  # a fix whose stations' residuals are this unlikely under their expected errors is not `tracking`
_RANGE_CAP = 2.0  # a truth's range counts up to this many times the crossing's (beyond, the Cauchy prior rules)
# The place-like error's prior was fitted to two walking observers (docs/design.md, "Errors that no crossing
# shows"): a receiver as coarse as they were (a learned station error of about 7 deg), a handful of stations per
# emitter. It is applied in that regime and fades outside it: half at this station error, as this power of the
# scale's ratio to it (their learned 7-11 deg keep it whole; a 3 deg receiver, where nothing was fitted, keeps 3 %) ...
PLACE_LIKE_SCALE_DEG = 4.0
PLACE_LIKE_STEEPNESS = 12
PLACE_LIKE_STATIONS = 6  # ... and as the square of the ratio beyond this many stations of one emitter
_NEGLIGIBLE = 1e-3  # a share of the hypotheses' posterior too small to change a region
REPEATED_READINGS = 3  # a group whose median station has this many readings measures their scatter apart

__all__ = ["EmitterFix", "PooledResult", "ReceiverCalibration", "SurveyReading", "locate_pooled"]


@dataclass(frozen=True)
class EmitterFix:
    """One emitter's estimate: WGS84, the covariance (m^2, east/north at the emitter), its state and warnings,
    and its highest-density regions (level -> rings of (lat, lon)) with the mass the covariance's ellipses hold."""

    emitter: str
    lat: float
    lon: float
    cov: np.ndarray
    state: EstimateState
    warnings: list
    stations: int
    readings: int
    receivers: list
    hpd: dict
    ellipse_mass: dict
    count: SurveyCount | None = None  # how many transmitters its bearings come from (None: not counted)

    def semi_axes(self, level: float = 0.95) -> tuple[float, float]:
        """The covariance's ellipse at this level: semi-major, semi-minor (m)."""
        a, b, _ = ellipse_axes(self.cov, -2.0 * math.log(1.0 - level))
        return a, b


@dataclass(frozen=True)
class ReceiverCalibration:
    """What the survey taught about one receiver: its bias (deg; NaN: not learned) and what it is learned from."""

    name: str
    bias_deg: float
    bias_sd_deg: float
    emitters: int
    stations: int


@dataclass
class PooledResult:
    """Every emitter's fix, the ones refused with their reason, the receivers' calibration, each group's pooled
    noise (docs/interface.md, "locate") and warnings about the input."""

    fixes: dict = field(default_factory=dict)
    refused: dict = field(default_factory=dict)
    receivers: dict = field(default_factory=dict)
    noise: list = field(default_factory=list)
    warnings: list = field(default_factory=list)


def _geometry(emitter: str, stations: list[Station], scatter: dict[str, float]) -> Geometry | str:
    """The emitter's geometry in a frame at its stations' centroid, or why it has none."""
    if len({(s.lat, s.lon) for s in stations}) < 2:
        return "all its bearings come from one place: a direction, but no range"
    frame = LocalFrame(*centroid([s.lat for s in stations], [s.lon for s in stations]), 0.0)
    lat, lon = np.array([s.lat for s in stations]), np.array([s.lon for s in stations])
    e, n = frame.to_enu(lat, lon)
    xy = np.column_stack([e, n])
    # each station's azimuth from its own north, turned to the frame's (the meridians converge: near a pole
    # stations a few km apart see north tens of degrees apart)
    centre = wrap_pi(np.array([s.centre for s in stations]) + 0.5 * np.pi - frame.north_angle(lat, lon))
    var = np.array([station_variance(s, scatter.get(s.receiver, 0.0)) for s in stations])
    return Geometry(emitter, frame, xy, centre, var, tuple(s.receiver for s in stations),
                    tuple(s.name for s in stations), prior_scale(xy, centre))


def _groups(geoms: dict[str, Geometry]) -> list[list[str]]:
    """Emitters linked by shared receivers (union-find): each group pools its own noise."""
    parent = {e: e for e in geoms}

    def root(e: str) -> str:
        while parent[e] != e:
            parent[e] = parent[parent[e]]
            e = parent[e]
        return e

    first: dict[str, str] = {}
    for e, g in geoms.items():
        for r in g.receivers:
            parent[root(e)] = root(first.setdefault(r, e))
    groups: dict[str, list[str]] = defaultdict(list)
    for e in geoms:
        groups[root(e)].append(e)
    return list(groups.values())


@dataclass(frozen=True)
class _Solved:
    """A group's fixes under its pooled hypotheses' weights."""

    log_w: np.ndarray
    log_z: dict
    boxes: dict
    regions: dict
    biases: dict
    shifts: dict
    extra: dict


def _solve(geoms: dict[str, Geometry], noise: NoiseGrid, progress: Callable[[str, int, int], None]) -> _Solved:
    """Pool the group's evidence over the hypotheses, fix every emitter; then learn the biases and fix again."""
    shifts = {e: np.zeros(len(g.xy)) for e, g in geoms.items()}
    extra = {e: np.zeros(len(g.xy)) for e, g in geoms.items()}
    biases: dict[str, Bias] = {}
    for round_ in range(_ROUNDS):
        stage = f"calibrating the receivers, round {round_ + 1} of {_ROUNDS}"
        found = {}
        for done, (e, g) in enumerate(geoms.items()):
            progress(f"{stage}, evidence", done, len(geoms))
            found[e] = evidence(g, shifts[e], extra[e], noise)
        log_z = {e: z for e, (z, _) in found.items()}
        total = noise.log_prior + sum(log_z.values())
        log_w = total - logsumexp(total, axis=0)
        boxes, regions = {}, {}
        for done, (e, g) in enumerate(geoms.items()):  # one emitter's grid at a time: thousands of ids hold none
            progress(f"{stage}, fixes", done, len(geoms))
            z = zoom(g, shifts[e], extra[e], noise, log_w, found[e][1])
            p = mixture(z.log_joint, log_z[e], log_w)
            # past the cells, in every round: the biases are learned from these points, and a point a cell's
            # resolution off would carry its own jitter into them
            point = refined_mode(g, z.box, p, shifts[e], extra[e], noise, log_w, log_z[e])
            boxes[e], regions[e] = z.box, summarise(z.box, p, point)
        biases = learn_biases(geoms, {e: r.point for e, r in regions.items()})
        if not biases or round_ == _ROUNDS - 1:
            break
        for e, g in geoms.items():
            for k, r in enumerate(g.receivers):
                if r in biases:
                    shifts[e][k], extra[e][k] = biases[r].without[e]
    return _Solved(log_w, log_z, boxes, regions, biases, shifts, extra)


def _displaced(geom: Geometry, solved: _Solved, noise: NoiseGrid) -> Region:
    """The region once one receiver's shared, place-like error is added: its bearings of one emitter may all point
    at a place beside it (scattering by the transmitter, an observer's belief), which no crossing shows. Its size
    is the receiver class's prior, in shares of the truth's range (so a truth beyond the crossing is displaced
    further), times the share of the stations that the emitter's most frequent receiver holds (stations of
    different receivers are independent instruments: a receiver with a single station shares nothing). It applies
    to each station-error hypothesis in proportion to how coarse that hypothesis is (`coarse_share`), so the
    posterior is the mixture of the fine hypotheses' own region and the coarse ones' displaced region."""
    e, region = geom.emitter, solved.regions[geom.emitter]
    most = Counter(geom.receivers).most_common(1)[0][1]
    if most < 2 or noise.repeated or not np.any(noise.shared_place > 0):
        return region  # a station that repeats its readings is an instrument's, not an observer's stop
    coarse = coarse_share(np.degrees(noise.tau))
    share_coarse = float(np.exp(solved.log_w) @ coarse)
    if share_coarse < _NEGLIGIBLE:
        return region
    src = solved.boxes[e]
    lj = log_joint(geom, src, solved.shifts[e], solved.extra[e], noise)
    with np.errstate(divide="ignore"):
        log_coarse, log_fine = np.log(coarse), np.log1p(-coarse)
    rng_m = float(median_range(geom.xy, region.point[:1], region.point[1:])[0])
    # an emitter ringed by many stations is where it was not fitted (3-5 a collar): it fades fast beyond six
    shares = noise.shared_place * most / len(geom.receivers) * min(1.0, PLACE_LIKE_STATIONS / len(geom.xy)) ** 2
    cap = _RANGE_CAP * rng_m
    out = widened(src, 3.0 * float(shares.max()) * cap)
    floor = 0.5 * min(src.hx, src.hy) / CELLS  # a share of 0 still moves the mass onto the wider grid
    p_coarse = mixture(lj, solved.log_z[e], solved.log_w + log_coarse)
    q = displaced(src, p_coarse, out, geom.xy, shares, noise.shared_weight, cap, geom.prior_scale, floor)
    if share_coarse > 1.0 - _NEGLIGIBLE:
        return summarise(out, q)
    fine_w = solved.log_w + log_fine
    p_fine = mixture(lj, solved.log_z[e], fine_w)
    # the point is the mode of the part holding most of the mass: the whole mixture's mode would follow a spike of
    # a few per cent (the fine hypotheses' crossing is far narrower than the coarse ones' displaced region)
    point = mode(out, q) if share_coarse >= 0.5 else refined_mode(
        geom, src, p_fine, solved.shifts[e], solved.extra[e], noise, fine_w, solved.log_z[e])
    cov = (1.0 - share_coarse) * moment(src, p_fine, point) + share_coarse * moment(out, q, point)
    return summarise(out, (1.0 - share_coarse) * rebinned(src, p_fine, out) + share_coarse * q, point, cov)


def coarse_share(scale_deg: np.ndarray) -> np.ndarray:
    """The chance that a receiver of this station error (deg) is as coarse as the observers the place-like error
    was fitted to (a person with a Yagi, learned at 7-11 deg): near 1 from about 5 deg, a half at 4 deg, 3 % at
    3 deg and nothing below 2.5 deg, where bearings that agree to a few degrees suggest an instrument and nothing
    suggests the error."""
    return 1.0 / (1.0 + (PLACE_LIKE_SCALE_DEG / np.maximum(scale_deg, 1e-9)) ** PLACE_LIKE_STEEPNESS)


def _noise_summary(noise: NoiseGrid, log_w: np.ndarray, receivers: list[str], emitters: int) -> dict:
    weights, deg = np.exp(log_w), np.degrees
    return {"receivers": receivers, "scale_deg": round(float(deg(expected_error(noise, weights))), 2),
            "scale_deg_90": [round(float(deg(quantile_of(noise.tau, weights, q))), 2) for q in (0.05, 0.95)],
            "wild_share": round(float(weights @ noise.wild), 3), "emitters": emitters}


def _fix(geom: Geometry, region: Region, shift: np.ndarray, extra: np.ndarray, scale_deg: float,
         readings: int) -> EmitterFix:
    """The published fix: its state, and a warning for each station far off and for a misleading ellipse."""
    lat, lon, _ = geom.frame.to_geodetic(float(region.point[0]), float(region.point[1]))
    warnings, state = [], EstimateState.TRACKING
    resid = np.degrees(wrap_pi(residuals(geom, region.point) - shift))
    expected = np.sqrt(scale_deg**2 + np.degrees(np.sqrt(geom.var + extra)) ** 2)
    for name, r, ex in zip(geom.names, resid, expected, strict=True):
        if abs(r) > _OFF_Z * ex:
            warnings.append(f"station {name or 'unnamed'}'s bearing is {r:+.0f} deg off the estimate (expected "
                            f"within +-{ex:.0f}): a reflection, a misread, or a different emitter")
    a95 = ellipse_axes(region.cov)[0]
    reach = float(median_range(geom.xy, region.point[:1], region.point[1:])[0])
    if len(geom.xy) < 3:
        state = EstimateState.POORLY_DETERMINED
        warnings.append("bearings from two places only: nothing checks their crossing")
    elif len(geom.xy) == 3:
        state = EstimateState.POORLY_DETERMINED
        warnings.append("three stations: one wild bearing among them could not be told from the others")
    # the stations not named as off: do they meet within their spread? (a named one is the wild share's)
    z2 = (resid / expected) ** 2
    z2 = z2[z2 <= _OFF_Z**2]
    fit_p = float(chi2_sf(float(z2.sum()), z2.size - 2)) if z2.size > 2 else 1.0
    if fit_p < _FIT_P:
        state = EstimateState.POORLY_DETERMINED
        warnings.append(f"the bearings do not meet within their expected spread (chi-square p = {fit_p:.2g}): one "
                        "of them may be wild")
    if a95 > reach:
        state = EstimateState.POORLY_DETERMINED
        warnings.append(f"the 95 % region ({size_text(a95)} m) is wide for the range ({size_text(reach)} m)")
    if len(region.hpd[0.95]) > 1:
        state = EstimateState.POORLY_DETERMINED
        warnings.append(f"the 95 % region is in {len(region.hpd[0.95])} parts: see `hpd`")
    held = region.ellipse_mass[0.95]
    if not _HELD_LOW <= held <= _HELD_HIGH:
        word = "understates" if held < _HELD_LOW else "overstates"
        warnings.append(f"the 95 % ellipse {word} the posterior (it holds {100 * held:.0f} %): see `hpd`")
    hpd = {lvl: [np.column_stack(geom.frame.to_geodetic(ring[:, 0], ring[:, 1])[:2]) for ring in region.hpd[lvl]]
           for lvl in LEVELS}
    return EmitterFix(geom.emitter, float(lat), float(lon), region.cov, state, warnings, len(geom.xy), readings,
                      sorted(set(geom.receivers)), hpd, dict(region.ellipse_mass))


def _part_fix(readings: list[SurveyReading], receiver_class: str) -> SurveyTransmitter | None:
    """One transmitter of an id that several share, fixed by this model from the readings it took (not counted
    again), or None where it has no fix."""
    fix = locate_pooled(readings, receiver_class, max_k=1).fixes.get(readings[0].emitter) if readings else None
    return None if fix is None else SurveyTransmitter(fix.lat, fix.lon, fix.cov, math.nan, fix.state)


def _calibrations(geoms: dict[str, Geometry], biases: dict[str, Bias]) -> dict[str, ReceiverCalibration]:
    heard: dict[str, set] = defaultdict(set)
    stations: Counter = Counter()
    for e, g in geoms.items():
        for r in g.receivers:
            heard[r].add(e)
            stations[r] += 1
    out = {}
    for r, emitters in heard.items():
        bias, var = biases[r].overall if r in biases else (math.nan, math.nan)
        out[r] = ReceiverCalibration(r, math.degrees(bias), math.degrees(math.sqrt(var)), len(emitters), stations[r])
    return out


def _with_count(fix: EmitterFix, count: SurveyCount) -> EmitterFix:
    """The fix with its id's transmitter count."""
    state, warnings = count.applied(fix.state, fix.warnings)
    return replace(fix, state=state, warnings=warnings, count=count)


def _nothing(*_args) -> None:
    return None


def locate_pooled(readings: list[SurveyReading], receiver_class: str = "unknown", max_k: int = 3,
                  on_fix: Callable[[str, EmitterFix | str, dict | None], None] = _nothing,
                  progress: Callable[[str, int, int], None] = _nothing) -> PooledResult:
    """Every emitter's fix from a survey's readings (docs/interface.md, "locate"), each id's transmitters counted
    up to `max_k` (1: not counted); a ValueError for an unknown receiver class. A long survey is followed by
    `on_fix(id, fix or why none, its group's noise summary)` as each id is done (its group's noise learned), and
    `progress(stage, done, of)` while its group is calibrated."""
    grids = {repeated: noise_grid(receiver_class, repeated) for repeated in (False, True)}  # a bad class: at once
    stations, warnings = make_stations(readings)
    result = PooledResult(warnings=warnings)
    scatter = pooled_scatter(stations)
    by_emitter: dict[str, list[Station]] = defaultdict(list)
    for s in stations:
        by_emitter[s.emitter].append(s)
    geoms: dict[str, Geometry] = {}
    for e, mine in by_emitter.items():
        g = _geometry(e, mine, scatter)
        if isinstance(g, str):
            result.refused[e] = g
            on_fix(e, g, None)
        else:
            geoms[e] = g
    heard: dict[str, list[SurveyReading]] = defaultdict(list)
    for r in readings:
        heard[r.emitter].append(r)
    for names in _groups(geoms):
        group = {e: geoms[e] for e in names}
        repeats = np.median([s.n for e in names for s in by_emitter[e]])
        noise = grids[bool(repeats >= REPEATED_READINGS)]
        solved = _solve(group, noise, progress)
        summary = _noise_summary(noise, solved.log_w, sorted({r for g in group.values() for r in g.receivers}),
                                 len(group))
        result.noise.append(summary)
        for e, g in group.items():
            region = _displaced(g, solved, noise)
            fix = _fix(g, region, solved.shifts[e], solved.extra[e], summary["scale_deg"], len(heard[e]))
            counted = count_id(heard[e], g, region.point, math.radians(summary["scale_deg"]), max_k,
                               lambda part: _part_fix(part, receiver_class))
            result.fixes[e] = fix if counted is None else _with_count(fix, counted)
            on_fix(e, result.fixes[e], summary)
        result.receivers.update(_calibrations(group, solved.biases))
    result.warnings += _receiver_warnings(result.receivers)
    return result


def _receiver_warnings(receivers: dict[str, ReceiverCalibration]) -> list[str]:
    """A word when most receivers are heard too rarely to learn anything of their own (a column of ids)."""
    few = [c for c in receivers.values() if c.emitters < BIAS_MIN_EMITTERS]
    if len(receivers) >= 10 and len(few) > len(receivers) / 2:
        return [f"{len(few)} of {len(receivers)} receivers heard fewer than 3 ids: none of them learns a bias of its "
                "own (is the `receiver` column what took each bearing?)"]
    return []

