"""Settings a program that runs the engine makes for its process (`settle_process`), never a Localizer: a process's
allocator and threads are its program's to set. keep_freed_memory: the C allocator keeps freed memory for reuse (the
filters' particles x points temporaries are a few MB each, and glibc by default maps each afresh and returns it at
free, so every temporary paid its pages' first-touch faults: 2-4x the arithmetic on this machine). one_blas_thread:
BLAS on one thread (the engine's linear algebra is 2x2 and 3x3 and small products, which more threads do not speed
up, and an idle BLAS thread spins). Every program calls settle_process (the ROS ones in ros_main.run_node;
replay, simulate, report, locate, the launcher; the benchmarks' runs), the check worker at its start. OldObjects:
the node's kept readings out of the cyclic garbage collector's full passes (docs/ros.md, "Latency")."""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
import gc
import logging
import time

# numpy's and scipy's BLAS libraries (each its own) loaded before one_blas_thread limits them
import numpy  # noqa: F401
import scipy.linalg  # noqa: F401
from threadpoolctl import threadpool_info, threadpool_limits

log = logging.getLogger("aoa_localizer")

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameters (malloc.h)
MMAP_THRESHOLD = 32 * 1024 * 1024  # glibc's largest: blocks below come from the heap and are reused
TRIM_THRESHOLD = 256 * 1024 * 1024  # free memory kept at the heap's top before any is given back


@functools.cache
def keep_freed_memory() -> bool:
    """Tell glibc's malloc to serve blocks up to 32 MiB from its heap and keep up to 256 MiB of freed memory;
    True when applied (False on another C library: nothing changes). Once per process: the settings are the
    process's, and finding the C library runs ldconfig."""
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt if name else None
    except (OSError, AttributeError):
        mallopt = None
    if mallopt is None:
        log.debug("no glibc mallopt: the allocator keeps its defaults")
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))


@functools.cache
def one_blas_thread() -> bool:
    """BLAS (OpenBLAS under numpy and scipy) on one thread; True when every BLAS library loaded runs on one. Its
    threads spin while they wait for work, CPU taken from the rest of the machine for no speed on the engine's small
    matrices (docs/benchmarks.md, "One BLAS thread"). Once per process, as the allocator's setting."""
    threadpool_limits(limits=1, user_api="blas")
    blas = [pool for pool in threadpool_info() if pool["user_api"] == "blas"]
    return bool(blas) and all(pool["num_threads"] == 1 for pool in blas)


def settle_process() -> None:
    """What a program that runs the engine sets for its process: freed memory kept, BLAS on one thread."""
    keep_freed_memory()
    one_blas_thread()


class OldObjects:
    """Every `period_s`, from the node's idle time: collect the young generations, then gc.freeze() what survived,
    so the collector's full passes never walk the hundreds of thousands of readings 50 channels keep (one pass
    held the callbacks 200 ms). Frozen objects are still freed when their last reference goes; only reference
    cycles among them wait for thaw(), which a node calls when it drops its Localizer (reset, parameter change).
    thaw() only unfreezes: the full pass that frees the dropped cycles (about 150 ms with a node's objects) runs
    at the next tick, at most once per `full_period_s`, so a burst of resets costs one pass, not one each."""

    def __init__(self, period_s: float = 1.0, full_period_s: float = 10.0):
        self.period_s = period_s
        self.full_period_s = full_period_s
        self.last = time.monotonic()
        self.last_full = -float("inf")
        self.full_due = False
        self.full_passes = 0

    def tick(self):
        now = time.monotonic()
        if now - self.last < self.period_s:
            return
        if self.full_due:
            if now - self.last_full < self.full_period_s:
                return  # freezing now would freeze the dropped cycles with the rest: wait for the full pass
            gc.collect()
            self.full_due, self.last_full = False, now
            self.full_passes += 1
        else:
            gc.collect(1)
        self.last = now
        gc.freeze()

    def thaw(self):
        """All objects back under the collector; the full pass that frees the dropped Localizer's cycles is due."""
        gc.unfreeze()
        self.full_due = True
