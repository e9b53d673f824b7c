"""Where a Localizer's deferred work runs and what it owes, in one place.

A track defers two kinds of work. Its jobs (start searches and global checks) run a few pieces per point
(`reproducible`: a seed repeats a run; slices.py), their result applied in the call that made the last piece, or in
the check worker's process (`realtime`: the node's), their result applied at the track's next point or by
`idle()`. Under `realtime` the Metropolis-Hastings moves of a step are owed instead of made in it (a resampling's
sweeps, a worker check's move on its modes): the scheduler keeps the debt of each filter and makes the moves when
the caller has time: `idle()` one, `catch_up()` all of them, else each following point one. Any of these moves keeps
the posterior invariant, so when it is made changes no law.
"""
from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from concurrent.futures import Future, wait
from dataclasses import dataclass
from typing import TYPE_CHECKING
from weakref import WeakKeyDictionary

import numpy as np

from aoa_localizer.engine.checks import CheckResult, CheckWorker
from aoa_localizer.engine.rejections import Reason
from aoa_localizer.engine.slices import SlicedJob, Steps
from aoa_localizer.filters.base import ParticleFilter
from aoa_localizer.filters.resample_move import ResampleMove

if TYPE_CHECKING:  # the tracks take the scheduler: the type only, for the checker
    from aoa_localizer.engine.track import EmitterTrack

log = logging.getLogger("aoa_localizer")

SWEEPS_PER_POINT = 1  # owed sweeps a point makes when the caller gave no time for them


@dataclass
class Debt:
    """What one filter owes: a global check's move on its modes, and a resampling's sweeps."""

    modes: bool = False
    sweeps: int = 0

    def __int__(self) -> int:
        return int(self.modes) + self.sweeps


class Scheduler:
    """Runs the tracks' jobs inline or in the worker (`realtime`), and makes the moves they owe when asked."""

    def __init__(self, realtime: bool, reject: Callable[[Reason], None]):
        """`reject`: told of a move that failed (counted as an internal error, the track goes on)."""
        self.worker = CheckWorker() if realtime else None
        self.reject = reject
        # Keyed by the filter that owes: a filter replaced (re-start, divergence) takes its debt with it.
        self._debts: WeakKeyDictionary[ParticleFilter, Debt] = WeakKeyDictionary()

    @property
    def realtime(self) -> bool:
        """Jobs go to the worker and moves are owed (else both are made in the call)."""
        return self.worker is not None

    @property
    def failures(self) -> int:
        """The worker's failed jobs in a row (0 inline)."""
        return self.worker.failures if self.worker is not None else 0

    def start(self, whole: Callable[[], CheckResult], steps: Steps[CheckResult], budget_us: float
              ) -> Future | SlicedJob:
        """A job: `whole` handed to the worker (its future); inline, or when the worker cannot take it, its `steps`
        made a few pieces per point, up to `budget_us` a call (slices.py), the first call's pieces now."""
        future = None if self.worker is None else self.worker.submit(whole)
        if future is not None:
            return future
        job = SlicedJob(steps, budget_us)
        job.advance()
        return job

    def finished(self, tracks: Iterable[EmitterTrack]) -> list[EmitterTrack]:
        """The tracks whose job finished, its result applied now, that have a new estimate."""
        return [t for t in tracks if t.collect() and t.estimating]

    # -- the moves owed ------------------------------------------------------------------------------
    def take(self, f: ParticleFilter) -> None:
        """A new filter: under `realtime` its resamplings' sweeps are owed, not made in its step (a bounded step)."""
        if self.realtime and isinstance(f, ResampleMove):
            f.deferred = True

    def debt(self, f: ParticleFilter | None) -> Debt:
        """What `f` owes now (nothing for None)."""
        if f is None:
            return Debt()
        return self._debts.setdefault(f, Debt())

    def owe_modes(self, f: ParticleFilter) -> None:
        """A check's move on its modes is owed by `f` (made between points, or at its next point)."""
        self.debt(f).modes = True

    def stepped(self, f: ParticleFilter) -> None:
        """After `f` took a point: a new resampling's sweeps become owed, and the sweeps still owed from the one
        before are made now (resamplings that come faster than the debt is paid get all their sweeps, as when they
        are made in the step: the cloud would otherwise collapse onto a few copies); without a resampling the point
        makes SWEEPS_PER_POINT of them."""
        if not isinstance(f, ResampleMove) or not f.deferred:
            return
        debt = self.debt(f)
        if f.resampled:
            made, debt.sweeps = debt.sweeps, f.sweeps
        else:
            made = min(debt.sweeps, SWEEPS_PER_POINT)
            debt.sweeps -= made
        if made:
            f.move(made)

    def pay_modes(self, track: EmitterTrack) -> bool:
        """The move on the last check's modes, if the track's filter owes one; True when it was made."""
        f = track.filter
        debt = self.debt(f)
        if not debt.modes:
            return False
        debt.modes = False
        return track.supervisor.move_on_modes()

    def owed(self, track: EmitterTrack) -> int:
        """Moves the track's filter owes (0 inline)."""
        return int(self.debt(track.filter))

    def move_one(self, tracks: Iterable[EmitterTrack]) -> bool:
        """One owed move, for the track owing the most (the modes' move before the sweeps); False when none was owed
        (or it failed: counted)."""
        owing = max(tracks, key=self.owed, default=None)
        if owing is None or not self.owed(owing):
            return False
        f = owing.filter
        if f is None or not f.finite():
            return False
        try:
            if self.pay_modes(owing):
                return True
            debt = self.debt(f)
            if not debt.sweeps or not isinstance(f, ResampleMove):
                return False
            debt.sweeps -= 1
            f.move(1)
            return True
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            log.exception("a move sweep between points failed; skipped")
            self.reject(Reason.INTERNAL_ERROR)
            return False

    def wait(self, tracks: Iterable[EmitterTrack]) -> None:
        """Wait until the worker has finished the tracks' jobs (their results are applied at each one's next point,
        as live)."""
        wait([t.job.future for t in tracks if t.job is not None and isinstance(t.job.future, Future)])

    def close(self) -> None:
        """Stop the worker (a job running finishes; its result is dropped)."""
        if self.worker is not None:
            self.worker.close()
