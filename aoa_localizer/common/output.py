"""Output files a program writes: checked before any work, and moved into place only when they hold what the run
made, so a typo in an input path, a crash or a refused input never destroys a file that was there."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path


def check_output(path: Path, inputs: tuple[Path, ...] = (), option: str = "--output") -> None:
    """A ValueError naming `option` for an output that is a folder, in a folder that does not exist, or one of
    the inputs (it would be overwritten)."""
    if path.is_dir():
        raise ValueError(f"{option} {path} is a folder; give a file")
    if not path.parent.is_dir():
        raise ValueError(f"{option} {path}: no folder {path.parent}")
    if path.exists() and any(p.exists() and path.resolve() == p.resolve() for p in inputs):
        raise ValueError(f"{option} {path} is an input: it would be overwritten")


class StagedFile:
    """A text file written beside `path`: `place()` moves it onto `path` and goes on writing there (a reader sees
    the run's lines as they come), `keep()` places and closes it; `drop()` (or leaving unplaced) removes it and
    leaves `path` as it was."""

    def __init__(self, path: Path):
        self.path = path
        self.placed = False
        fd, self._tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        self.file = os.fdopen(fd, "w", encoding="utf-8")

    def place(self) -> None:
        if not self.placed:
            self.file.flush()
            os.replace(self._tmp, self.path)  # the open file goes with its name: later writes land at `path`
            self.placed = True

    def keep(self) -> None:
        self.place()
        self.file.close()

    def drop(self) -> None:
        self.file.close()
        if not self.placed:
            Path(self._tmp).unlink(missing_ok=True)

    def __enter__(self) -> StagedFile:
        return self

    def __exit__(self, *exc) -> None:
        if not self.file.closed:
            self.drop()


def write_staged(path: Path, text: str) -> None:
    """Write `text` to `path` through a StagedFile: an interrupted or failed write leaves the old file whole."""
    with StagedFile(path) as staged:
        staged.file.write(text)
        staged.keep()


def file_name(ident: str) -> str:
    """An emitter's id or channel as a file name: characters a file name cannot hold become `_`."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in ident) or "emitter"
