"""rosbag2 bags: write simulated runs with rosbags; read any rosbag2 bag (MCAP or sqlite3, split, compressed, with
or without metadata.yaml) back as engine records.

Each storage file is read by rosbags on its own (bag_files); a damaged MCAP file is read again record by record
(mcap_salvage), so every trustworthy message is delivered and the damage is reported as a BagError afterwards.
"""
from __future__ import annotations

import itertools
import logging
import re
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from . import build
from .bag_files import BadPayload, BagFiles, BagFilesError, TopicInfo, describe_topics
from .db3_salvage import read_db3_salvaged
from .decompress import oversized_chunks
from .fields import (
    bearing_from_pose,
    df_from_vector3stamped,
    df_scan,
    fix_from_navsatfix,
    heading_from_imu,
    stamp_seconds,
)
from .mcap_salvage import RawMessage, Salvage, read_salvaged

log = logging.getLogger("aoa_localizer.bag")

TOPICS = {"fix": "/gps/fix", "bearing": "/df/bearing", "truth": "/sim/truth", "datum": "/sim/datum",
          "heading": "/heading/imu", "scan": "/df/scan"}
# One transmitter's truth among several (a channel's, as the node names them: /sim/f446000000/truth)
CHANNEL_TRUTH = re.compile(r"^/sim/(?P<channel>[A-Za-z][A-Za-z0-9_]*)/truth$")
_TYPES = {"fix": "sensor_msgs/msg/NavSatFix", "bearing": "geometry_msgs/msg/Vector3Stamped",
          "truth": "geometry_msgs/msg/PointStamped", "datum": "sensor_msgs/msg/NavSatFix",
          "scan": "sensor_msgs/msg/PointCloud2"}


SEAL_EVERY_S = 1.0  # an MCAP chunk is closed (with its CRC) and flushed this often: a crash loses at most this much


class BagError(RuntimeError):
    """The bag cannot be read (at all, or past some point): the message says where and why."""


def typestore():
    return get_typestore(Stores.ROS2_JAZZY)


def _qos(reliable: bool, latched: bool) -> Qos:
    zero = QosTime(0, 0)
    return Qos(QosHistory.KEEP_LAST, 1 if latched else 10,
               QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
               QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE,
               zero, zero, QosLiveliness.AUTOMATIC, zero, False)


# What each kind of topic may carry, by message type; anything else there is 'foreign': counted, skipped.
_ACCEPTED = {"fix": ("sensor_msgs/msg/NavSatFix",),
             "bearing": ("geometry_msgs/msg/Vector3Stamped", "geometry_msgs/msg/PoseWithCovarianceStamped"),
             "truth": ("geometry_msgs/msg/PointStamped",), "datum": ("sensor_msgs/msg/NavSatFix",),
             "heading": ("sensor_msgs/msg/Imu",), "scan": ("sensor_msgs/msg/PointCloud2",)}
_POSE = "geometry_msgs/msg/PoseWithCovarianceStamped"


def event_kind(kind: str, msgtype: str) -> str:
    """The event a message of `msgtype` on a `kind` topic makes: the kind itself, 'bearing_pose' for the pose
    encoding of a bearing, or 'foreign' for a type the topic should not carry."""
    if msgtype not in _ACCEPTED[kind]:
        return "foreign"
    return "bearing_pose" if msgtype == _POSE else kind


@dataclass
class BagEvent:
    """One message of interest, converted: kind is 'fix', 'bearing' (DF record), 'bearing_pose' (PoseBearing),
    'truth', 'datum', or 'foreign' (record: (topic, message type); not deserialised)."""

    kind: str
    log_time_ns: int
    record: Any
    station: str = ""  # the station whose topic carried it ("": the default topics)
    channel: str = ""  # a truth's channel (CHANNEL_TRUTH; "": the bag's one /sim/truth)


def write_bag(path: Path | str, fixes, bearings, truth_enu=None, datum=None, stations=None, scans: bool = False):
    """Write fixes (stamp, lat, lon, alt rows), DF records (stamp, azimuth, quality[, frequency] rows) and, for
    simulated runs, the truth (ENU in `map`: one (east, north) on /sim/truth, or {channel: (east, north)}, each
    transmitter's on /sim/CHANNEL/truth) and the datum (/sim/datum) as a rosbag2 MCAP bag.
    `stations` ({NAME: (fixes, bearings)}) adds each station's on /NAME/gps/fix and /NAME/df/bearing; `scans`
    writes each station's records of one stamp as one scan on /df/scan (/NAME/df/scan) instead."""
    ts = typestore()
    T = build.rosbags_types(ts)
    sources = {"": (fixes, bearings), **(stations or {})}
    messages = []
    for name, (its_fixes, its_bearings) in sources.items():
        prefix = f"/{name}" if name else ""
        messages += [(f[0], prefix + TOPICS["fix"], "fix", build.navsatfix(T, f[0], f[1], f[2], f[3]))
                     for f in its_fixes]
        if scans:
            for stamp, rows in itertools.groupby(its_bearings, key=lambda b: b[0]):
                r = np.array([list(b[:4]) + [0.0] * (4 - len(b[:4])) for b in rows], float)
                messages.append((stamp, prefix + TOPICS["scan"], "scan", build.df_scan(T, stamp, r[:, 1], r[:, 2],
                                                                                        r[:, 3])))
        else:
            messages += [(b[0], prefix + TOPICS["bearing"], "bearing",
                          build.df_record(T, b[0], b[1], b[2], *b[3:4])) for b in its_bearings]
    t0 = min(m[0] for m in messages) if messages else 0.0
    truths = truth_enu if isinstance(truth_enu, dict) else {} if truth_enu is None else {"": truth_enu}
    for channel, (east, north) in truths.items():
        topic = f"/sim/{channel}/truth" if channel else TOPICS["truth"]
        messages.append((t0, topic, "truth", build.point_stamped(T, t0, float(east), float(north))))
    if datum is not None:
        origin = build.navsatfix(T, t0, datum[0], datum[1], datum[2], frame_id="map")
        messages.append((t0, TOPICS["datum"], "datum", origin))
    messages.sort(key=lambda m: m[0])
    with Writer(Path(path), version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for topic, kind in dict.fromkeys((t, k) for _, t, k, _ in messages):
            latched = kind in ("truth", "datum")
            conns[topic] = (writer.add_connection(topic, _TYPES[kind], typestore=ts,
                                                  offered_qos_profiles=[_qos(reliable=True, latched=latched)]),
                            _TYPES[kind])
        sealed = t0
        for stamp, topic, _, msg in messages:
            if stamp - sealed >= SEAL_EVERY_S:  # chunks of about a second, like a recording
                seal_chunk(writer)
                sealed = stamp
            conn, msgtype = conns[topic]
            writer.write(conn, int(round(stamp * 1e9)), ts.serialize_cdr(msg, msgtype))
        seal_chunk(writer)


_CRC_AT = 9 + 24  # a chunk record's uncompressed_crc: after opcode, length and three uint64 fields (MCAP spec)


def seal_chunk(writer: Writer) -> bool:
    """Close the open MCAP chunk of a rosbags writer, give it its CRC and push it to disk; False when nothing
    was open (or the writer is not the MCAP one this knows). rosbags closes chunks only at 1 MiB and leaves their
    CRC 0 ("not computed"), so without this a crash loses a whole chunk and damage inside one goes unnoticed."""
    storage = getattr(writer, "storage", None)
    chunk = getattr(storage, "chunk", None)
    if storage is None or chunk is None or not getattr(chunk, "msgs", None) or not hasattr(storage, "close_chunk"):
        return False
    crc = zlib.crc32(chunk.bio.getvalue())
    start = storage.bio.tell()
    storage.close_chunk()
    end = storage.bio.tell()
    storage.bio.seek(start + _CRC_AT)
    storage.bio.write(crc.to_bytes(4, "little"))
    storage.bio.seek(end)
    storage.bio.flush()
    return True


def _convert(kind: str, msg):
    if kind == "fix" or kind == "datum":
        return fix_from_navsatfix(msg)
    if kind == "bearing":
        return df_from_vector3stamped(msg)
    if kind == "bearing_pose":
        return bearing_from_pose(msg)
    if kind == "heading":
        return heading_from_imu(msg)
    return (stamp_seconds(msg.header), msg.point.x, msg.point.y)


def _scan_events(decoded, msg: RawMessage, station: str) -> Iterator[BagEvent]:
    """A scan's readings as DF-record events; a cloud that holds none is 'foreign', named with why."""
    try:
        records = df_scan(decoded)
    except (AttributeError, TypeError, ValueError, IndexError, KeyError) as exc:
        yield BagEvent("foreign", msg.log_time, (msg.topic, f"{msg.msgtype}: {exc}"), station)
        return
    for r in records:
        yield BagEvent("bearing", msg.log_time, r, station)


class BagTopicsError(BagError):
    """A valid bag without the topics the engine needs: the message lists what it has and what it needs."""


def stations_in(topic_names) -> dict[str, dict[str, str]]:
    """The stations a bag's topic names show: NAME for each pair `/NAME/gps/fix`, `/NAME/df/bearing` or
    `/NAME/df/scan` (the node's `stations` layout; with each of them and `/NAME/heading/imu` present), as
    {NAME: {kind: topic}}. NAME is the namespace's
    last part, or the whole namespace where two end alike (`/team1/car` and `/team2/car`: one was dropped)."""
    names = set(topic_names)
    pairs: list[tuple[str, dict[str, str]]] = []
    for topic in sorted(names):
        prefix, _, tail = topic.rpartition("/gps/fix")
        readings = {f"{prefix}/df/bearing", f"{prefix}/df/scan"} & names
        if tail or not prefix.rpartition("/")[2] or not readings:
            continue
        its = {"fix": topic, "bearing": f"{prefix}/df/bearing"}
        for kind, name in (("scan", "df/scan"), ("heading", "heading/imu")):
            if f"{prefix}/{name}" in names:
                its[kind] = f"{prefix}/{name}"
        pairs.append((prefix, its))
    last = [prefix.rpartition("/")[2] for prefix, _ in pairs]
    return {(name if last.count(name) == 1 else prefix.strip("/")): its
            for name, (prefix, its) in zip(last, pairs, strict=True)}


def found_stations(path, inventory, topics: dict[str, str]) -> dict[str, dict[str, str]] | None:
    """The stations the bag's topic names show when it lacks `topics`' fix or bearing topic (a bag of several
    stations read without --station), said in a warning; None otherwise."""
    names = {t.name for t in inventory}
    if topics["fix"] in names and {topics["bearing"], topics["scan"]} & names:
        return None
    found = stations_in(names) or None
    if found:
        log.warning("%s has no %s and %s: reading the stations its topic names show: %s", path, topics["fix"],
                    topics["bearing"], "; ".join(f"{n} ({its['fix']}, {its['bearing']})" for n, its in found.items()))
    return found


def _needs(topics: dict[str, str]) -> str:
    return (f"{topics['fix']} ({' or '.join(_ACCEPTED['fix'])}) and "
            f"{topics['bearing']} ({' or '.join(_ACCEPTED['bearing'])}) or {topics.get('scan', TOPICS['scan'])} "
            f"({_ACCEPTED['scan'][0]})")


def read_bag(path: Path | str, topics: dict[str, str] | None = None,
             stations: dict[str, dict[str, str]] | None = None) -> Iterator[BagEvent]:
    """Events of the given topics ({kind: topic}, default TOPICS) of a rosbag2 bag (MCAP or sqlite3, split,
    compressed), file by file in recording order, each file in log-time order. `stations` ({NAME: {kind: topic}},
    kinds fix, bearing and optionally heading) replace the default fix, bearing and heading topics; their events
    carry the station's name.

    Raises BagTopicsError before any event when the bag lacks the fix or the bearing topic, BagError for an
    unreadable bag, and for a damaged one after yielding every message that could be trusted.
    """
    topics = {**TOPICS, **(topics or {})}
    try:
        with BagFiles(path) as files:
            reader = RawReader(files)
            inventory = reader.topics()
            stations = stations or found_stations(path, inventory, topics)
            by_topic = {t: (k, "") for k, t in topics.items()}
            channel_of = {t.name: m["channel"] for t in inventory if (m := CHANNEL_TRUTH.match(t.name))}
            by_topic.update((name, ("truth", "")) for name in channel_of)
            needed = [topics]
            if stations:
                by_topic = {t: (k, "") for k, t in topics.items()
                            if k not in ("fix", "bearing", "heading", "scan")}
                by_topic.update({t: (k, name) for name, its in stations.items() for k, t in its.items()})
                by_topic.update((name, ("truth", "")) for name in channel_of)
                needed = list(stations.values())
            names = {t.name for t in inventory}
            for need in needed:
                if need["fix"] not in names or not {need["bearing"], need.get("scan", "")} & names:
                    raise BagTopicsError(f"{path}: no usable fix and bearing topics; it has "
                                         f"{describe_topics(inventory)}; the engine needs {_needs(need)} (choose "
                                         "others with --fix-topic and --bearing-topic, or --station)")
            ts, count = typestore(), 0
            for msg in reader.messages(set(by_topic)):
                of_kind, station = by_topic[msg.topic]
                kind = event_kind(of_kind, msg.msgtype)
                if kind == "foreign":
                    yield BagEvent(kind, msg.log_time, (msg.topic, msg.msgtype), station)
                else:
                    try:
                        decoded = ts.deserialize_cdr(msg.data, msg.msgtype)
                    except Exception as exc:  # noqa: BLE001 - any decoding failure means these bytes are damaged
                        reader.damage.append(f"an undecodable {msg.msgtype} on {msg.topic} "
                                             f"({type(exc).__name__}: {exc})")
                        reader.lost += 1
                        continue
                    if kind == "scan":  # a receiver's readings of one instant: each one a DF record
                        yield from _scan_events(decoded, msg, station)
                    else:
                        yield BagEvent(kind, msg.log_time, _convert(kind, decoded), station,
                                       channel_of.get(msg.topic, ""))
                count += 1
    except BagFilesError as exc:
        raise BagError(str(exc)) from exc
    if files.not_compressed:
        log.warning("%s: metadata.yaml says every message is compressed, but %d were stored plain; read as stored",
                    path, files.not_compressed)
    reader.damage += files.skipped_files
    if reader.damage:
        raise BagError(f"{path}: damaged after {count} messages ({'; '.join(reader.damage)}; "
                       f"{reader.lost} messages known lost, {reader.recovered} recovered from inside the damaged part)")


class RawReader:
    """Every message of a bag's storage files as stored (topic, type, log time, CDR bytes). Each file is read by
    rosbags on its own; a damaged MCAP file is read again record by record (mcap_salvage), so what comes before
    the damage, and intact chunks after a CRC failure, are still delivered. `damage` says what was wrong."""

    def __init__(self, files: BagFiles):
        self.files = files
        self.damage: list[str] = []
        self.lost = 0  # messages known to be lost (in chunks that failed their CRC check)
        self.recovered = 0  # messages read from the damaged part of a file
        self._checked: dict[Path, list[str]] = {}  # each file's chunks past their limits, looked for once
        self._open: dict[Path, AnyReader] = {}
        files.on_close(self.close)

    def _reader(self, file: Path) -> AnyReader:
        """rosbags' reader of one file, opened once for its topics and its messages: opening parses every
        connection's QoS and message definition (seconds at 30,000 topics)."""
        if file not in self._open:
            reader = AnyReader([file], default_typestore=typestore())
            reader.open()
            self._open[file] = reader
        return self._open[file]

    def _release(self, file: Path):
        reader = self._open.pop(file, None)
        if reader is not None:
            reader.close()

    def close(self):
        for file in list(self._open):
            self._release(file)

    def topics(self) -> list[TopicInfo]:
        """The topics every file declares, with their message counts (a damaged file: as far as it can be read)."""
        seen: dict[tuple[str, str], int] = {}
        qos: dict[tuple[str, str], tuple] = {}
        for file in self.files.files:
            try:
                if self._bombs(file):
                    raise BagError("chunks past their limits")
                for c in self._reader(file).connections:
                    seen[(c.topic, c.msgtype)] = seen.get((c.topic, c.msgtype), 0) + c.msgcount
                    qos.setdefault((c.topic, c.msgtype), tuple(getattr(c.ext, "offered_qos_profiles", ())))
            except Exception:  # noqa: BLE001 - rosbags cannot open it: count what the record-by-record read finds
                self._release(file)
                for msg in self._salvaged(file, Salvage()):
                    seen[(msg.topic, msg.msgtype)] = seen.get((msg.topic, msg.msgtype), 0) + 1
        return [TopicInfo(name, msgtype, n, qos.get((name, msgtype), ()))
                for (name, msgtype), n in sorted(seen.items())]

    def messages(self, wanted: set[str]) -> Iterator[RawMessage]:
        for file in self.files.files:
            yield from self._file(file, wanted)

    def _bombs(self, file: Path) -> list[str]:
        """Why rosbags must not read an MCAP file: chunks that would decompress past their limits (rosbags
        decompresses a whole chunk at once, unbounded)."""
        if file not in self._checked:
            self._checked[file] = list(oversized_chunks(file)) if file.suffix == ".mcap" else []
        return self._checked[file]

    def _payload(self, msg: RawMessage) -> RawMessage | None:
        """The message with its CDR bytes, or None (counted as damage) when they cannot be read within limits."""
        try:
            return RawMessage(msg.topic, msg.msgtype, msg.log_time, self.files.payload(msg.data))
        except BadPayload as exc:
            self.damage.append(f"{exc} on {msg.topic}")
            self.lost += 1
            return None

    def _file(self, file: Path, wanted: set[str]) -> Iterator[RawMessage]:
        done = 0
        try:
            bombs = self._bombs(file)
            if bombs:
                raise BagError("; ".join(bombs))
            reader = self._reader(file)
            conns = [c for c in reader.connections if c.topic in wanted]
            if not conns:  # rosbags reads every connection when given none
                return
            for conn, log_time, raw in reader.messages(connections=conns):
                msg = self._payload(RawMessage(conn.topic, conn.msgtype, log_time, raw))
                done += 1
                if msg is not None:
                    yield msg
            return
        except Exception as exc:  # noqa: BLE001 - rosbags refuses or stops: the record-by-record read decides
            failure = exc
        finally:
            self._release(file)
        yield from self._after_failure(file, wanted, done, failure)

    def _after_failure(self, file: Path, wanted: set[str], done: int, failure: Exception) -> Iterator[RawMessage]:
        """A file rosbags refused or stopped in, read record by record past the `done` messages it gave."""
        if file.suffix not in (".db3", ".mcap"):
            self.damage.append(f"{file.name}: {type(failure).__name__}: {failure}")
            return
        report = Salvage()
        for i, raw_msg in enumerate(m for m in self._salvaged(file, report) if m.topic in wanted):
            if i >= done:
                msg = self._payload(raw_msg)
                if msg is not None:
                    yield msg
                    self.recovered += 1
        if report.damage:
            self.damage.append(f"{file.name}: {'; '.join(report.damage)}")
            self.lost += report.lost_messages
        else:
            log.warning(
                "%s: rosbags could not read it (%s); read record by record",
                file,
                str(failure).splitlines()[0] if str(failure) else type(failure).__name__,
            )

    def _salvaged(self, file: Path, report: Salvage) -> Iterator[RawMessage]:
        """An MCAP or sqlite3 file read record by record (payloads as stored)."""
        if file.suffix == ".db3":
            return read_db3_salvaged(file, report)
        return read_salvaged(file.read_bytes(), report)

