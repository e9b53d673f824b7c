"""What an emitter track holds between its parts: the state it is in and its points."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum, StrEnum

from aoa_localizer.engine.types import ObservationPoint, Reading


class TrackState(Enum):
    """Where a track is: no estimate yet; a provisional sample of a proper but undetermined posterior (published as
    `poorly_determined`); a running filter."""

    COLLECTING = "collecting"
    PROVISIONAL = "provisional"
    TRACKING = "tracking"


class Phase(StrEnum):
    """What a track is doing, as the first words of its status line."""

    COLLECTING = "collecting bearings"
    WAITING_FOR_GEOMETRY = "waiting for geometry"
    POORLY_DETERMINED = "poorly determined"
    TRACKING = "tracking"
    CHECKING = "checking"
    DIVERGED = "filter diverged"


@dataclass(frozen=True)
class Status:
    """A track's status as values; `words()` makes the line programs print. `why`: what the start search said
    (waiting for geometry, poorly determined); `held` of `needed` points (collecting); `disagree` of `tested` recent
    points (checking); `restarted_from`: the emitter moved and the filter re-started from this many recent points."""

    phase: Phase
    why: str = ""
    held: int = 0
    needed: int = 0
    disagree: int = 0
    tested: int = 0
    restarted_from: int = 0

    def words(self) -> str:
        if self.phase is Phase.COLLECTING:
            return f"{self.phase}: {self.held} of {self.needed} points" if self.needed else str(self.phase)
        if self.phase in (Phase.WAITING_FOR_GEOMETRY, Phase.POORLY_DETERMINED):
            return f"{self.phase}: {self.why}"
        if self.phase is Phase.CHECKING:
            return f"{self.phase}: {self.disagree} of the last {self.tested} points disagree"
        if self.phase is Phase.DIVERGED:
            return f"{self.phase}: restarting from new bearings"
        if self.restarted_from:
            return f"{self.phase} (emitter moved: re-started from the last {self.restarted_from} points)"
        return str(self.phase)


@dataclass(frozen=True)
class TrackStatus:
    """A track as programs read it (the node's /diagnostics): its state, its status (`text`: its words), whether
    the cloud no longer explains the newest points (the estimate is being checked), the share of recent points it
    explains only as outliers, the points and bearings its estimate uses, what its latest point cost (s), and
    whether a start search, global check, transmitter count or site-part fit is under way (`working`: its result is
    still to come)."""

    state: TrackState
    status: Status
    alarm: bool
    outlier_share: float
    points_used: int
    bearings_used: int
    update_s: float
    working: bool = False

    @property
    def text(self) -> str:
        return self.status.words()


@dataclass
class WindowEntry:
    """One observation point the track keeps: its readings, the point made of them, how many readings it gated out."""

    readings: Sequence[Reading]
    point: ObservationPoint
    gated: int

    @property
    def used(self) -> int:
        """The readings the point used."""
        return len(self.readings) - self.gated
