"""What an emitter track holds between its parts: the state it is in, its points and the job it has handed to the
check worker."""
from __future__ import annotations

from concurrent.futures import Future
from dataclasses import dataclass
from enum import Enum

from aoa_localizer.engine.scheduling.slices import SlicedJob
from aoa_localizer.engine.types import ObservationPoint, Reading
from aoa_localizer.filters.base import ParticleFilter


class TrackState(Enum):
    """Where a track is: no estimate yet; a provisional sample of a proper but undetermined posterior (published as
    `poorly_determined`); a running filter."""

    COLLECTING = "collecting"
    PROVISIONAL = "provisional"
    TRACKING = "tracking"


@dataclass(frozen=True)
class TrackStatus:
    """A track as programs read it (the node's /diagnostics): its state, the one-line status, whether the cloud no
    longer explains the newest points (the estimate is being checked), the share of recent points it explains only
    as outliers, the points and bearings its estimate uses, and what its latest point cost (s)."""

    state: TrackState
    text: str
    alarm: bool
    outlier_share: float
    points_used: int
    bearings_used: int
    update_s: float


@dataclass
class WindowEntry:
    """One observation point the track keeps: its readings, the point made of them, how many readings it gated out."""

    readings: list[Reading]
    point: ObservationPoint
    gated: int

    @property
    def used(self) -> int:
        """The readings the point used."""
        return len(self.readings) - self.gated


@dataclass
class PendingJob:
    """A job running in the check worker, or made a few pieces per point: a start search (`filter` None) or a global
    check for `filter`, with the reading groups of its snapshot (the originals: the worker's copies come back as
    points in their order)."""

    future: Future | SlicedJob
    filter: ParticleFilter | None
    groups: list[list[Reading]]

    def advance(self) -> None:
        """A point came: a sliced job makes its pieces for it (a worker's goes on by itself)."""
        if isinstance(self.future, SlicedJob):
            self.future.advance()

    def release(self) -> None:
        """A point came: a sliced job's result held back from the call that finished it is ready (slices.py)."""
        if isinstance(self.future, SlicedJob):
            self.future.release()

    @property
    def in_calls(self) -> bool:
        """Made a few pieces per point (not in the worker)."""
        return isinstance(self.future, SlicedJob)

    @property
    def is_start(self) -> bool:
        return self.filter is None
