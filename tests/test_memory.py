"""Process settings (engine/scheduling/memory.py): the allocator keeps freed memory, BLAS runs on one thread; old
objects leave the collector's full passes yet are freed as usual, and their cycles go at the first tick after thaw(),
one full pass for a burst of thaws."""
import gc
import os
import platform
import subprocess
import sys
import weakref

from aoa_localizer.engine.scheduling.memory import OldObjects, keep_freed_memory


def test_keep_freed_memory_applies_on_glibc():
    assert keep_freed_memory() is (platform.libc_ver()[0] == "glibc")


def test_a_settled_process_runs_blas_on_one_thread_with_the_same_products():
    """In a process of its own (the suite's is settled by conftest): BLAS on as many threads as cores before,
    one after, and a product BLAS makes is the same."""
    code = ("import numpy as np; from threadpoolctl import threadpool_info\n"
            "from aoa_localizer.engine.scheduling.memory import settle_process\n"
            "a = np.arange(40000.0).reshape(200, 200) % 7; before = a @ a\n"
            "threads = lambda: sorted({p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas'})\n"
            "print(threads()); settle_process(); print(threads(), bool(np.array_equal(a @ a, before)))")
    env = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    before, after = out.stdout.splitlines()
    assert before == f"[{os.cpu_count()}]" and after == "[1] True", out.stdout


class Node:
    """A small object that can be weakly referenced and put in a reference cycle."""

    def __init__(self):
        self.other = None


def test_old_objects_are_frozen_each_period_freed_by_reference_and_their_cycles_after_thaw():
    old = OldObjects(period_s=0.0)
    try:
        alone, a, b = Node(), Node(), Node()
        a.other, b.other = b, a  # a cycle
        gone_alone, gone_cycle = weakref.ref(alone), weakref.ref(a)
        old.tick()
        assert gc.get_freeze_count() > 0
        del alone, a, b
        assert gone_alone() is None  # the last reference went: freed at once, frozen or not
        gc.collect()
        assert gone_cycle() is not None  # a frozen cycle waits for thaw
        old.thaw()
        assert gc.get_freeze_count() == 0
        old.tick()  # the full pass, then the survivors frozen again
        assert gone_cycle() is None and old.full_passes == 1
    finally:
        gc.unfreeze()


def test_a_tick_before_the_period_freezes_nothing():
    gc.unfreeze()
    old = OldObjects(period_s=3600.0)
    old.tick()
    assert gc.get_freeze_count() == 0


def test_a_burst_of_thaws_is_one_full_pass_and_nothing_freezes_while_one_is_due():
    """Issue 51, item 4: each reset used to make a full pass (about 150 ms with a node's objects) at once."""
    old = OldObjects(period_s=0.0, full_period_s=3600.0)
    try:
        for _ in range(50):
            old.thaw()
            old.tick()
        assert old.full_passes == 1  # the first; the rest wait for the period
        assert old.full_due and gc.get_freeze_count() == 0  # a dropped cycle is never frozen before its pass
    finally:
        gc.unfreeze()
