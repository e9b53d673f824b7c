"""A program's first second: a Ctrl-C or SIGTERM while it still imports numpy, scipy and rclpy stops it at once
with its documented code and one line, not a traceback (a foreground start) or nothing at all (a process started
with SIGINT ignored, as a shell's background job is: it used to run to the end and exit 0)."""
from __future__ import annotations

import importlib
import os
import signal
import sys
from collections.abc import Callable
from typing import Any


def program(name: str, home: str, interrupted: int) -> Callable[..., Any]:
    """The entry point of program `name`, whose `main` is in module `home`: until that module is imported, SIGINT
    and SIGTERM end the process with `interrupted` (its code for a Ctrl-C); then the signals' handlers are what
    they were and the program's own take over."""

    def run(*args: Any, **kwargs: Any) -> Any:
        def stop(signum, _frame):
            print(f"{name}: stopped by {signal.Signals(signum).name} while starting", file=sys.stderr, flush=True)
            os._exit(interrupted)  # mid-import: nothing to clean up, and an exception would be a traceback

        old = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            main = importlib.import_module(home).main
        finally:
            for s, handler in old.items():
                signal.signal(s, handler)
        return main(*args, **kwargs)

    return run


def renamed(main: Callable[..., Any], old: str, new: str) -> Callable[..., Any]:
    """A command's old name: one line on stderr that says its new name, then the program."""

    def run(*args: Any, **kwargs: Any) -> Any:
        print(f"{old}: this command is now `{new}`; the name `{old}` goes in the next release", file=sys.stderr)
        return main(*args, **kwargs)

    return run
