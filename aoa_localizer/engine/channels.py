"""Emitters keyed by carrier frequency: a DF record's frequency picks its channel (within `channel_tolerance_hz`
of the channel's), each channel has its own emitter track, point builders (one per station) and estimate.
Records without a frequency (0 or NaN) share the default channel, so single-emitter use is unchanged."""
from __future__ import annotations

import logging
import math
import zlib
from collections.abc import Callable, Sequence

import numpy as np

from aoa_localizer.engine.config import FREQUENCY_MAX_HZ, LocalizerConfig
from aoa_localizer.engine.inference.global_search import Mode
from aoa_localizer.engine.inference.receiver_pool import PooledNoise, pooled_noise
from aoa_localizer.engine.points.preprocess import PointBuilder
from aoa_localizer.engine.rejections import Reason
from aoa_localizer.engine.scheduling.scheduler import JobPlace, Scheduler
from aoa_localizer.engine.track.emitter_track import EmitterTrack
from aoa_localizer.engine.types import Estimate, EstimateState, Reading

log = logging.getLogger("aoa_localizer")

Closed = list[tuple["Channel", Sequence[Reading]]]  # closed observation points, each with its channel

DEFAULT = "default"  # the channel of records without a frequency
# Carrier frequencies a DF receiver can report: above 0 and at most 1 THz (receivers stop near 50 GHz), so a
# channel's id stays a short, valid ROS name token whatever the record says
# Frequencies remembered with their channel: past this the memory starts again (a stream of distinct jittered
# frequencies would otherwise grow it without bound; a forgotten one is matched by tolerance again)
_HEARD_MAX = 4096


GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0  # its multiples mod 1 fill [0, 1) evenly whatever their count


def channel_id(frequency_hz: float) -> str:
    """The stable id of a channel first heard at `frequency_hz`: 'f' and the frequency in whole Hz (a valid ROS
    name token, so it can name a topic namespace)."""
    return f"f{int(round(frequency_hz))}"


class Channel:
    """One emitter: its frequency (NaN for the default channel), track, builders per station and latest estimate."""

    def __init__(self, cid: str, frequency_hz: float, cfg: LocalizerConfig, rng: np.random.Generator, reject,
                 scheduler: Scheduler, first_point: float = 1.0,
                 pool: Callable[[], PooledNoise | None] | None = None):
        """`first_point`: the share of the observation-point limits its builders give their first point; `pool`: asks
        for the receiver's calibration pooled over the other channels (its track's first search asks once)."""
        self.id, self.frequency_hz, self.cfg, self.first_point = cid, frequency_hz, cfg, first_point
        self.track = EmitterTrack(cfg, rng, reject, scheduler, pool)
        self.surveying = JobPlace()  # its live survey fix among the scheduler's jobs (the Localizer's)
        self.builders: dict[str, PointBuilder] = {}
        self.estimate: Estimate | None = None
        self.last_heard = -math.inf  # the newest DF stamp admitted on this channel (GPS clock)
        self.retired = False

    def builder(self, station: str) -> PointBuilder:
        b = self.builders.get(station)
        if b is None:
            b = self.builders[station] = PointBuilder(self.cfg, self.first_point)
            b.emitter = self._place()
        return b

    def published(self, estimate: Estimate):
        """The channel's new estimate: kept, and its place given to the builders (a point's span follows its
        range)."""
        self.estimate = estimate
        place = self._place()
        for b in self.builders.values():
            b.emitter = place

    @property
    def pooled_start(self) -> PooledNoise | None:
        """The receiver's noise pooled over its other channels that this channel's calibration started from (None:
        it started from the configured model)."""
        return self.track.calibration.pooled

    def batch_estimate(self) -> Mode | None:
        """The robust batch maximum-likelihood place of every point the channel holds (no filter): the benchmarks'
        reference (EmitterTrack.batch_estimate)."""
        return self.track.batch_estimate()

    def _place(self) -> tuple[float, float] | None:
        """The estimate's place, once it is determined: a wide or provisional one's may lie by the road, and would
        cut points small for nothing."""
        est = self.estimate
        return None if est is None or est.state == EstimateState.POORLY_DETERMINED else (est.east, est.north)


class Channels:
    """The live channels, the retired ones, and the rule that maps a frequency to a channel."""

    def __init__(self, cfg: LocalizerConfig, rng: np.random.Generator, reject, scheduler: Scheduler):
        """`scheduler`: the Localizer's, shared by the channels' tracks."""
        self.cfg, self.rng, self._reject, self.scheduler = cfg, rng, reject, scheduler
        self.live: dict[str, Channel] = {}
        # the last retired channel of each id, its final estimate kept; the newest max_channels of them
        self.retired: dict[str, Channel] = {}
        self._heard: dict[float, Channel] = {}  # frequency -> its channel, for frequencies heard before
        self._opened = 0  # frequency channels opened so far
        self._retire_check = -math.inf  # DF stamp of the last look for silent channels
        self.default = self._open(DEFAULT, math.nan)

    def _open(self, cid: str, frequency_hz: float) -> Channel:
        # The default channel draws from the Localizer's generator (a seed reproduces today's runs); each other
        # channel from its own, derived from the seed and its id, so its run does not depend on the others'.
        if cid == DEFAULT:
            rng = self.rng
        elif self.cfg.seed is None:
            rng = np.random.default_rng()
        else:
            rng = np.random.default_rng([self.cfg.seed, zlib.crc32(cid.encode())])
        channel = Channel(cid, frequency_hz, self.cfg, rng, self._reject, self.scheduler, self._first_point(cid),
                          lambda: self.pooled_noise(but=channel))
        self.live[cid] = channel
        return channel

    def pooled_noise(self, but: Channel | None = None) -> PooledNoise | None:
        """The receiver's noise as the channels that calibrated theirs show it (receiver_pool.py; `but` left out):
        one receiver hears every channel of a Localizer."""
        return pooled_noise(c.track.calibration.noise for c in (*self.live.values(), *self.retired.values())
                            if c is not but)

    def _first_point(self, cid: str) -> float:
        """Carriers of one scan share their stamps, so their points would all close at the same reading and make a
        burst of work (docs/design.md, "Many channels"): the k-th frequency channel's first point is cut at
        1 - 0.9 frac(k / golden ratio) of the limits, which spreads the closings evenly; the default channel's
        and the first frequency channel's points are as a single emitter's."""
        if cid == DEFAULT:
            return 1.0
        k, self._opened = self._opened, self._opened + 1
        return 1.0 - 0.9 * ((k * GOLDEN) % 1.0)

    def for_frequency(self, frequency_hz: float) -> Channel | Reason:
        """The channel of a record's frequency (a new one if none is near), or the reason it has none."""
        f = frequency_hz
        if math.isnan(f) or f == 0:
            return self.live.get(DEFAULT) or self._open(DEFAULT, math.nan)
        if not 0 < f <= FREQUENCY_MAX_HZ:  # False for inf
            return Reason.BAD_FREQUENCY
        known = self._heard.get(f)  # a receiver reports a carrier's frequency the same way every time
        if known is not None:
            return known
        best, gap = None, self.cfg.channel_tolerance_hz
        for ch in self.live.values():
            d = abs(ch.frequency_hz - f)  # NaN for the default channel: never <= gap
            if d <= gap:
                best, gap = ch, d
        if best is None:
            if sum(1 for c in self.live.values() if c.id != DEFAULT) >= self.cfg.max_channels:
                return Reason.CHANNEL_LIMIT
            best = self._open(channel_id(f), f)
        if len(self._heard) >= _HEARD_MAX:
            self._heard.clear()
        self._heard[f] = best
        return best

    def discard_unheard(self, channel: Channel) -> None:
        """Close a frequency channel no record was ever admitted on (the one that opened it was refused)."""
        if channel.id != DEFAULT and channel.last_heard == -math.inf and self.live.get(channel.id) is channel:
            del self.live[channel.id]
            for f in [f for f, c in self._heard.items() if c is channel]:
                del self._heard[f]

    def retire_silent(self, now: float, every_time: bool = False) -> Closed:
        """Once per second of DF time (`every_time`: now), retire the frequency channels silent for
        `channel_timeout_s` before `now` (0: never); returns their open points, closed. A channel never heard is
        closed, not retired: it has nothing to keep."""
        timeout = self.cfg.channel_timeout_s
        if timeout <= 0 or (now - self._retire_check < 1.0 and not every_time):
            return []
        self._retire_check = now
        for c in [c for c in self.live.values() if c.last_heard == -math.inf]:
            self.discard_unheard(c)
        gone = [c for c in self.live.values() if c.id != DEFAULT and now - c.last_heard > timeout]
        if gone:
            self._heard.clear()
        closed: Closed = []
        for c in gone:
            c.retired = True
            del self.live[c.id]
            self.retired.pop(c.id, None)
            self.retired[c.id] = c
            closed += [(c, group) for group in (b.flush() for b in c.builders.values()) if group]
            log.info("channel %s (%.0f Hz) silent for %.0f s: retired, its last estimate kept", c.id, c.frequency_hz,
                     now - c.last_heard)
        while len(self.retired) > self.cfg.max_channels:  # the oldest retired go: memory bounded over any stream
            del self.retired[next(iter(self.retired))]
        return closed

    def primary(self) -> Channel | None:
        """The channel a single-emitter consumer reads (the node's `emitter/pose`): the default channel while it has
        an estimate, else the channel with an estimate from the most points (the first opened on a tie)."""
        if self.default.estimate is not None:
            return self.default
        return max((c for c in self.all() if c.estimate is not None), key=lambda c: c.track.points_used,
                   default=None)

    def all(self) -> list[Channel]:
        """Live channels, then retired ones not live again, in the order they were opened."""
        return list(self.live.values()) + [c for cid, c in self.retired.items() if cid not in self.live]
