"""The start-run-stop of a ROS program: refuse to start with a clear message (exit 2), run until done,
SIGINT or SIGTERM, always destroy the node and shut rclpy down (exit 0)."""
from __future__ import annotations

import sys

import rclpy
from rclpy.executors import ExternalShutdownException


def run_node(name: str, make, run, refusals: tuple, argv=None) -> int:
    """make() builds the node (raising one of `refusals` to refuse); run(node) works until done."""
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
