"""Bounded decompression for bags: every decompression (an MCAP chunk, a message, a whole storage file) stops at a
documented limit and at the record's own declared size, so a small hostile bag cannot take the machine's memory
or disk (a 56 KB bag whose chunk expanded to 1 GiB took 3.3 GB).

Limits (docs/failure_behaviour.md, "Bags"): an MCAP chunk at most CHUNK_MAX_BYTES decompressed (rosbag2 writes
768 KiB chunks, this project about a second of messages) and never past its declared `uncompressed_size`; a
message at most MESSAGE_MAX_BYTES; a whole compressed file at most FILE_RATIO times its own size (and
FILE_MIN_BYTES) and never past the free space of the temporary directory less a margin.
"""
from __future__ import annotations

import io
import shutil
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import zstandard

CHUNK_MAX_BYTES = 128 * 1024 * 1024
MESSAGE_MAX_BYTES = 64 * 1024 * 1024
FILE_RATIO = 200
FILE_MIN_BYTES = 64 * 1024 * 1024
DISK_MARGIN_BYTES = 1024 * 1024 * 1024
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
_STEP = 1024 * 1024

_MCAP_MAGIC = b"\x89MCAP0\r\n"
_CHUNK = 0x06


class TooLarge(ValueError):
    """Decompressed data past its limit: the message says which and how large."""


def zstd_bounded(data: bytes, limit: int) -> bytes:
    """`data` (one or more zstd frames) decompressed, or TooLarge once the output passes `limit` bytes; zstandard's
    own errors (zstandard.ZstdError) for data that is not zstd."""
    out = bytearray()
    with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data), read_across_frames=True) as reader:
        while chunk := reader.read(_STEP):
            out += chunk
            if len(out) > limit:
                raise TooLarge(f"expands past {limit} bytes")
    return bytes(out)


def zstd_file_bounded(src: BinaryIO, dst: BinaryIO, limit: int) -> int:
    """Decompress a zstd stream from `src` into `dst`, at most `limit` bytes (TooLarge past it); the bytes written."""
    written = 0
    with zstandard.ZstdDecompressor().stream_reader(src, read_across_frames=True) as reader:
        while chunk := reader.read(_STEP):
            written += len(chunk)
            if written > limit:
                raise TooLarge(f"expands past {limit} bytes")
            dst.write(chunk)
    return written


def file_limit(compressed: Path, into: Path) -> int:
    """The most a compressed storage file may expand to: FILE_RATIO times its size (at least FILE_MIN_BYTES), and
    never more than the free space at `into` less DISK_MARGIN_BYTES."""
    free = shutil.disk_usage(into).free - DISK_MARGIN_BYTES
    return max(min(max(FILE_RATIO * compressed.stat().st_size, FILE_MIN_BYTES), free), 0)


def chunk_limit(declared: int) -> int:
    return min(declared, CHUNK_MAX_BYTES)


def oversized_chunks(file: Path) -> Iterator[str]:
    """Why each chunk of an MCAP file cannot be read within its limits (declared too large, or zstd data that
    expands past its declared size), from the top-level records alone: a file with any goes to the
    record-by-record reader, which skips such chunks. Reads one chunk at a time."""
    with open(file, "rb") as f:
        if f.read(8) != _MCAP_MAGIC:
            return
        while True:
            at = f.tell()
            head = f.read(9)
            if len(head) < 9:
                return
            op, length = head[0], struct.unpack_from("<Q", head, 1)[0]
            if op != _CHUNK:
                f.seek(length, io.SEEK_CUR)
                continue
            body = f.read(length)
            if len(body) < length or len(body) < 40:
                return  # a cut file: the record-by-record reader says so
            problem = _chunk_problem(body)
            if problem:
                yield f"the chunk at byte {at} {problem}"


def _chunk_problem(body: bytes) -> str | None:
    """Why one chunk record's body cannot be decompressed within its limits, or None."""
    declared = struct.unpack_from("<Q", body, 16)[0]
    n = struct.unpack_from("<I", body, 28)[0]
    compression, records = body[32:32 + n].decode(errors="replace"), body[32 + n + 8:]
    if compression and declared > CHUNK_MAX_BYTES:
        return f"declares {declared} bytes, over the {CHUNK_MAX_BYTES} limit"
    past = f"expands past its declared {declared} bytes"
    if compression == "zstd":
        try:
            zstd_bounded(records, declared)
        except TooLarge:
            return past
        except zstandard.ZstdError:
            return None  # not zstd after all: the CRC or the reader says so
    elif compression == "lz4":
        import lz4.frame

        try:
            out = lz4.frame.LZ4FrameDecompressor().decompress(records, max_length=declared + 1)
        except RuntimeError:
            return None  # not lz4 after all
        if len(out) > declared:
            return past
    return None
