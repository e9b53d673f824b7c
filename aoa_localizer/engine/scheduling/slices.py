"""Work cut into pieces: a generator that yields after each piece and returns its result, run whole (in the check
worker, at the end of data) or a few pieces per point (`scheduling: reproducible`), so no single call carries a
whole global check and a seed still repeats a run. After the filter's step, a call makes pieces until the metered
cost of the step and the pieces reaches the job's budget: the kernels charge what they cost by a model of their
size (`charge`), so how far a job has got depends on the points alone, never on the clock."""
from __future__ import annotations

import threading
from collections.abc import Generator, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T")
Steps = Generator[None, None, T]  # yields after each piece of work, returns the result


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
PIECE_US = 71.0  # what a piece costs besides the metered kernels
# A call's pieces: the piece that reaches its budget is the call's last, and may overrun it by its own cost. A
# global check shares its call with the filter's step and the sweeps it makes; a start search comes before there
# is a filter, so it may take more (its result waits for the next point once it spent half: SlicedJob.advance).
CHECK_BUDGET_US = 4000.0
START_BUDGET_US = 6000.0
# A resampling's sweeps made in a call, the step included: the rest are owed to the following points (scheduler.py)
SWEEP_BUDGET_US = 5000.0
PIECE_EVALUATIONS = 30_000  # bearing densities a grid's score makes per piece (a millisecond or two)

_meter = threading.local()  # a thread's own, so Localizers in other threads never move a job's pieces
# The meter counts whole nanoseconds, in an int: a call's cost is a difference of the thread's totals, and in floats
# that difference carried the totals' rounding (2000 + 1500 + 1500 came to 4999.99999999999 after 130,000 us of
# earlier work), so where a budget's edge fell depended on what the thread had metered before
_NS_PER_US = 1000


def charge(cost: Cost, elements: int) -> None:
    """Count what a kernel call over `elements` elements cost."""
    _meter.spent_ns = getattr(_meter, "spent_ns", 0) + round(_NS_PER_US * (cost.per_call + cost.per_element * elements))


def spent_ns() -> int:
    """The metered cost so far in this thread (nanoseconds, by the models): take differences of these."""
    return getattr(_meter, "spent_ns", 0)


def metered_since(start_ns: int) -> float:
    """The metered cost since `start_ns` (a spent_ns() reading), in microseconds: exact, whatever came before."""
    return (spent_ns() - start_ns) / _NS_PER_US


class Call:
    """What the pieces made in one call have cost so far."""

    def __init__(self) -> None:
        self.start_ns, self.pieces = spent_ns(), 0
        self.swept = False  # a resampling's sweep (or part of one) was made in the call

    def cost(self) -> float:
        """The call's metered cost so far (microseconds, by the models), its pieces' own cost included."""
        return metered_since(self.start_ns) + PIECE_US * self.pieces


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


def run_whole(steps: Steps[T]) -> T:
    """Every piece of `steps`, then its result."""
    while True:
        try:
            next(steps)
        except StopIteration as stop:
            return stop.value


class SlicedJob(Generic[T]):
    """A job run a few pieces at a time by `advance` (what a Future's `done` and `result` are to the track: `result`
    makes the pieces left). An exception a piece raises is kept and raised by `result`, as a Future's is."""

    def __init__(self, steps: Steps[T], budget_us: float):
        """`budget_us`: the metered cost a call's pieces may reach."""
        self._steps, self.budget_us = steps, budget_us
        self._done = False
        self._held = False  # finished in a call that had spent half its budget: done() at the next point
        self._value: T | None = None
        self._error: BaseException | None = None

    def advance(self) -> None:
        """Pieces while the call's cost, the filter's step included, with the last piece's once more stays under the
        budget; at least one per call, so a job goes on however dear the steps are (none once done)."""
        call, last, was_done = current_call(), 0.0, self._done
        while not self._done and not (call.pieces and call.cost() + last >= self.budget_us):
            before = call.cost()
            self._next()
            call.pieces += 1
            last = call.cost() - before
        # Applying a result costs about as much as a piece or two (a start's sample and sweeps, a check's points
        # rebuilt and cloud re-weighted): after half the budget, it waits for the next point, as a worker's does.
        if self._done and not was_done:
            self._held = call.cost() >= 0.5 * self.budget_us

    def release(self) -> None:
        """A new point came: a result held back from the call that finished it is ready."""
        self._held = False

    def _next(self) -> None:
        try:
            next(self._steps)
        except StopIteration as stop:
            self._done, self._value = True, stop.value
        except Exception as exc:  # noqa: BLE001 - kept for result(), as a worker's Future keeps it
            self._done, self._error = True, exc

    def done(self) -> bool:
        return self._done and not self._held

    def result(self) -> T:
        """The job's result, its pieces left made first; the exception a piece raised, if one did."""
        while not self._done:
            self._next()
        if self._error is not None:
            raise self._error
        return self._value  # type: ignore[return-value]  # set with _done when no piece raised
