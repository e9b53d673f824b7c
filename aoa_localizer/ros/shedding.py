"""When the engine's work outruns the input: DF records thinned by one rule the node says and counts, instead of a
backlog growing unseen in the input queue (or the queue dropping whole messages, fixes among them). No rclpy here.

The rule (docs/ros.md, "Overload"): after each diagnostics period in which the messages the node took had waited LAG_S
or more (median) since they arrived, while the engine's calls (add_bearing, add_fix, idle: the work a record brings)
filled SHED_LOAD of the period, the share of DF records kept halves, down to KEEP_MIN; after a period with no such wait
(under QUICK_S) in which they filled under RELIEF_LOAD, it doubles back, up to all. Messages lost from a full queue
without such a wait (many single records a second: rclpy's take of each one is the limit) are said, not shed for:
measured, thinning then lost as many messages and used a fifth of the records. Each DF record is kept with that
probability, the same for every channel and station, so each channel's readings thin alike over time and a point is made
of fewer readings (its sigma says so). Fixes and headings are never shed: a bearing needs its antenna's place."""
from __future__ import annotations

import random

KEEP_MIN = 1.0 / 16.0  # the least share of DF records kept
LAG_S = 0.25  # the median wait of the period's messages before the node took them, from which it sheds more
SHED_LOAD = 0.5  # share of the period in the engine from which a backlog is its work's: it sheds more
QUICK_S = 0.05  # the median wait under which the messages were taken at once: no backlog
RELIEF_LOAD = 0.3  # share of the period in the engine under which it keeps more again (twice this is not far
# over SHED_LOAD: the records taken back make it shed again only where the engine's work is what holds it back)


class Shedding:
    """The share of DF records the node keeps, and what it shed."""

    def __init__(self, enabled: bool = True, seed: int = 0):
        self.enabled = enabled
        self.keep = 1.0
        self.rng = random.Random(seed)  # a seed: a replay sheds the same records again
        self.shed = 0  # DF records shed since the start
        self.period_shed = 0
        self.period_offered = 0

    def enable(self, on: bool) -> None:
        """Shedding allowed from now (off: every record kept again)."""
        self.enabled = on
        if not on:
            self.keep = 1.0

    def keeps(self) -> bool:
        """Whether the next DF record goes to the engine (else it is counted as shed)."""
        self.period_offered += 1
        if self.keep >= 1.0 or self.rng.random() < self.keep:
            return True
        self.shed += 1
        self.period_shed += 1
        return False

    def judge(self, lag_s: float, engine: float) -> str | None:
        """End of a diagnostics period: the median message waited `lag_s` before it was taken, the engine's calls
        took `engine` of the wall time. The words for /diagnostics
        while it sheds (this period's records shed, and the share kept from now), else None."""
        shed, offered = self.period_shed, self.period_offered
        self.period_shed = self.period_offered = 0
        if not self.enabled:
            return None
        if lag_s >= LAG_S and engine >= SHED_LOAD:
            self.keep = max(self.keep / 2.0, KEEP_MIN)
        elif lag_s < QUICK_S and engine < RELIEF_LOAD:
            self.keep = min(self.keep * 2.0, 1.0)
        if not shed and self.keep >= 1.0:
            return None
        done = f"{shed} of {offered} DF records shed in this period" if offered else "no DF records in this period"
        return (f"shedding load: {done}; from now each DF record is kept with probability {self.keep:.3g} "
                "(every channel alike; fixes are never shed)")
