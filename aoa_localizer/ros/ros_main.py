"""The start-run-stop of a ROS program: refuse to start with a clear message (exit 2), run until done,
SIGINT or SIGTERM, always destroy the node and shut rclpy down (exit 0)."""
from __future__ import annotations

import os
import sys

import rclpy
from rclpy.executors import ExternalShutdownException


def wants_help(argv) -> bool:
    """-h or --help before any --ros-args: print usage, start nothing (not even on a ROS domain)."""
    args = list(sys.argv if argv is None else argv)
    own = args[:args.index("--ros-args")] if "--ros-args" in args else args
    return "-h" in own or "--help" in own


def run_node(name: str, make, run, refusals: tuple, argv=None, usage: str = "") -> int:
    """make() builds the node (raising one of `refusals` to refuse); run(node) works until done. With -h or
    --help, `usage` is printed and nothing starts."""
    if wants_help(argv):
        try:
            print(usage, flush=True)
        except BrokenPipeError:  # `--help | head`: the reader left; not an error of ours
            sys.stdout = open(os.devnull, "w")  # the interpreter's exit flush must not fail either
        return 0
    rclpy.init(args=argv)
    try:
        node = make()
    except refusals + (rclpy.exceptions.ParameterException,) as exc:
        print(f"{name}: refusing to start: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    try:
        run(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
