"""The vehicle's track for vehicle/path, without rclpy: a Localizer observer keeping the latest accepted fixes."""
from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np

from aoa_localizer.engine.types import Reading


class VehiclePath:
    """The latest `length` accepted fixes as (stamp, east, north) in the map frame; each also calls
    `on_valid_fix` (the node's stale-GPS watch)."""

    def __init__(self, length: int, on_valid_fix: Callable[[], None]):
        self.poses: deque[tuple[float, float, float]] = deque(maxlen=length)
        self.on_valid_fix = on_valid_fix
        self.sent = 0  # fixes added since the path was last taken by new_path()
        self.added = 0

    def on_fix(self, stamp: float, east: float, north: float, station: str = "") -> None:
        self.poses.append((stamp, east, north))
        self.added += 1
        self.on_valid_fix()

    def on_point(self, readings: list[Reading], kept: np.ndarray) -> None:
        """Observation points are drawn by emitter/markers, not in the path."""

    def resize(self, length: int):
        self.poses = deque(self.poses, maxlen=length)

    def clear(self):
        """The map frame moved: the old poses are in the wrong frame."""
        self.poses.clear()

    def new_path(self) -> list[tuple[float, float, float]] | None:
        """The poses when a fix came since the last call (None otherwise, or when the path is empty)."""
        if self.added == self.sent or not self.poses or self.poses.maxlen == 0:
            return None
        self.sent = self.added
        return list(self.poses)
