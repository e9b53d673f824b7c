"""Reliability III, items 6 and 11: decompression bombs and damaged bags. Every decompression is bounded, every
genuine message before and after a bad record is used, and the damage is reported (never a traceback)."""
from __future__ import annotations

import subprocess
import sys
import zlib
from pathlib import Path

import pytest
import yaml
import zstandard
from test_bag_formats import _TYPES, _chunks, _messages

from aoa_localizer.simulation.scenarios import simulate
from msgs_adapters import decompress
from msgs_adapters.bag import TOPICS, BagError, _qos, read_bag, typestore, write_bag
from msgs_adapters.bag_files import BagFiles, BagFilesError

GIB = 1024**3


@pytest.fixture(scope="module")
def data():
    return simulate("seed", 2)


@pytest.fixture(scope="module")
def zeros_gib() -> bytes:
    """1 GiB of zeros as zstd (about 40 KB): what a bomb carries."""
    cctx = zstandard.ZstdCompressor(level=1)
    piece = bytes(16 * 1024 * 1024)
    with_size = cctx.compressobj()
    out = b"".join(with_size.compress(piece) for _ in range(GIB // len(piece))) + with_size.flush()
    assert len(out) < 200_000
    return out


def _count(bag) -> dict:
    events, damage = {"fix": 0, "bearing": 0}, None
    try:
        for e in read_bag(bag):
            if e.kind in events:
                events[e.kind] += 1
    except BagError as exc:
        damage = str(exc)
    return {**events, "damage": damage}


def _chunk_record(records: bytes, declared: int, compression: str = "zstd") -> bytes:
    body = (b"\0" * 16 + declared.to_bytes(8, "little") + b"\0" * 4 + len(compression).to_bytes(4, "little")
            + compression.encode() + len(records).to_bytes(8, "little") + records)
    return b"\x06" + len(body).to_bytes(8, "little") + body


def _peak_rss_mb(code: str) -> float:
    """Run `code` in a fresh interpreter; its peak RSS (MB)."""
    res = subprocess.run([sys.executable, "-c", code + "\nimport resource; "
                          "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    return float(res.stdout.split()[-1])


@pytest.mark.slow
@pytest.mark.parametrize("declared", [1000, GIB])  # declared small (a lie), or declared huge
def test_a_chunk_that_expands_to_a_gibibyte_is_skipped_and_the_rest_is_read(tmp_path, data, zeros_gib, declared):
    """A 56 KB bag whose zstd chunk expanded to 1 GiB took 3.3 GB of RSS."""
    write_bag(tmp_path / "bag", data.fixes, data.bearings)
    mcap = next((tmp_path / "bag").glob("*.mcap"))
    raw = mcap.read_bytes()
    offset, _ = _chunks(raw)[len(_chunks(raw)) // 2]
    mcap.write_bytes(raw[:offset] + _chunk_record(zeros_gib, declared) + raw[offset:])
    got = _count(tmp_path / "bag")
    assert (got["fix"], got["bearing"]) == (len(data.fixes), len(data.bearings))  # every genuine message
    assert got["damage"] and f"the chunk at byte {offset}" in got["damage"]
    rss = _peak_rss_mb(f"from msgs_adapters.bag import read_bag\ntry:\n    list(read_bag({str(tmp_path / 'bag')!r}))\n"
                       "except Exception:\n    pass")
    assert rss < 1024, rss


def _message_compressed_bag(path: Path, data, bad: bytes | None, compress: bool = True):
    """An MCAP bag whose metadata.yaml claims per-message zstd, each genuine message compressed (or, with
    `compress` False, stored plain: a wrong claim), and `bad` stored as one more bearing's payload."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts, cctx = typestore(), zstandard.ZstdCompressor()
    messages = _messages(data)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {k: writer.add_connection(TOPICS[k], _TYPES[k], typestore=ts,
                                          offered_qos_profiles=[_qos(reliable=True, latched=False)]) for k in _TYPES}
        for i, (stamp, kind, msg) in enumerate(messages):
            cdr = ts.serialize_cdr(msg, _TYPES[kind])
            writer.write(conns[kind], int(stamp * 1e9), cctx.compress(cdr) if compress else cdr)
            if bad is not None and i == len(messages) // 2:
                writer.write(conns["bearing"], int(stamp * 1e9), bad)
    meta = yaml.safe_load((path / "metadata.yaml").read_text())
    meta["rosbag2_bagfile_information"].update(compression_mode="MESSAGE", compression_format="zstd")
    (path / "metadata.yaml").write_text(yaml.safe_dump(meta))


@pytest.mark.parametrize("kind", ["bomb", "corrupt"])
def test_a_bad_compressed_message_costs_only_itself(tmp_path, data, zeros_gib, kind):
    """A corrupt message of a per-message-compressed bag ended the replay in ZstdError; a message that expands
    to a gibibyte took the memory."""
    bad = zeros_gib if kind == "bomb" else decompress.ZSTD_MAGIC + b"\x00garbage" * 10
    _message_compressed_bag(tmp_path / "bag", data, bad)
    got = _count(tmp_path / "bag")
    assert (got["fix"], got["bearing"]) == (len(data.fixes), len(data.bearings))
    assert "a compressed message that cannot be read" in got["damage"]


def test_a_wrong_claim_of_message_compression_reads_the_messages_as_stored(tmp_path, data):
    _message_compressed_bag(tmp_path / "bag", data, None, compress=False)
    got = _count(tmp_path / "bag")
    assert (got["fix"], got["bearing"], got["damage"]) == (len(data.fixes), len(data.bearings), None)


def test_a_compressed_file_that_expands_past_its_limit_is_skipped(tmp_path, data, zeros_gib):
    """A 98 KB .mcap.zstd wrote 2 GiB to /tmp and returned 0."""
    write_bag(tmp_path / "bag", data.fixes, data.bearings)
    (tmp_path / "bag" / "metadata.yaml").unlink()
    (tmp_path / "bag" / "zz_bomb.mcap.zstd").write_bytes(zeros_gib)
    got = _count(tmp_path / "bag")
    assert (got["fix"], got["bearing"]) == (len(data.fixes), len(data.bearings))
    assert "zz_bomb.mcap.zstd not read: decompressed, it expands past" in got["damage"]
    alone = tmp_path / "alone"
    alone.mkdir()
    (alone / "x.mcap.zstd").write_bytes(zeros_gib)
    with pytest.raises(BagFilesError, match="no storage file could be read"):
        BagFiles(alone)


def test_a_sqlite3_bag_with_a_corrupt_page_gives_up_only_that_page(tmp_path, data):
    """A .db3 with one corrupt page was reported as "no topics at all" and nothing was salvaged."""
    from rosbags.rosbag2 import StoragePlugin
    from test_bag_formats import _write

    _write(tmp_path / "bag", _messages(data), StoragePlugin.SQLITE3)
    db = next((tmp_path / "bag").glob("*.db3"))
    raw = bytearray(db.read_bytes())
    pages = len(raw) // 4096
    assert pages > 10
    page = pages // 2
    raw[page * 4096:(page + 1) * 4096] = bytes([0xA5]) * 4096
    db.write_bytes(bytes(raw))
    got = _count(tmp_path / "bag")
    whole = len(data.fixes) + len(data.bearings)
    assert got["damage"] and "cannot be read" in got["damage"]
    assert whole - 200 < got["fix"] + got["bearing"] < whole  # a 4 KiB page holds a few dozen messages


@pytest.mark.slow
def test_a_recording_cut_between_chunks_is_reported_as_damaged(tmp_path, data):
    """A recording killed mid-way (its chunks sealed, no footer) replayed with exit 0 or 3; the docs say 1."""
    write_bag(tmp_path / "bag", data.fixes, data.bearings)
    mcap = next((tmp_path / "bag").glob("*.mcap"))
    raw = mcap.read_bytes()
    offset, length = _chunks(raw)[len(_chunks(raw)) // 2]
    mcap.write_bytes(raw[:offset + length])  # the recorder was killed right after sealing this chunk
    (tmp_path / "bag" / "metadata.yaml").unlink()
    res = subprocess.run([sys.executable, "-m", "aoa_localizer.replay", tmp_path / "bag", "--offline", "--output",
                          tmp_path / "e.jsonl"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 1, res.stderr
    assert "without its footer (a recording that was cut)" in res.stderr and "Traceback" not in res.stderr
    assert zlib.crc32(raw) != zlib.crc32(mcap.read_bytes())


def test_a_huge_metadata_yaml_is_not_parsed(tmp_path, data):
    """Item 12: a 6 MB metadata.yaml took 91 s and 2.2 GB to parse."""
    write_bag(tmp_path / "bag", data.fixes, data.bearings)
    (tmp_path / "bag" / "metadata.yaml").write_text("a: [" + "1, " * 3_000_000 + "1]\n")
    got = _count(tmp_path / "bag")
    assert (got["fix"], got["bearing"], got["damage"]) == (len(data.fixes), len(data.bearings), None)


@pytest.mark.slow
@pytest.mark.parametrize("special", ["zero", "fifo", "fifo_meta"])
@pytest.mark.parametrize("program", ["replay", "report"])
def test_a_special_file_in_a_bag_folder_is_refused_at_once(tmp_path, data, special, program):
    """Issue 64, item 7: bag_0.mcap a link to /dev/zero grew `replay --offline` to 5.9 GB without end; a FIFO named
    bag_0.mcap (or metadata.yaml) hung `replay` and `report`. Refused with the reason, exit 2, in bounded time."""
    import os

    bag = tmp_path / "bag"
    write_bag(bag, data.fixes, data.bearings)
    target = bag / ("metadata.yaml" if special == "fifo_meta" else "extra_1.mcap")
    target.unlink(missing_ok=True)
    if special == "zero":
        target.symlink_to("/dev/zero")
    else:
        os.mkfifo(target)
    with pytest.raises(BagFilesError, match="not a regular file"):
        BagFiles(bag)
    args = ([bag, "--offline", "--output", tmp_path / "o.jsonl"] if program == "replay"
            else [bag, "--out", tmp_path / "rep"])
    res = subprocess.run([sys.executable, "-m", f"aoa_localizer.{program}", *map(str, args)], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 2 and "not a regular file" in res.stderr and "Traceback" not in res.stderr
