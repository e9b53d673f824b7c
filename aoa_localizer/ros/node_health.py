"""What the node's /diagnostics says beyond the engine's status, without rclpy: inputs gone stale (WARN), a node
that cannot keep up (WARN, with what it refused meanwhile) and a filter that keeps restarting (ERROR), in the
node's clock (ROS time, so sim time works)."""
from __future__ import annotations

from collections import Counter, deque
from collections.abc import Mapping

import numpy as np

RESTARTS_FOR_ERROR = 3  # restarts within RESTART_WINDOW_S that turn /diagnostics to ERROR
RESTART_WINDOW_S = 60.0
RESTART_KINDS = ("global_restart", "emitter_moved", "filter_diverged")  # node_monitor.restarts_made's kinds


class Overload:
    """Whether the node keeps up, and what was refused or lost while it did not: a stall's lost inputs show up as
    refusals while its backlog is worked off (fixes lost leave gaps, so bearings are refused as gps_gap), so the
    words hold for HOLD more periods after the cause, and the refusals of those periods are named as its."""

    HOLD = 1

    def __init__(self):
        self.rejected: Counter = Counter()  # refusals while overloaded, by reason, since start
        self.lost = 0  # inputs lost (stamp gaps, middleware) while overloaded, since start
        self._seen_rejected: Counter = Counter()
        self._seen_missing = 0
        self._hold = 0
        self._cause = ""

    def judge(self, cause: str | None, rejected: Mapping[str, int], missing: int) -> str | None:
        """This period's verdict: `cause` (None: it kept up), the engine's refusals and the inputs missing so far;
        the words for /diagnostics, or None."""
        new = Counter(rejected)
        new.subtract(self._seen_rejected)
        new = +new  # the refusals of this period (a reset that cleared the counts gives none)
        new_missing = max(missing - self._seen_missing, 0)
        self._seen_rejected, self._seen_missing = Counter(rejected), missing
        if cause:
            self._hold, self._cause = self.HOLD + 1, cause
        if not self._hold:
            return None
        self._hold -= 1
        self.rejected.update(new)
        self.lost += new_missing
        words = [cause or f"just before: {self._cause}"]
        if new:
            words.append("refused meanwhile: " + ", ".join(f"{n} as {k}" for k, n in new.most_common()))
        if "gps_gap" in new:
            words.append("those gps_gap refusals follow fixes lost for lack of time, not a GPS fault")
        if new_missing:
            words.append(f"{new_missing} inputs never arrived (stamp gaps, middleware)")
        words.append("fewer particles or channels, or a faster machine, help")
        return "; ".join(words)


class NodeHealth:
    """Arrival times of DF readings and valid fixes, and the times the filter restarted."""

    def __init__(self, now: float, stale_after_s: float):
        self.stale_after_s = stale_after_s
        self.started = now
        self.last_reading: float | None = None
        self.last_valid_fix: float | None = None
        self.restarts: deque[float] = deque()
        self.restart_total = 0

    def reading(self, now: float):
        self.last_reading = now

    def valid_fix(self, now: float):
        self.last_valid_fix = now

    def count_restarts(self, now: float, counts: Mapping[str, int]):
        """`counts`: the engine's running totals by kind; the ones new since the last call are stamped `now`."""
        total = sum(counts.get(k, 0) for k in RESTART_KINDS)
        if total < self.restart_total:  # a new Localizer (parameters changed): its totals start again
            self.restart_total = 0
        self.restarts.extend([now] * (total - self.restart_total))
        self.restart_total = total
        while self.restarts and self.restarts[0] < now - RESTART_WINDOW_S:
            self.restarts.popleft()

    def stale(self, now: float) -> list[tuple[str, str, str]]:
        """(key, value, words) for each input silent longer than stale_after_s (since the start if never seen)."""
        out = []
        for key, last, what in (("df_stale", self.last_reading, "DF reading"),
                                ("gps_stale", self.last_valid_fix, "valid GPS fix")):
            silent = now - (self.started if last is None else last)
            if silent > self.stale_after_s:
                since = "since the start" if last is None else f"for {silent:.1f} s"
                out.append((key, f"no {what} {since} (stale_after_s {self.stale_after_s:g})",
                            f"no {what} {since}"))
        return out

    def restart_error(self) -> tuple[str, str] | None:
        """(value, words) when the filter restarted RESTARTS_FOR_ERROR times within RESTART_WINDOW_S."""
        if len(self.restarts) < RESTARTS_FOR_ERROR:
            return None
        words = f"the filter restarted {len(self.restarts)} times in the last {RESTART_WINDOW_S:g} s"
        return words + " (bearings inconsistent with one fixed emitter, or a wrong configuration)", words


class LatencyHistogram:
    """Every pose's latency since the node started, in bins 1/40 of a decade wide (6 %) from 10 us to 100 s: a
    percentile over hours in constant memory; read as the upper edge of the bin it falls in (never optimistic)."""

    def __init__(self):
        self.edges = np.logspace(-2, 5, 7 * BINS_PER_DECADE + 1)  # ms
        self.counts = np.zeros(self.edges.size + 1, dtype=np.int64)  # below the first edge, bins, above the last

    def add(self, latencies_ms):
        np.add.at(self.counts, np.searchsorted(self.edges, latencies_ms), 1)

    @property
    def total(self) -> int:
        return int(self.counts.sum())

    def percentile(self, q: float) -> float:
        """The q-th percentile (0-100) in ms, as the upper edge of its bin (inf above 100 s; NaN with none)."""
        if not self.total:
            return float("nan")
        i = int(np.searchsorted(np.cumsum(self.counts), q / 100.0 * self.total))
        return float(self.edges[i]) if i < self.edges.size else float("inf")


BINS_PER_DECADE = 40
