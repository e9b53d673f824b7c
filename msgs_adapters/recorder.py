"""Record every topic of a live graph into a rosbag2 MCAP bag (what `ros2 bag record -a -s mcap` does):
raw CDR messages from rclpy, written by rosbags with each topic's offered QoS, log time = receive time."""
from __future__ import annotations

import logging
import time
from pathlib import Path

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer

from .bag import SEAL_EVERY_S, seal_chunk, typestore
from .types import message_class

log = logging.getLogger("aoa_localizer.recorder")
_INFINITE = QosTime(2147483647, 4294967295)  # how rosbag2 writes an infinite duration


def _qos_time(duration) -> QosTime:
    ns = duration.nanoseconds
    if ns >= 2**63 - 1 or ns < 0:
        return _INFINITE
    return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)


def rosbags_qos(profile) -> Qos:
    """An rclpy QoSProfile as the rosbags Qos recorded in metadata.yaml (same enum numbering)."""
    return Qos(QosHistory(int(profile.history)), int(profile.depth), QosReliability(int(profile.reliability)),
               QosDurability(int(profile.durability)), _qos_time(profile.deadline), _qos_time(profile.lifespan),
               QosLiveliness(int(profile.liveliness)), _qos_time(profile.liveliness_lease_duration),
               bool(profile.avoid_ros_namespace_conventions))


def matching_qos(profiles) -> QoSProfile:
    """A subscription QoS that connects to every given publisher and still gets latched messages."""
    best_effort = any(p.reliability == ReliabilityPolicy.BEST_EFFORT for p in profiles)
    latched = profiles and all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in profiles)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                      reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class BagRecorder:
    """Subscribes raw to each topic as it appears (call poll() now and then) and writes it to `path`. A write that
    fails (a full disk, a vanished directory) stops the recording, not the run: `failed` says why, the bag keeps
    what was written before (replay salvages it)."""

    def __init__(self, node, path: Path | str, exclude=("/parameter_events",)):
        self.node, self.exclude = node, set(exclude)
        self.ts = typestore()
        self.writer = Writer(Path(path), version=9, storage_plugin=StoragePlugin.MCAP)
        self.writer.open()
        self.subs: dict = {}  # topic: subscription (None: not recordable)
        self.conns: dict = {}  # topic: rosbags connection
        self.count = 0
        self.failed: str | None = None
        self._sealed_at = time.monotonic()

    def _stop_on(self, exc: OSError, doing: str):
        """A failed write: stop recording, keep the run."""
        self.failed = f"{exc.strerror or exc} while {doing}, after {self.count} messages"
        log.warning("recording stopped (%s); the run goes on, the bag keeps what was written before", self.failed)
        self._unsubscribe()

    def _unsubscribe(self):
        for sub in self.subs.values():
            if sub is not None:
                self.node.destroy_subscription(sub)
        self.subs = {topic: None for topic in self.subs}

    def poll(self):
        """Subscribe to topics that appeared since the last call; seal the open chunk when it is due."""
        if self.failed:
            return
        try:
            self._poll()
        except OSError as exc:
            self._stop_on(exc, "adding a topic or sealing a chunk")

    def _poll(self):
        self._seal_if_due()
        for topic, types in self.node.get_topic_names_and_types():
            if topic in self.subs or topic in self.exclude:
                continue
            msgtype = types[0]
            cls = message_class(msgtype)
            if cls is None or msgtype not in self.ts.types:
                log.warning("not recording %s: unknown type %s", topic, msgtype)
                self.subs[topic] = None
                continue
            pubs = self.node.get_publishers_info_by_topic(topic)
            if not pubs:
                continue
            profiles = [p.qos_profile for p in pubs]
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.ts,
                                                           offered_qos_profiles=[rosbags_qos(profiles[0])])
            self.subs[topic] = self.node.create_subscription(
                cls, topic, lambda data, t=topic: self._write(t, data), matching_qos(profiles), raw=True)

    def _write(self, topic: str, data: bytes):
        if self.failed:
            return
        try:
            self.writer.write(self.conns[topic], time.time_ns(), data)
            self.count += 1
            self._seal_if_due()
        except OSError as exc:
            self._stop_on(exc, f"writing {topic}")

    def _seal_if_due(self):
        """Seal the open MCAP chunk (with its CRC) about once a second, so a recorder killed (SIGKILL, power)
        leaves a bag whose complete chunks replay and whose damage is detected."""
        now = time.monotonic()
        if now - self._sealed_at >= SEAL_EVERY_S:
            self._sealed_at = now
            seal_chunk(self.writer)

    def close(self):
        self._unsubscribe()
        try:
            seal_chunk(self.writer)
            self.writer.close()
        except OSError as exc:
            if not self.failed:
                self.failed = f"{exc.strerror or exc} while closing the bag, after {self.count} messages"
            log.warning("the bag could not be closed (%s): it has no index; replay salvages it", exc)
