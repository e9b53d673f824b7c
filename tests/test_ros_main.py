"""The start-run-stop shared by every ROS program: a signal that arrives while the node is being served stops it
cleanly (exit 0, node destroyed, no traceback), never by shutting the context down under a wait."""
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from conftest import ros_env

ROOT = Path(__file__).resolve().parent.parent
pytestmark = [pytest.mark.ros, pytest.mark.slow]  # a real rclpy context

PROGRAM = textwrap.dedent("""
    import os, signal, sys
    import rclpy
    from aoa_localizer.ros.ros_main import run_node, spin

    SIG = signal.{sig}
    ticks = []

    def make():
        node = rclpy.create_node("stopper")
        # a 1 ms timer: the executor builds a wait set a thousand times a second, the window rclpy's own
        # handler used to shut the context down in
        node.create_timer(0.001, lambda: ticks.append(1) if len(ticks) != 300 else os.kill(os.getpid(), SIG))
        destroy = node.destroy_node
        node.destroy_node = lambda: (print("destroyed after", len(ticks), "ticks"), destroy())[1]
        return node

    def run(node, stop):
        spin(node, stop)
        print("stopped by", stop.by)

    sys.exit(run_node("stopper", make, run, (ValueError,), ["stopper"]))
""")


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT"])
def test_a_signal_while_spinning_stops_the_program_cleanly(domain, sig):
    res = subprocess.run([sys.executable, "-c", PROGRAM.format(sig=sig)], env=ros_env(domain), cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert f"stopped by {sig}" in res.stdout and "destroyed after 300 ticks" in res.stdout, res.stdout
    assert "Traceback" not in res.stderr and "RCLError" not in res.stderr, res.stderr


def test_a_program_refused_at_start_exits_2_and_leaves_no_context(domain):
    program = textwrap.dedent("""
        import sys, rclpy
        from aoa_localizer.ros.ros_main import run_node
        def make():
            raise ValueError("no good")
        code = run_node("refused", make, None, (ValueError,), ["refused"])
        print("context left:", rclpy.ok())
        sys.exit(code)
    """)
    res = subprocess.run([sys.executable, "-c", program], env=ros_env(domain), cwd=ROOT, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 2 and "refused: refusing to start: no good" in res.stderr, res.stderr
    assert "context left: False" in res.stdout


def test_a_teardown_that_hangs_ends_the_program_with_its_code_said(domain):
    """Fast DDS and rclpy have hung now and then in a node's destruction after its work was done (a launcher waited
    for a vehicle that had played its scenario): past TEARDOWN_S the program says so and exits with its code."""
    program = textwrap.dedent("""
        import sys, time, rclpy
        from aoa_localizer.ros import ros_main
        ros_main.TEARDOWN_S = 1.0
        def make():
            node = rclpy.create_node("stuck")
            node.destroy_node = lambda: time.sleep(120)  # the middleware's teardown never returns
            return node
        def run(node, stop):
            print("work done", flush=True)
        sys.exit(ros_main.run_node("stuck", make, run, (ValueError,), ["stuck"]))
    """)
    res = subprocess.run([sys.executable, "-c", program], env=ros_env(domain), cwd=ROOT, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0 and "work done" in res.stdout, res.stderr
    assert "stuck: the ROS middleware did not shut down within 1 s; exiting without it" in res.stderr
