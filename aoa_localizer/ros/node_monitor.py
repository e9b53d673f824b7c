"""What the node watches of itself and says on /diagnostics: its inputs (received, lost, stamp gaps), its load and
latency, and the engine's state, robustness and warnings, one status for the localizer and one per channel."""
from __future__ import annotations

import math
import time
from collections import Counter, OrderedDict
from collections.abc import Callable
from typing import Any

import numpy as np
from rclpy.event_handler import SubscriptionEventCallbacks

from aoa_localizer.engine.channels import DEFAULT
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.crlb import ellipse_axes
from aoa_localizer.engine.inference.noise import sentence as noise_sentence
from aoa_localizer.engine.ingest.input_guard import StampGaps
from aoa_localizer.engine.outputs.view import LocalizerView
from aoa_localizer.engine.rejections import FIX_REASONS
from aoa_localizer.engine.types import EstimateState
from aoa_localizer.reporting.words import clock_hint_words
from aoa_localizer.ros.node_health import LatencyHistogram, NodeHealth, Overload
from aoa_localizer.ros.node_outputs import PosteriorWork
from aoa_localizer.ros.shedding import LAG_S, Shedding

_MAX_LOAD = 0.8  # share of wall time spent working (inputs, idle moves, diagnostics) above which it warns
_LAG_SANE_NS = 3_600_000_000_000  # a receive stamp further back than an hour is not this host's clock: no wait taken
_STALL_PERIODS = 2.0  # a diagnostics period this many times longer than configured: the node was held up
_GAP_FACTOR = 1.5  # a stamp gap this many typical intervals long holds lost records (a regular receiver jitters less)
_GAP_STREAMS = 256  # input streams whose stamp gaps are followed; past it the one heard least recently is dropped


def _gaps(streams: OrderedDict, station: str, frequency_hz: float = math.nan) -> StampGaps:
    """The stamp gaps of one input stream: a station's fixes, or its DF records of one frequency (NaN: the default
    channel); the _GAP_STREAMS heard most recently are kept."""
    key = (station, frequency_hz if math.isfinite(frequency_hz) else 0.0)
    gaps = streams.get(key)
    if gaps is None:
        gaps = streams[key] = StampGaps(factor=_GAP_FACTOR)
        if len(streams) > _GAP_STREAMS:
            streams.popitem(last=False)
    else:
        streams.move_to_end(key)
    return gaps


class SequenceGaps:
    """Messages an input's publisher numbered that the node never took: lost on the network, or overwritten in a
    full subscription queue, which the middleware does not report. Read from the gaps in the middleware's
    publication sequence numbers; where they step back (several publishers on the topic, or one that restarted) they
    say nothing more, and counting stops."""

    def __init__(self):
        self.last: int | None = None
        self.missing = 0
        self.several = False

    def add(self, seq) -> None:
        if not isinstance(seq, int) or self.several:
            return
        if self.last is not None:
            if seq <= self.last:
                self.several = True
                return
            self.missing += seq - self.last - 1
        self.last = seq


class NodeMonitor:
    """The node's counts, timings and input health over a diagnostics period, and the /diagnostics it makes of them
    and of the engine. `period_s()` reads diagnostics_period_s (a parameter that may change)."""

    def __init__(self, now: float, stale_after_s: float, period_s: Callable[[], float], shed: bool = True):
        """`shed`: thin the DF records when the input outruns the node (shedding.py)."""
        self.period_s = period_s
        self.health = NodeHealth(now, stale_after_s)
        self.counts = dict.fromkeys(("fixes_received", "bearings_received", "scans_received", "adapter_errors",
                                     "fixes_lost", "bearings_lost"), 0)
        self.lost_reported = 0  # fixes_lost + bearings_lost at the last diagnostics
        self.df_gaps: OrderedDict[tuple[str, float], StampGaps] = OrderedDict()  # per station and frequency
        self.fix_gaps: OrderedDict[tuple[str, float], StampGaps] = OrderedDict()  # per station
        self.callback_s: list[float] = []
        self.callback_max_s = 0.0
        self.other_s = 0.0  # work in the period outside the input callbacks: idle moves, the periodic work
        self.parameter_changes = 0  # parameter sets accepted
        self.posterior_work = PosteriorWork()  # the posterior grids of this period
        self.restarts = 0  # track restarts they made (a burst of sets makes one)
        self.period_start = time.perf_counter()
        self.overload = Overload()
        self.shedding = Shedding(shed)
        self.take_lag_s: list[float] = []  # how long each message of the period waited before the node took it
        self.engine_s = 0.0  # the period's time in the engine's calls (add_bearing, add_fix, idle): what shedding cuts
        self.arrival_ns = time.time_ns()
        self.sequences: dict[str, SequenceGaps] = {}  # each input subscription's publication numbers
        self.taken = 0  # input messages taken since the start
        self.seen_missing = (0, 0)  # (taken, sequence-missing) at the last diagnostics
        self.latency_ms: list[float] = []  # from a message's arrival to the publication of each pose it made
        self.latency_since_start = LatencyHistogram()

    # -- what the node tells it -----------------------------------------------------------------------
    def lost_counter(self, key: str) -> SubscriptionEventCallbacks:
        """The middleware's message-lost events of a subscription, counted under `key`."""

        def on_lost(status):
            self.counts[key] += int(status.total_count_change)

        return SubscriptionEventCallbacks(message_lost=on_lost)

    def arrived(self, info, stream: str = "") -> None:
        """When the message being handled reached this process (the middleware's receive time, else now): the
        start of the latency of any pose it produces; and its publication number on input `stream`."""
        received = info.get("received_timestamp", 0) if isinstance(info, dict) else 0
        now = time.time_ns()
        self.arrival_ns = received if received > 0 else now
        if 0 <= now - self.arrival_ns < _LAG_SANE_NS:  # the middleware's stamp is this host's clock
            self.take_lag_s.append(1e-9 * (now - self.arrival_ns))
        self.taken += 1
        if isinstance(info, dict):
            gaps = self.sequences.get(stream)
            if gaps is None:
                gaps = self.sequences[stream] = SequenceGaps()
            gaps.add(info.get("publication_sequence_number"))

    def fix_stamp(self, station: str, stamp: float) -> None:
        if math.isfinite(stamp):
            _gaps(self.fix_gaps, station).add(stamp)

    def df_stamp(self, station: str, stamp: float, frequency_hz: float = math.nan) -> None:
        if math.isfinite(stamp):
            _gaps(self.df_gaps, station, frequency_hz).add(stamp)

    def published(self) -> None:
        """A pose the input being handled made went out."""
        self.latency_ms.append(1e-6 * (time.time_ns() - self.arrival_ns))

    def timed(self, t0: float) -> None:
        """An input callback that started at perf_counter `t0` ended."""
        dt = time.perf_counter() - t0
        self.callback_s.append(dt)
        self.callback_max_s = max(self.callback_max_s, dt)

    def period_done(self) -> None:
        """The period's latencies join those since the start (before its diagnostics)."""
        self.latency_since_start.add(self.latency_ms)

    def end_period(self, t0: float) -> None:
        """The periodic work that started at `t0` is done: a new period begins (that work counts in it)."""
        self.callback_s, self.callback_max_s, self.latency_ms, self.take_lag_s = [], 0.0, [], []
        self.engine_s = 0.0
        self.period_start = time.perf_counter()
        self.other_s = self.period_start - t0

    # -- /diagnostics ---------------------------------------------------------------------------------
    def diagnostics(self, view: LocalizerView, config: LocalizerConfig, now: float, held: dict,
                    wrong: dict[str, list[str]]) -> tuple[int, str, dict]:
        """(level, message, values) of the node's health: OK while it works as designed, whatever the estimate's
        state (waiting for a fix, collecting, checking, `poorly_determined`, `tracking`: the message and `state`
        say which, and an estimate's own warnings join the message); WARN while the estimate is `suspect` (the model
        does not fit the bearings) or any input or node warning holds (its words join the message); ERROR while the
        filter keeps restarting.
        `held`: parameters waiting for the rest of their group; `wrong`: what is wrong with the inputs' publishers,
        by diagnostics key (Node._publisher_problems)."""
        values = self._state_values(view, config)
        values.update(self._robustness_values(view, config))
        if held:
            values["parameters_held"] = ", ".join(sorted(held)) + " (waiting for the rest of the group)"
        values.update(df_stamp_gaps=sum(g.gaps for g in self.df_gaps.values()),
                      df_missing_by_stamp=sum(g.missing for g in self.df_gaps.values()),
                      fix_stamp_gaps=sum(g.gaps for g in self.fix_gaps.values()),
                      fixes_missing_by_stamp=sum(g.missing for g in self.fix_gaps.values()))
        self.health.count_restarts(now, restarts_made(view))
        warnings = self._warnings(view, config, wrong) + self.health.stale(now)
        error = self.health.restart_error()
        if error:
            warnings.append(("restarting", *error))
        est = view.estimate
        # An estimate's own warnings are findings (two transmitters on the frequency, an offset learned and taken
        # off, a wide ellipse) said in the message at OK; a suspect estimate's say why it is WARN
        findings: list[tuple[str, str, str]] = []
        if est is not None:
            values["state"] = est.state
            said = [(f"warning_{i}", text, text) for i, text in enumerate(est.warnings)]
            if est.state == EstimateState.SUSPECT:
                warnings += said
            else:
                findings = said
        values.update({key: value for key, value, _ in warnings})
        level = 2 if error else 1 if warnings else 0
        return level, "; ".join([view.status] + [words for _, _, words in warnings + findings]), values

    def _state_values(self, view: LocalizerView, config: LocalizerConfig) -> dict[str, Any]:
        """Counts, rejections by reason, callback load and the estimate."""
        track = view.track
        # Totals over every channel kept (each channel's own are in its status, channel_diagnostics)
        tracks = [channel.track for channel in view.channels] or [track]
        values: dict[str, Any] = dict(self.counts)
        values.update(status=view.status, algorithm=config.algorithm,
                      bearings_used=sum(t.bearings_used for t in tracks),
                      points_used=sum(t.points_used for t in tracks),
                      jobs_running=sum(t.working for t in tracks),  # searches, checks, counts, fits: results to come
                      unknown_quality=view.unknown_quality, other_band=view.other_band,
                      bearings_rejected=sum(v for k, v in view.rejected.items() if k not in FIX_REASONS),
                      fixes_rejected=sum(v for k, v in view.rejected.items() if k in FIX_REASONS))
        values.update({f"rejected.{k}": v for k, v in sorted(view.rejected.items())})
        if self.callback_s:
            values.update(callback_mean_ms=f"{1e3 * sum(self.callback_s) / len(self.callback_s):.3f}",
                          callback_max_ms=f"{1e3 * self.callback_max_s:.3f}",
                          callbacks_in_period=len(self.callback_s))
        values.update(load_pct=f"{100 * self._load():.0f}", period_s=f"{time.perf_counter() - self.period_start:.3f}",
                      rejected_while_overloaded=sum(self.overload.rejected.values()),
                      input_messages_missed=sum(g.missing for g in self.sequences.values()),
                      records_shed=self.shedding.shed, records_kept_share=f"{self.shedding.keep:.4g}",
                      parameter_changes=self.parameter_changes, restarts=self.restarts)
        w = self.posterior_work
        if w.made or w.deferred:  # the grids listened to: their cost is named, not blamed on the filter
            values.update(posterior_grids_made=w.made, posterior_grids_waiting=w.deferred,
                          posterior_grids_ms=f"{1e3 * w.seconds:.1f}")
        if self.latency_ms:
            p50, p99, top = np.percentile(self.latency_ms, (50, 99, 100), method="higher")
            values.update(poses_in_period=len(self.latency_ms), pose_latency_p50_ms=f"{p50:.3f}",
                          pose_latency_p99_ms=f"{p99:.3f}", pose_latency_max_ms=f"{top:.3f}")
        if self.latency_since_start.total:
            values.update(poses_since_start=self.latency_since_start.total,
                          pose_latency_p99_ms_since_start=f"{self.latency_since_start.percentile(99):.3f}")
        est = view.estimate
        if est is not None:
            values.update(ess=f"{est.ess:.1f}", update_ms=f"{1e3 * track.update_s:.3f}", east=f"{est.east:.2f}",
                          north=f"{est.north:.2f}", lat=f"{est.lat:.7f}", lon=f"{est.lon:.7f}",
                          ellipse95_major_m=f"{ellipse_axes(est.cov)[0]:.2f}")
        return values

    def _load(self) -> float:
        """Share of the period since the last diagnostics spent working: input callbacks, idle moves and the
        periodic work (a period the node was held up in lasts longer than configured: its wall time counts)."""
        period = max(time.perf_counter() - self.period_start, self.period_s())
        return (sum(self.callback_s) + self.other_s) / period

    def _warnings(self, view: LocalizerView, config: LocalizerConfig,
                  wrong: dict[str, list[str]]) -> list[tuple[str, str, str]]:
        """(key, value, words for the status message) of each warning that holds now."""
        out = []
        for key, problems in wrong.items():  # a publisher of another type; more than one source on one input topic
            if problems:
                out.append((key, "; ".join(problems), problems[0]))
        overload = self._overload(view)
        if overload:
            out.append(("overload", overload, "the node cannot keep up with its inputs"))
        lost = self.counts["fixes_lost"] + self.counts["bearings_lost"]
        if lost > self.lost_reported:
            out.append(("messages_lost", f"{lost - self.lost_reported} input messages lost by the middleware in the "
                        "last period (network, or input_queue_depth too small for the load)",
                        "input messages are being lost"))
        self.lost_reported = lost
        clock = clock_hint_words(view.clock_hint, config.df_time_offset_s)
        if clock:
            out.append(("clock_offset", clock, "the DF stamps look offset from the GPS clock"))
        return out

    def _overload(self, view: LocalizerView) -> str | None:
        """Why the node could not keep up in this period (its work over _MAX_LOAD of the wall time, or the period
        held up), with the inputs refused meanwhile; the words hold one more period, since what a stall lost is
        refused while its backlog is worked off. None when it kept up."""
        period = self.period_s()
        wall = time.perf_counter() - self.period_start
        load = self._load()
        lag = float(np.median(self.take_lag_s)) if self.take_lag_s else 0.0
        cause = None
        missed = sum(g.missing for g in self.sequences.values())
        new_taken, new_missed = self.taken - self.seen_missing[0], missed - self.seen_missing[1]
        self.seen_missing = (self.taken, missed)
        if new_missed > 0:
            share = 100.0 * new_missed / (new_taken + new_missed)
            cause = (f"{new_missed} input messages ({share:.1f} % of the period's) never reached it: its input queue "
                     "(input_queue_depth) overflowed or the network dropped them (a receiver's channels as one scan on "
                     "df/scan cost one message)")
        elif wall > _STALL_PERIODS * period:
            cause = f"the node was held up: this diagnostics period lasted {wall:.1f} s ({period:g} s configured)"
        elif lag >= LAG_S:
            cause = f"the messages it took had waited {lag:.2f} s (median) since they arrived: a backlog"
        elif load > _MAX_LOAD:
            cause = f"the node worked {100 * load:.0f} % of the last period"
        words = self.overload.judge(cause, view.rejected, self._missing())
        shedding = self.shedding.judge(lag, self.engine_s / max(wall, period))
        return "; ".join(w for w in (words, shedding) if w) or None

    def _missing(self) -> int:
        """Inputs that never arrived, as far as anything can tell: the middleware's lost counts, and the stamp gaps
        or the publication numbers' gaps."""
        stamps = sum(g.missing for g in self.df_gaps.values()) + sum(g.missing for g in self.fix_gaps.values())
        # the stamps' gaps and the publication numbers' see the same losses: the larger count, not both
        return (self.counts["fixes_lost"] + self.counts["bearings_lost"]
                + max(stamps, sum(g.missing for g in self.sequences.values())))

    @staticmethod
    def _robustness_values(view: LocalizerView, config: LocalizerConfig) -> dict:
        """Self-calibrated noise, modes, the health test and the robustness events, as diagnostic values."""
        values: dict[str, Any] = {}
        if config.calibrate_noise:
            noise = dict(view.noise)
            values["noise"] = noise_sentence(noise)
            values.update({f"noise.sigma_deg.q{k}": v for k, v in noise["sigma_deg"].items()})
            values.update({"noise.reading_outlier_prob": noise["reading_outlier_prob"],
                           "noise.point_outlier_prob": noise["point_outlier_prob"]})
        pooled = view.receiver_noise
        if pooled is not None:  # one receiver over its channels (receiver_pool.py)
            values.update({"receiver_noise": pooled.sentence(), "receiver_noise.scale": round(pooled.scale, 3),
                           "receiver_noise.channels": pooled.channels})
        values["health.recent_outlier_share"] = f"{view.track.outlier_share:.2f}"
        est = view.estimate
        if est is not None:
            values["modes"] = len(est.modes)
            values.update({f"mode.{i + 1}": f"E {e:.1f} N {n:.1f} mass {m:.3f}"
                           for i, (e, n, m) in enumerate(est.modes)})
        values.update({f"events.{k}": v for k, v in sorted(view.events.items())})
        return values

    @staticmethod
    def channel_diagnostics(view: LocalizerView, diag_name: str) -> list[tuple[str, int, str, dict]]:
        """One status per frequency channel: WARN while its estimate is `suspect`, else OK (retired, before its
        first estimate, checking, `poorly_determined` or `tracking`: the message says which)."""
        out = []
        for channel in view.channels:
            if channel.id == DEFAULT:
                continue
            track, est = channel.track, channel.estimate
            values: dict[str, Any] = {"frequency_hz": f"{channel.frequency_hz:.0f}", "status": track.text,
                                      "bearings_used": track.bearings_used, "points_used": track.points_used,
                                      "topics": f"emitter/{channel.id}/"}
            if est is not None:
                values.update(east=f"{est.east:.2f}", north=f"{est.north:.2f}", lat=f"{est.lat:.7f}",
                              lon=f"{est.lon:.7f}", ellipse95_major_m=f"{ellipse_axes(est.cov)[0]:.2f}")
            level = 1 if not channel.retired and est is not None and est.state == EstimateState.SUSPECT else 0
            message = f"retired (silent for channel_timeout_s); {track.text}" if channel.retired else track.text
            out.append((f"{diag_name} channel {channel.id}", level, message, values))
        return out


def restarts_made(view: LocalizerView) -> Counter:
    """The restarts of every channel's filter so far, by kind: a re-start from a global check or because the
    emitter moved (one event each; the bearings an `emitter_moved` restart drops are rejections, not restarts),
    and a diverged filter (one rejection each)."""
    made: Counter = Counter()
    for channel in view.channels:
        made.update({k: channel.events.get(k, 0) for k in ("global_restart", "emitter_moved")})
    made["filter_diverged"] = view.rejected.get("filter_diverged", 0)
    return made
