"""The start-run-stop of a ROS program: refuse to start with a clear message (exit 2), run until done,
SIGINT or SIGTERM, always destroy the node and shut rclpy down (exit 0), within TEARDOWN_S."""
from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from aoa_localizer.engine.scheduling.memory import settle_process

POLL_S = 0.1  # how soon a spinning program notices SIGINT or SIGTERM
# The middleware's teardown (a node destroyed, rclpy shut down) at most: past it a program whose work is done exits
# without it. Fast DDS and rclpy have been seen to hang there now and then (a busy machine, a peer leaving)
TEARDOWN_S = 10.0


class Stop:
    """The SIGINT or SIGTERM a program was asked to stop by; its loops poll `requested`. rclpy's own handler is not
    used: it shuts the context down under whatever the program is doing, and a wait or a publish then dies in an
    RCLError traceback."""

    def __init__(self):
        self.by: str | None = None

    def __call__(self, signum, _frame):
        self.by = signal.Signals(signum).name

    @property
    def requested(self) -> bool:
        return self.by is not None


def spin(node, stop: Stop):
    """Serve the node's callbacks until asked to stop."""
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while not stop.requested:
            executor.spin_once(timeout_sec=POLL_S)
    finally:
        executor.remove_node(node)
        executor.shutdown()


def bounded_teardown(name: str, teardown: Callable[[], None], exit_code: int) -> None:
    """`teardown()` (destroying a node, shutting rclpy down); should it hang past TEARDOWN_S, the process says so and
    exits with `exit_code`: its work is done and what it had to say is said, only the middleware's goodbye is lost."""
    guard = threading.Timer(TEARDOWN_S, _abandon_teardown, (name, exit_code))
    guard.daemon = True
    guard.start()
    try:
        teardown()
    finally:
        guard.cancel()


def _abandon_teardown(name: str, exit_code: int) -> None:
    print(f"{name}: the ROS middleware did not shut down within {TEARDOWN_S:g} s; exiting without it",
          file=sys.stderr)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(exit_code)


def wants_help(argv) -> bool:
    """-h or --help before any --ros-args: print usage, start nothing (not even on a ROS domain)."""
    args = list(sys.argv if argv is None else argv)
    own = args[:args.index("--ros-args")] if "--ros-args" in args else args
    return "-h" in own or "--help" in own


def run_node(name: str, make, run, refusals: tuple, argv=None, usage: str = "") -> int:
    """make() builds the node (raising one of `refusals` to refuse); run(node, stop) works until done or
    `stop.requested`. With -h or --help, `usage` is printed and nothing starts. The process is settled for the
    engine first (freed memory kept, BLAS on one thread: scheduling/memory.py)."""
    if wants_help(argv):
        try:
            print(usage, flush=True)
        except BrokenPipeError:  # `--help | head`: the reader left; not an error of ours
            sys.stdout = open(os.devnull, "w")  # the interpreter's exit flush must not fail either
        return 0
    settle_process()
    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except RCLError as exc:  # --ros-args rcl cannot parse (a -p value YAML reads as a mixed list): one line
        print(f"{name}: refusing to start: {str(exc).split(', at ')[0]}", file=sys.stderr)
        return 2
    stop = Stop()
    old = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    node, code = None, 1  # 1: the run raised (its traceback follows the teardown)

    def teardown():
        try:
            if node is not None:
                node.destroy_node()
        finally:
            rclpy.try_shutdown()

    try:
        try:
            node = make()
        except refusals + (rclpy.exceptions.ParameterException,) as exc:
            print(f"{name}: refusing to start: {exc}", file=sys.stderr)
            code = 2
            return code
        run(node, stop)
        code = 0
    finally:
        bounded_teardown(name, teardown, code)
        for s, handler in old.items():
            signal.signal(s, handler)
    return code
