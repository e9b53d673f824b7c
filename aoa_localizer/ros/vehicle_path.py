"""The vehicle's track for vehicle/path, without rclpy: a Localizer observer keeping the latest accepted fixes."""
from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence

import numpy as np

from aoa_localizer.engine.types import Reading


class VehiclePath:
    """The latest `length` accepted fixes of each station as (stamp, east, north) in the map frame; each also calls
    `on_valid_fix` (the node's stale-GPS watch)."""

    def __init__(self, length: int, on_valid_fix: Callable[[], None]):
        self.length = length
        self.poses: dict[str, deque[tuple[float, float, float]]] = {}
        self.on_valid_fix = on_valid_fix
        self.sent: dict[str, int] = {}  # fixes of each station added when its path was last taken by new_paths()
        self.added: dict[str, int] = {}

    def on_fix(self, stamp: float, east: float, north: float, station: str = "") -> None:
        self.poses.setdefault(station, deque(maxlen=self.length)).append((stamp, east, north))
        self.added[station] = self.added.get(station, 0) + 1
        self.on_valid_fix()

    def on_point(self, readings: Sequence[Reading], kept: np.ndarray) -> None:
        """Observation points are drawn by emitter/markers, not in the path."""

    def resize(self, length: int):
        self.length = length
        self.poses = {k: deque(v, maxlen=length) for k, v in self.poses.items()}

    def clear(self):
        """The map frame moved: the old poses are in the wrong frame."""
        for poses in self.poses.values():
            poses.clear()

    def new_paths(self) -> dict[str, list[tuple[float, float, float]]]:
        """The poses of each station that had a fix since the last call (none when its path is empty, or the
        length is 0)."""
        out = {}
        for station, poses in self.poses.items():
            if self.added[station] != self.sent.get(station) and poses and self.length:
                self.sent[station] = self.added[station]
                out[station] = list(poses)
        return out
