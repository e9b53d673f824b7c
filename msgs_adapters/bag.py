"""rosbag2 MCAP bags: write simulated runs with rosbags, read any rosbag2 MCAP bag back as engine records.

Reading goes through rosbags; a bag it cannot open (truncated file, missing metadata.yaml) is read
again record by record with the `mcap` stream reader and mcap-ros2-support, so the messages before
the damage are still delivered and the damage is reported as a BagError afterwards.
"""
from __future__ import annotations

import logging
from io import BytesIO
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

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
from .fields import bearing_from_pose, df_from_vector3stamped, fix_from_navsatfix, stamp_seconds

log = logging.getLogger("aoa_localizer.bag")

TOPICS = {"fix": "/gps/fix", "bearing": "/df/bearing", "truth": "/sim/truth", "datum": "/sim/datum"}
_TYPES = {"fix": "sensor_msgs/msg/NavSatFix", "bearing": "geometry_msgs/msg/Vector3Stamped",
          "truth": "geometry_msgs/msg/PointStamped", "datum": "sensor_msgs/msg/NavSatFix"}


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
             "truth": ("geometry_msgs/msg/PointStamped",), "datum": ("sensor_msgs/msg/NavSatFix",)}
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
    record: object


def write_bag(path: Path | str, fixes, bearings, truth_enu=None, datum=None):
    """Write fixes (stamp, lat, lon, alt rows), DF records (stamp, azimuth, quality rows) and, for
    simulated runs, the truth (/sim/truth, ENU in `map`) and the datum (/sim/datum) as a rosbag2 MCAP bag."""
    ts = typestore()
    T = build.rosbags_types(ts)
    messages = [(f[0], "fix", build.navsatfix(T, f[0], f[1], f[2], f[3])) for f in fixes]
    messages += [(b[0], "bearing", build.df_record(T, b[0], b[1], b[2])) for b in bearings]
    t0 = min(m[0] for m in messages) if messages else 0.0
    if truth_enu is not None:
        messages.append((t0, "truth", build.point_stamped(T, t0, float(truth_enu[0]), float(truth_enu[1]))))
    if datum is not None:
        messages.append((t0, "datum", build.navsatfix(T, t0, *datum, frame_id="map")))
    messages.sort(key=lambda m: m[0])
    with Writer(Path(path), version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for kind in dict.fromkeys(k for _, k, _ in messages):
            latched = kind in ("truth", "datum")
            conns[kind] = writer.add_connection(TOPICS[kind], _TYPES[kind], typestore=ts,
                                                offered_qos_profiles=[_qos(reliable=True, latched=latched)])
        for stamp, kind, msg in messages:
            writer.write(conns[kind], int(round(stamp * 1e9)), ts.serialize_cdr(msg, _TYPES[kind]))


def _convert(kind: str, msg):
    if kind == "fix" or kind == "datum":
        return fix_from_navsatfix(msg)
    if kind == "bearing":
        return df_from_vector3stamped(msg)
    if kind == "bearing_pose":
        return bearing_from_pose(msg)
    return (stamp_seconds(msg.header), msg.point.x, msg.point.y)


def read_bag(path: Path | str, topics: dict[str, str] | None = None) -> Iterator[BagEvent]:
    """Events of the given topics ({kind: topic}, default TOPICS) in log-time order.

    Raises BagError for an unreadable bag; for a damaged one, after yielding what came before the damage.
    """
    topics = {**TOPICS, **(topics or {})}
    by_topic = {t: k for k, t in topics.items()}
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    from rosbags.highlevel import AnyReader

    try:
        reader = AnyReader([path], default_typestore=typestore())
        reader.open()
    except Exception as exc:  # rosbags refuses damaged or metadata-less bags: fall back to the stream
        yield from _read_mcap_stream(path, by_topic, opened_error=exc)
        return
    count = 0
    try:
        conns = [c for c in reader.connections if c.topic in by_topic]
        for conn, log_time, raw in reader.messages(connections=conns):
            kind = event_kind(by_topic[conn.topic], conn.msgtype)
            if kind == "foreign":
                yield BagEvent(kind, log_time, (conn.topic, conn.msgtype))
            else:
                yield BagEvent(kind, log_time, _convert(kind, reader.deserialize(raw, conn.msgtype)))
            count += 1
    except Exception as exc:
        raise BagError(f"{path}: damaged after {count} messages ({type(exc).__name__}: {exc})") from exc
    finally:
        reader.close()


_MAGIC = b"\x89MCAP0\r\n"
_CHUNK, _FOOTER, _DATA_END = 0x06, 0x02, 0x0F


def salvage(data: bytes) -> tuple[bytes, str | None]:
    """An MCAP byte string cut short or damaged, as a stream of its complete records: a cut chunk gives up every
    complete record inside it (uncompressed chunks, what the rosbags writer makes; a compressed one is lost whole).
    Returns (magic + records, what was wrong or None)."""
    out, pos, damage = [_MAGIC], len(_MAGIC), None
    if not data.startswith(_MAGIC):
        return b"", "no MCAP magic"
    while pos < len(data):
        if pos + 9 > len(data):
            damage = f"cut at byte {pos}"
            break
        op, length = data[pos], int.from_bytes(data[pos + 1:pos + 9], "little")
        body = data[pos + 9:pos + 9 + length]
        cut = len(body) < length
        if op == _CHUNK:
            inner, why = _chunk_records(body)
            out.append(inner)
            if cut or why:
                damage = f"{'cut' if cut else why} in the chunk at byte {pos}"
                break
        elif cut:
            damage = f"cut at byte {pos}"
            break
        elif op in (_FOOTER, _DATA_END) or op == 0:
            if op == 0:
                damage = f"an invalid record (opcode 0) at byte {pos}"
            break  # the summary after the data section repeats what the chunks hold
        else:
            out.append(data[pos:pos + 9 + length])
        pos += 9 + length
    return b"".join(out), damage


def _chunk_records(body: bytes) -> tuple[bytes, str | None]:
    """The complete records inside a (possibly cut) chunk body, and why it could not all be read, if so."""
    head = 8 + 8 + 8 + 4
    if len(body) < head + 4:
        return b"", "cut"
    n = int.from_bytes(body[head:head + 4], "little")
    compression = body[head + 4:head + 4 + n].decode(errors="replace")
    start = head + 4 + n + 8
    if compression:
        return b"", f"a compressed ({compression}) chunk"
    records, pos, why = body[start:], 0, None
    while pos + 9 <= len(records):
        length = int.from_bytes(records[pos + 1:pos + 9], "little")
        if records[pos] == 0 or pos + 9 + length > len(records):
            why = "cut" if records[pos] else "an invalid record"
            break
        pos += 9 + length
    return records[:pos], why


def _stream_events(stream, by_topic: dict[str, str]) -> Iterator[BagEvent]:
    """Events of an MCAP byte stream in record order (schemas and channels as they come)."""
    from mcap.stream_reader import StreamReader
    from mcap_ros2.decoder import DecoderFactory

    decoder_factory = DecoderFactory()
    schemas, channels, decoders = {}, {}, {}
    for record in StreamReader(stream, skip_magic=False).records:
        name = type(record).__name__
        if name == "Schema":
            schemas[record.id] = record
        elif name == "Channel":
            channels[record.id] = record
        elif name == "Message":
            channel = channels.get(record.channel_id)
            if channel is None or channel.topic not in by_topic:
                continue
            msgtype = schemas[channel.schema_id].name
            kind = event_kind(by_topic[channel.topic], msgtype)
            if kind == "foreign":
                yield BagEvent(kind, record.log_time, (channel.topic, msgtype))
                continue
            if channel.id not in decoders:
                decoders[channel.id] = decoder_factory.decoder_for(channel.message_encoding, schemas[channel.schema_id])
            yield BagEvent(kind, record.log_time, _convert(kind, decoders[channel.id](record.data)))


def _mcap_files(path: Path) -> list[Path]:
    return sorted(path.glob("*.mcap")) if path.is_dir() else [path]


def _read_mcap_stream(path: Path, by_topic: dict[str, str], opened_error: Exception) -> Iterator[BagEvent]:
    """Record-by-record read with the mcap library. A file damaged part-way is read again from its salvaged
    records (every complete record, inside a cut chunk too), then the damage is raised as a BagError."""
    files = _mcap_files(path)
    if not files or not all(f.is_file() for f in files):
        raise BagError(f"{path}: not a rosbag2 MCAP bag ({opened_error})")
    count = 0
    for file in files:
        done = 0  # events of this file already delivered
        try:
            with open(file, "rb") as fh:
                for event in _stream_events(fh, by_topic):
                    yield event
                    done += 1
                    count += 1
        except Exception as exc:  # noqa: BLE001 - any failure of the stream reader means damage: salvage
            stream, damage = salvage(file.read_bytes())
            recovered = 0
            try:
                for i, event in enumerate(_stream_events(BytesIO(stream), by_topic)):
                    if i >= done:
                        yield event
                        recovered += 1
                        count += 1
            except Exception:  # noqa: BLE001 - the salvaged stream simply ends where the damage was
                pass
            raise BagError(f"{file}: damaged after {count} messages ({damage or f'{type(exc).__name__}: {exc}'}; "
                           f"{recovered} of them recovered from inside the damaged part)") from exc
    log.warning("%s: rosbags could not open it (%s); read all %d messages record by record", path, opened_error, count)
