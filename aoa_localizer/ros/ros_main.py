"""The start-run-stop of a ROS program: refuse to start with a clear message (exit 2), run until done,
SIGINT or SIGTERM, always destroy the node and shut rclpy down (exit 0)."""
from __future__ import annotations

import os
import signal
import sys

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

POLL_S = 0.1  # how soon a spinning program notices SIGINT or SIGTERM


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


def wants_help(argv) -> bool:
    """-h or --help before any --ros-args: print usage, start nothing (not even on a ROS domain)."""
    args = list(sys.argv if argv is None else argv)
    own = args[:args.index("--ros-args")] if "--ros-args" in args else args
    return "-h" in own or "--help" in own


def run_node(name: str, make, run, refusals: tuple, argv=None, usage: str = "") -> int:
    """make() builds the node (raising one of `refusals` to refuse); run(node, stop) works until done or
    `stop.requested`. With -h or --help, `usage` is printed and nothing starts."""
    if wants_help(argv):
        try:
            print(usage, flush=True)
        except BrokenPipeError:  # `--help | head`: the reader left; not an error of ours
            sys.stdout = open(os.devnull, "w")  # the interpreter's exit flush must not fail either
        return 0
    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except RCLError as exc:  # --ros-args rcl cannot parse (a -p value YAML reads as a mixed list): one line
        print(f"{name}: refusing to start: {str(exc).split(', at ')[0]}", file=sys.stderr)
        return 2
    stop = Stop()
    old = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            node = make()
        except refusals + (rclpy.exceptions.ParameterException,) as exc:
            print(f"{name}: refusing to start: {exc}", file=sys.stderr)
            return 2
        try:
            run(node, stop)
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
        for s, handler in old.items():
            signal.signal(s, handler)
    return 0
