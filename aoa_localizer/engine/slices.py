"""Work cut into pieces: a generator that yields after each piece and returns its result, run whole (in the check
worker, at the end of data) or a fixed number of pieces per point (`scheduling: reproducible`), so no single call
carries a whole global check and a seed still repeats a run: how far a job has got depends on the points alone,
never on the clock."""
from __future__ import annotations

from collections.abc import Generator
from typing import Generic, TypeVar

T = TypeVar("T")
Steps = Generator[None, None, T]  # yields after each piece of work, returns the result

# A piece (an annealing level of a refinement, an EM fit, a grid's score, one stamp shift's fit) costs about as
# much as a pass over PIECE_POINTS points plus one over its K points, so a job makes
# max(1, PIECES_PER_CALL // (1 + K / PIECE_POINTS)) pieces per call: the same share of work at any size, never the
# whole job in one call.
PIECE_POINTS = 100
PIECES_PER_CALL = 12
PIECE_EVALUATIONS = 50_000  # bearing densities a grid's score makes per piece (a millisecond or two)


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

    def __init__(self, steps: Steps[T], points: int):
        """`points`: how many points the job works over (what a piece costs)."""
        self._steps = steps
        self.pieces = max(1, int(PIECES_PER_CALL / (1.0 + points / PIECE_POINTS)))
        self._done = False
        self._value: T | None = None
        self._error: BaseException | None = None

    def advance(self) -> None:
        """One call's pieces (none once done)."""
        for _ in range(self.pieces):
            if self._done:
                return
            self._next()

    def _next(self) -> None:
        try:
            next(self._steps)
        except StopIteration as stop:
            self._done, self._value = True, stop.value
        except Exception as exc:  # noqa: BLE001 - kept for result(), as a worker's Future keeps it
            self._done, self._error = True, exc

    def done(self) -> bool:
        return self._done

    def result(self) -> T:
        """The job's result, its pieces left made first; the exception a piece raised, if one did."""
        while not self._done:
            self._next()
        if self._error is not None:
            raise self._error
        return self._value  # type: ignore[return-value]  # set with _done when no piece raised
