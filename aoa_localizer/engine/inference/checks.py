"""A track's global check and its start search as jobs: the noise fit and the global search over a snapshot of its
points, which can run beside the filter (in a worker process) while new points keep coming.

The check's expensive part (EM noise fits at a few candidate places, the points rebuilt with the fitted noise,
the search for every mode, the stamp-shift test) reads only the snapshot: readings and points are immutable, the
noise model and the prior are copies. Its result is applied by the track, in the call that ends its last turn
(`scheduling: reproducible`: made in turns within the calls, so a seed repeats a run; slices.py) or at the track's
next point (`realtime`), where the cheap part
runs on the current cloud and points: the re-weighting by the new noise, the emitter-moved test, the re-start test.
A start search's result starts the filter from the modes it found over the points held then.

The worker is a process, not a thread: a thread shares the interpreter lock, and a busy check stretched every
callback of the node (measured: twice as long). A snapshot crosses as a few arrays (its readings' fields packed).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.crlb import ELLIPSE_95
from aoa_localizer.engine.geodesy import wrap_pi
from aoa_localizer.engine.inference.clock_check import ClockHint, best_shift
from aoa_localizer.engine.inference.global_search import (
    Mode,
    Points,
    Robust,
    find_modes,
    log_posterior,
    point_log_densities,
    refine,
    residuals,
)
from aoa_localizer.engine.inference.noise import NoiseModel, point_outlier_prob
from aoa_localizer.engine.inference.offset import ALL_OFFSETS_DEG, PRIOR_LOG_ODDS, joint_optimum, shifted
from aoa_localizer.engine.inference.point_batch import Built, PointBatch, points_of
from aoa_localizer.engine.inference.provisional import DRAWS, provisional_sample
from aoa_localizer.engine.inference.start_grid import StartGrid
from aoa_localizer.engine.points.course import moved
from aoa_localizer.engine.points.preprocess import Group, fields
from aoa_localizer.engine.types import Reading


def refined(x: np.ndarray, pts: Points, rob: Robust) -> np.ndarray:
    """The posterior mode nearest x (Gauss-Newton)."""
    return refine(x[None, :], np.zeros(1), pts, rob)[0][0]


def fit_noise(batch: PointBatch, noise: NoiseModel, rob: Robust, candidates: list[np.ndarray], by_density: bool,
              offset: float = 0.0, try_course: bool = False) -> Fit | None:
    """Position and noise jointly: at each candidate place, and at the best mode under the configured noise, EM
    fits the noise and Gauss-Newton refines the place; the pair whose readings are likeliest wins (a wrong place
    explained by a wide noise loses to the right place with the right noise), unless its core is hollow (a place
    between two sources, whose readings cluster either side of it). Then, with `learn_offset`, a constant bearing
    offset (offset.py) is tried at the winner: adopted when the readings' likelihood gains more than the bearing
    reference's prior log odds; and, with `try_course`, for a north reference on a moving vehicle, the bearings turned
    by its course (course.py) with an offset of their own, adopted when they gain as much again over the best of
    north and explain more than an emitter that moved once or keeps moving. None when the readings are too few for
    a fit."""
    cfg, c = batch.cfg, batch.cols
    if c.theta.size < 2:
        return None
    rob = replace(rob, grid=None)  # each trial noise is taken as it is
    joint = _joint(batch, noise, rob, offset)
    configured = batch.points(None, offset)
    eps = cfg.outlier_prob if cfg.likelihood == "mixture" else 0.0
    narrow = find_modes(configured, Robust(eps, cfg.gps_sigma_m), by_density)
    best = None
    for x in list(candidates) + [m.mean for m in narrow[:1]]:
        fit = joint(x, offset)
        if fit is None:
            return None
        # a fit whose core is hollow explains the readings by a noise they do not have: any other wins over it
        if best is None or (not fit[1].hollow, fit[0]) > (not best[1].hollow, best[0]):
            best = fit
    if best is None:
        return None
    ll, trial, x = best
    out = Fit(trial, x, offset, batch)
    if not cfg.learn_offset:
        return out
    found = _offset_fit(batch.points(trial, offset), x, rob, offset, joint)
    # a first offset must beat the bearing reference's prior odds; one already learned is refined by any gain
    needed = 0.0 if offset else PRIOR_LOG_ODDS[cfg.bearing_reference]
    if found is not None and found[0] > ll + needed:
        ll, out = found[0], Fit(found[1], found[2], found[3], batch)
    if try_course and not batch.course and cfg.bearing_reference != "vehicle" and moved(c.v_east, c.v_north):
        turned = PointBatch(batch.groups, cfg, course=True)
        on_course = _offset_fit(turned.points(out.noise, 0.0), out.at, rob, 0.0, _joint(turned, noise, rob, 0.0),
                                ALL_OFFSETS_DEG)
        if on_course is not None and on_course[0] > ll + PRIOR_LOG_ODDS[cfg.bearing_reference]:
            course_fit = Fit(on_course[1], on_course[2], on_course[3], turned)
            turned_pts = turned.points(course_fit.noise, course_fit.offset)
            one = float(log_posterior(refined(course_fit.at, turned_pts, rob), turned_pts, rob))
            if not _moved_explains_more(out, one, rob) and not _moving_explains_more(
                    out, one, rob, PRIOR_LOG_ODDS[cfg.bearing_reference]):
                out = course_fit
    return out


def _moved_explains_more(north: Fit, one: float, rob: Robust) -> bool:
    """Whether an emitter that moved explains the points read from north at least as well as the bearings turned by the
    course do (`one`: their robust log posterior at the course fit's place), by their robust log posteriors, the move's
    extra coordinates charged log K (BIC): both bend the bearings at one moment, and a single turn cannot tell them
    apart by itself. The move is placed where the vehicle turned most, each part's place found by its global search;
    then the move goes to the point that explains the points best under those two places, and each place is refined on
    its part."""
    c, of, k = north.batch.cols, north.batch.of, north.batch.sizes.size
    if k < 6:
        return False
    heading = np.arctan2(np.bincount(of, c.v_north, k), np.bincount(of, c.v_east, k))
    cut = int(np.argmax(np.abs(wrap_pi(np.diff(heading[1:-1])))) + 2)  # at least two points either side
    pts = north.batch.points(north.noise, north.offset)
    places = []
    for part in (pts.take(np.arange(cut)), pts.take(np.arange(cut, k))):
        modes = find_modes(part, rob, True)
        places.append(modes[0].mean if modes else refined(north.at, part, rob))
    before, after = (np.cumsum(point_log_densities(x, pts, rob)) for x in places)
    # the old place up to the move, the new one from it on; at least two points either side
    cut = int(np.argmax(before[1:-2] + after[-1] - after[1:-2])) + 2
    split = 0.0
    for x, part in zip(places, (pts.take(np.arange(cut)), pts.take(np.arange(cut, k))), strict=True):
        split += float(log_posterior(refined(x, part, rob), part, rob))
    return split - math.log(k) >= one


_PIECES = 3  # a moving emitter's path, as places each holding a run of the points ...
_PIECE_POINTS = 6  # ... of at least this many


def _moving_explains_more(north: Fit, one: float, rob: Robust, prior_log_odds: float) -> bool:
    """Whether an emitter that keeps moving explains the points read from north at least as well as the bearings
    turned by the course do (`one`, as for _moved_explains_more), by their robust log posteriors, each further
    place's coordinates charged log K (BIC), and the course charged the reference's prior log odds against it, as it
    is against north (a reference set wrong is the course's claim; a transmitter on the move is no misconfiguration).
    A car's bearings drift as it drives, and a fit that turns them by the DF vehicle's course can follow part of the
    drift; a path of places, each holding an equal run of the points, follows all of it. The course's own signature,
    a bend in the bearings at each of the vehicle's turns, is what a path split by time cannot make."""
    k = north.batch.sizes.size
    pieces = min(_PIECES, k // _PIECE_POINTS)
    if pieces < 2:
        return False
    pts = north.batch.points(north.noise, north.offset)
    path = 0.0
    for run in np.array_split(np.arange(k), pieces):
        part = pts.take(run)
        modes = find_modes(part, rob, True)
        path += float(log_posterior(refined(modes[0].mean if modes else north.at, part, rob), part, rob))
    return path - (pieces - 1) * math.log(k) + prior_log_odds >= one


@dataclass
class Fit:
    """A noise fit: the noise, the place it was fitted at, the bearing offset (rad) and the points' readings as the
    fit reads them (`batch.course`: turned by the vehicle's course)."""

    noise: NoiseModel
    at: np.ndarray
    offset: float
    batch: PointBatch


JointFit = Callable[[np.ndarray, float], tuple[float, NoiseModel, np.ndarray] | None]


def _joint(batch: PointBatch, noise: NoiseModel, rob: Robust, offset: float) -> JointFit:
    """The joint fit at a place x and offset b over the batch's readings (`offset`: the one its points carry)."""
    c = batch.cols
    quality, base, heading_var = c.quality, c.sigma, c.heading_sigma**2
    at_readings = shifted(Points(c.east, c.north, c.theta, base), offset)

    def joint(x: np.ndarray, b: float) -> tuple[float, NoiseModel, np.ndarray] | None:
        """Noise at x, then x under that noise, twice; the readings' log likelihood, the noise, the place."""
        trial, ll, readings = noise.copy(), float("nan"), shifted(at_readings, b - offset)
        for _ in range(2):
            ll = trial.fit(residuals(x, readings), quality, base, heading_var)
            if not np.isfinite(ll):
                return None
            x = refined(x, batch.points(trial, b), rob)
        return ll, trial, x

    return joint


def _offset_fit(pts: Points, x: np.ndarray, rob: Robust, offset: float, joint: JointFit,
                starts_deg: np.ndarray | None = None) -> tuple[float, NoiseModel, np.ndarray, float] | None:
    """The joint (place, offset) optimum from x (offset.py) with the noise fitted again there: (log likelihood,
    noise, place, offset); None when the optimum is the current offset, or its fit's core is hollow."""
    b, x_b, _ = joint_optimum(pts, x, rob, starts_deg)
    if not b:
        return None
    total = float(wrap_pi(offset + b))
    fit = joint(x_b, total)
    return None if fit is None or fit[1].hollow else (fit[0], fit[1], fit[2], total)


@dataclass
class Snapshot:
    """What a global check reads: the kept points' readings and points ((K, 5) rows), the noise model and point
    outlier share, the robust posterior's prior, and the places the noise fit starts from (the cloud's best
    particle, the best mode of the last check)."""

    cfg: LocalizerConfig
    groups: list[Sequence[Reading]]
    rows: np.ndarray
    noise: NoiseModel
    outlier_prob: float
    rob: Robust
    best_particle: np.ndarray | None = None  # None before the start
    mode_means: list[np.ndarray] = field(default_factory=list)
    offset: float = 0.0  # the bearing offset learned so far (rad, offset.py)
    course: bool = False  # the bearings are read as turned by the vehicle's course (course.py)
    start_grid: StartGrid | None = None  # a start search's grid and sums from the search before (start_grid.py)
    sample_seed: int = 0  # a start search's provisional sample draws with this seed (provisional.py)

    def __getstate__(self) -> dict:
        """For the worker process: the readings' fields as one array and the group sizes (a list of Reading
        objects pickles tens of times slower)."""
        state = dict(self.__dict__)
        packed = np.concatenate([fields(g) for g in self.groups], axis=1) if self.groups else None
        state["groups"] = (packed, [len(g) for g in self.groups])
        return state

    def __setstate__(self, state: dict):
        packed, sizes = state["groups"]
        # fields only: what make_point and the fits read
        groups = [Group(cols=block) for block in np.split(packed, np.cumsum(sizes)[:-1], axis=1)] if sizes else []
        self.__dict__.update(state, groups=groups)

    def robust(self, outlier_prob: float, fitted: bool) -> Robust:
        """The snapshot's robust posterior (its priors, the radio-range prior among them) with another point outlier
        share (the likelihood's, as the track's); `fitted`: after a noise fit, which ends the noise's latent
        hypotheses."""
        eps = outlier_prob if self.cfg.likelihood == "mixture" else 0.0
        return replace(self.rob, outlier_prob=eps, grid=None if fitted else self.rob.grid)


@dataclass
class CheckResult:
    """A check's findings: the fitted noise and the place it was fitted at (None: no fit), each snapshot group's
    point under it (in the snapshot's order; empty without a fit), and the modes and stamp-shift hint over those
    points."""

    noise: NoiseModel | None
    at: np.ndarray | None
    built: list[Built]
    modes: list[Mode]
    hint: ClockHint | None = None
    offset: float = 0.0  # the bearing offset the fit found (rad; the snapshot's when no fit was made)
    course: bool = False  # the fit reads the bearings turned by the vehicle's course (the snapshot's without a fit)
    why: str = ""  # a start search without a usable mode, or a best mode not determined enough to start from: why
    searched: int = 0  # points in the snapshot
    determined: bool = True  # a start search: the best mode is determined enough to start the filter from
    start_grid: StartGrid | None = None  # a start search: its grid and sums, for the next one
    # a start search whose best mode is not determined: a weighted sample of the posterior it searched (places,
    # log weights; provisional.py)
    sample: tuple[np.ndarray, np.ndarray] | None = None


class _Calibrated:
    """The snapshot's points and outlier share, after a noise fit when one was made."""

    def __init__(self, snap: Snapshot):
        self.snap, self.pts, self.outlier = snap, Points.of(snap.rows), snap.outlier_prob
        self.before = self.batch = PointBatch(snap.groups, snap.cfg, snap.course)  # as the snapshot reads them
        self.noise: NoiseModel | None = None
        self.at: np.ndarray | None = None
        self.built: list[Built] = []
        self.offset = snap.offset

    def fit(self, candidates: list[np.ndarray], by_density: bool, try_course: bool = False) -> None:
        snap = self.snap
        fit = fit_noise(self.before, snap.noise, snap.rob, candidates, by_density, snap.offset, try_course)
        if fit is not None:
            self.noise, self.at, self.offset, self.batch = fit.noise, fit.at, fit.offset, fit.batch
            self._rebuild()
            if self.offset != snap.offset and self._stamp_shift_explains_more():
                self.offset, self.batch = snap.offset, self.before
                self._rebuild()

    def _rebuild(self):
        """The points and their outlier share under the fitted noise, offset and reading of the bearings."""
        self.built = self.batch.built(self.noise, self.offset)
        self.pts = points_of([p for p, _ in self.built])
        self.outlier = point_outlier_prob(residuals(self.at, self.pts), self.pts.sigma, self.snap.outlier_prob)

    def _stamp_shift_explains_more(self) -> bool:
        """Whether a DF stamp shift (clock_check.py) explains the points at the previous offset at least as well as
        the newly learned offset does: on a moving vehicle a late clock also bends every bearing, by an angle that
        follows the geometry, and an offset must not take the blame for it."""
        snap, at = self.snap, self.at
        assert at is not None  # called after a fit
        rob = snap.robust(self.outlier, True)
        before = self.before.points(self.noise, snap.offset)
        hint = best_shift(before, self.before.velocity(), at, rob)
        if hint is None:
            return False
        shifted_best = float(log_posterior(refined(at, before, rob), before, rob)) + hint.gain
        return shifted_best >= float(log_posterior(refined(at, self.pts, rob), self.pts, rob))

    def result(self, modes: list[Mode], hint: ClockHint | None = None, why: str = "",
               determined: bool = True) -> CheckResult:
        return CheckResult(self.noise, self.at, self.built, modes, hint, self.offset, self.batch.course, why,
                           len(self.snap.rows), determined, self.snap.start_grid)

    def provisional(self, modes: list[Mode], why: str) -> CheckResult:
        """A start search's result whose best mode is not determined: its modes, why, and a weighted sample of the
        posterior it searched (the radio-range prior's, under the fitted noise when it made a fit)."""
        snap = self.snap
        rob = snap.rob if self.noise is None else snap.robust(self.outlier, True)
        rng = np.random.default_rng(snap.sample_seed)
        sample = provisional_sample(modes, self.pts, rob, snap.start_grid, max(snap.cfg.num_particles, DRAWS), rng)
        return replace(self.result(modes, why=why, determined=False), sample=sample)


def run_check(snap: Snapshot) -> CheckResult:
    """The expensive part of a global check over the snapshot (nothing outside it is read or changed)."""
    cal = _Calibrated(snap)
    if snap.cfg.calibrate_noise and snap.best_particle is not None:
        start = refined(snap.best_particle, cal.pts, snap.rob)
        # the course needs a track's worth of points and turns: a global check tries it, a start search does not
        cal.fit([start] + snap.mode_means, False, try_course=True)
    pts, rob = cal.pts, snap.robust(cal.outlier, cal.noise is not None)
    modes = find_modes(pts, rob, False)
    hint = None
    if modes:
        hint = best_shift(pts, cal.before.velocity(), modes[0].mean, rob)
    return cal.result(modes, hint)


def ellipse_and_reach(mean: np.ndarray, cov: np.ndarray, east: np.ndarray, north: np.ndarray) -> tuple[float, float]:
    """The 95 % ellipse's semi-major axis and the distance from `mean` to the nearest antenna (at least 1 m), m: a
    place is determined when the first is small against the second."""
    reach = max(1.0, float(np.min(np.hypot(east - mean[0], north - mean[1]))))
    return math.sqrt(ELLIPSE_95 * max(float(np.linalg.eigvalsh(cov)[-1]), 0.0)), reach


def search_start(snap: Snapshot, min_inliers: int, max_ellipse_range_share: float,
                 final: bool = False) -> CheckResult:
    """Modes of the robust posterior over the points waiting for a start (highest density first: under a flat
    prior a far, poorly determined mode gains Laplace mass from its size), after a noise fit when the best is
    determined. No modes, and why, when the posterior is not proper yet (no two bearings cross steeply enough in
    front of their antennas); the modes with `determined` False, and why, when it is proper but the best is not
    determined well enough to start the filter from (too few points agree, or its ellipse is wide for its range).
    `final`: the end of data, where nearly parallel bearings still give their (radio-range bounded) posterior."""
    cfg, cal = snap.cfg, _Calibrated(snap)
    if len(cal.pts) < 2:
        return cal.result([], why="no crossing of bearings in front of the antennas")
    # The grid of the search before, with its sums, while the points stay within it (start_grid.py)
    snap.start_grid = snap.start_grid or StartGrid()
    modes = snap.start_grid.modes(cal.pts, snap.rob)
    if modes and modes[0].crossing_deg >= cfg.init_min_crossing_deg and cfg.calibrate_noise:
        cal.fit([m.mean for m in modes[:2]], True)
        if cal.noise is not None:
            modes = find_modes(cal.pts, snap.robust(cal.outlier, True), True)
    if not modes:
        return cal.result([], why="no crossing of bearings in front of the antennas")
    best = modes[0]
    if best.crossing_deg < cfg.init_min_crossing_deg:
        why = f"bearings nearly parallel: best crossing {best.crossing_deg:.1f} deg < {cfg.init_min_crossing_deg:g} deg"
        return cal.provisional(modes, why) if final else cal.result([], why=why, determined=False)
    if best.inliers < min_inliers:
        return cal.provisional(modes, f"the best place explains only {best.inliers} points (needs {min_inliers})")
    size, reach = ellipse_and_reach(best.mean, best.cov, cal.pts.east, cal.pts.north)
    if size > max_ellipse_range_share * reach:
        return cal.provisional(modes, f"position not determined yet: 95 % ellipse {size:.0f} m at {reach:.0f} m "
                                      "from the track")
    return cal.result(modes)
