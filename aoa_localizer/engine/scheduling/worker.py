"""The process that runs the Localizer's background jobs (the start searches, global checks and counts, plain
functions of their inputs) beside the caller under `scheduling: realtime`: started at the first job, at a lower
priority, gone with its parent."""
from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from aoa_localizer.engine.scheduling.memory import settle_process
from aoa_localizer.engine.scheduling.parent_death import die_with_parent

log = logging.getLogger("aoa_localizer")

WORKER_NICENESS = 10  # the checks yield the CPU to the node's callbacks (and to the rest of the vehicle's software)


def _background(parent_pid: int):
    """In the worker process: a lower scheduling priority, so a check never delays the callbacks; Ctrl-C (sent to
    the whole process group) is the parent's to handle: the pool stops the worker when the parent exits, and
    SIGTERM does when the parent is killed (the worker, and with it multiprocessing's resource tracker, used to
    stay behind)."""
    die_with_parent(parent_pid)
    os.nice(WORKER_NICENESS)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    settle_process()


class CheckWorker:
    """One worker process that runs the Localizer's background jobs, one at a time, oldest first; started at the
    first job, started again if it died (its job fails with BrokenProcessPool, counted by the track). A worker
    that cannot start, or that died MAX_BREAKS times in a row, is not tried again: submit returns None and the jobs
    run in the caller."""

    MAX_BREAKS = 3

    def __init__(self):
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()
        self.unusable = ""  # why the worker could not start (then every job runs inline)
        self.failures = 0  # jobs that raised (the first is logged with its traceback, the rest counted)
        self._breaks = 0  # jobs in a row lost to a dead worker process

    def _done(self, future: Future):
        """A job ended (in the pool's thread: only counts here)."""
        exc = None if future.cancelled() else future.exception()
        self._breaks = self._breaks + 1 if isinstance(exc, BrokenProcessPool) else 0
        self.failures += exc is not None

    def submit(self, job: Callable[[], object]) -> Future | None:
        with self._lock:
            if self.unusable:
                return None
            if self._breaks >= self.MAX_BREAKS:
                self._give_up(f"its process died {self._breaks} times in a row", started=True)
                return None
            for _ in range(2):
                try:
                    if self._pool is None:
                        # spawn, not fork: the parent runs threads (rclpy's, the pool's own) that fork would copy
                        self._pool = ProcessPoolExecutor(
                            max_workers=1, mp_context=multiprocessing.get_context("spawn"), initializer=_background,
                            initargs=(os.getpid(),))
                    future = self._pool.submit(job)
                    future.add_done_callback(self._done)
                    return future
                except BrokenProcessPool:
                    self._stop()
                # No processes allowed, a script's unguarded main, or a daemonic process (a multiprocessing.Pool's
                # worker), which multiprocessing forbids to have children (an AssertionError)
                except (RuntimeError, OSError, AssertionError) as exc:
                    self._give_up(str(exc).strip().splitlines()[0] or type(exc).__name__)
                    return None
            self._give_up("the check worker died at its start twice")
            return None

    def _give_up(self, reason: str, started: bool = False):
        """No worker from now on; the warning names the `__main__` guard where the worker could not start."""
        self.unusable = reason
        self._stop()
        hint = "" if started else (" A script that sets scheduling: realtime needs its main code under "
                                   "`if __name__ == \"__main__\":` (the worker is a spawned process).")
        log.warning("the check worker is given up (%s): the checks run in the calls from now on, as with "
                    "scheduling: reproducible.%s", reason, hint)

    def close(self):
        """Stop taking jobs; the one running finishes, the waiting ones are dropped."""
        with self._lock:
            self._stop()

    def _stop(self):
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
