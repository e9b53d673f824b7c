"""Every intact message of a damaged MCAP file, read record by record (MCAP spec layout, no summary needed).

A cut chunk gives up each complete record inside it; a chunk whose CRC does not match its content is skipped whole
(its messages are counted, never used) and reading goes on after it; a broken record frame ends the file.
"""
from __future__ import annotations

import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field

from .decompress import TooLarge, chunk_limit, zstd_bounded

MAGIC = b"\x89MCAP0\r\n"
_SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _FOOTER, _DATA_END = 0x03, 0x04, 0x05, 0x06, 0x02, 0x0F


@dataclass
class RawMessage:
    """One message as stored: its topic, type, log time (ns) and CDR bytes."""

    topic: str
    msgtype: str
    log_time: int
    data: bytes


@dataclass
class Salvage:
    """What reading a damaged file found: the damage (None when the file was sound) and the messages it cost."""

    damage: list[str] = field(default_factory=list)
    lost_messages: int = 0


def _u16(b: bytes, at: int) -> int:
    return int.from_bytes(b[at:at + 2], "little")


def _u32(b: bytes, at: int) -> int:
    return int.from_bytes(b[at:at + 4], "little")


def _u64(b: bytes, at: int) -> int:
    return int.from_bytes(b[at:at + 8], "little")


def _string(b: bytes, at: int) -> tuple[str, int]:
    n = _u32(b, at)
    return b[at + 4:at + 4 + n].decode(errors="replace"), at + 4 + n


def _records(buf: bytes) -> Iterator[tuple[int, bytes] | tuple[None, str]]:
    """(opcode, body) of each complete record; (None, why) once the framing breaks."""
    pos = 0
    while pos < len(buf):
        if pos + 9 > len(buf):
            yield None, f"cut at byte {pos}"
            return
        op, length = buf[pos], _u64(buf, pos + 1)
        if op == 0:
            yield None, f"an invalid record (opcode 0) at byte {pos}"
            return
        if pos + 9 + length > len(buf):
            yield None, f"cut at byte {pos}"
            return
        yield op, buf[pos + 9:pos + 9 + length]
        pos += 9 + length


def read_salvaged(data: bytes, report: Salvage) -> Iterator[RawMessage]:
    """The messages of an MCAP file's bytes in file order, as far as they can be trusted; `report` gets the damage."""
    if not data.startswith(MAGIC):
        report.damage.append("no MCAP magic")
        return
    yield from _Salvager(report).top_level(data)


class _Salvager:
    """Walks an MCAP file's records, keeping schemas and channels as they come."""

    def __init__(self, report: Salvage):
        self.report = report
        self.schemas: dict[int, str] = {}
        self.channels: dict[int, tuple[str, int]] = {}

    def top_level(self, data: bytes) -> Iterator[RawMessage]:
        """The file's records after the magic, by hand, so each chunk knows its byte offset for the report."""
        pos = len(MAGIC)
        while pos < len(data):
            if pos + 9 > len(data):
                self.report.damage.append(f"cut at byte {pos}")
                return
            op, length = data[pos], _u64(data, pos + 1)
            body = data[pos + 9:pos + 9 + length]
            if op == 0:
                self.report.damage.append(f"an invalid record (opcode 0) at byte {pos}")
                return
            if len(body) < length:
                yield from self.cut(op, body, pos)
                return
            if op in (_FOOTER, _DATA_END):
                return  # the summary after the data section repeats what the chunks declared
            if op == _CHUNK:
                yield from self.chunk(body, pos)
            else:
                yield from self.records(data[pos:pos + 9 + length], "")
            pos += 9 + length
        self.report.damage.append(f"it ends at byte {pos} without its footer (a recording that was cut)")

    def cut(self, op: int, body: bytes, pos: int) -> Iterator[RawMessage]:
        """A record the file ends inside: an uncompressed chunk still gives up its complete records."""
        if op == _CHUNK and len(body) >= 36:
            self.report.damage.append(f"cut in the chunk at byte {pos}")
            compression, at = _string(body, 28)
            if not compression:
                yield from self.records(body[at + 8:], f" inside the chunk at byte {pos}")
        else:
            self.report.damage.append(f"cut at byte {pos}")

    def chunk(self, body: bytes, offset: int) -> Iterator[RawMessage]:
        """A whole chunk: decompressed, checked against its CRC (skipped and counted on a mismatch), read."""
        crc, declared = _u32(body, 24), _u64(body, 16)
        compression, at = _string(body, 28)
        inner = body[at + 8:at + 8 + _u64(body, at)]
        if compression:
            if compression != "zstd":
                self.report.damage.append(f"a {compression} chunk at byte {offset}: not read")
                return
            import zstandard

            try:
                inner = zstd_bounded(inner, chunk_limit(declared))
            except (TooLarge, zstandard.ZstdError) as exc:
                self.report.damage.append(f"the chunk at byte {offset} cannot be read within its declared size and "
                                          f"the limit ({exc}); skipped")
                return
        if crc and zlib.crc32(inner) != crc:
            lost = sum(1 for op, _ in _records(inner) if op == _MESSAGE)
            self.report.damage.append(f"the chunk at byte {offset} failed its CRC check; its {lost} messages not used")
            self.report.lost_messages += lost
            return
        yield from self.records(inner, f" inside the chunk at byte {offset}")

    def records(self, buf: bytes, where: str) -> Iterator[RawMessage]:
        for op, body in _records(buf):
            if op is None or isinstance(body, str):
                self.report.damage.append(f"{body!s}{where}")
                return
            if op == _SCHEMA:
                self.schemas[_u16(body, 0)] = _string(body, 2)[0]
            elif op == _CHANNEL:
                self.channels[_u16(body, 0)] = (_string(body, 4)[0], _u16(body, 2))
            elif op == _MESSAGE:
                chan = self.channels.get(_u16(body, 0))
                if chan is None:
                    self.report.damage.append(f"a message on an undeclared channel{where}")
                    self.report.lost_messages += 1
                    continue
                yield RawMessage(chan[0], self.schemas.get(chan[1], ""), _u64(body, 6), body[22:])
            elif op in (_FOOTER, _DATA_END):
                return
