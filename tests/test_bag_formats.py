"""Bags as ros2 bag writes them (sqlite3, split, compressed, QoS in metadata.yaml unlike the storage's copy), bags
without the needed topics, and damage that only a CRC reveals. Fixture bags are made here with rosbags."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

from aoa_localizer.common.bag_run import run_bag
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.simulation.scenarios import simulate
from msgs_adapters import build
from msgs_adapters.bag import TOPICS, BagError, BagTopicsError, _qos, read_bag, typestore, write_bag

_TYPES = {"fix": "sensor_msgs/msg/NavSatFix", "bearing": "geometry_msgs/msg/Vector3Stamped"}


@pytest.fixture(scope="module")
def data():
    return simulate("seed", 2)


def _messages(data):
    T = build.rosbags_types(typestore())
    msgs = [(f[0], "fix", build.navsatfix(T, f[0], f[1], f[2], f[3])) for f in data.fixes]
    msgs += [(b[0], "bearing", build.df_record(T, b[0], b[1], b[2])) for b in data.bearings]
    return sorted(msgs, key=lambda m: m[0])


def _write(path: Path, messages, storage=StoragePlugin.MCAP, compression=None):
    ts = typestore()
    writer = Writer(path, version=9, storage_plugin=storage)
    if compression is not None:
        writer.set_compression(compression, CompressionFormat.ZSTD)
    with writer:
        conns = {k: writer.add_connection(TOPICS[k], _TYPES[k], typestore=ts,
                                          offered_qos_profiles=[_qos(reliable=True, latched=False)]) for k in _TYPES}
        for stamp, kind, msg in messages:
            writer.write(conns[kind], int(stamp * 1e9), ts.serialize_cdr(msg, _TYPES[kind]))


def _split(path: Path, messages, storage):
    """One bag in two storage files with one metadata.yaml, as `ros2 bag record --max-bag-duration` leaves it."""
    half = len(messages) // 2
    _write(path, messages[:half], storage)
    _write(path.with_name("second"), messages[half:], storage)
    second = next(f for f in path.with_name("second").iterdir() if f.suffix in (".mcap", ".db3"))
    target = path / f"{path.name}_1{second.suffix}"
    second.rename(target)
    meta = yaml.safe_load((path / "metadata.yaml").read_text())
    info = meta["rosbag2_bagfile_information"]
    info["relative_file_paths"].append(target.name)
    info["message_count"] = len(messages)
    (path / "metadata.yaml").write_text(yaml.safe_dump(meta))


def _events(bag) -> list:
    return [(e.kind, e.log_time_ns, e.record) for e in read_bag(bag) if e.kind in ("fix", "bearing")]


@pytest.mark.parametrize("variant", ["sqlite3", "split_mcap", "split_sqlite3", "file_zstd", "message_zstd",
                                     "qos_differs_from_metadata"])
def test_every_message_of_a_ros2_bag_layout_is_read(tmp_path, data, variant):
    """Reliability finding: 8 of 21 ros2/rosbag2 test bags yielded 0 messages (rosbags drops a topic whose QoS in
    metadata.yaml differs from the storage's copy); sqlite3, split and compressed bags are supported."""
    messages = _messages(data)
    reference = tmp_path / "reference"
    _write(reference, messages)
    bag = tmp_path / "bag"
    if variant == "sqlite3":
        _write(bag, messages, StoragePlugin.SQLITE3)
    elif variant.startswith("split"):
        _split(bag, messages, StoragePlugin.SQLITE3 if variant.endswith("sqlite3") else StoragePlugin.MCAP)
    elif variant.endswith("zstd"):
        _write(bag, messages, compression=CompressionMode.FILE if variant == "file_zstd" else CompressionMode.MESSAGE)
    else:
        _write(bag, messages)
        meta_path = bag / "metadata.yaml"
        meta = yaml.safe_load(meta_path.read_text())
        for topic in meta["rosbag2_bagfile_information"]["topics_with_message_count"]:
            topic["topic_metadata"]["offered_qos_profiles"] = [{**q, "depth": 77} for q in
                                                              topic["topic_metadata"]["offered_qos_profiles"]]
        meta_path.write_text(yaml.safe_dump(meta))
    got, want = _events(bag), _events(reference)
    assert len(want) == len(messages)
    assert got == want


@pytest.mark.slow
def test_a_bag_without_the_needed_topics_says_what_it_has_and_what_it_needs(tmp_path):
    """Reliability finding: 11 valid ros2 bags without the default topics were "damaged after 0 messages
    (KeyError)", exit 2. They are now described."""
    ts = typestore()
    T = ts.types
    with Writer(tmp_path / "bag", version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        conn = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=ts)
        for i in range(3):
            writer.write(conn, i, ts.serialize_cdr(T["std_msgs/msg/String"](data=f"hello {i}"), "std_msgs/msg/String"))
    with pytest.raises(BagTopicsError) as exc:
        list(read_bag(tmp_path / "bag"))
    assert "/chatter (std_msgs/msg/String, 3 messages)" in str(exc.value)
    assert "needs /gps/fix (sensor_msgs/msg/NavSatFix) and /df/bearing" in str(exc.value)
    res = subprocess.run([sys.executable, "-m", "aoa_localizer.replay", tmp_path / "bag", "--offline",
                          "--output", tmp_path / "e.jsonl"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "/chatter (std_msgs/msg/String, 3 messages)" in res.stderr
    assert "Traceback" not in res.stderr


def _chunks(data: bytes) -> list[tuple[int, int]]:
    """(offset, length) of each chunk record of an MCAP file."""
    pos, out = 8, []
    while pos + 9 <= len(data) and data[pos] not in (0x0F, 0x02):
        length = int.from_bytes(data[pos + 1:pos + 9], "little")
        if data[pos] == 0x06:
            out.append((pos, 9 + length))
        pos += 9 + length
    return out


@pytest.mark.slow
def test_damage_inside_a_chunk_is_caught_by_its_crc_and_the_other_chunks_are_used(tmp_path, data):
    """Reliability finding 4: 4 KiB of zeros mid-file went unnoticed (exit 0, 100 of 300 bearings silently
    missing; no chunk CRCs were written). Bags are now written in chunks of about a second with CRCs; a chunk that
    fails its CRC is not used, the rest is, and the damage is reported (exit 1)."""
    write_bag(tmp_path / "bag", data.fixes, data.bearings)
    mcap = next((tmp_path / "bag").glob("*.mcap"))
    raw = bytearray(mcap.read_bytes())
    chunks = _chunks(bytes(raw))
    assert len(chunks) > 20  # about one a second
    offset, length = chunks[len(chunks) // 2]
    raw[offset + length - 40] ^= 0x01  # one flipped bit inside a message of the middle chunk
    mcap.write_bytes(bytes(raw))
    whole = len(data.fixes) + len(data.bearings)
    loc = Localizer(LocalizerConfig(seed=1))
    estimates = []
    run = run_bag(tmp_path / "bag", {}, loc, estimates.append)
    assert run.damage and "failed its CRC check" in run.damage
    lost = int(run.damage.split("CRC check; its ")[1].split(" messages")[0])
    assert lost >= 1 and run.messages == whole - lost
    assert estimates
    res = subprocess.run([sys.executable, "-m", "aoa_localizer.replay", tmp_path / "bag", "--offline", "--output",
                          tmp_path / "e.jsonl"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 1 and "failed its CRC check" in res.stderr


def test_an_unreadable_sqlite3_file_is_an_error_not_an_empty_bag(tmp_path, data):
    _write(tmp_path / "bag", _messages(data), StoragePlugin.SQLITE3)
    db = next((tmp_path / "bag").glob("*.db3"))
    db.write_bytes(b"garbage" * 100)
    with pytest.raises(BagError):
        list(read_bag(tmp_path / "bag"))


def test_two_stations_whose_namespaces_end_alike_are_two_stations():
    """Issue 51, item 6: `/team1/car/...` and `/team2/car/...` were one station, the second dropped without a count."""
    from msgs_adapters.bag import stations_in

    topics = ["/team1/car/gps/fix", "/team1/car/df/bearing", "/team2/car/gps/fix", "/team2/car/df/bearing",
              "/mast/gps/fix", "/mast/df/bearing", "/mast/heading/imu", "/lonely/gps/fix"]
    assert stations_in(topics) == {
        "team1/car": {"fix": "/team1/car/gps/fix", "bearing": "/team1/car/df/bearing"},
        "team2/car": {"fix": "/team2/car/gps/fix", "bearing": "/team2/car/df/bearing"},
        "mast": {"fix": "/mast/gps/fix", "bearing": "/mast/df/bearing", "heading": "/mast/heading/imu"},
    }


def test_a_bag_of_thousands_of_topics_is_described_in_a_line_of_its_busiest():
    """Issue 51, item 13: the missing-topics error named all 30,000 topics of a bag in one 1.4 MB line."""
    from msgs_adapters.bag_files import DESCRIBED_TOPICS, TopicInfo, describe_topics

    topics = [TopicInfo(f"/t{k}", "std_msgs/msg/String", k) for k in range(30_000)]
    text = describe_topics(topics)
    assert len(text) < 2000 and text.startswith("/t29999 (std_msgs/msg/String, 29999 messages)")
    assert text.endswith(f"and {30_000 - DESCRIBED_TOPICS} more topics")
    assert describe_topics(topics[:2]) == "/t1 (std_msgs/msg/String, 1 messages), /t0 (std_msgs/msg/String, 0 messages)"


@pytest.mark.slow
@pytest.mark.parametrize("storage", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_each_storage_file_is_opened_once_and_closed_with_the_bag(tmp_path, data, storage, monkeypatch):
    """Issue 51, item 13: rosbags parsed every topic's QoS and message definition twice (once for the topics, once
    for the messages): 12.4 s before the first estimate at 30,000 topics, 7.4 s now."""
    from rosbags.highlevel import AnyReader

    from msgs_adapters.bag import RawReader
    from msgs_adapters.bag_files import BagFiles

    messages = _messages(data)
    _split(tmp_path / "b", messages, storage)
    opened: list[AnyReader] = []
    real_open = AnyReader.open

    def counted(self):
        opened.append(self)
        real_open(self)

    monkeypatch.setattr(AnyReader, "open", counted)
    assert len(list(read_bag(tmp_path / "b"))) == len(messages)
    assert len(opened) == 2 and all(r.stack is None for r in opened)  # two files, each once, all closed
    opened.clear()
    with BagFiles(tmp_path / "b") as files:
        RawReader(files).topics()  # no messages asked for: the open files wait for the bag's close
        assert len(opened) == 2 and all(r.stack is not None for r in opened)
    assert all(r.stack is None for r in opened)


@pytest.mark.slow
def test_a_bag_of_scans_reads_as_the_same_records_one_message_each(tmp_path, data):
    """Issue 69: a receiver's readings of one stamp recorded as one scan on /df/scan (a bridge's `--scan`) are the
    same DF records, in the same order, as a bag of one message each; a bag with scans and no /df/bearing is read,
    and a cloud that holds no readings is named, not fed."""
    two = [row for b in data.bearings for row in ((*b[:3], 433.92e6), (b[0], (b[1] + 10.0) % 360, b[2], 446e6))]
    write_bag(tmp_path / "records", data.fixes, two)
    write_bag(tmp_path / "scans", data.fixes, two, scans=True)

    def events(bag):
        return [(e.kind, e.log_time_ns, repr(tuple(e.record))) for e in read_bag(bag)]  # NaN sigmas alike

    assert events(tmp_path / "scans") == events(tmp_path / "records")
    assert sum(1 for e in events(tmp_path / "records") if e[0] == "bearing") == 2 * len(data.bearings)
    loc = Localizer(LocalizerConfig(seed=1))
    run_bag(tmp_path / "scans", {}, loc, lambda est: None)
    assert {"f433920000", "f446000000"} <= {c.id for c in loc._channels.all()}

    ts = typestore()
    T = build.rosbags_types(ts)
    bad = T.PointCloud2(header=build.header(T, 5.0, "df"), height=1, width=3, fields=[], is_bigendian=False,
                        point_step=8, row_step=24, data=build.np.zeros(24, build.np.uint8), is_dense=True)
    with Writer(tmp_path / "bad", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        fix = writer.add_connection(TOPICS["fix"], _TYPES["fix"], typestore=ts)
        scan = writer.add_connection(TOPICS["scan"], "sensor_msgs/msg/PointCloud2", typestore=ts)
        writer.write(fix, 1, ts.serialize_cdr(build.navsatfix(T, 5.0, 44.0, 7.0, 0.0), _TYPES["fix"]))
        writer.write(scan, 2, ts.serialize_cdr(bad, "sensor_msgs/msg/PointCloud2"))
    foreign = [e.record for e in read_bag(tmp_path / "bad") if e.kind == "foreign"]
    assert foreign == [("/df/scan", "sensor_msgs/msg/PointCloud2: a DF scan needs an azimuth_deg field")]
