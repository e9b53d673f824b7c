"""The receiver as the bearings show it: the calibrated noise model, the point outlier share, the noise as latent
hypotheses while the readings cannot calibrate it yet, and a learned constant bearing offset. Points are made with
them; a new calibration returns the track's points rebuilt with it (the track adopts them and re-weights its
cloud)."""
from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.inference.checks import fit_noise
from aoa_localizer.engine.inference.global_search import Robust, residuals
from aoa_localizer.engine.inference.noise import NoiseModel, point_outlier_prob
from aoa_localizer.engine.inference.point_batch import Built, PointBatch, offset_point, points_of, sigmas
from aoa_localizer.engine.inference.receiver import NoiseGrid
from aoa_localizer.engine.inference.receiver_pool import PooledNoise
from aoa_localizer.engine.points.course import group_courses, turned
from aoa_localizer.engine.points.preprocess import columns, make_point
from aoa_localizer.engine.track.state import WindowEntry
from aoa_localizer.engine.types import ObservationPoint, Reading

log = logging.getLogger("aoa_localizer")


@dataclass
class Recalibration:
    """What a new calibration makes of a track's points: them rebuilt with it, how many more of their readings it
    gates out (fewer: negative), and the events it counts (recalibrated, offset_learned, offset_taken_back,
    course_learned)."""

    window: deque[WindowEntry]
    gated: int
    events: list[str] = field(default_factory=list)


class Calibrator:
    """One track's receiver calibration (noise.py, receiver.py, offset.py)."""

    def __init__(self, cfg: LocalizerConfig, pool: Callable[[], PooledNoise | None] | None = None):
        """`pool`: asks for the receiver's calibration pooled over its other channels (Channels.pooled_noise)."""
        self.cfg = cfg
        self.noise = NoiseModel(cfg.outlier_prob)
        self.outlier_prob = cfg.outlier_prob  # point level, in the likelihood
        # The receiver's noise as latent hypotheses, marginalised with the position until the readings calibrate it
        # (None: known, or calibrated)
        self.grid: NoiseGrid | None = None
        self.offset = 0.0  # a constant bearing offset the data determined (ENU rad, offset.py), taken off every point
        # the bearings turn with the vehicle: each is turned by its course before the offset (course.py)
        self.course = False
        self.held_course = math.nan  # the course the newest point's readings ended on
        if cfg.noise == "unknown" and cfg.likelihood == "mixture":
            self.grid = NoiseGrid.for_config(cfg)
        # The receiver's calibration pooled over its other channels (Channels.pooled_noise), asked once, at the
        # track's first search; `pooled` what it said (None: nothing was pooled)
        self.pool = pool
        self.pooled: PooledNoise | None = None
        self._pool_asked = False
        self._summary: tuple[NoiseModel, int, float, dict] | None = None  # (model, fits, share, summary)

    def noise_prior(self) -> NoiseGrid | None:
        """The latent noise the track's searches and filter use (None once the readings calibrated it): the weak
        prior, or, from the track's first search on, the receiver's pooled calibration when other channels have
        one. Taken once, so the searches and the filter always agree on it."""
        if self.grid is not None and not self._pool_asked:
            self._pool_asked = True
            pooled = self.pool() if self.pool is not None else None
            if pooled is not None:
                self.grid, self.pooled = NoiseGrid.for_config(self.cfg, pooled), pooled
        return self.grid

    def sigmas(self, readings: Sequence[Reading]) -> np.ndarray:
        """Each reading's sigma under the calibrated noise model (the configured one until calibrated)."""
        return sigmas(readings, self.noise if self.cfg.calibrate_noise else None)

    def make(self, readings: Sequence[Reading]) -> tuple[ObservationPoint, np.ndarray]:
        """The point of `readings` under the calibrated noise model (the readings' own sigmas until calibrated)."""
        if self.course:
            readings, self.held_course = turned(readings, self.held_course)
        calibrated = self.cfg.calibrate_noise
        made = make_point(readings, self.cfg, self.sigmas(readings) if calibrated else None,
                          self.noise.heading_scale if calibrated else 1.0)
        return offset_point(made, self.offset)

    @property
    def lik_outlier_prob(self) -> float:
        """The outlier share the likelihood uses: the calibrated one for `likelihood: mixture`, 0 for the paper's
        Gaussian (which then stays Gaussian, in the filter and in the searches)."""
        return self.outlier_prob if self.cfg.likelihood == "mixture" else 0.0

    def noise_summary(self, base_sigma_deg: Callable[[float], float]) -> dict:
        """The calibrated noise's summary (NoiseModel.summary) with the point outlier share; every estimate carries
        one, so it is made again only for another model, a new fit (a model changes only by fit(), which counts
        them) or another share. The caller gets its own dicts."""
        n, cached = self.noise, self._summary
        if cached is None or cached[0] is not n or cached[1:3] != (n.fits, self.outlier_prob):
            summary = n.summary(base_sigma_deg)
            summary["point_outlier_prob"] = round(self.outlier_prob, 4)
            cached = self._summary = (n, n.fits, self.outlier_prob, summary)
        summary = cached[3]
        return {**summary, "sigma_deg": dict(summary["sigma_deg"])}

    def calibrate(self, window: deque[WindowEntry], robust: Robust, candidates: list[np.ndarray],
                  by_density: bool) -> Recalibration | None:
        """Fit position and noise jointly (checks.fit_noise) from the candidate places, then adopt the fit: the
        `window`'s points rebuilt with it; None when no fit was made."""
        batch = PointBatch([e.readings for e in window], self.cfg)
        fit = fit_noise(batch, self.noise, robust, candidates, by_density)
        if fit is None:
            return None
        return self.apply(fit.noise, fit.at, {}, fit.offset, fit.batch.course, window)

    def apply(self, noise: NoiseModel, at: np.ndarray, built: dict[int, tuple[Sequence[Reading], Built]], offset: float,
              course: bool, window: deque[WindowEntry]) -> Recalibration:
        """Adopt `noise`, the bearing `offset` and `course` (bearings turned by the vehicle's course), fitted at the
        place `at`: the `window`'s points rebuilt with them (`built`: points already made with them, by their
        group's identity), and the point outlier share re-estimated on them (a changed offset moves the posterior:
        the check's re-start test that follows finds the new place)."""
        events = ["recalibrated"]
        self.noise = noise
        window_courses = group_courses([columns(e.readings) for e in window]) if course else None
        if course and not self.course:
            self.course = True
            self.offset = offset
            events.append("course_learned")
            log.warning("the bearings turn with the vehicle: they look measured from its forward axis, not from "
                        "north; learned, and each is turned by the vehicle's course (%s)", self.offset_advice())
        if offset != self.offset:
            self.offset = offset
            events.append("offset_learned" if offset else "offset_taken_back")  # taken back: the taker says why
            if offset and self.course:
                log.warning("the bearings turned by the vehicle's course look %+.1f deg off: learned (%s)",
                            self.offset_deg, self.offset_advice())
            elif offset:
                log.warning("the bearings look %+.1f deg off the true bearings: learned, and taken off every bearing "
                            "(%s)", self.offset_deg, self.offset_advice())
        if window_courses is not None and window_courses.size:
            self.held_course = float(window_courses[0])
        built = dict(built)
        late = [e.readings for e in window if (b := built.get(id(e.readings))) is None or b[0] is not e.readings]
        if late and not self.course:  # (turned by the course, each point holds the course from the one before)
            # The points that came after the check's snapshot, made together: one by one, they held up the call
            batch = PointBatch(late, self.cfg).built(self.noise if self.cfg.calibrate_noise else None, self.offset)
            built.update((id(g), (g, b)) for g, b in zip(late, batch, strict=True))
        rebuilt: deque[WindowEntry] = deque()
        delta = 0
        for entry in window:
            made = built.get(id(entry.readings))
            point, kept = made[1] if made is not None and made[0] is entry.readings else self.make(entry.readings)
            now = int((~kept).sum())
            delta += now - entry.gated
            rebuilt.append(WindowEntry(entry.readings, point, now))
        if window_courses is not None and window_courses.size:
            self.held_course = float(window_courses[-1])
        pts = points_of([e.point for e in rebuilt])
        self.outlier_prob = point_outlier_prob(residuals(at, pts), pts.sigma, self.outlier_prob)
        self.grid = None  # the readings calibrated the noise: from now on it is taken as fitted
        return Recalibration(rebuilt, delta, events)

    @property
    def offset_deg(self) -> float:
        """The learned offset as azimuth degrees: true azimuth = read azimuth + this."""
        return math.degrees(self.offset)

    def offset_advice(self) -> str:
        """The setting that would take the learned offset off at the receiver, as a question."""
        cfg = self.cfg
        if self.course:
            mount = self.offset_deg - 90.0 + (cfg.magnetic_declination_deg
                                              if cfg.bearing_reference == "magnetic_north" else 0.0)
            return (f"set bearing_reference to vehicle, heading_source to track (or imu) and mount_offset_deg to "
                    f"{(mount + 180.0) % 360.0 - 180.0:.1f}?")
        if cfg.bearing_reference == "vehicle":
            return f"set mount_offset_deg to {cfg.mount_offset_deg + self.offset_deg:.1f}?"
        if cfg.bearing_reference == "magnetic_north":
            return f"set magnetic_declination_deg to {cfg.magnetic_declination_deg + self.offset_deg:.1f}?"
        return ("a magnetic declination or mount offset not applied, or the DF's north reference set wrong "
                "(bearing_reference, magnetic_declination_deg, mount_offset_deg)?")
