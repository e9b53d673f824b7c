"""Process memory settings (engine/scheduling/memory.py): the allocator keeps freed memory; old objects leave the
collector's full passes yet are freed as usual, and their cycles go at thaw()."""
import gc
import platform
import weakref

from aoa_localizer.engine.scheduling.memory import OldObjects, keep_freed_memory


def test_keep_freed_memory_applies_on_glibc():
    assert keep_freed_memory() is (platform.libc_ver()[0] == "glibc")


class Node:
    """A small object that can be weakly referenced and put in a reference cycle."""

    def __init__(self):
        self.other = None


def test_old_objects_are_frozen_each_period_freed_by_reference_and_their_cycles_at_thaw():
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
        assert gone_cycle() is None and gc.get_freeze_count() == 0
    finally:
        gc.unfreeze()


def test_a_tick_before_the_period_freezes_nothing():
    gc.unfreeze()
    old = OldObjects(period_s=3600.0)
    old.tick()
    assert gc.get_freeze_count() == 0
