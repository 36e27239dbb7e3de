"""Output files written whole (issue 43): every file a command writes for its user (``--json``,
tables, summaries, figures, the report) goes through :func:`atomic_path` or
:func:`write_atomic`: written under a temporary name in the same folder (so the rename cannot
cross file systems), flushed to the disk (``fsync``), then renamed over the destination with
``os.replace``. A reader sees the old file or the new one, never a part; a failure (a full
disk) leaves the destination as it was, removes the temporary file and raises
:class:`OutputError`, whose one line names the file.

Imports nothing of eha but the error hierarchy: every layer may use it.
"""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from eha.errors import FAILURE, EhaError


class OutputError(EhaError, OSError):
    """An output file could not be written (full disk, I/O error); one line naming it. A
    failure of the machine (exit 1); the destination is left as it was."""

    exit_code = FAILURE


def _file_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


#: Mode of the files written (mkstemp makes 0600; outputs are shared like any file).
FILE_MODE = _file_mode()


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` (same suffix, so writers that infer the format from it
    work) for the block to write; on success it is flushed to the disk and renamed to
    ``path``; on any error it is removed and ``path`` is left as it was.

    Raises
    ------
    OutputError
        An ``OSError`` while writing (the file named, with the reason).
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".part{path.suffix}",
                                    dir=path.parent)
        os.close(fd)
    except OSError as exc:
        raise OutputError(f"{path}: could not be written ({exc.strerror or exc})") from None
    tmp = Path(name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, FILE_MODE)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OutputError):
            raise
        raise OutputError(f"{path}: could not be written ({exc.strerror or exc}); the file "
                          "is left as it was") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_atomic(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` (text as UTF-8, or bytes) to ``path`` whole (:func:`atomic_path`);
    returns the path."""
    with atomic_path(path) as tmp:
        if isinstance(data, str):
            tmp.write_text(data, encoding="utf-8")
        else:
            tmp.write_bytes(data)
    return Path(path)


def write_json(path: str | Path, data: Any, indent: int | None = 2, **kw) -> Path:
    """``data`` as JSON (``json.dumps(data, indent=indent, **kw)``) to ``path``, whole."""
    import json

    return write_atomic(path, json.dumps(data, indent=indent, **kw))


__all__ = ["atomic_path", "write_atomic", "write_json", "OutputError", "FILE_MODE"]
