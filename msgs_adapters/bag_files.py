"""A rosbag2 bag's storage files as ros2 bag leaves them: MCAP or sqlite3, split into several files, whole-file or
per-message zstd compression, with or without metadata.yaml; each file opened on its own so that no message is lost.

rosbags' directory reader drops the messages of a topic whose QoS in metadata.yaml differs from the storage's own
copy (8 of 21 ros2/rosbag2 test bags read as empty); reading the storage files themselves avoids that.
"""
from __future__ import annotations

import logging
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import yaml

from .decompress import MESSAGE_MAX_BYTES, ZSTD_MAGIC, file_limit, zstd_bounded, zstd_file_bounded

log = logging.getLogger("aoa_localizer.bag")
STORAGE_SUFFIXES = (".mcap", ".db3")
# A split bag of thousands of files has a metadata.yaml of a few hundred KiB; a 6 MB one took 91 s and 2.2 GB
METADATA_MAX_BYTES = 4 * 1024 * 1024


class BagFilesError(RuntimeError):
    """The path is not a rosbag2 bag (nothing there, no storage file, an unreadable metadata.yaml)."""


class BadPayload(ValueError):
    """A message whose compressed bytes cannot be read within their limit: the message says why."""


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag as its storage declares it."""

    name: str
    msgtype: str
    count: int
    qos: tuple = ()  # the offered QoS profiles recorded with it (rosbags Qos), when the storage has them


SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # the same safe subset of YAML, in C


def _bag_file(name: str) -> bool:
    """A storage file's name (name.mcap, name.db3, or compressed whole: name.mcap.zstd)."""
    return name.endswith(STORAGE_SUFFIXES) or name.endswith(tuple(s + ".zstd" for s in STORAGE_SUFFIXES))


class BagFiles:
    """The storage files of a bag at `path` (a bag directory, or one .mcap/.db3 file), decompressed into a temporary
    directory when the bag compresses whole files. Use as a context manager; `files` are in recording order."""

    def __init__(self, path: Path | str):
        self.path = Path(path)
        self.message_compression = False  # every payload zstd-compressed on its own
        self.declared_messages: int | None = None  # metadata.yaml's message_count, when there is one
        self.not_compressed = 0  # messages of a bag that claims message compression stored plain
        self.skipped_files: list[str] = []  # compressed files that could not be read within their limit
        self._tmp: tempfile.TemporaryDirectory | None = None
        self._closers: list[Callable[[], None]] = []
        self.files = self._find()

    def _find(self) -> list[Path]:
        path = self.path
        if not path.exists():
            raise BagFilesError(f"{path}: no such bag")
        if path.is_file():
            return self._plains([path])
        if not path.is_dir():  # a FIFO, a device: reading one would wait for ever or never end
            raise BagFilesError(f"{path}: neither a bag folder nor a regular file (a pipe or a device?)")
        meta = path / "metadata.yaml"
        special = [f.name for f in path.iterdir() if (_bag_file(f.name) or f == meta) and f.exists()
                   and not f.is_file()]
        if special:  # /dev/zero behind bag_0.mcap grew the reader to 5.9 GB; a FIFO waited for ever
            raise BagFilesError(f"{path}: {', '.join(sorted(special))} is not a regular file (a pipe, a device or a "
                                "link to one): not read")
        if meta.is_file() and meta.stat().st_size > METADATA_MAX_BYTES:
            log.warning("%s: %d bytes, more than any bag's metadata (%d): not read; reading the storage files", meta,
                        meta.stat().st_size, METADATA_MAX_BYTES)
        elif meta.is_file():
            try:
                # libyaml's safe loader where PyYAML has it: the pure-Python one took 5 s on 4000 topics' metadata
                info = yaml.load(meta.read_text(), Loader=SAFE_LOADER)["rosbag2_bagfile_information"]
                names = [Path(p).name for p in info.get("relative_file_paths") or []]
            except Exception as exc:  # noqa: BLE001 - any malformed metadata: read the storage files themselves
                log.warning("%s: metadata.yaml unreadable (%s: %s); reading the storage files", meta,
                            type(exc).__name__, exc)
                names, info = [], {}
            self.message_compression = (info.get("compression_mode") or "").upper() == "MESSAGE"
            self.declared_messages = info.get("message_count")
            files = [path / n for n in names if (path / n).is_file()]
            if files:
                return self._plains(files)
        files = sorted(f for f in path.iterdir() if _bag_file(f.name) and f.is_file())
        if not files:
            raise BagFilesError(f"{path}: not a rosbag2 bag (no .mcap or .db3 file)")
        return self._plains(files)

    def _plains(self, files: list[Path]) -> list[Path]:
        out = [p for p in map(self._plain, files) if p is not None]
        if not out:
            raise BagFilesError(f"{self.path}: no storage file could be read ({'; '.join(self.skipped_files)})")
        return out

    def _plain(self, file: Path) -> Path | None:
        """The file itself, or its decompressed copy when ros2 bag compressed it whole (name.mcap.zstd); None (said
        in `skipped_files`) when that copy would pass its limit (decompress.file_limit) or is not zstd."""
        if not file.name.endswith(".zstd"):
            return file
        import zstandard

        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="aoa_bag_")
        out = Path(self._tmp.name) / file.name[: -len(".zstd")]
        limit = file_limit(file, Path(self._tmp.name))
        try:
            with open(file, "rb") as src, open(out, "wb") as dst:
                zstd_file_bounded(src, dst, limit)
        except (zstandard.ZstdError, ValueError, OSError) as exc:
            out.unlink(missing_ok=True)
            self.skipped_files.append(f"{file.name} not read: decompressed, it {exc}")
            log.warning("%s: not read (decompressed, it %s)", file, exc)
            return None
        return out

    def payload(self, raw: bytes) -> bytes:
        """A message's CDR bytes (decompressed when the bag compresses each message); BadPayload when they cannot be
        read within MESSAGE_MAX_BYTES. A bag whose metadata.yaml claims message compression for plain messages
        (no zstd magic) gets them as stored, counted in `not_compressed`."""
        if not self.message_compression:
            return raw
        import zstandard

        raw = bytes(raw)
        if not raw.startswith(ZSTD_MAGIC):
            self.not_compressed += 1
            return raw
        try:
            return zstd_bounded(raw, MESSAGE_MAX_BYTES)
        except (zstandard.ZstdError, ValueError) as exc:
            raise BadPayload(f"a compressed message that cannot be read ({type(exc).__name__}: {exc})") from None

    def on_close(self, closer: Callable[[], None]):
        """Call `closer` at close(), before the temporary files go (a reader holding one open)."""
        self._closers.append(closer)

    def close(self):
        while self._closers:
            self._closers.pop()()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> BagFiles:
        return self

    def __exit__(self, *exc):
        self.close()


DESCRIBED_TOPICS = 20  # a message names this many of a bag's topics, the ones with the most messages


def describe_topics(topics: list[TopicInfo]) -> str:
    """'name (type, N messages)', one per topic (the DESCRIBED_TOPICS busiest, and how many more), for messages
    that say what a bag holds: a bag of 30,000 topics made a 1.4 MB line."""
    shown = sorted(topics, key=lambda t: -t.count)[:DESCRIBED_TOPICS]
    text = ", ".join(f"{t.name} ({t.msgtype}, {t.count} messages)" for t in shown) or "no topics at all"
    more = len(topics) - len(shown)
    return f"{text} and {more} more topic{'s' if more != 1 else ''}" if more else text
