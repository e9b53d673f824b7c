"""The engine's output side: the channels' tracks take the closed observation points, and each new estimate is made,
kept as its channel's and the newest, and handed to `on_estimate`.

The Localizer hands the points the intake closed to `Estimates.take_points` and never sees them again: the route of
a point runs one way, from the intake through the tracks to the estimate (docs/design.md, "Data flow").
"""
from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from aoa_localizer.engine.channels import Channel, Channels, Closed
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame, ground_to_map
from aoa_localizer.engine.inference.motion import SURE_MOVING_P, UNSURE_P, Motion, mixture
from aoa_localizer.engine.ingest.intake import Intake
from aoa_localizer.engine.rejections import Reason, Rejections
from aoa_localizer.engine.scheduling import slices
from aoa_localizer.engine.scheduling.scheduler import PendingJob, Scheduler
from aoa_localizer.engine.survey.survey_log import LiveFixes, SurveyFix, counted, live_fix
from aoa_localizer.engine.survey.survey_solver import SurveySolver
from aoa_localizer.engine.track.report import between_transmitters, co_channel, stations_disagree
from aoa_localizer.engine.track.said import Moving, Said, positive_definite
from aoa_localizer.engine.types import Estimate, EstimateState, Transmitter

AGREE_CHI2 = 9.21  # two places further apart than this (Mahalanobis, squared, both covariances: 1 % for 2-D)


def with_motion(motion: Motion | None, said: Motion | None, mean: np.ndarray, cov: np.ndarray, state: EstimateState,
                warnings: list[str], unheeded: bool = False, explained: bool = False
                ) -> tuple[np.ndarray, np.ndarray, EstimateState, list[str], dict[str, Any]]:
    """A standing transmitter's estimate with what the motion watch says (`motion`; `said`: what the estimate may
    follow, motion.py): the probability of motion, the velocity over both models (a standing one's is zero), and
    where neither model is sure (UNSURE_P) the place of their mixture, `undecided`, never `tracking` (an estimate
    that does not follow the watch stands: velocity zero, its covariance the watch's second moment times p); a watch
    sure of motion that the estimate does not follow (`unheeded`: Held.motion_unheeded) is said, and the estimate is
    not `tracking`; nor is one that keeps the standing place while motion is as probable as UNSURE_P (the watch not
    yet sure for long enough to be followed: a transmitter that has begun to walk away), unless the count
    `explained` the motion as transmitters taking turns. Such a held place's covariance is the two models' second
    moment about it, so its ellipse holds where a mover would be now as probably as the watch says."""
    moves: dict[str, Any] = {"motion_probability": motion.p_moving if motion is not None else float("nan")}
    if said is None and motion is not None:
        # the estimate stands: no velocity, spread by what the watch makes of a motion it may have
        p, v = motion.p_moving, motion.velocity
        moves.update(velocity=np.zeros(2), velocity_cov=p * (motion.velocity_cov + np.outer(v, v)))
    if said is None:
        held = None
        if unheeded and motion is not None:
            held = (f"the bearings look like a moving transmitter's (p = {motion.p_moving:.2f}), but the channel has "
                    "learned a bearing offset: the place is the standing filter's; check the offset it learned")
        elif motion is not None and motion.p_moving >= UNSURE_P and not explained:
            held = (f"the transmitter may be moving (p = {motion.p_moving:.2f}): the place is where it stood, until "
                    "the motion is sure")
        if held is None or motion is None:
            return mean, cov, state, warnings, moves
        # the place stands, and its covariance holds where a mover would be now: the models' second moment about it
        d = motion.mean - mean
        p = motion.p_moving
        cov = (1.0 - p) * cov + p * (motion.cov + np.outer(d, d))
        return mean, cov, _not_tracking(state), warnings + [held], moves
    p, v = said.p_moving, said.velocity
    moves.update(velocity=p * v, velocity_cov=p * said.velocity_cov + p * (1.0 - p) * np.outer(v, v))
    if p < UNSURE_P:
        return mean, cov, state, warnings, moves
    mean, cov = mixture(p, mean, cov, said.mean, said.cov)
    warnings = warnings + [f"the transmitter may be moving (p = {p:.2f}): the place is between where it stood and "
                           "where a mover would be now"]
    moves["motion"] = "undecided"
    return mean, cov, _not_tracking(state), warnings, moves


def _not_tracking(state: EstimateState) -> EstimateState:
    """`tracking` made `poorly_determined`; any other state as it is."""
    return EstimateState.POORLY_DETERMINED if state == EstimateState.TRACKING else state


class Estimates:
    """Points into tracks, tracks into estimates. `newest` is the newest estimate of any channel (None before one)
    and `latest` its channel (the default channel before one); `on_estimate` is called with each new one."""

    def __init__(self, cfg: LocalizerConfig, channels: Channels, intake: Intake, scheduler: Scheduler,
                 reject: Rejections, on_estimate: Callable[[Estimate], None] | None = None,
                 survey_solver: SurveySolver | None = None):
        self.cfg, self.channels, self.intake, self.scheduler, self.reject = cfg, channels, intake, scheduler, reject
        self.on_estimate = on_estimate
        self.survey_solver = survey_solver  # None: no survey model (a standing antenna's channel keeps its filter's)
        self.newest: Estimate | None = None
        self.latest: Channel = channels.default
        self.live_fixes = LiveFixes()

    def take_points(self, closed: Closed) -> Estimate | None:
        """The channels' tracks take the closed points in order, the points of one track within one call's budget
        for its jobs (slices.py; each track its own, so a channel's run never depends on another's); returns the
        newest estimate they made (a survey-like channel's survey fix also while its filter has not started)."""
        estimate = None
        calls: dict[int, slices.Call] = {}
        observer = self.intake.observer
        for channel, readings in closed:
            track = channel.track
            with slices.one_call(calls.setdefault(id(track), slices.Call())):
                self.scheduler.point_came(channel.surveying)
                said = track.add(readings)
                self.scheduler.take_turn(channel.surveying)  # its live survey fix's turn, after the track's
            if observer is not None:
                observer.on_point(readings, track.last_kept)
            if said is not None:
                estimate = self.publish(channel, said) or estimate
            elif self.cfg.end_of_data_model == "survey":  # a survey-like channel's fix needs no started filter
                estimate = self._live_survey(channel) or estimate
        return estimate

    def publish(self, channel: Channel, said: Said | None = None, end_of_data: bool = False) -> Estimate | None:
        """The channel's new estimate from what its track says (`said`; None: asked of it now), kept and handed to
        `on_estimate`; None (counted) when its covariance is not positive definite. A survey-like channel's is the
        survey model's while it has a fix (_live_survey)."""
        if said is None:
            said = channel.track.said(final=end_of_data)  # several transmitters taking turns are no mover
        if isinstance(said, Moving):
            return self._publish_moving(channel, said, end_of_data)
        if not end_of_data and self.cfg.end_of_data_model == "survey":
            live = self._live_survey(channel)
            if live is not None:
                return live
        if said.degenerate:
            self.reject(Reason.COVARIANCE_DEGENERATE)
            return None
        frame = self.intake.datum_frame()
        count, mean, cov, state, warnings = said.count, said.mean, said.cov, said.state, said.warnings
        transmitters: list[Transmitter] = []
        if count is not None:
            places, words = co_channel(count, said.antennas, self.cfg.max_emitters_per_channel)
            warnings = warnings + words
            for said_too in (between_transmitters(count, mean, cov), stations_disagree(count)):
                if said_too is not None:
                    warnings.append(said_too)
                    if state == EstimateState.TRACKING:
                        state = EstimateState.POORLY_DETERMINED
            for place, place_state in places:
                t_lat, t_lon, _ = frame.to_geodetic(place.mean[0], place.mean[1])
                transmitters.append(Transmitter(float(place.mean[0]), float(place.mean[1]), float(t_lat),
                                                float(t_lon), place.cov.copy(), place.share, place_state))
        mean, cov, state, warnings, moves = with_motion(said.motion, said.followed, mean, cov, state, warnings,
                                                        said.unheeded, said.explained)
        lat, lon, _ = frame.to_geodetic(mean[0], mean[1])
        from_map = np.linalg.inv(ground_to_map(frame.north_angle(lat, lon), LocalFrame.skew(mean[0], mean[1])))
        estimate = Estimate(stamp=said.stamp, east=float(mean[0]), north=float(mean[1]), lat=float(lat),
                            lon=float(lon), cov=np.array(cov), ground_cov=from_map @ np.asarray(cov) @ from_map.T,
                            bearings_used=said.bearings_used, points_used=said.points_used, ess=said.ess,
                            algorithm=self.cfg.algorithm, particles=said.particles, weights=said.weights,
                            modes=said.modes, noise=said.noise, channel=channel.id,
                            frequency_hz=channel.frequency_hz, state=state, warnings=warnings,
                            end_of_data=end_of_data, transmitter_count=count.count if count is not None else 1,
                            count_probability=count.probability if count is not None else float("nan"),
                            transmitters=transmitters, **moves)
        return self._announce(channel, estimate)

    def _publish_moving(self, channel: Channel, said: Moving, end_of_data: bool) -> Estimate | None:
        """A moving transmitter's estimate: where the motion watch's moving model has it now, its velocity, and
        `poorly_determined` while its range is not observed (the observer has not turned across its line of sight)."""
        motion = said.motion
        if not positive_definite(motion.cov):
            self.reject(Reason.COVARIANCE_DEGENERATE)
            return None
        frame = self.intake.datum_frame()
        east, north = (float(v) for v in motion.mean)
        lat, lon, _ = frame.to_geodetic(east, north)
        from_map = np.linalg.inv(ground_to_map(frame.north_angle(lat, lon), LocalFrame.skew(east, north)))
        speed = float(np.hypot(*motion.velocity))
        heading = math.degrees(math.atan2(motion.velocity[0], motion.velocity[1])) % 360.0
        warnings = [f"the transmitter moves (p = {motion.p_moving:.2f}): {speed:.1f} m/s towards {heading:03.0f} "
                    "deg; the place is where it is now"]
        state = EstimateState.TRACKING if motion.p_moving >= SURE_MOVING_P else EstimateState.POORLY_DETERMINED
        if not motion.range_observed:
            state = EstimateState.POORLY_DETERMINED
            warnings.append("a moving transmitter's range is not observed from bearings until the observer turns "
                            "across its line of sight: the ellipse is long along it")
        estimate = Estimate(stamp=said.stamp, east=east, north=north, lat=float(lat), lon=float(lon),
                            cov=np.array(motion.cov), ground_cov=from_map @ motion.cov @ from_map.T,
                            bearings_used=said.bearings_used, points_used=said.points_used,
                            ess=float(said.particles.shape[0]), algorithm=self.cfg.algorithm,
                            particles=said.particles, weights=said.weights, modes=[(east, north, 1.0)],
                            noise=said.noise, channel=channel.id, frequency_hz=channel.frequency_hz, state=state,
                            warnings=warnings, end_of_data=end_of_data, motion="moving",
                            motion_probability=motion.p_moving, velocity=motion.velocity.copy(),
                            velocity_cov=motion.velocity_cov.copy())
        return self._announce(channel, estimate)

    def finish(self) -> Estimate | None:
        """The end of data's estimates: the survey model's for the survey-like channels (with `end_of_data_model:
        survey`), each other live channel's after its last global check. Returns the last of them."""
        estimate = None
        surveyed = self._survey_end() if self.cfg.end_of_data_model == "survey" else {}
        for channel in self.channels.all():  # a survey's channels may have retired between its bearings
            if channel.id in surveyed:
                estimate = self._publish_survey(channel, surveyed[channel.id]) or estimate
            elif not channel.retired and channel.track.finish():
                estimate = self.publish(channel, end_of_data=True) or estimate
        return estimate

    def _survey_end(self) -> dict[str, SurveyFix]:
        """The survey model's fixes of the survey-like channels (survey_log.py), {} without any or a solver."""
        solve = self.survey_solver
        if solve is None or self.intake.frame is None:
            return {}
        survey = self.intake.pairing.survey_log
        records = survey.survey_records(self.intake.frame, [c.id for c in self.channels.all() if self._surveyed(c)])
        return solve(records, self.cfg.receiver_class, self.cfg.max_emitters_per_channel) if records else {}

    def _live_survey(self, channel: Channel) -> Estimate | None:
        """A survey-like channel's estimate while the data come (every bearing from a fixed site, or stops that
        show a site part; from three places on): the survey model's fix of its bearings alone, made again as they grow
        (SurveyLog.due) as a job of the scheduler's (the check worker's, or made in turns at the points that follow:
        a fix that counts transmitters takes up to seconds) and published once it is done; until then the last one,
        restamped; None (the filter's estimate) for any other channel or while the model has no fix for it. The end
        of data pools every survey-like channel (finish)."""
        survey, fixes, place = self.intake.pairing.survey_log, self.live_fixes, channel.surveying
        done = self.scheduler.finished(place)
        if not self._surveyed(channel):  # a drive's, or stops that show no site part: the filter's
            fixes.forget(channel.id)
            return None
        if done is not None:
            return self._adopt_live_fix(channel, done)
        solve = self.survey_solver
        if solve is not None and fixes.due(survey, channel.id) and self.scheduler.job(place) is None:
            counting = fixes.count_due(survey, channel.id)
            last = fixes.solving(survey, channel.id, counting)
            max_k = self.cfg.max_emitters_per_channel if counting else 1
            records = survey.survey_records(self.intake.datum_frame(), [channel.id])
            job = functools.partial(live_fix, solve, records, channel.id, self.cfg.receiver_class, max_k, last)
            self.scheduler.start(place, job, slices.CHECK_BUDGET_US, None, [], first_turn=False)
        last_made = fixes.live.get(channel.id)
        if last_made is None:
            return None
        return self._announce(channel, replace(last_made, stamp=channel.track.last_stamp))

    def _surveyed(self, channel: Channel) -> bool:
        """Whether the survey model makes a channel's estimate (SurveyLog.survey_like, told whether its filter has
        started)."""
        return self.intake.pairing.survey_log.survey_like(channel.id, channel.track.filter is not None)

    def _adopt_live_fix(self, channel: Channel, done: PendingJob) -> Estimate | None:
        """A live survey fix the scheduler finished, published (and its count kept when it made one)."""
        fix = self.scheduler.value(done, "a live survey fix")[1]
        made = self._publish_survey(channel, fix, end_of_data=False) if fix is not None else None
        self.live_fixes.made(channel.id, made, fix.count if fix is not None else None)
        return made

    def _publish_survey(self, channel: Channel, fix: SurveyFix, end_of_data: bool = True) -> Estimate | None:
        """A survey-like channel's estimate from the survey model, in the map frame."""
        if not positive_definite(fix.cov):
            self.reject(Reason.COVARIANCE_DEGENERATE)
            return None
        frame = self.intake.datum_frame()
        east, north = frame.to_enu(fix.lat, fix.lon)
        track = channel.track
        to_map = ground_to_map(frame.north_angle(fix.lat, fix.lon), LocalFrame.skew(east, north))
        cov = to_map @ fix.cov @ to_map.T
        state, warnings = self._against_filter(channel, np.array([east, north], float), cov, fix)
        estimate = Estimate(stamp=track.last_stamp, east=float(east), north=float(north), lat=fix.lat, lon=fix.lon,
                            cov=cov, ground_cov=np.array(fix.cov),
                            bearings_used=fix.bearings, points_used=track.points_used,
                            ess=float("nan"), algorithm="survey", modes=[(float(east), float(north), 1.0)],
                            noise=fix.noise, channel=channel.id, frequency_hz=channel.frequency_hz, state=state,
                            warnings=warnings, end_of_data=end_of_data, regions=fix.regions,
                            **counted(fix.count, frame))
        return self._announce(channel, estimate)

    def _against_filter(self, channel: Channel, place: np.ndarray, cov: np.ndarray,
                        fix: SurveyFix) -> tuple[EstimateState, list[str]]:
        """A stopped vehicle's survey fix checked against its own particle filter: the two models read one set of
        readings (a site part in one, independent readings in the other), so where their places lie further apart
        than both ellipses allow (AGREE_CHI2), one of them misreads the stops (a reflection's ghost in the stops'
        readings pulls every stop one way, which the survey model takes for independent site errors): the fix is
        `poorly_determined`, said. Fixed stations are not checked: there the filter is known to take a steady bias
        for independent readings."""
        warnings = list(fix.warnings)
        track = channel.track
        if channel.id not in self.intake.pairing.survey_log.stopped or track.filter is None:
            return fix.state, warnings
        mean, filter_cov = track.estimate()
        gap = place - np.asarray(mean, float)
        both = cov + np.asarray(filter_cov, float)
        if not positive_definite(both) or float(gap @ np.linalg.solve(both, gap)) <= AGREE_CHI2:
            return fix.state, warnings
        warnings.append(f"the survey model and the particle filter disagree by {float(np.hypot(*gap)):.0f} m, more "
                        "than both ellipses allow: the stops' readings share an error one of them misreads (a "
                        "reflection?)")
        return EstimateState.POORLY_DETERMINED, warnings

    def _announce(self, channel: Channel, estimate: Estimate) -> Estimate:
        """Keep a channel's new estimate as its and the newest, and hand it to `on_estimate`."""
        channel.published(estimate)
        self.newest = estimate
        self.latest = channel
        if self.on_estimate is not None:
            self.on_estimate(estimate)
        return estimate
