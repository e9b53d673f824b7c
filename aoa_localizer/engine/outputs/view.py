"""What programs read of a Localizer between inputs, as values copied when asked (`Localizer.view`,
`Localizer.posterior`): the engine's objects never leave it, so nothing read can change under its reader or be
changed by it."""
from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.inference.clock_check import ClockHint
from aoa_localizer.engine.inference.global_search import Mode, Points, Robust
from aoa_localizer.engine.inference.receiver_pool import PooledNoise
from aoa_localizer.engine.outputs.next_goal import NextGoal, next_goal
from aoa_localizer.engine.outputs.posterior_grid import PosteriorGrid, posterior_grid
from aoa_localizer.engine.track.state import TrackStatus
from aoa_localizer.engine.types import Estimate


def frozen(counts: Mapping[str, int]) -> Mapping[str, int]:
    """A read-only copy of a count by reason or event (a reason never seen reads 0, as in a Counter)."""
    return MappingProxyType(Counter(counts))


@dataclass(frozen=True)
class ChannelView:
    """One channel (a frequency's transmitter, or several sharing it): its newest estimate, its track's state and
    its robustness events (alarm, global_restart, emitter_moved, recalibrated)."""

    id: str
    frequency_hz: float  # NaN: the default channel (readings without a frequency)
    retired: bool  # not heard for a while: its last estimate stands, a new reading opens it again
    estimate: Estimate | None
    track: TrackStatus
    events: Mapping[str, int]


@dataclass(frozen=True)
class LocalizerView:
    """The Localizer as a program reads it (the node's /diagnostics and outputs, a report): the newest estimate of
    any channel, the state in one line, the inputs not used by reason, the events, and each channel."""

    estimate: Estimate | None  # the newest of any channel; None before the first
    status: str  # waiting for a fix, collecting bearings, ... tracking; the commonest refusal when most were refused
    primary: str | None  # the channel a single-emitter consumer reads (the node's emitter/pose); None before one
    latest: str  # the channel of the newest estimate (the default channel before one)
    track: TrackStatus  # the latest channel's track
    estimates: Mapping[str, Estimate]  # each channel's newest estimate, by channel id (live, then retired ones)
    channels: tuple[ChannelView, ...]  # live, then retired ones; () in a light view
    rejected: Mapping[str, int]  # inputs not used, by reason (rejections.Reason; docs/design.md's table)
    events: Mapping[str, int]  # the latest channel's robustness events and the input events (clock jumps)
    unknown_quality: int  # readings used with NaN quality (the default sigma)
    other_band: int  # DF records outside frequency_band_hz (another node's band), neither used nor refused
    frame: LocalFrame | None  # the map frame at the datum; None before it is set
    stations: tuple[str, ...]  # the stations heard or declared ("": the default one)
    vehicles: Mapping[str, tuple[float, float]]  # each moving station's newest accepted fix (east, north; m)
    # the latest channel's self-calibrated noise: sigma (deg) per quality band, outlier rates ({} in a light view)
    noise: Mapping
    clock_hint: ClockHint | None  # the DF clock offset the latest channel's last global check points to
    receiver_noise: PooledNoise | None  # the receiver's noise pooled over channels (two or more frequencies heard)

    def channel(self, cid: str | None = None) -> ChannelView | None:
        """The channel `cid` ("default": readings without a frequency), or without `cid` the latest estimate's;
        None when it is not heard (or the view is light)."""
        wanted = self.latest if cid is None else cid
        return next((c for c in self.channels if c.id == wanted), None)


@dataclass(frozen=True)
class PosteriorView:
    """One channel's posterior, copied: its estimate, the particles it comes from, the points and robust settings
    it is over, and the points its filter uses (rows of antenna east, north, bearing theta (ENU rad), its sigma
    (rad) and the antenna position's sigma (m), oldest first)."""

    channel: str
    estimate: Estimate
    particles: np.ndarray  # (N, 2) east, north
    weights: np.ndarray  # (N,)
    current: bool  # the cloud describes the points held now (a provisional sample can lag behind them)
    points: Points
    robust: Robust
    modes: tuple[Mode, ...]
    used_points: np.ndarray  # (K, 5)
    start_cloud: np.ndarray | None  # the particles its filter started from (after its latest start), or None

    def recent_points(self, n: int) -> np.ndarray:
        """The last `n` rows of `used_points` (all of them when it holds fewer)."""
        rows = self.used_points
        return rows[len(rows) - min(n, len(rows)):]

    def grid(self) -> PosteriorGrid:
        """The posterior on a map grid around the estimate (engine/outputs/posterior_grid.py)."""
        est = self.estimate
        places = np.vstack([self.particles, np.array([m[:2] for m in est.modes]).reshape(-1, 2)])
        return posterior_grid(self.points, self.robust, np.array([est.east, est.north]), est.cov, places,
                              self.modes)

    def next_goal(self, vehicle: tuple[float, float], radius_m: float) -> NextGoal | None:
        """Where within `radius_m` of `vehicle` (east, north) the next bearing is expected to shrink the posterior
        most (engine/outputs/next_goal.py), for a bearing as noisy as the median of the points used; None while a
        provisional sample is behind the points held (the vehicle should drive on, across its bearings)."""
        if not self.current:
            return None
        sigma = float(np.median(self.points.sigma)) if len(self.points.sigma) else math.nan
        return next_goal(self.particles, self.weights, vehicle, radius_m, sigma)
