"""One receiver heard on many channels (issue 50: one receiver, many emitters): the noise scale its channels that
calibrated their own noise found, pooled, as the prior of a channel that has not calibrated yet. A new emitter
heard by a receiver the node already knows starts from what that receiver does, not from the configuration's
guess; how far one channel's scale may lie from the others' (multipath differs by frequency and place) stays
in the prior, so a few channels cannot make a new one overconfident. The end of data's survey model pools the
same way, over its own family (aoa_localizer.pooled)."""
from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from aoa_localizer.engine.inference.noise import NoiseModel

# How far one channel's noise scale may lie from another's of the same receiver (log sd: x1.65) while fewer than
# three channels show their spread; with three or more their own spread, never under x1.28
CHANNEL_SPREAD_LOG_SD = 0.5
_MIN_SPREAD_LOG_SD = 0.25


@dataclass(frozen=True)
class PooledNoise:
    """The receiver's noise as its calibrated channels show it: the scale on the configured sigma (geometric mean
    over the channels), the log sd a new channel's prior takes around it, and what it rests on."""

    scale: float
    log_sd: float
    channels: int
    readings: int

    def sentence(self) -> str:
        return (f"{self.scale:.2f}x the configured sigma over {self.channels} calibrated channel"
                f"{'s' if self.channels > 1 else ''} ({self.readings} readings); a new channel starts from it "
                f"(x/{math.exp(1.96 * self.log_sd):.1f} at 95 %)")


def pooled_noise(models: Iterable[NoiseModel]) -> PooledNoise | None:
    """The pooled scale of the models that were fitted (each one's log k averaged over its bands by their
    readings), or None when none was."""
    logs, readings = [], 0.0
    for m in models:
        used = m.readings >= 1.0
        if not m.fits or not used.any():
            continue
        logs.append(float(np.average(np.log(m.k[used]), weights=m.readings[used])))
        readings += float(m.readings[used].sum())
    if not logs:
        return None
    n = len(logs)
    spread = max(_MIN_SPREAD_LOG_SD, float(np.std(logs, ddof=1))) if n >= 3 else CHANNEL_SPREAD_LOG_SD
    # a new channel's scale: the pool's mean (itself uncertain by spread / sqrt(n)) plus its own departure
    return PooledNoise(math.exp(float(np.mean(logs))), spread * math.sqrt(1.0 + 1.0 / n), n, int(round(readings)))
