"""What an emitter track holds and what is read off it: its points, its filter or provisional sample, the last
search's modes and their proposal, the receiver's calibration, its status; the estimate, the robust posterior's
settings and the snapshot a search takes of it. EmitterTrack (emitter_track.py) is the only class that changes it."""
from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable, Sequence
from typing import cast

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.inference.checks import Snapshot
from aoa_localizer.engine.inference.co_channel import Count
from aoa_localizer.engine.inference.emitter_model import EmitterModel
from aoa_localizer.engine.inference.global_search import Mode, Points, Robust, radio_reach
from aoa_localizer.engine.inference.motion import (
    DOUBT_POINTS,
    MOTION_YIELDS_TO_COUNT,
    MOVING_P,
    Motion,
    MotionWatch,
)
from aoa_localizer.engine.inference.offset import marginalise, prior_sd
from aoa_localizer.engine.inference.point_batch import points_of, rows_of
from aoa_localizer.engine.inference.receiver_pool import PooledNoise
from aoa_localizer.engine.inference.safety import ModeProposal
from aoa_localizer.engine.points.preprocess import reading_sigma
from aoa_localizer.engine.scheduling.scheduler import JobPlace, PendingJob, Scheduler
from aoa_localizer.engine.track.calibrator import Calibrator
from aoa_localizer.engine.track.report import assess, cloud_estimate, mode_masses, spatial_median, wide_for_range
from aoa_localizer.engine.track.state import Phase, Status, TrackState, TrackStatus, WindowEntry
from aoa_localizer.engine.track.supervisor import Supervisor
from aoa_localizer.engine.types import EstimateState, Reading
from aoa_localizer.filters.base import ParticleFilter

_CURRENT_SHARE = 0.9  # a provisional sample's share of the points held for it to count as current
HEARD_READINGS = 5000  # the newest readings (whole points) the transmitter count looks at: about 1 MB a channel
# Counts that keep agreeing are made ever less often, up to every this many readings (a count of transmitters taking
# turns costs about a second: every HEARD_READINGS it was 3 times the rest of a channel's work); one that changes
# brings them back to every HEARD_READINGS
COUNT_EVERY_MAX = 8 * HEARD_READINGS


class Held:
    """One emitter track's state, and the values read off it."""

    supervisor: Supervisor  # the track's (EmitterTrack makes it): its health is part of what the track reports

    def __init__(self, cfg: LocalizerConfig, rng: np.random.Generator, scheduler: Scheduler,
                 pool: Callable[[], PooledNoise | None] | None = None):
        self.cfg, self.rng, self.scheduler = cfg, rng, scheduler
        self.calibration = Calibrator(cfg, pool)
        # The points waiting for a start, then the filter's history
        self.window: deque[WindowEntry] = deque()
        self.filter: ParticleFilter | None = None
        # A sample of the posterior while it is proper but not determined enough to start the filter from: the
        # estimate (state `poorly_determined`) until the filter starts
        self.provisional: ParticleFilter | None = None
        self.modes: list[Mode] = []
        self.proposal: ModeProposal | None = None
        self.events: Counter = Counter()  # global_restart, emitter_moved, recalibrated, alarm, offset_learned
        self.status = Status(Phase.COLLECTING)
        self.points_seen = 0
        self.points_used = 0
        self.bearings_used = 0
        self.last_update_s = float("nan")
        self.last_stamp = float("nan")  # stamp of the newest observation point
        self.last_kept = np.zeros(0, bool)  # which readings the newest point kept (the report's trace)
        # Whether the transmitter moves (motion.py): the watch, begun with the filter, and what it last said
        self.watch: MotionWatch | None = None
        self.watched_offset = 0.0  # the bearing offset (rad) the calibration took off at the watch's last point
        self.motion: Motion | None = None
        self.doubts: deque[bool] = deque(maxlen=DOUBT_POINTS)  # per recent point: the filter in alarm, or none
        self.sure_run = 0  # points in a row the watch has been all but sure of motion
        # Every point's readings as heard (the transmitter count's: the window drops points when the emitter moved,
        # which is what transmitters taking turns look like), their number, and the last count with the readings
        # it was made from
        self.heard: deque[Sequence[Reading]] = deque()
        self.heard_held = 0  # readings in `heard`
        self.heard_readings = 0  # readings heard since the start
        self.counted: Count | None = None
        self.counted_readings = 0  # readings heard when the count under way (or the last) began
        self.counted_upto = 0  # readings heard when the count adopted (self.counted) began
        # Readings heard when the bearings last began to look like more than one fixed transmitter's (`misfit`:
        # motion the estimate would follow, many wild bearings, a filter in alarm; None: never). Transmitters taking
        # turns look like each, so a count is asked for then, and none of them is said until a count begun since
        # answered
        self.count_asked: int | None = None
        self.misfit = False
        self.count_every = HEARD_READINGS  # readings between counts past the doubling ones: longer while they agree
        self.counting = JobPlace()
        # The site part's fit (site_part.py), made beside the points as a count is: the covariance it adds, the
        # filter it was fitted for (a re-started filter starts without it) and the points it read
        self.site_fitting = JobPlace()
        self.site_spread = np.zeros((2, 2))
        self.site_filter: ParticleFilter | None = None
        self.site_points = 0

    @property
    def places(self) -> tuple[object, ...]:
        """The track's keys among the scheduler's jobs: its start search or check, its count, its site-part fit."""
        return self, self.counting, self.site_fitting

    @property
    def moving(self) -> bool:
        """The motion watch finds the transmitter moving (p >= MOVING_P) and the estimate follows it."""
        said = self.motion_said
        return said is not None and said.p_moving >= MOVING_P

    @property
    def standing_doubted(self) -> bool:
        """The standing filter itself has doubted its place within the last DOUBT_POINTS points (in alarm, or no
        filter: re-starting), or the watch has been all but sure of motion (p >= SURE_MOTION_P) for as many points
        in a row: only then may the estimate leave the filter for the watch. A misfit the filter absorbs (an offset
        it learns, a twin mode) read as motion cost the static cases more than a mover gains; a filter that widens
        its noise to explain a walker does not doubt itself, and the run of sure points says what it does not."""
        return any(self.doubts) or self.sure_run >= DOUBT_POINTS

    @property
    def motion_unheeded(self) -> bool:
        """The watch has been all but sure of motion for DOUBT_POINTS points in a row, and the estimate keeps the
        filter's only because the channel learned a bearing offset (motion_said): said in a warning. (A probable
        motion not yet sure for as long has a warning of its own: outputs.estimates.with_motion.)"""
        return self.sure_run >= DOUBT_POINTS and bool(self.calibration.offset) and self.motion_said is None

    @property
    def count_explains_motion(self) -> bool:
        """The count is all but sure of several transmitters heard in turns, which look like one that jumps."""
        c = self.counted
        return c is not None and c.count >= 2 and c.in_turns and c.probability >= MOTION_YIELDS_TO_COUNT

    @property
    def motion_said(self) -> Motion | None:
        """What the motion watch says, for the estimate to follow; None before it says anything, while the standing
        filter has no doubt (standing_doubted), while a count asked for is under way (count_pending), while the
        count is all but sure of several heard in turns (transmitters taking turns look like one that jumps, and
        the count is the model made for them; a walker's drift has been counted as two at p = 0.90, so only a
        count of p >= MOTION_YIELDS_TO_COUNT outranks the watch, and places heard one after another are a mover's
        path), or while the channel has learned a bearing offset (motion_unheeded says so)."""
        if self.count_explains_motion or not self.standing_doubted:
            return None
        if self.count_pending:
            return None
        if self.calibration.offset:
            # weighed against the standing model with the offset, a mover still won where the bearings were the
            # vehicle's (read as north) before their course was learned: 1.1-1.3 km off, `moving`
            return None
        return self.motion

    @property
    def counts_possible(self) -> bool:
        """The channel's transmitters are counted (max_emitters_per_channel above 1, bearings not turned by the
        vehicle's course)."""
        return self.cfg.max_emitters_per_channel >= 2 and not self.calibration.course

    @property
    def count_pending(self) -> bool:
        """A count was asked for (count_asked) and none begun since has answered."""
        return self.counts_possible and self.count_asked is not None and self.counted_upto < self.count_asked

    @property
    def job(self) -> PendingJob | None:
        """The start search or global check running for this track: the scheduler holds it."""
        return self.scheduler.job(self)

    @property
    def state(self) -> TrackState:
        if self.filter is not None:
            return TrackState.TRACKING
        return TrackState.COLLECTING if self.provisional is None else TrackState.PROVISIONAL

    def summary(self) -> TrackStatus:
        """The track as programs read it (Localizer.track_status)."""
        sup = self.supervisor
        working = any(self.scheduler.job(place) is not None for place in self.places)
        return TrackStatus(self.state, self.status, sup.alarm, sup.health.share, self.points_used, self.bearings_used,
                           self.last_update_s, working)

    def snapshot(self) -> Snapshot:
        """What a start search or global check needs, copied: it may run in the worker while the track goes on."""
        f = self.filter
        best = f.x[np.argmax(f.log_target(f.x))].copy() if f is not None and self.cfg.calibrate_noise else None
        c = self.calibration
        return Snapshot(self.cfg, [e.readings for e in self.window], rows_of([e.point for e in self.window]),
                        c.noise.copy(), c.outlier_prob, self.robust(), best, [m.mean.copy() for m in self.modes[:1]],
                        c.offset, c.course)

    # -- what the track holds -------------------------------------------------------------------------
    @property
    def debtor(self) -> tuple[ParticleFilter | None, ModeProposal | None]:
        """What the scheduler's owed moves are made with: the filter, and the proposal of its last check's modes."""
        return self.filter, self.proposal

    @property
    def running(self) -> ParticleFilter:
        """The filter, where the code runs only once it started."""
        if self.filter is None:
            raise RuntimeError("no filter running")  # an engine bug, never bad input
        return self.filter

    @property
    def cloud(self) -> ParticleFilter:
        """The particles the estimate comes from: the running filter, or the provisional sample before it."""
        if self.filter is not None:
            return self.filter
        if self.provisional is None:
            raise RuntimeError("no estimate yet")  # an engine bug, never bad input
        return self.provisional

    @property
    def cloud_is_current(self) -> bool:
        """Whether the cloud describes the points held now: a running filter's always; a provisional sample's while it
        holds all but a tenth of them (a start search that finds no place leaves the last sample standing)."""
        if self.filter is not None:
            return True
        return self.provisional is not None and self.provisional.k >= _CURRENT_SHARE * len(self.window)

    @property
    def estimating(self) -> bool:
        """Whether there is an estimate: a running filter or a provisional sample."""
        return self.state is not TrackState.COLLECTING

    @property
    def model(self) -> EmitterModel:
        """The running filter's emitter model (the track always builds one)."""
        return cast(EmitterModel, self.running.model)

    def used_points(self) -> np.ndarray:
        """(K, 5) rows east, north, theta, sigma, gps sigma of the points the running filter keeps; (0, 5) before."""
        if self.filter is None:
            return np.zeros((0, 5))
        return np.array(self.model.history.data, float).reshape(-1, 5)

    def points(self) -> Points:
        return points_of([e.point for e in self.window])

    def posterior_points(self) -> Points:
        """The points the estimate's posterior is over: the running filter's, else the ones held."""
        return Points.of(self.model.history.data) if self.filter is not None else self.points()

    def robust(self, prior: bool = True) -> Robust:
        """The robust posterior's settings the searches use: the calibrated outlier share and latent noise, with the
        filter's prior, the configured one, or (before a start) the radio-range prior of the points held."""
        c, cfg = self.calibration, self.cfg
        if prior and self.filter is not None and self.model.prior_prec.any():
            return Robust(c.lik_outlier_prob, cfg.gps_sigma_m, self.model.prior_mean, self.model.prior_prec,
                          c.noise_prior(), self.model.reach)
        if prior and cfg.prior_east is not None and cfg.prior_north is not None and cfg.prior_sigma_m is not None:
            return Robust(c.lik_outlier_prob, cfg.gps_sigma_m, np.array([cfg.prior_east, cfg.prior_north]),
                          np.eye(2) / cfg.prior_sigma_m**2, c.noise_prior())
        reach = (self.reach() if self.filter is None else self.model.reach) if prior else None
        return Robust(c.lik_outlier_prob, cfg.gps_sigma_m, grid=c.noise_prior(), reach=reach)

    def reach(self) -> tuple[float, float, float] | None:
        """The radio-range prior of the points held (global_search.radio_reach); None before any."""
        if not self.window:
            return None
        return radio_reach(np.array([[e.point.east, e.point.north] for e in self.window]))

    # -- estimates ------------------------------------------------------------------------------------
    def noise_summary(self) -> dict:
        """The self-calibrated noise: sigma (deg) per quality band with data, reading and point outlier rates."""
        return self.calibration.noise_summary(lambda q: math.degrees(reading_sigma(q, self.cfg)))

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """The published place and covariance, marginalised over the residual bearing offset the points cannot tell
        from a place (offset.marginalise): a running filter's mean and covariance (with what the points' shared site
        part adds, once fitted), or where its ellipse is wide for the range (its tails along the rays drag the mean
        out), its spatial median with the ellipse holding 95 % of the cloud; a provisional sample's highest-density
        place (its best mode) with that ellipse."""
        if self.filter is None:
            mean, cov = cloud_estimate(self.cloud, self.modes[0].mean)
        else:
            mean, cov = self.filter.estimate()
            if wide_for_range(self.model.history.data, mean, cov)[0]:
                mean, cov = cloud_estimate(self.filter, spatial_median(self.filter.x, self.filter.weights))
        if self.filter is not None and self.site_filter is self.filter:
            cov = cov + self.site_spread  # the points' shared site part (site_part.py)
        sd = math.inf if self.calibration.offset else prior_sd(self.cfg)
        if sd == 0.0:
            return mean, cov
        pts = self.posterior_points()
        shift, spread = marginalise(pts, mean, self.robust(), sd)
        return mean + shift, cov + spread

    def assess(self, mean: np.ndarray, cov: np.ndarray, others_share: float = 0.0
               ) -> tuple[list, EstimateState, list[str]]:
        """The estimate's modes (east, north, mass), its state and the warnings behind it (report.py), the
        `others_share` of the readings other transmitters on the frequency explain not counted as wild."""
        modes = mode_masses(self.cloud, self.modes)
        history = self.model.history.data if self.filter is not None else None
        state, warnings = assess(mean, cov, modes, self.supervisor.health, self.calibration, self.status, history,
                                 others_share, self.count_pending)
        return modes, state, warnings

