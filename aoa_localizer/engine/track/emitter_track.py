"""One emitter's track: observation points -> start -> filter updates, with the robustness layer around any filter.

The Localizer pairs readings with the GPS track and groups them; a track turns each group into an observation
point and keeps the estimate honest on messy data. The track is the one owner of its state (its points, filter,
provisional sample, modes, job and status): three parts decide, and it acts on what they return:

* the initiator (initiator.py) says when to search for a start and what a search found, and makes the filters: an
  importance sample of the robust posterior from the search's modes (every mode in proportion to its mass), a
  provisional sample, or triangulation or the prior;
* the supervisor (supervisor.py) watches each new point's health, says when a global check is due (made inline, or
  its expensive part in a worker process: checks.py) and what its modes make of the cloud (a move, or a re-start),
  and whether the emitter moved;
* the calibrator (calibrator.py) holds the receiver as the data show it (noise, outlier share, latent noise, bearing
  offset): points are made with it, and a new calibration returns the points rebuilt with it.
"""
from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import replace
from functools import partial

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.inference.checks import CheckResult, refined
from aoa_localizer.engine.inference.co_channel import (
    COUNT_GROWTH,
    COUNT_SURE,
    MIN_READINGS,
    Count,
    Readings,
    count_job,
)
from aoa_localizer.engine.inference.global_search import Mode, Points, Robust, find_modes
from aoa_localizer.engine.inference.motion import MOVING_P, SURE_MOTION_P, UNSURE_P, Motion, MotionWatch, median_bearing
from aoa_localizer.engine.inference.noise import NoiseModel
from aoa_localizer.engine.inference.point_batch import Built
from aoa_localizer.engine.inference.receiver_pool import PooledNoise
from aoa_localizer.engine.inference.safety import ModeProposal, importance_sample
from aoa_localizer.engine.inference.site_part import site_part_spread
from aoa_localizer.engine.points.preprocess import Columns, fields, first_antenna, stations
from aoa_localizer.engine.rejections import Reason
from aoa_localizer.engine.scheduling.scheduler import PendingJob, Scheduler
from aoa_localizer.engine.scheduling.slices import CHECK_BUDGET_US, START_BUDGET_US
from aoa_localizer.engine.track.calibrator import Recalibration
from aoa_localizer.engine.track.held import COUNT_EVERY_MAX, HEARD_READINGS, Held
from aoa_localizer.engine.track.initiator import START_SWEEPS, Holding, Initiator, Outcome
from aoa_localizer.engine.track.report import looks_wild, others_share
from aoa_localizer.engine.track.said import Moving, Said, Standing, positive_definite
from aoa_localizer.engine.track.state import Phase, Status, WindowEntry
from aoa_localizer.engine.track.supervisor import CheckVerdict, Moved, Supervisor, Watch
from aoa_localizer.engine.types import EstimateState, ObservationPoint, Reading
from aoa_localizer.filters.base import ParticleFilter

log = logging.getLogger("aoa_localizer")

_CALIBRATION_SWEEPS = 2  # moves after a calibration that left the cloud's weights degenerate
COUNT_MAX_READINGS = 1500  # more heard: every k-th point's readings (whole points: a bin's readings stay together)
STATION_BIAS_SD_DEG = 5.0  # the prior sd of each station's steady bias in a count of several stations' readings
SITE_MIN_POINTS = 12  # the site part is fitted from this many of the filter's points on ...
SITE_GROWTH = 1.25  # ... and again once they grew by this factor (a fit costs 5-30 ms)


class EmitterTrack(Held):
    """The life of one emitter's estimate: points in, the filter started, supervised and calibrated; the one
    owner of what it holds (held.py). `reject(reason, count)` counts unused inputs."""

    def __init__(self, cfg: LocalizerConfig, rng: np.random.Generator, reject: Callable[[Reason, int], None],
                 scheduler: Scheduler, pool: Callable[[], PooledNoise | None] | None = None):
        """`scheduler`: where the start searches and global checks run (inline, or beside the filter); `pool`: the
        receiver's calibration pooled over its other channels, asked for (Calibrator)."""
        super().__init__(cfg, rng, scheduler, pool)
        self.reject = reject
        self.initiator = Initiator(cfg, rng, scheduler)
        self.supervisor = Supervisor(cfg)

    # -- the flow -----------------------------------------------------------------------------------
    def add(self, readings: Sequence[Reading]) -> Said | None:
        """One closed group of readings; what the track says after it (said()) when the filter took it (or started)
        and has a new estimate, else None. Its job's turn comes after the filter's step, within what the step left
        of the call's budget (the Localizer opens it: slices.one_call)."""
        t0 = time.perf_counter()
        owed_before = self.scheduler.debt(self.filter).modes
        for place in self.places:
            self.scheduler.point_came(place)
        applied = self.apply_job()  # a job's findings first: they may change the noise the point is made with
        self.heard.append(readings)
        self.heard_readings += len(readings)
        self.heard_held += len(readings)
        while self.heard_held > HEARD_READINGS and len(self.heard) > 1:
            self.heard_held -= len(self.heard.popleft())
        point, kept = self.calibration.make(readings)
        self.motion = self._watch_motion(median_bearing(readings)) or self.motion  # the cloud before the point
        self.last_stamp, self.last_kept = point.stamp, kept
        entry = WindowEntry(readings, point, int((~kept).sum()))
        if entry.gated:
            self.reject(Reason.POINT_OUTLIER, entry.gated)
        self.points_seen += 1
        if self.filter is None:
            self.window.append(entry)
            # (a provisional sample applied above is a new estimate even when no search finishes now)
            took = self._try_start() or (applied and self.estimating)
        else:
            took = self._update(entry, owed_before)
        self.scheduler.take_turn(self)
        if self.apply_job():  # one that finished now is applied now, as at a point
            took = self.estimating
        self.doubts.append(self.filter is None or self.supervisor.alarm)
        sure = self.motion is not None and self.motion.p_moving >= SURE_MOTION_P
        self.sure_run = self.sure_run + 1 if sure else 0
        moving = self.motion is not None and self.motion.p_moving >= MOVING_P and self.standing_doubted
        misfit = moving or self.supervisor.alarm or looks_wild(self.calibration)
        if misfit and not self.misfit and not self.count_pending:
            self.count_asked = self.heard_readings  # one ask at a time: a misfit that comes and goes asks once answered
        self.misfit = misfit
        self.scheduler.take_turn(self.counting)
        self._count()
        self.scheduler.take_turn(self.site_fitting)
        self.fit_site_part()
        self.last_update_s = time.perf_counter() - t0  # what this point cost, searches and calibration included
        return self.said() if took or self.moving else None

    def _watch_motion(self, point: ObservationPoint) -> Motion | None:
        """A point's readings (as one, as the receiver gave them: median_bearing) read by the motion watch
        (motion.py), begun on the first, against the filter's cloud and the covariance it would publish before the
        point (motion is judged once a filter runs: a provisional sample's
        spread is no standing transmitter's posterior); None with `motion_model: static` or without `global_safety`
        (the filters alone), while the bearings are turned by the vehicle's course, or when the watch failed
        (counted `internal_error`); the watch begins again when the calibration learns an offset or takes one back
        while motion is improbable."""
        if self.cfg.motion_model == "static" or not self.cfg.global_safety:  # the filters alone: no watch either
            return None
        if self.calibration.course:  # bearings turned by the vehicle's course: every turn would read as a move
            self.watch, self.sure_run, self.motion = None, 0, None
            return None
        # an offset learned or taken back: the standing model the watch's odds were weighed against is another, and
        # it begins again, unless it found motion probable (an offset learned then may be a mover's drift read as one,
        # and the watch begun again lost the mover: a walker's estimates were the filter's own, 12 % inside their
        # ellipse); a refined offset is the same model refined, and the watch goes on (its moving cloud reads the
        # bearings as given: a mover's track begun again at each refinement lost what it had learned of the mover)
        another = (self.watched_offset == 0.0) != (self.calibration.offset == 0.0)
        probable = self.motion is not None and self.motion.p_moving >= UNSURE_P
        if self.watch is not None and another and not probable:
            self.watch, self.sure_run, self.motion = None, 0, None
        elif self.watch is not None:
            self.watched_offset = self.calibration.offset
        if self.watch is None:  # the first point is the moving cloud's prior: its line of bearing
            self.watch = MotionWatch(point, self.cfg.max_transmitter_speed_mps, self.rng.spawn(1)[0],
                                     self.cfg.gps_sigma_m)
            self.watched_offset = self.calibration.offset
            return None
        f = self.filter
        try:
            standing = None if f is None else (f.x, f.weights, self.estimate()[1], self.calibration.offset)
            return self.watch.step(point, standing)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError, MemoryError):
            # a failed watch costs the motion, never the point: it begins again at the next one
            log.exception("motion watch failed; it begins again")
            self.reject(Reason.INTERNAL_ERROR, 1)
            self.watch = None
            return None

    def _update(self, entry: WindowEntry, owed_before: bool = False) -> bool:
        """The running filter's update with one point (and the moves it owes the scheduler), then the supervisor's
        watch; False when it did not take it. `owed_before`: a check's move on the modes was owed before the point
        came (and was not made between points): made now."""
        f = self.running
        before = self.model.history.appended
        logw_before = f.logw  # replaced by the update, never changed in place
        try:
            ok = f.update(entry.point)
            if ok:
                self.scheduler.stepped(f)
            if ok and self.model.history.appended > before:
                self.window.append(entry)
                while len(self.window) > len(self.model.history):
                    self.window.popleft()
            if ok and f.finite():
                self._watch(f, logw_before)
                if owed_before:
                    self.scheduler.pay_modes(self.filter, self.proposal)
            if self.filter is None:  # the emitter moved and the re-start waits for more points
                return False
            f = self.running
        except (ArithmeticError, ValueError, np.linalg.LinAlgError, MemoryError):
            log.exception("filter update failed; point skipped")
            self.reject(Reason.INTERNAL_ERROR, 1)
            return False
        if not f.finite():
            self._diverged()
            return False
        if not ok:
            self.reject(Reason.WEIGHTS_DEGENERATE, 1)
            return False
        self.points_used += 1
        self.bearings_used += entry.point.n_readings
        return True

    def _restart(self):
        """Drop the filter (the emitter moved) and start again from the points kept."""
        self.filter = None
        self.modes, self.proposal = [], None
        self.points_used = 0
        self.bearings_used = 0
        self._try_start()

    def _diverged(self):
        self.filter = None
        self.window.clear()
        self.status = Status(Phase.DIVERGED)
        log.error("filter %s diverged (non-finite particles or estimate); restarting", self.cfg.algorithm)
        self.reject(Reason.FILTER_DIVERGED, 1)

    def finish(self) -> bool:
        """End of data: the worker's job still running is applied (and a start the worker lagged behind is tried
        inline), then one more global check over everything kept runs inline (unless the last point just had
        one). True when the estimate changed."""
        t0 = time.perf_counter()
        changed = False
        while self.job is not None:  # a stale start search is run again, over all the points: wait for that too
            changed = self.apply_job(wait=True) or changed
        self.scheduler.pay_all(self.filter)
        if self.filter is None:  # the end of data: the best estimate the points allow, never "collecting"
            self.initiator.search_now()
            changed = self._try_start(inline=True, final=True) or changed
        if self.filter is not None and self.cfg.global_safety and self.supervisor.last_search_point != self.points_seen:
            self._global_check(inline=True)
            self.apply_job(wait=True)  # the start search of an emitter-moved re-start
            changed = True
        if self.filter is not None:  # the site part at the final place, over every point kept
            before = self.site_spread
            self.fit_site_part(final=True)
            changed = changed or self.site_spread is not before
        self.last_update_s = time.perf_counter() - t0
        return changed and self.estimating

    def apply_job(self, wait: bool = False) -> bool:
        """Apply the worker's result once it is ready (`wait`: wait for it); True when one was applied. A result for
        a filter that has since been replaced (re-start, divergence) is dropped."""
        job = self.scheduler.finished(self, wait)
        if job is None:
            return False
        ok, result = self.scheduler.value(job, "a start search" if job.is_start else "a global check")
        if not ok or self.filter is not job.filter:
            return False
        try:
            if job.is_start:
                return self._apply_start(result, job.groups)
            self._apply_check(result, job.groups)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            log.exception("applying a global check failed; skipped")
            self.reject(Reason.INTERNAL_ERROR, 1)
            return False
        if self.filter is not None and not self.filter.finite():
            self._diverged()
        return True

    def _apply_fit(self, res: CheckResult, groups: list[Sequence[Reading]]):
        """A search's noise and offset fit, if it made one, adopted by the calibrator."""
        if res.noise is not None and res.at is not None:
            self._recalibrate(res.noise, res.at, _by_group(groups, res.built), res.offset, res.course)

    # -- starts ---------------------------------------------------------------------------------------
    def _try_start(self, inline: bool = False, final: bool = False) -> bool:
        """Start the filter once the points allow (`inline`: the start search here, even with a worker; `final`: the
        end of data, with whatever points there are)."""
        cfg, ini = self.cfg, self.initiator
        if cfg.has_prior:
            return self._start_then_replay(*ini.prior(), "prior")
        if len(self.window) > cfg.init_max_points:
            self.window.popleft()
            self.reject(Reason.INIT_BUFFER_FULL, 1)
        if len(self.window) < (min(2, cfg.init_bearings) if final else cfg.init_bearings):
            self.status = Status(Phase.COLLECTING, held=len(self.window), needed=cfg.init_bearings)
            return False
        if cfg.init_method == "triangulation":
            made = ini.triangulation([e.point for e in self.window])
            if isinstance(made, str):
                self.status = Status(Phase.WAITING_FOR_GEOMETRY, made)
                return False
            return self._start_then_replay(*made, "triangulation")
        if not final and not ini.search_due(len(self.window), self.job is not None):
            return False
        snap = self.snapshot()
        job = ini.search_job(snap, final)
        if inline:
            return self._apply_start(job(), snap.groups)
        self.scheduler.start(self, job, START_BUDGET_US, None, snap.groups)
        return self.apply_job()  # a sliced search small enough to finish in its first call starts the filter now

    def _apply_start(self, res: CheckResult, groups: list[Sequence[Reading]]) -> bool:
        """Start the filter from a start search's modes over the points held now (a background search's snapshot
        may have fewer): an importance sample of the posterior, then MH sweeps; or hold a provisional sample and
        wait for more points (searching again at once when enough came while it ran)."""
        outcome = self.initiator.outcome(res, len(self.window))
        if outcome is Outcome.SEARCH_AGAIN:
            return self._try_start()
        self._apply_fit(res, groups)
        modes = res.modes
        if outcome is Outcome.START:
            self.provisional = None
            self.filter, self.proposal = self.initiator.sample_posterior(modes, self._holding())
            self._started(f"global search: best of {len(modes)} mode(s), {modes[0].inliers} of {len(self.window)} "
                          "points agree")
            self._hold_modes(modes)
            return True
        self.status = Status(Phase.WAITING_FOR_GEOMETRY, res.why)
        if modes and res.sample is not None:
            # Proper but not determined: publish the search's sample of the posterior (wide, honest), not nothing
            self.provisional, self.proposal = self.initiator.provisional(modes, res.sample, res.searched,
                                                                         self._holding())
            self.status = Status(Phase.POORLY_DETERMINED, res.why)
            self._hold_modes(modes, groups)
        searched_again = len(self.window) >= self.initiator.next_start_try and self._try_start()
        return searched_again or bool(modes)

    def _holding(self) -> Holding:
        c = self.calibration
        return Holding([e.point for e in self.window], self.reach(), c.lik_outlier_prob, c.noise_prior())

    def _hold_modes(self, modes: list[Mode], searched: list[Sequence[Reading]] | None = None):
        """The track's modes and its estimate's points: every point waiting (none before: a start holds all), or
        those of them the search drew a provisional sample over (`searched`: their readings)."""
        self.modes = modes
        held = list(self.window)
        if searched is not None:
            ids = {id(g) for g in searched}
            held = [e for e in held if id(e.readings) in ids]
        self.points_used = len(held)
        self.bearings_used = sum(e.used for e in held)

    def _start_then_replay(self, particles: np.ndarray, mean: np.ndarray, cov: np.ndarray, how: str) -> bool:
        """A filter started from `particles` (the paper's start, or the prior), then every point held updates it."""
        c = self.calibration
        self.filter = self.initiator.replayed_filter(particles, mean, cov, c.noise_prior(), c.lik_outlier_prob)
        waiting, self.window = list(self.window), deque()
        self._started(how)
        result = False
        for entry in waiting:
            result = self._update(entry) or result
        return result

    def _started(self, how: str):
        self.status = Status(Phase.TRACKING)
        self.supervisor.started(len(self.window))
        log.info("filter %s started after %d observation points (%s)", self.cfg.algorithm, self.points_seen, how)

    # -- supervision ----------------------------------------------------------------------------------
    def _watch(self, f: ParticleFilter, logw_before: np.ndarray):
        """The supervisor's watch of the point `f` just took, acted on: a calibration, the alarm's status and
        events, a global check, or the moves while in alarm."""
        watch: Watch = self.supervisor.watch(f, logw_before, len(self.window), self.points_seen,
                                             self.calibration.outlier_prob, self.job)
        if watch.calibrate:
            best = f.x[np.argmax(f.log_target(f.x))]
            self._calibrate([refined(best, self.points(), self.robust())], False)
            return
        if watch.alarm_began:
            self.events["alarm"] += 1
        if watch.alarm:
            self.events["alarm_points"] += 1
            flags = self.supervisor.health.flags
            self.status = Status(Phase.CHECKING, disagree=sum(flags), tested=len(flags))
        elif self.status.phase is Phase.CHECKING:
            self.status = Status(Phase.TRACKING)
        if watch.check:
            self._global_check()
        elif watch.sweeps:
            f.rejuvenate(watch.sweeps, self.proposal)

    def _global_check(self, inline: bool = False):
        """Noise calibration, emitter-moved test, global search, MH move or re-start: whole here (`inline`), or its
        expensive part handed to the worker or made in turns, one per point (applied by apply_job() once finished:
        here when it finished in its first call)."""
        snap = self.snapshot()
        job = self.supervisor.check_job(snap, self.points_seen)
        if inline:
            self._apply_check(job(), snap.groups)
            return
        self.scheduler.start(self, job, CHECK_BUDGET_US, self.running, snap.groups)
        self.apply_job()

    def _apply_check(self, res: CheckResult, groups: list[Sequence[Reading]]):
        """The cheap part of a global check, on the current cloud and points: re-weight by the fitted noise,
        emitter-moved test (in alarm), then the modes' MH move or a re-start from a far better mode."""
        self._apply_fit(res, groups)
        if self.supervisor.alarm:
            moved = self.supervisor.moved(self.points(), self.points_seen, self.running,
                                          self.calibration.lik_outlier_prob, bool(self.calibration.noise.fits))
            if moved is not None:
                self._emitter_moved(moved)
                return
        if not res.modes:
            return
        f = self.running
        self.modes = res.modes
        self.proposal = ModeProposal.over(res.modes, self.points())
        verdict = self.supervisor.verdict(res, f, self.points(), self.robust(), self.scheduler.realtime)
        if verdict is CheckVerdict.RESTART:
            self.events["global_restart"] += 1
            f.replace_cloud(importance_sample(f.log_target, self.proposal, f.n, self.rng))
            f.rejuvenate(START_SWEEPS, self.proposal)
        elif verdict is CheckVerdict.MOVE:
            f.rejuvenate(1, self.proposal)
        else:  # realtime: the modes' move is owed, made between points (or at the next point)
            self.scheduler.owe_modes(f)

    def _emitter_moved(self, moved: Moved):
        """Drop the points from before the move and re-start from the recent ones."""
        dropped = [self.window.popleft() for _ in range(len(self.window) - moved.recent)]
        self.reject(Reason.EMITTER_MOVED, sum(e.used for e in dropped))
        self.events["emitter_moved"] += 1
        self._restart()
        if self.filter is not None:
            self.status = Status(Phase.TRACKING, restarted_from=moved.recent)

    # -- calibration ----------------------------------------------------------------------------------
    def _calibrate(self, candidates: list[np.ndarray], by_density: bool) -> bool:
        """A joint fit of position and noise from the candidate places, adopted; True when one was made."""
        recalibration = self.calibration.calibrate(self.window, self.robust(), candidates, by_density)
        if recalibration is not None:
            self._adopt(recalibration)
        return recalibration is not None

    def _recalibrate(self, noise: NoiseModel, at: np.ndarray, built: dict[int, tuple[Sequence[Reading], Built]],
                     offset: float, course: bool):
        if self.counted is not None and self.counted.count >= 2 and self.counted.probability >= COUNT_SURE:
            # several transmitters on the air: their bearings, fitted as one, differ by an angle that is no
            # receiver's offset (the count fits its own offset beside none); the offset in use stays
            offset = self.calibration.offset
        self._adopt(self.calibration.apply(noise, at, built, offset, course, self.window))

    def _adopt(self, recalibration: Recalibration):
        """The points rebuilt with a new calibration, and the cloud re-weighted by the change of posterior."""
        f = self.filter  # None while waiting to start: only the points are rebuilt
        old = f.log_target(f.x) if f is not None else None
        if recalibration.gated:
            self.reject(Reason.POINT_OUTLIER, recalibration.gated)
        self.window = recalibration.window
        self.events.update(recalibration.events)
        if f is None or old is None:
            return
        self.model.history.data = self.points().rows()
        self.model.lik.outlier_prob = self.calibration.lik_outlier_prob
        self.model.grid = None
        f.reweight(f.log_target(f.x) - old)
        if f.ess() < self.cfg.ess_threshold * f.n:
            f.resample()
            f.rejuvenate(_CALIBRATION_SWEEPS, self.proposal)

    def said(self, final: bool = False) -> Said:
        """What the track says now: the newest count made (at the end of data, `final`, made again over every
        reading), then the mover the estimate follows (Moving), or the standing place with its state (Standing)."""
        count = self.count_transmitters(final=final)
        noise = self.noise_summary() if self.cfg.calibrate_noise else None
        if self.moving:
            motion, watch = self.motion_said, self.watch
            assert motion is not None and watch is not None
            return Moving(self.last_stamp, motion, watch.place.copy(), watch.weights.copy(), self.bearings_used,
                          self.points_used, noise)
        mean, cov = (np.asarray(v, float) for v in self.estimate())
        degenerate = not positive_definite(cov)
        modes, state, warnings = ([], EstimateState.POORLY_DETERMINED, []) if degenerate else self.assess(
            mean, cov, others_share(count, mean))
        # the antennas only rate the transmitters' ellipses: a single transmitter (most channels) skips them
        antennas = (np.array([first_antenna(g) for g in self.heard])
                    if count is not None and count.transmitters else None)
        cloud = self.cloud
        return Standing(self.last_stamp, mean, cov, degenerate, modes, state, warnings, cloud.ess(), cloud.x.copy(),
                        cloud.weights.copy(), self.bearings_used, self.points_used, noise, count, antennas,
                        self.motion, self.motion_said, self.motion_unheeded, self.count_explains_motion)

    def count_transmitters(self, final: bool = False) -> Count | None:
        """How many transmitters the channel's bearings come from (co_channel.py): the newest count made. At the end
        of data (`final`) the count under way is waited for, and made again whenever the readings grew."""
        if final:
            self._count(final=True)
        return self.counted

    def _count(self, final: bool = False):
        """A count that finished is adopted; a new one is started when the readings heard doubled since the last
        began or grew by count_every (HEARD_READINGS, longer while counts agree; a long run's newest are counted),
        or at the end of data whenever they grew: a job of the scheduler's (the check worker's, or made in turns),
        made here at the end of data. No count
        before MIN_READINGS, with `max_emitters_per_channel` 1, or while the bearings are turned by the course."""
        self._adopt_count(self.scheduler.finished(self.counting, wait=final))
        cfg, c = self.cfg, self.calibration
        grown = self.heard_readings > self.counted_readings
        asked = self.count_asked is not None and self.counted_readings < self.count_asked
        due = grown and (final or asked or self.heard_readings >= min(COUNT_GROWTH * self.counted_readings,
                                                                       self.counted_readings + self.count_every))
        if (cfg.max_emitters_per_channel < 2 or c.course or self.heard_readings < MIN_READINGS or not due
                or not self.estimating or self.scheduler.job(self.counting) is not None):
            return
        groups = list(self.heard)
        stride = math.ceil(self.heard_held / COUNT_MAX_READINGS)
        chosen = groups[::-1][::stride][::-1]  # the newest point always in
        # The readings as heard, with their own sigmas (the configured model): a receiver calibrated on two
        # transmitters' bearings reads them as one wide noise or an offset; the count fits its own of both
        f = Columns(*np.concatenate([fields(g) for g in chosen], axis=1))
        heard = Readings(f.stamp, f.east, f.north, f.theta, np.maximum(f.sigma, 1e-4), f.quality)
        names, station = np.unique([s for g in chosen for s in stations(g)], return_inverse=True)
        if names.size >= 2:  # each station's receiver may carry a steady bias of its own: a site of the count's
            heard = replace(heard, site=station, site_sd=math.radians(STATION_BIAS_SD_DEG))
        first = self.filter.estimate()[0] if self.filter is not None else self.modes[0].mean
        job = partial(count_job, heard, np.asarray(first, float), cfg.max_emitters_per_channel, c.offset,
                      tuple(str(n) for n in names) if names.size >= 2 else ())
        self.counted_readings = self.heard_readings
        if final:
            self.counted, self.counted_upto = job(), self.counted_readings
            return
        self.scheduler.start(self.counting, job, CHECK_BUDGET_US, None, [])
        self._adopt_count(self.scheduler.finished(self.counting))  # a count small enough to finish in its first turn

    def between_points(self) -> bool:
        """Between points (Localizer.idle, for a track one of whose jobs finished): a transmitter count or site-part
        fit that finished is adopted now, not at the next point, which may never come, and one now due (a filter
        just started) is begun. True when one was adopted (the estimate it changes is to be published)."""
        counted, spread = self.counted, self.site_spread
        self._count()
        self.fit_site_part()
        return self.counted is not counted or self.site_spread is not spread

    def _adopt_count(self, done: PendingJob | None):
        """A finished count adopted (a failed one leaves the last)."""
        if done is not None:
            ok, count = self.scheduler.value(done, "a transmitter count")
            if ok:
                self.count_every = count_every(self.count_every, self.counted, count)
                self.counted, self.counted_upto = count, self.counted_readings
                self._offset_taken_back(count)

    def _offset_taken_back(self, count: Count | None):
        """An offset learned from the bearings of several transmitters read as one (the count places them at no
        offset) is taken back: the points are rebuilt without it."""
        c = self.calibration
        if (count is None or count.count < 2 or count.probability < COUNT_SURE or count.offset != 0.0
                or c.offset == 0.0 or c.course):
            return
        log.warning("the bearing offset learned (%+.1f deg) was %d transmitters' bearings read as one: taken back",
                    c.offset_deg, count.count)
        at = self.filter.estimate()[0] if self.filter is not None else count.transmitters[0].mean
        self._adopt(c.apply(c.noise, np.asarray(at, float), {}, 0.0, False, self.window))

    def fit_site_part(self, final: bool = False):
        """A finished site-part fit adopted; a new one started once the filter's points grew by SITE_GROWTH since the
        last (from site_part.MIN_POINTS), made here at the end of data (`final`)."""
        self._adopt_site_part(self.scheduler.finished(self.site_fitting, wait=final))
        f = self.filter
        if f is None or self.scheduler.job(self.site_fitting) is not None:
            return
        pts = self.posterior_points()
        n = pts.east.size
        fresh = self.site_filter is not f
        if n < SITE_MIN_POINTS or not (final or fresh or n >= SITE_GROWTH * self.site_points) or (
                final and not fresh and n == self.site_points):
            return
        job = partial(site_part_fit, id(f), pts, np.asarray(f.estimate()[0], float), self.robust())
        self.site_points = n
        if final:
            self._adopt_site_part_value(job())
            return
        self.scheduler.start(self.site_fitting, job, CHECK_BUDGET_US, None, [])
        self._adopt_site_part(self.scheduler.finished(self.site_fitting))

    def _adopt_site_part(self, done: PendingJob | None):
        if done is not None:
            ok, value = self.scheduler.value(done, "a site part's fit")
            if ok:
                self._adopt_site_part_value(value)

    def _adopt_site_part_value(self, value: tuple[int, np.ndarray]):
        """A fit's covariance, kept while the filter it was made for runs."""
        made_for, spread = value
        if self.filter is not None and id(self.filter) == made_for:
            self.site_filter, self.site_spread = self.filter, spread

    def batch_estimate(self) -> Mode | None:
        """Robust batch maximum likelihood over every point held (no filter): global search, joint noise
        calibration, Gauss-Newton; the best mode with its Laplace covariance. The benchmark's reference."""
        modes = find_modes(self.points(), self.robust(), by_density=True)
        if modes and self.cfg.calibrate_noise and self._calibrate([m.mean for m in modes[:2]], True):
            modes = find_modes(self.points(), self.robust(), by_density=True)
        return modes[0] if modes else None


def site_part_fit(made_for: int, pts: Points, at: np.ndarray, rob: Robust) -> tuple[int, np.ndarray]:
    """site_part_spread as a job (a plain function of its inputs): the covariance, with `made_for`, the identity of
    the filter whose points were read."""
    return made_for, site_part_spread(pts, at, rob)


def count_every(every: int, before: Count | None, now: Count | None) -> int:
    """The readings until the count after `now`: twice `every` (at most COUNT_EVERY_MAX) when `now` says what
    `before` said, each surely (p >= 0.9); else HEARD_READINGS again."""
    agree = (before is not None and now is not None and before.count == now.count
             and min(before.probability, now.probability) >= 0.9)
    return min(2 * every, COUNT_EVERY_MAX) if agree else HEARD_READINGS


def _by_group(groups: Iterable[Sequence[Reading]], built: list[Built]) -> dict[int, tuple[Sequence[Reading], Built]]:
    """A check's points rebuilt with its noise, by their group's identity (empty when the check made none)."""
    return {id(g): (g, b) for g, b in zip(groups, built, strict=True)} if built else {}
