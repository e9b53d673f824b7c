"""Work cut into turns. A job is a plain function of its inputs, run whole (in the check worker, at the end of data)
or, under `scheduling: reproducible`, in a thread of its own that takes turns with its caller: a turn per point, so
no single call carries a whole global check and a seed still repeats a run. Only one of the two runs at a time.

The kernels declare what they cost by a model of their size (`metered`); the scheduler's meter counts it, and a
job's thread gives its turn back after a kernel once the call's metered cost, the filter's step included, with one
more stretch like the last would reach the job's budget. How far a job has got depends on the points alone, never
on the clock. The maths knows nothing of turns or budgets, but its kernels declare their cost here (`metered`): the
one import from the numerical modules to this room."""
from __future__ import annotations

import functools
import threading
import weakref
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Generic, ParamSpec, TypeVar

T = TypeVar("T")
P = ParamSpec("P")


@dataclass(frozen=True)
class Cost:
    """A kernel's cost model: microseconds per call and per element it makes (least squares over the public
    scenarios' pieces and provisional samples on the development machine; only their ratios matter)."""

    per_call: float
    per_element: float


RESIDUALS = Cost(51.0, 0.036)  # global_search: residuals of places against points, and what a step makes of them
DENSITIES = Cost(45.0, 0.012)  # receiver: the latent noise's densities, an element per hypothesis, place and point
EM_STEP = Cost(71.0, 0.017)  # noise: an EM iteration's responsibilities over runs x readings
LOOKS = Cost(185.0, 0.021)  # emitter_model: the posterior at a move's looks, the move's own work included
POINTS_MADE = Cost(135.0, 0.13)  # point_batch: every point remade from its readings
BATCH_MADE = Cost(117.0, 0.95)  # point_batch: a batch's readings gathered (elements: readings + 4 per point), per pass
# co_channel: one EM iteration of a count's fit, its places' Gauss-Newton steps, scales and biases included (elements:
# readings x places; least squares over fits of 60-1500 readings and 1-3 places, median model / real 0.93)
COUNT_EM = Cost(238.0, 0.20)
# pooled/grid: the survey model's log likelihood over some of a grid's cells (elements: stations x cells x distinct
# noise scales; 0.005-0.010 us an element on this machine, 2026-11-27)
SURVEY_GRID = Cost(150.0, 0.02)
# What a job's stretch costs besides its kernel's model: the Python around it (a Gauss-Newton step's solve, an EM
# step's sums), chosen so a turn's time per metered microsecond, and when a start comes, are what was measured
# (docs/benchmarks.md, "Jobs in turns")
STRETCH_US = 20.0
# A call's turns: the stretch that reaches its budget is the turn's last, and may overrun it by its own cost. A
# global check shares its call with the filter's step and the sweeps it makes; a start search comes before there
# is a filter, so it may take more (its result waits for the next point once it spent half: SlicedJob.advance).
CHECK_BUDGET_US = 4000.0
START_BUDGET_US = 6000.0
# A resampling's sweeps made in a call, the step included: the rest are owed to the following points (scheduler.py)
SWEEP_BUDGET_US = 5000.0
PIECE_EVALUATIONS = 30_000  # bearing densities a grid's score makes at once (its memory: a few megabytes)

_meter = threading.local()  # a thread's own counter, open call and (in a job's thread) turns
# The meter counts whole nanoseconds, in an int: a call's cost is a difference of totals, and in floats that
# difference carried the totals' rounding (2000 + 1500 + 1500 came to 4999.99999999999 after 130,000 us of earlier
# work), so where a budget's edge fell depended on what the thread had metered before
_NS_PER_US = 1000


class _Counter:
    """The metered nanoseconds of one thread."""

    def __init__(self) -> None:
        self.ns = 0


def _counter() -> _Counter:
    counter = getattr(_meter, "counter", None)
    if counter is None:
        counter = _meter.counter = _Counter()
    return counter


def charge(cost: Cost, elements: int) -> _Turns | None:
    """Count what a kernel call over `elements` elements cost: in this thread's total and, in a job's thread, in the
    call it has its turn in; that thread's turns (None outside a job)."""
    ns = round(_NS_PER_US * (cost.per_call + cost.per_element * elements))
    _counter().ns += ns
    turns: _Turns | None = getattr(_meter, "turns", None)
    if turns is not None and turns.call is not None:
        turns.call.jobs_ns += ns
    return turns


def metered(cost: Cost, elements: Callable[..., int]) -> Callable[[Callable[P, T]], Callable[P, T]]:
    """A kernel's declared cost: `elements` of the call's arguments (read after it) priced by `cost`. Inside a
    job's turn the kernel's end is where the job may give the turn back."""
    def declare(kernel: Callable[P, T]) -> Callable[P, T]:
        @functools.wraps(kernel)
        def counted(*args: P.args, **kwargs: P.kwargs) -> T:
            out = kernel(*args, **kwargs)
            turns = charge(cost, elements(*args, **kwargs))
            if turns is not None:
                turns.kernel_done()
            return out
        return counted
    return declare


def spent_ns() -> int:
    """The metered cost so far in this thread (nanoseconds, by the models): take differences of these."""
    return _counter().ns


def metered_since(start_ns: int) -> float:
    """The metered cost since `start_ns` (a spent_ns() reading), in microseconds: exact, whatever came before."""
    return (spent_ns() - start_ns) / _NS_PER_US


class Call:
    """What one call has cost so far: the thread's own metered work since it began, and its jobs' turns."""

    def __init__(self) -> None:
        self._counter = _counter()
        self._start = self._counter.ns
        self.jobs_ns = 0  # metered in the jobs' threads during their turns in this call
        self.pieces = 0  # kernels the jobs made in the call
        self.swept = False  # a resampling's sweep (or part of one) was made in the call

    def cost(self) -> float:
        """The call's metered cost so far (microseconds, by the models), its jobs' turns included."""
        return (self._counter.ns - self._start + self.jobs_ns) / _NS_PER_US


def current_call() -> Call:
    """The call open in this thread (one_call), or a new one that starts now."""
    return getattr(_meter, "call", None) or Call()


@contextmanager
def one_call(call: Call | None = None) -> Iterator[None]:
    """The jobs advanced inside share one budget, `call`'s if given (a point that finishes one job and starts the
    next; a track's points closed by one input); outside, each advance has its own."""
    outer = getattr(_meter, "call", None)
    _meter.call = outer or call or Call()
    try:
        yield
    finally:
        _meter.call = outer


class _Cancelled(Exception):
    """Raised in a dropped job's thread at its next kernel, so the thread ends (no job catches a broad Exception:
    tests/test_layout.py keeps the maths to named errors)."""


class _Turns:
    """A job's thread and its turns: the caller hands a turn over and waits until it comes back."""

    def __init__(self, job: Callable[[], object], budget_us: float):
        self.job, self.budget_us = job, budget_us
        self.cond = threading.Condition()
        self.job_runs = False  # the job's thread has the turn (the caller waits)
        self.call: Call | None = None  # the call the turn is part of
        self.whole = False  # the turn lasts to the job's end
        self.cancelled = False
        self.done = False
        self.value: object = None
        self.error: BaseException | None = None
        self.mark = 0.0  # the call's cost at the last kernel's end
        self.last = 0.0  # the last stretch's metered cost: what the next may cost
        self.thread: threading.Thread | None = None

    def run(self) -> None:
        """The job's thread: the job, then the turn back for good."""
        _meter.turns = self
        try:
            self.value = self.job()
        except _Cancelled:
            pass
        except Exception as exc:  # noqa: BLE001 - kept for result(), as a worker's Future keeps it
            self.error = exc
        with self.cond:
            self.done, self.job_runs, self.call = True, False, None
            self.cond.notify_all()

    def kernel_done(self) -> None:
        """In the job's thread: after a kernel, the turn goes back when one more stretch like the last would reach
        the budget."""
        call = self.call
        if call is None:
            return
        call.jobs_ns += round(_NS_PER_US * STRETCH_US)
        now = call.cost()
        self.last, self.mark = now - self.mark, now
        call.pieces += 1
        if not self.whole and now + self.last >= self.budget_us:
            with self.cond:
                self.job_runs = False
                self.cond.notify_all()
                while not (self.job_runs or self.cancelled):
                    self.cond.wait()
            if self.cancelled:
                raise _Cancelled

    def give(self, call: Call, whole: bool) -> None:
        """In the caller: a turn for the job, back when it ends (a turn left running by an exception in the caller,
        a Ctrl-C, ends first)."""
        with self.cond:
            while self.job_runs:
                self.cond.wait()
            if self.done:
                return
            if self.thread is not None and not self.thread.is_alive():  # a fork's child has none of its threads
                self.done, self.error = True, RuntimeError("the job's thread is gone (the process was forked)")
                return
            self.call, self.whole, self.mark = call, whole, call.cost()
            self.job_runs = True
            if self.thread is None:
                self.thread = threading.Thread(target=self.run, name="aoa-job", daemon=True)
                self.thread.start()
            else:
                self.cond.notify_all()
            while self.job_runs:
                self.cond.wait()
            self.call = None

    def cancel(self) -> None:
        """The job was dropped: a thread waiting for its turn ends (at once, with nothing of the job made)."""
        with self.cond:
            self.cancelled = True
            self.cond.notify_all()


class SlicedJob(Generic[T]):
    """A job run a turn per call by `advance` (what a Future's `done` and `result` are to the track: `result`
    makes the rest). An exception the job raises is kept and raised by `result`, as a Future's is."""

    def __init__(self, job: Callable[[], T], budget_us: float):
        """`budget_us`: the metered cost a call, the filter's step included, may reach."""
        self._turns = _Turns(job, budget_us)
        self.budget_us = budget_us
        self._held = False  # finished in a call that had spent half its budget: done() at the next point
        weakref.finalize(self, self._turns.cancel)  # a job dropped unfinished takes its thread with it

    def advance(self) -> None:
        """A turn, unless the call's jobs already made a kernel and spent its budget (at least one kernel a call,
        so a job goes on however dear the steps are; none once done)."""
        turns, call = self._turns, current_call()
        if turns.done or (call.pieces and call.cost() >= self.budget_us):
            return
        turns.give(call, whole=False)
        # Applying a result costs about as much as a stretch or two (a start's sample and sweeps, a check's points
        # rebuilt and cloud re-weighted): after half the budget, it waits for the next point, as a worker's does.
        if turns.done:
            self._held = call.cost() >= 0.5 * self.budget_us

    def release(self) -> None:
        """A new point came: a result held back from the call that finished it is ready."""
        self._held = False

    def done(self) -> bool:
        return self._turns.done and not self._held

    def result(self) -> T:
        """The job's result, the rest of it made first; the exception it raised, if it did."""
        turns = self._turns
        turns.give(current_call(), whole=True)
        if turns.error is not None:
            raise turns.error
        return turns.value  # type: ignore[return-value]  # set when the job returned
