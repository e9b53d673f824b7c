"""Whether the bearings fit the track better with the DF stamps shifted: a receiver delay or clock offset that
`df_time_offset_s` should take off. A moving vehicle turns a stamp error into a position error along its velocity,
so the likeliest shift (with the emitter re-fitted for each) estimates the offset, and the gain in log likelihood
says whether the data really prefer it."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aoa_localizer.engine.inference.global_search import Points, Robust, log_posterior, refine

# The shifts tried, s: whole seconds over +-3 s, then halves and quarters around the best (a log likelihood that
# moves smoothly with the shift: 11 fits where the quarter-second grid takes 25). 0 is the reference.
COARSE_S, FINE_S = np.arange(-3.0, 3.0001, 1.0), (0.5, 0.25)
MIN_GAIN = 10.0  # log-likelihood gain (nats) before a shift is suggested: odds of e^10 against chance
MIN_SPEED_MPS = 1.0  # below this typical speed a stamp error moves nothing: no verdict


@dataclass(frozen=True)
class ClockHint:
    """The DF stamp shift the bearings prefer (s, added to the stamps) and its log-likelihood gain over none."""

    shift_s: float
    gain: float


def best_shift(pts: Points, velocity: np.ndarray, x0: np.ndarray, rob: Robust) -> ClockHint | None:
    """The shift (to a quarter second, COARSE_S then FINE_S) that fits best when it beats no shift by MIN_GAIN, else
    None. `velocity` (K, 2) is the vehicle's east/north velocity at each point, `x0` the emitter estimate the fits
    start from."""
    if len(pts) < 3 or float(np.median(np.hypot(velocity[:, 0], velocity[:, 1]))) < MIN_SPEED_MPS:
        return None
    scores: dict[float, float] = {}

    def score(shift: float) -> float:
        if shift not in scores:
            moved = Points(pts.east + velocity[:, 0] * shift, pts.north + velocity[:, 1] * shift, pts.theta,
                           pts.sigma, pts.gps)
            x = refine(np.asarray(x0, float)[None, :], np.zeros(1), moved, rob)[0][0]
            scores[shift] = float(log_posterior(x, moved, rob))
        return scores[shift]

    for shift in COARSE_S.tolist():
        score(shift)
    best = max(COARSE_S.tolist(), key=score)
    for step in FINE_S:
        for shift in (best - step, best + step):
            score(shift)
        best = max((best - step, best, best + step), key=score)
    gain = scores[best] - scores[0.0]
    if best == 0.0 or not gain >= MIN_GAIN:
        return None
    return ClockHint(best, gain)
