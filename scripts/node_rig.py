"""What the node speed scripts share: a localizer node process in a domain of its own (or one already running),
a client with the node's input publishers matched, and its /diagnostics status. Used by node_throughput.py and
node_load.py; nothing here measures anything."""
from __future__ import annotations

import os
import random
import subprocess
import sys
import tempfile
import time

import rclpy
from rclpy.qos import QoSProfile

from msgs_adapters import build
from msgs_adapters.fields import diagnostics_values

STATUS = "aoa_localizer: localizer"


class Attached:
    """A node this script did not start (e.g. one under a profiler): measured, left running."""

    def __init__(self, pid: int):
        self.pid = pid

    def terminate(self):
        pass

    def kill(self):
        pass

    def poll(self):
        return None if os.path.exists(f"/proc/{self.pid}") else 0

    def wait(self, _timeout):
        pass


class NodeRig:
    """`with NodeRig(["num_particles:=50"]) as rig:` a node and a client whose gps/fix and df/bearing publishers
    (rig.pub_fix, rig.pub_df, rig.pub_scan) have matched it; rig.on_status(values) is called with each localizer status.
    `attach`: the pid of a node already running in ROS_DOMAIN_ID instead of a new one."""

    def __init__(self, node_params: list[str], on_status=None, attach: int | None = None):
        if attach:
            self.domain, self.proc = int(os.environ["ROS_DOMAIN_ID"]), Attached(attach)
        else:
            self.domain = random.randint(1, 101)
            env = dict(os.environ, ROS_DOMAIN_ID=str(self.domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
            cmd = [sys.executable, "-m", "aoa_localizer.node", "--ros-args", "-p", "seed:=1"]
            cmd += [a for p in node_params for a in ("-p", p)]
            self.stderr = tempfile.TemporaryFile()  # read only if the node dies (a pipe could fill and stall it)
            self.proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=self.stderr,
                                         start_new_session=True)
        self.on_status = on_status or (lambda values: None)

    def __enter__(self) -> NodeRig:
        self.ctx = rclpy.Context()
        rclpy.init(args=[], context=self.ctx, domain_id=self.domain)
        self.node = rclpy.create_node("node_rig", context=self.ctx)
        self.T = T = build.rclpy_types()
        self.node.create_subscription(T.DiagnosticArray, "/diagnostics", self._diagnostics, 10)
        self.pub_fix = self.node.create_publisher(T.NavSatFix, "gps/fix", QoSProfile(depth=100))
        self.pub_df = self.node.create_publisher(T.Vector3Stamped, "df/bearing", QoSProfile(depth=1000))
        self.pub_scan = self.node.create_publisher(T.PointCloud2, "df/scan", QoSProfile(depth=100))
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        end = time.monotonic() + 10
        while time.monotonic() < end and not (self.pub_df.get_subscription_count()
                                              and self.pub_fix.get_subscription_count()
                                              and self.pub_scan.get_subscription_count()):
            self.executor.spin_once(timeout_sec=0.05)
            self._alive()
        if not (self.pub_df.get_subscription_count() and self.pub_fix.get_subscription_count()):
            raise SystemExit("the node's inputs did not match within 10 s")
        return self

    def _alive(self):
        """Stop the measurement, with the node's last words, when the node has exited."""
        if self.proc.poll() is not None:
            said = b""
            if hasattr(self, "stderr"):
                self.stderr.seek(0)
                said = self.stderr.read()[-2000:]
            raise SystemExit(f"the node exited (code {self.proc.poll()}): {said.decode(errors='replace')}")

    def _diagnostics(self, msg):
        values = diagnostics_values(msg).get(STATUS)
        if values:
            self.on_status(values)

    def spin_until(self, target: float):
        """Serve the client until time.monotonic() reaches `target`."""
        while (left := target - time.monotonic()) > 0:
            self.executor.spin_once(timeout_sec=left)
        self._alive()

    def __exit__(self, *exc):
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
        self.proc.terminate()
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:  # a node still working off a backlog: the figures are taken already
            print("the node did not stop within 30 s of SIGTERM: killed", file=sys.stderr)
            self.proc.kill()
            self.proc.wait(10)
        return False
