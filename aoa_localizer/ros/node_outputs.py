"""What the node publishes of the engine's estimates: each channel's pose, fix, particles and markers (emitter/ for the
primary channel), the channel summary, the datum and the vehicles' paths."""
from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from aoa_localizer.engine.channels import DEFAULT
from aoa_localizer.engine.crlb import ELLIPSE_95, ellipse_axes, ellipse_points
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.outputs.view import LocalizerView
from aoa_localizer.ros.vehicle_path import VehiclePath
from msgs_adapters import build

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


@dataclass
class PosteriorWork:
    """Posterior grids made, waiting for a later call, and the time they took."""

    made: int = 0
    deferred: int = 0
    seconds: float = 0.0

    def add(self, other: PosteriorWork) -> None:
        self.made += other.made
        self.deferred = other.deferred  # what waits now, not summed over the calls
        self.seconds += other.seconds


class NodeOutputs:
    """The node's publishers of what the engine makes. `types`: the message classes (msgs_adapters.build)."""

    def __init__(self, node: Node, types: SimpleNamespace, stations: list[str], map_frame: str, emitter_frame: str,
                 now: Callable[[], float]):
        self.node, self.types, self.map_frame, self.emitter_frame, self.now = node, types, map_frame, emitter_frame, now
        self.channel_pubs: dict[str, SimpleNamespace] = {DEFAULT: self._channel_publishers("emitter/")}
        self.pub_channels = node.create_publisher(types.String, "emitter/channels", LATCHED)
        self.pub_datum = node.create_publisher(types.NavSatFix, "emitter/datum", LATCHED)
        self.pub_path = {name: node.create_publisher(types.Path, (f"{name}/" if name else "") + "vehicle/path", 1)
                         for name in stations}  # relative names: namespaces and remaps apply
        self.summary_sent: Any = None  # the channel summary last published on emitter/channels
        self._grids: dict[str, tuple[Any, Any]] = {}  # per channel: the estimate its last grid drew, and the grid
        self._grid_turn = 0  # the listened channel the next round of grids starts with
        self._grid_sent: dict[str, float] = {}  # per channel: when its grid last went out (monotonic s)
        self.datum_sent: Any = None  # the LocalFrame last published on emitter/datum
        self.transmitter_pubs: dict[tuple[str, int], Any] = {}  # (channel, k): its k-th transmitter's pose

    def _channel_publishers(self, prefix: str) -> SimpleNamespace:
        """pose and velocity (latched), fix, particles and markers under `prefix` (emitter/ or emitter/<channel>/). A
        frequency channel's publishers go without rclpy's default QoS-event handlers: each is a waitable the executor
        walks at every message, and 50 channels' 200 of them took most of the node's time."""
        T = self.types
        events = PublisherEventCallbacks(use_default_callbacks=prefix == "emitter/")

        def make(kind, topic, qos):
            return self.node.create_publisher(kind, prefix + topic, qos, event_callbacks=events)

        return SimpleNamespace(pose=make(T.PoseWithCovarianceStamped, "pose", LATCHED),
                               velocity=make(T.TwistWithCovarianceStamped, "velocity", LATCHED),
                               fix=make(T.NavSatFix, "fix", LATCHED), particles=make(T.PoseArray, "particles", 10),
                               markers=make(T.MarkerArray, "markers", 10),
                               posterior=make(T.OccupancyGrid, "posterior", 1),
                               goal=make(T.PoseStamped, "next_goal", 1),
                               goal_marker=make(T.Marker, "next_goal_marker", 1))

    def estimate(self, loc: Localizer, est, marker_rays: int):
        """An estimate on its channel's topics, and on emitter/ too when its channel is the primary one."""
        pubs = self.channel_pubs.get(est.channel)
        if pubs is None:
            pubs = self.channel_pubs[est.channel] = self._channel_publishers(f"emitter/{est.channel}/")
        view = loc.view(light=True)
        self._publish_on(loc, view, pubs, est, marker_rays)
        self._transmitters(est)
        if est.channel != DEFAULT and view.primary == est.channel:
            self._publish_on(loc, view, self.channel_pubs[DEFAULT], est, marker_rays)  # emitter/ carries the primary

    def _publish_on(self, loc: Localizer, view: LocalizerView, pubs: SimpleNamespace, est, marker_rays: int):
        """The estimate on one set of publishers (a channel's, or emitter/ for the primary channel)."""
        T, frame = self.types, self.map_frame
        pubs.pose.publish(build.emitter_pose(T, est, frame))
        if est.velocity is not None and est.velocity_cov is not None:
            pubs.velocity.publish(build.emitter_velocity(T, est, frame))
        alt0 = view.frame.alt0 if view.frame is not None else 0.0  # an estimate comes after the datum
        pubs.fix.publish(build.emitter_fix(T, est, alt0, self.emitter_frame))
        # The cloud and the markers cost about 1 ms to build: only for someone listening.
        if pubs.particles.get_subscription_count():
            pubs.particles.publish(build.particle_array(T, est, frame))
        if pubs.markers.get_subscription_count():
            post = loc.posterior(est.channel)
            rays = post.recent_points(marker_rays)[:, :3] if post is not None else np.zeros((0, 3))
            ring = ellipse_points((est.east, est.north), est.cov, ELLIPSE_95)
            pubs.markers.publish(build.markers(T, est, rays, ring, frame))

    def _transmitters(self, est):
        """Each transmitter of a channel several share (co-channel), on `emitter/<channel>/transmitter_<k>/pose`
        (`emitter/transmitter_<k>/pose` for the default channel; latched; k from 1, the most heard first)."""
        prefix = "emitter/" if est.channel == DEFAULT else f"emitter/{est.channel}/"
        for k, t in enumerate(est.transmitters, start=1):
            pub = self.transmitter_pubs.get((est.channel, k))
            if pub is None:
                pub = self.transmitter_pubs[(est.channel, k)] = self.node.create_publisher(
                    self.types.PoseWithCovarianceStamped, f"{prefix}transmitter_{k}/pose", LATCHED)
            pub.publish(build.emitter_pose(self.types, est.at_transmitter(t), self.map_frame))

    def posteriors(self, loc: Localizer, budget_s: float, period_s: float) -> PosteriorWork:
        """Each channel's posterior grid on its emitter/<channel>/posterior, and the primary channel's on
        emitter/posterior, for the ones someone listens to, each at most once a `period_s`. A grid costs cells x
        points, so a channel's is made again only when its estimate changed (else its last grid goes out again),
        and once this call's grids took `budget_s` the rest wait for the next call, which starts where this one
        stopped: called between messages, the grids never hold an input up for long."""
        listened = self._listened(loc, "posterior")
        work = PosteriorWork()
        if not listened:
            return work
        start, now = self._grid_turn % len(listened), time.monotonic()
        t0 = time.perf_counter()
        for k in range(len(listened)):
            cid, est, listening = listened[(start + k) % len(listened)]
            if now - self._grid_sent.get(cid, -math.inf) < period_s:
                continue
            cached = self._grids.get(cid)
            if cached is None or cached[0] is not est:
                if time.perf_counter() - t0 >= budget_s:
                    work.deferred += 1
                    continue
                post = loc.posterior(cid)
                if post is None:
                    continue
                grid = post.grid()
                cached = self._grids[cid] = (est, build.occupancy_grid(
                    self.types, est.stamp, grid.east0, grid.north0, grid.resolution, grid.value, self.map_frame))
                work.made += 1
                self._grid_turn = (start + k + 1) % len(listened)
            for pub in listening:
                pub.publish(cached[1])
            self._grid_sent[cid] = now
        work.seconds = time.perf_counter() - t0
        return work

    def next_goals(self, loc: Localizer, vehicle: tuple[float, float] | None, radius_m: float):
        """Each channel's goal (engine/outputs/next_goal.py) for the vehicle at `vehicle` (map frame) on its
        emitter/<channel>/next_goal and next_goal_marker, the primary channel's on emitter/, for the ones someone
        listens to; none without an estimate or a vehicle's place."""
        if vehicle is None:
            return
        for cid, est, listening in self._listened(loc, "goal", "goal_marker"):
            post = loc.posterior(cid)
            goal = post.next_goal(vehicle, radius_m) if post is not None else None
            if goal is None:
                continue
            place = (goal.east, goal.north)
            pose = build.goal_pose(self.types, est.stamp, vehicle, place, self.map_frame)
            arrow = build.goal_arrow(self.types, est.stamp, vehicle, place, cid, self.map_frame)
            for pub in listening:
                pub.publish(pose if pub.msg_type is self.types.PoseStamped else arrow)

    def _listened(self, loc: Localizer, *kinds: str) -> list[tuple[str, Any, list]]:
        """The channels with an estimate and a listener on one of their `kinds` of publishers (its own, or
        emitter/'s for the primary channel): (id, its estimate, those publishers). One pass over the publishers: a
        node keeps hundreds of them; the Localizer is read only when someone listens."""
        wanted = []
        for cid, pubs in self.channel_pubs.items():
            listening = [getattr(pubs, kind) for kind in kinds if getattr(pubs, kind).get_subscription_count()]
            if listening:
                wanted.append((cid, listening))
        if not wanted:
            return []
        view = loc.view(light=True)
        out: dict[str, tuple[str, Any, list]] = {}
        for cid, listening in wanted:
            channel = (view.primary or DEFAULT) if cid == DEFAULT else cid
            est = view.estimates.get(channel)
            if est is not None:
                out.setdefault(channel, (channel, est, []))[2].extend(listening)
        return list(out.values())

    @staticmethod
    def channel_summary(view: LocalizerView) -> dict[str, dict]:
        """Every channel with an estimate: its frequency, topics, state (live or retired) and latest estimate."""
        out = {}
        for channel in view.channels:
            est = channel.estimate
            if est is None:
                continue
            out[channel.id] = {
                "frequency_hz": channel.frequency_hz if math.isfinite(channel.frequency_hz) else None,
                "topics": "emitter/" if channel.id == DEFAULT else f"emitter/{channel.id}/",
                "state": "retired" if channel.retired else "live",
                "stamp": est.stamp, "lat": est.lat, "lon": est.lon, "east": round(est.east, 2),
                "north": round(est.north, 2), "ellipse95_major_m": round(float(ellipse_axes(est.cov)[0]), 2),
                "points_used": est.points_used, "transmitter_count": est.transmitter_count,
                "count_probability": (round(est.count_probability, 4) if math.isfinite(est.count_probability)
                                      else None),
                "transmitters": [{"lat": t.lat, "lon": t.lon, "east": round(t.east, 2), "north": round(t.north, 2),
                                  "ellipse95_major_m": round(float(ellipse_axes(t.cov)[0]), 2),
                                  "share": round(t.share, 4), "state": str(t.state)} for t in est.transmitters],
            }
        return out

    def summary_due(self, channels: list[str]) -> bool:
        """Whether one of these channels (ones that just made an estimate) is not in the last emitter/channels."""
        sent = self.summary_sent
        return any(sent is None or c not in sent for c in channels)

    def summary(self, view: LocalizerView):
        """emitter/channels (latched std_msgs/String): a JSON object of the channels, when it changed."""
        summary = self.channel_summary(view)
        if summary != self.summary_sent:
            self.pub_channels.publish(self.types.String(data=json.dumps({"channels": summary}, sort_keys=True)))
            self.summary_sent = summary

    def datum(self, loc: Localizer, stamp: float | None = None):
        """emitter/datum (latched) whenever the map frame's origin is new: set from a fix (stamped with the fix that
        made it known: measurement time, as every output), or configured (the node's clock: no measurement yet)."""
        datum = loc.view(light=True).frame
        if datum is not None and datum != self.datum_sent:
            when = self.now() if stamp is None else stamp
            self.pub_datum.publish(build.datum_fix(self.types, when, datum.lat0, datum.lon0, datum.alt0,
                                                   self.map_frame))
            self.datum_sent = datum

    def paths(self, path: VehiclePath):
        """Each station's vehicle/path when a fix was added since the last one and someone listens (a full path each
        time: Path has no deltas, and 1000 poses cost about 15 ms to build)."""
        for station, poses in path.new_paths().items():
            pub = self.pub_path.get(station)
            if pub is not None and pub.get_subscription_count():
                pub.publish(build.vehicle_path(self.types, poses[-1][0], poses, self.map_frame))

    def drop_gone(self, view: LocalizerView):
        """The publishers of channels the engine no longer keeps (retired long ago): memory stays bounded under a
        stream of ever new frequencies."""
        kept = {c.id for c in view.channels} | {DEFAULT}
        self._grids = {cid: g for cid, g in self._grids.items() if cid in kept}
        self._grid_sent = {cid: t for cid, t in self._grid_sent.items() if cid in kept}
        for cid in [cid for cid in self.channel_pubs if cid not in kept]:
            for pub in vars(self.channel_pubs.pop(cid)).values():
                self.node.destroy_publisher(pub)
