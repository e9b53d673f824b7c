"""DF records that reach the node before the fix that places them. ROS orders no two topics: on a busy machine a
burst of DF records can be delivered before the fixes published beside them, and the engine, which holds a record
only 2 x gps_max_gap_s of DF time for a fix (a replay at 20x: a tenth of a second), refused them all as gps_gap or
before_first_fix. The node parks such a record (a moving station's, whose newest fix is older than it) and hands
it to the engine once a fix at or past its stamp has come, or after WAIT_S of the node's own time, or when more than
LIMIT wait; a record a fix already covers goes at once, so a stream in order costs nothing."""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from typing import Any

WAIT_S = 2.0  # the longest a record waits in the node for its fix (wall s): then the engine's rules decide
LIMIT = 20_000  # records parked at most (about 4 s of a 5000 records/s receiver); more: the oldest go on


class FixWait:
    """Each moving station's records that wait for a fix, in arrival order (so each station's order is kept)."""

    def __init__(self, feed: Callable[[str, Any], None], wait_s: float = WAIT_S, limit: int = LIMIT):
        """`feed(station, record)` hands a record to the engine."""
        self.feed, self.wait_s, self.limit = feed, wait_s, limit
        self.newest_fix: dict[str, float] = {}
        self.parked: dict[str, deque[tuple[float, Any]]] = {}
        self.count = 0
        self.waited = 0  # records that waited, since the start (the skew they absorbed)
        self.timed_out = 0  # records handed on after WAIT_S without their fix (the engine then decides)

    def bearing(self, station: str, record, now: float) -> None:
        """A DF record (with a `stamp`): to the engine now, or parked behind the station's waiting ones."""
        queue = self.parked.get(station)
        if not queue and record.stamp <= self.newest_fix.get(station, -math.inf):
            self.feed(station, record)
            return
        self.parked.setdefault(station, deque()).append((now, record))
        self.count += 1
        self.waited += 1
        while self.count > self.limit:
            self._release_oldest()

    def fix(self, station: str, stamp: float) -> None:
        """A fix of `station` at `stamp` was handed to the engine: the records it covers follow it."""
        if math.isfinite(stamp) and stamp > self.newest_fix.get(station, -math.inf):
            self.newest_fix[station] = stamp
        queue = self.parked.get(station)
        newest = self.newest_fix.get(station, -math.inf)
        while queue and queue[0][1].stamp <= newest:
            self._pop(station, queue)

    def due(self, now: float) -> None:
        """Records that waited WAIT_S go on (the GPS may have stopped: the engine counts them)."""
        for station, queue in self.parked.items():
            while queue and now - queue[0][0] >= self.wait_s:
                self.timed_out += 1
                self._pop(station, queue)

    def reset(self) -> None:
        """A new engine (parameters changed): what waited is handed to it, fixes start again."""
        for station, queue in self.parked.items():
            while queue:
                self._pop(station, queue)
        self.newest_fix.clear()

    def _release_oldest(self) -> None:
        station, queue = min(((s, q) for s, q in self.parked.items() if q), key=lambda sq: sq[1][0][0])
        self.timed_out += 1
        self._pop(station, queue)

    def _pop(self, station: str, queue: deque) -> None:
        _, record = queue.popleft()
        self.count -= 1
        self.feed(station, record)
