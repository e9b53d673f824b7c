"""Every readable message of a damaged rosbag2 sqlite3 file (a corrupt page used to make the whole bag "no topics
at all"): the topics table and the messages table read by id ranges, a range that fails split in halves down to
single rows, so one bad page costs only the rows on it."""
from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from pathlib import Path

from .mcap_salvage import RawMessage, Salvage

_BATCH = 4096


def read_db3_salvaged(file: Path, report: Salvage) -> Iterator[RawMessage]:
    """The messages of a sqlite3 bag file in id order, as far as they can be read; `report` gets the damage."""
    try:
        con = sqlite3.connect(f"file:{file}?mode=ro", uri=True)
    except sqlite3.Error as exc:
        report.damage.append(f"not an sqlite3 file ({exc})")
        return
    try:
        try:
            topics = {tid: (name, msgtype) for tid, name, msgtype in con.execute("SELECT id, name, type FROM topics")}
        except sqlite3.Error as exc:
            report.damage.append(f"its topics table cannot be read ({exc})")
            return
        try:
            last = con.execute("SELECT max(id) FROM messages").fetchone()[0] or 0
        except sqlite3.Error:
            last = file.stat().st_size  # ids are rows, and every row takes more than a byte
        yield from _rows(con, topics, 1, last, report)
        if report.lost_messages:
            report.damage.append(f"{report.lost_messages} rows of its messages table cannot be read")
    finally:
        con.close()


def _rows(con: sqlite3.Connection, topics: dict, first: int, last: int, report: Salvage) -> Iterator[RawMessage]:
    """Rows first..last, batch by batch; a batch that fails is split until the failing rows are single."""
    ranges = [(a, min(a + _BATCH - 1, last)) for a in range(first, last + 1, _BATCH)]
    while ranges:
        a, b = ranges.pop(0)
        try:
            rows = con.execute("SELECT id, topic_id, timestamp, data FROM messages WHERE id BETWEEN ? AND ? "
                               "ORDER BY id", (a, b)).fetchall()
        except sqlite3.Error:
            if a == b:
                report.lost_messages += 1
            else:
                mid = (a + b) // 2
                ranges[:0] = [(a, mid), (mid + 1, b)]
            continue
        for _, topic_id, stamp, data in rows:
            name, msgtype = topics.get(topic_id, (None, None))
            if name is None:
                report.lost_messages += 1
                continue
            yield RawMessage(name, msgtype, int(stamp), bytes(data))
