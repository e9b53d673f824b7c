"""Output files a program writes: checked before any work, and moved into place only when they hold what the run
made, so a typo in an input path, a crash or a refused input never destroys a file that was there."""
from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path


def check_output(path: Path, inputs: tuple[Path, ...] = (), option: str = "--output") -> None:
    """A ValueError naming `option` for an output that is a folder, not a regular file (a device, a FIFO), in a
    folder that does not exist or where no file can be made (/proc, a read-only place), or one of the inputs (it
    would be overwritten)."""
    if path.is_dir():
        raise ValueError(f"{option} {path} is a folder; give a file")
    if not path.parent.is_dir():
        raise ValueError(f"{option} {path}: no folder {path.parent}")
    if path.exists() and not path.is_file():
        raise ValueError(f"{option} {path} is not a regular file")
    if path.exists() and any(p.exists() and path.resolve() == p.resolve() for p in inputs):
        raise ValueError(f"{option} {path} is an input: it would be overwritten")
    _probe(path.parent, option, path)


def check_folder(path: Path, option: str, new: bool = False) -> None:
    """A ValueError naming `option` for an output folder that cannot be: a file, under a file, a folder where no
    file can be made (/proc, read-only), or (`new`, a bag's folder) one that exists already. Nothing is made: a
    missing folder is tried by making and removing a folder in its nearest existing parent."""
    if path.exists() and not path.is_dir():
        raise ValueError(f"{option} {path} is a file; give a folder")
    if new and path.exists():
        raise ValueError(f"{option} {path} exists; choose a new folder")
    existing = path
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"{option} {path}: {existing} is a file, not a folder")
    _probe(existing, option, path)


def _probe(folder: Path, option: str, path: Path) -> None:
    """A ValueError unless a file and a folder can be made (and removed) in `folder`."""
    try:
        with tempfile.TemporaryDirectory(dir=folder, prefix=".aoa_probe."):
            pass
        with tempfile.TemporaryFile(dir=folder, prefix=".aoa_probe."):
            pass
    except OSError as exc:
        raise ValueError(f"{option} {path}: nothing can be written in {folder} ({exc.strerror or exc})") from None


def user_mode() -> int:
    """The mode a new file gets under the process's umask (0644 under 022): read from /proc where it is shown, so
    no thread sees the umask changed for a moment."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return 0o666 & ~int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


class StagedFile:
    """A text file written beside `path`: `place()` moves it onto `path` and goes on writing there (a reader sees
    the run's lines as they come), `keep()` places and closes it; `drop()` (or leaving unplaced) removes it and
    leaves `path` as it was."""

    def __init__(self, path: Path):
        self.path = path
        self.placed = False
        fd, self._tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        os.fchmod(fd, user_mode())  # mkstemp's 0600 would outlive the move: the file is the user's, as any other
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


NAME_MAX_CHARS = 80  # a file name's stem from an id at most this long (with its hash), far below NAME_MAX (255)


def file_name(ident: str) -> str:
    """An emitter's id or channel as a file name's stem of its own: kept as it is when it is a plain name
    (letters, digits, `-_.`, not starting with a dot, at most NAME_MAX_CHARS); otherwise the characters a file name
    cannot hold become `_`, it is cut short, and a hash of the id is added, so `a/b`, `a:b` and `a_b` (and ids of
    300 characters) never share a file."""
    plain = "".join(c if c.isascii() and (c.isalnum() or c in "-_.") else "_" for c in ident)
    if plain == ident and ident and not ident.startswith(".") and len(ident) <= NAME_MAX_CHARS:
        return ident
    digest = hashlib.sha1(ident.encode("utf-8", "surrogatepass")).hexdigest()[:10]
    return f"{plain.lstrip('.')[:NAME_MAX_CHARS - 11] or 'emitter'}-{digest}"


def file_names(idents) -> dict[str, str]:
    """file_name of each id, made unique also where a file system ignores case (`A` and `a`): such ids get their
    hash too."""
    names = {ident: file_name(ident) for ident in idents}
    seen: dict[str, list[str]] = {}
    for ident, name in names.items():
        seen.setdefault(name.casefold(), []).append(ident)
    for same in seen.values():
        if len(same) > 1:
            for ident in same:
                digest = hashlib.sha1(ident.encode("utf-8", "surrogatepass")).hexdigest()[:10]
                names[ident] = f"{names[ident][:NAME_MAX_CHARS - 11]}-{digest}"
    return names
