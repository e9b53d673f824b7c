"""A child process that must not outlive its parent (the launcher's node and vehicle, the node's check worker):
Linux delivers it a signal when the parent dies, even by SIGKILL or the OOM killer (`PR_SET_PDEATHSIG`)."""
from __future__ import annotations

import ctypes
import os
import signal

_PR_SET_PDEATHSIG = 1  # prctl option: a signal for this process when its parent dies


def die_with_parent(parent_pid: int | None = None) -> None:
    """SIGTERM to this process when its parent dies (elsewhere than Linux: nothing). With `parent_pid`, a parent
    that died before this call (the signal is not sent then) ends this process at once."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        return
    if parent_pid is not None and os.getppid() != parent_pid:
        os._exit(0)
