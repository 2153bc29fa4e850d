"""Output folders: created and checked writable up front, so a bad --out fails with
one line before any work is done rather than with a traceback mid-run."""
from __future__ import annotations

from pathlib import Path

from graphtrack.errors import InputError


def writable_dir(path: str | Path, what: str = "the output folder") -> Path:
    """Create ``path`` (with parents) and prove a file can be written in it.

    Raises InputError ``"<path>: cannot write <what> (<reason>)"`` otherwise, and
    ``"<path>: is a file, not a folder (<what>): ..."`` for an existing file.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():   # mkdir would say "File exists", which reads as a clash
        raise InputError(f"{path}: is a file, not a folder ({what}): name a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".graphtrack-write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as e:
        raise InputError(f"{path}: cannot write {what} ({e.strerror or e})") from None
    return path
