"""Where a Localizer's deferred work runs, in one place.

A track defers two kinds of work. Its jobs (start searches and global checks) run in the call (`reproducible`: a seed
repeats a run) or in the check worker's process (`realtime`: the node's), their result applied at the track's next
point or by `idle()`. The Metropolis-Hastings moves it owes under `realtime` (a resampling's sweeps, a worker check's
move on its modes) are made when the caller has time: `idle()` makes one, `catch_up()` all of them, else each
following point makes one. Any of these moves keeps the posterior invariant, so when it is made changes no law.
"""
from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from concurrent.futures import Future, wait
from typing import TYPE_CHECKING

import numpy as np

from aoa_localizer.engine.checks import CheckWorker
from aoa_localizer.engine.rejections import Reason

if TYPE_CHECKING:  # the tracks take the scheduler: the type only, for the checker
    from aoa_localizer.engine.track import EmitterTrack

log = logging.getLogger("aoa_localizer")


class Scheduler:
    """Runs the tracks' jobs inline or in the worker (`realtime`), and makes the moves they owe when asked."""

    def __init__(self, realtime: bool, reject: Callable[[Reason], None]):
        """`reject`: told of a move that failed (counted as an internal error, the track goes on)."""
        self.worker = CheckWorker() if realtime else None
        self.reject = reject

    @property
    def realtime(self) -> bool:
        """Jobs go to the worker and moves are owed (else both are made in the call)."""
        return self.worker is not None

    @property
    def failures(self) -> int:
        """The worker's failed jobs in a row (0 inline)."""
        return self.worker.failures if self.worker is not None else 0

    def submit(self, job) -> Future | None:
        """The job handed to the worker (its future); None inline, or when the worker cannot take it (then the
        caller runs it)."""
        return None if self.worker is None else self.worker.submit(job)

    def finished(self, tracks: Iterable[EmitterTrack]) -> list[EmitterTrack]:
        """The tracks whose job finished, its result applied now, that have a new estimate."""
        return [t for t in tracks if t.collect() and t.estimating]

    def move_one(self, tracks: Iterable[EmitterTrack]) -> bool:
        """One owed move, for the track owing the most; False when none was owed (or it failed: counted)."""
        owing = max(tracks, key=lambda t: t.owed, default=None)
        if owing is None or not owing.owed:
            return False
        try:
            return owing.pay_owed()
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            log.exception("a move sweep between points failed; skipped")
            self.reject(Reason.INTERNAL_ERROR)
            return False

    def wait(self, tracks: Iterable[EmitterTrack]) -> None:
        """Wait until the worker has finished the tracks' jobs (their results are applied at each one's next point,
        as live)."""
        wait([t.job.future for t in tracks if t.job is not None])

    def close(self) -> None:
        """Stop the worker (a job running finishes; its result is dropped)."""
        if self.worker is not None:
            self.worker.close()
