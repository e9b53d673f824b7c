"""Where a Localizer's deferred work runs and what it owes, in one place.

A track defers two kinds of work. Its jobs (start searches and global checks) run in turns, one per point
(`reproducible`: a seed repeats a run; slices.py), their result applied in the call that made the last turn, or in
the check worker's process (`realtime`: the node's), their result applied at the track's next point or by
`idle()`. A resampling's Metropolis-Hastings sweeps are owed instead of made in its step: the scheduler keeps the
debt of each filter. Under `reproducible` a call makes them while its metered cost stays under SWEEP_BUDGET_US
(slices.py: by the points alone, never the clock), at least one a point, and the rest at the points that follow;
under `realtime` the caller makes them when it has time (`idle()` one, `catch_up()` all of them, else each
following point one), and a worker check's move on its modes is owed too. Any of these moves keeps the posterior
invariant, so when it is made changes no law.
"""
from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Future, wait
from dataclasses import dataclass
from typing import Any
from weakref import WeakKeyDictionary

import numpy as np

from aoa_localizer.engine.rejections import Reason
from aoa_localizer.engine.scheduling.slices import (
    SWEEP_BUDGET_US,
    Call,
    SlicedJob,
    current_call,
    metered_since,
    spent_ns,
)
from aoa_localizer.engine.scheduling.worker import CheckWorker
from aoa_localizer.engine.types import Reading
from aoa_localizer.filters.base import ParticleFilter
from aoa_localizer.filters.moves import Proposal
from aoa_localizer.filters.resample_move import ResampleMove

log = logging.getLogger("aoa_localizer")

SWEEPS_PER_POINT = 1  # owed sweeps a point makes when the caller gave no time for them
# Under `reproducible` a larger cloud's sweep is made this many particles at a time (a random order per sweep), so
# one sweep of a thousand particles over hundreds of points does not take a call by itself
SWEEP_PART = 100


@dataclass
class Debt:
    """What one filter owes: a global check's move on its modes, and a resampling's sweeps."""

    modes: bool = False
    sweeps: int = 0
    # the sweep being made a part at a time: its order of the particles (None: none begun) and how many have moved
    order: np.ndarray | None = None
    at: int = 0
    sweep_us: float = 0.0  # the metered cost of its last sweep (or part of one): what the next will cost

    def __int__(self) -> int:
        return int(self.modes) + self.sweeps


@dataclass
class PendingJob:
    """A track's job, running in the check worker or made in turns, one per point: a start search (`filter` None) or
    a global check for `filter`, with the reading groups of its snapshot (the originals: the worker's copies come
    back as points in their order)."""

    future: Future | SlicedJob
    filter: ParticleFilter | None
    groups: list[Sequence[Reading]]

    @property
    def in_calls(self) -> bool:
        """Made in turns within the calls (not in the worker)."""
        return isinstance(self.future, SlicedJob)

    @property
    def is_start(self) -> bool:
        return self.filter is None


class JobPlace:
    """A key for one kind of job among the scheduler's (a track's own place holds its search or check; these its
    transmitter count, and its channel's live survey fix)."""


class Scheduler:
    """Runs the tracks' jobs inline or in the worker (`realtime`), and makes the moves they owe when asked."""

    def __init__(self, realtime: bool, reject: Callable[[Reason], None]):
        """`reject`: told of a move that failed (counted as an internal error, the track goes on)."""
        self.worker = CheckWorker() if realtime else None
        self.reject = reject
        # Keyed by the filter that owes: a filter replaced (re-start, divergence) takes its debt with it.
        self._debts: WeakKeyDictionary[ParticleFilter, Debt] = WeakKeyDictionary()
        # Keyed by the track that waits for it: a track dropped takes its job with it (a sliced one ends its thread).
        self._jobs: WeakKeyDictionary[object, PendingJob] = WeakKeyDictionary()

    @property
    def realtime(self) -> bool:
        """Jobs go to the worker and moves are owed (else both are made in the call)."""
        return self.worker is not None

    @property
    def failures(self) -> int:
        """The worker's failed jobs in a row (0 inline)."""
        return self.worker.failures if self.worker is not None else 0

    def start(self, owner: object, job: Callable[[], object], budget_us: float, f: ParticleFilter | None,
              groups: list[Sequence[Reading]], first_turn: bool = True) -> None:
        """`owner`'s job, a plain function (a track's start search for `f` None, else a check for `f`, over the
        snapshot of `groups`; its transmitter count; its channel's live survey fix): handed to the worker; inline, or
        when the worker cannot take it, made in turns within the calls, up to `budget_us` a call (slices.py), the
        first turn now (`first_turn`; else at the owner's next point: a job begun outside its point's call)."""
        future = None if self.worker is None else self.worker.submit(job)
        if future is None:
            sliced = SlicedJob(job, budget_us)
            if first_turn:
                sliced.advance()
        self._jobs[owner] = PendingJob(future if future is not None else sliced, f, groups)

    def job(self, owner: object) -> PendingJob | None:
        """The job running for `owner`, if one is."""
        return self._jobs.get(owner)

    def point_came(self, owner: object) -> None:
        """A point came to `owner`: a result held back from the call that finished it is ready (slices.py)."""
        job = self._jobs.get(owner)
        if job is not None and isinstance(job.future, SlicedJob):
            job.future.release()

    def take_turn(self, owner: object) -> None:
        """After `owner`'s step: its job made in the calls takes its turn (a worker's goes on by itself)."""
        job = self._jobs.get(owner)
        if job is not None and isinstance(job.future, SlicedJob):
            job.future.advance()

    def finished(self, owner: object, wait: bool = False) -> PendingJob | None:
        """`owner`'s job once it is done (`wait`: waited for, or made to its end), handed back and no longer held;
        None while it runs, or when there is none."""
        job = self._jobs.get(owner)
        if job is None or not (wait or job.future.done()):
            return None
        del self._jobs[owner]
        return job

    def owners_done(self) -> set:
        """The owners whose job has finished: what idle() applies (looking at every channel's track instead cost a
        node with 250 channels a fifth of its time)."""
        return {owner for owner, job in self._jobs.items() if job.future.done()}

    # -- the moves owed ------------------------------------------------------------------------------
    def debt(self, f: ParticleFilter | None) -> Debt:
        """What `f` owes now (nothing for None)."""
        if f is None:
            return Debt()
        return self._debts.setdefault(f, Debt())

    def owe_modes(self, f: ParticleFilter) -> None:
        """A check's move on its modes is owed by `f` (made between points, or at its next point)."""
        self.debt(f).modes = True

    def stepped(self, f: ParticleFilter) -> None:
        """After `f` took a point: a new resampling's sweeps become owed, then the point makes some of the debt.
        `realtime`: the sweeps still owed from the resampling before are made now (resamplings that come faster than
        the caller's idle time pays get all their sweeps: the cloud would otherwise collapse onto a few copies), none
        of the new one's, and without a resampling SWEEPS_PER_POINT of them. `reproducible`: as many as the call's
        budget holds, at least one a call; a resampling's own sweeps replace what is left of the one before (a
        bounded call: each resampling still gets at least one at once, unless the call already made one or a job's
        turn or spent half its budget, and the rest while no other comes)."""
        if not isinstance(f, ResampleMove) or not f.deferred:
            return
        debt = self.debt(f)
        if not self.realtime:
            if f.resampled:
                debt.sweeps, debt.order = f.sweeps, None
            self._sweep_within_budget(f, debt, current_call())
            return
        if f.resampled:
            made, debt.sweeps = debt.sweeps, f.sweeps
        else:
            made = min(debt.sweeps, SWEEPS_PER_POINT)
            debt.sweeps -= made
        if made:
            f.move(made)

    @staticmethod
    def _sweep_within_budget(f: ResampleMove, debt: Debt, call: Call) -> None:
        """The owed sweeps one at a time while the call's metered cost with one more sweep's stays under
        SWEEP_BUDGET_US; at least one when the call made no sweep and gave no job a turn yet and spent under half the
        budget (a second point of one input, or a point after a job's turn or a check's result applied, owes them
        when the call is spent); a cloud of more than SWEEP_PART particles a part of a sweep at a time."""
        first = not (call.swept or call.pieces) and call.cost() < 0.5 * SWEEP_BUDGET_US
        while debt.sweeps and (first or call.cost() + debt.sweep_us < SWEEP_BUDGET_US):
            first, call.swept = False, True
            before = spent_ns()
            if f.n <= SWEEP_PART:
                f.move(1)
                debt.sweeps -= 1
            else:
                if debt.order is None:
                    debt.order, debt.at = f.rng.permutation(f.n), 0
                f.move(1, debt.order[debt.at:debt.at + SWEEP_PART])
                debt.at += SWEEP_PART
                if debt.at >= f.n:
                    debt.sweeps, debt.order = debt.sweeps - 1, None
            debt.sweep_us = metered_since(before)

    def pay_all(self, f: ParticleFilter | None) -> None:
        """Every sweep `f` owes, made now (the end of data)."""
        debt = self.debt(f)
        if debt.sweeps and isinstance(f, ResampleMove):
            made, debt.sweeps, debt.order = debt.sweeps, 0, None  # a sweep made in parts is made whole
            f.move(made)

    def pay_modes(self, f: ParticleFilter | None, proposal: Proposal | None) -> bool:
        """The move on the last check's modes (`proposal`: the track's, made from them), if `f` owes one; True when
        it was made (an MH move: made late, it keeps the posterior)."""
        debt = self.debt(f)
        if not debt.modes:
            return False
        debt.modes = False
        if f is None or proposal is None:
            return False
        f.rejuvenate(1, proposal)
        return True

    def owing(self) -> set:
        """The filters that owe moves now."""
        return {f for f, d in self._debts.items() if int(d)}

    def owed(self, f: ParticleFilter | None) -> int:
        """Moves `f` owes."""
        return int(self.debt(f))

    def move_one(self, debtors: Iterable[tuple[ParticleFilter | None, Proposal | None]]) -> bool:
        """Between points (`realtime`): one owed move, for the filter owing the most (the modes' move, with its
        track's proposal, before the sweeps); False when none was owed (or it failed: counted), and always under
        `reproducible`, whose moves follow its points alone."""
        if not self.realtime:
            return False
        f, proposal = max(debtors, key=lambda d: self.owed(d[0]), default=(None, None))
        if f is None or not self.owed(f) or not f.finite():
            return False
        try:
            if self.pay_modes(f, proposal):
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

    def value(self, job: PendingJob, what: str) -> tuple[bool, Any]:
        """A finished job's value, with True; (False, None) when it raised: counted as an internal error and logged
        (with its traceback, unless the worker failed in a row before), the owner going on as it was."""
        try:
            return True, job.future.result()
        except Exception:  # the worker's boundary: a failed job never stops its owner
            if self.failures <= 1:
                log.exception("%s failed; skipped (further failures are counted)", what)
            self.reject(Reason.INTERNAL_ERROR)
            return False, None

    def wait(self, owners: Iterable[object]) -> None:
        """Wait until the worker has finished the jobs of `owners` (their results are applied at each track's next
        point, as live); a job made in the calls has nothing to wait for."""
        jobs = (self._jobs.get(owner) for owner in owners)
        wait([job.future for job in jobs if job is not None and isinstance(job.future, Future)])

    def close(self) -> None:
        """Stop the worker (a job running finishes; its result is dropped)."""
        if self.worker is not None:
            self.worker.close()
