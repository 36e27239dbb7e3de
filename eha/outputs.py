"""Output files written whole (issue 43): every file a command writes for its user (``--json``,
tables, summaries, figures, the report) goes through :func:`atomic_path` or
:func:`write_atomic`: written under a temporary name in the same folder (so the rename cannot
cross file systems), flushed to the disk (``fsync``), then renamed over the destination with
``os.replace``. A reader sees the old file or the new one, never a part; a failure (a full
disk) leaves the destination as it was, removes the temporary file and raises
:class:`OutputError`, whose one line names the file.

Temporary names are unique (``.NAME.eha-PID-RANDOM.part.SUFFIX``): two commands writing the same
file never share one; those a killed process left (``kill -9``) are removed by the next write
of the same file (:func:`temp_beside`). A set of files written together (a design's CSV, JSON
and PNG) is replaced all or none (:func:`atomic_set`).

Imports nothing of eha but the error hierarchy: every layer may use it.
"""

from __future__ import annotations

import glob
import os
import re
import tempfile
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any, Iterator, Sequence

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


def pid_alive(pid: int) -> bool:
    """Is process ``pid`` alive (another user's counts as alive)?"""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def clean_leftovers(path: str | Path) -> int:
    """Remove the temporary files of ``path`` (:func:`temp_beside`) whose process is no
    longer alive (killed while it wrote); returns how many went."""
    path = Path(path)
    mine = re.compile(rf"\.{re.escape(path.name)}\.eha-(\d+)-")
    n = 0
    for name in glob.glob(os.path.join(glob.escape(str(path.parent)),
                                       f".{glob.escape(path.name)}.eha-*")):
        found = mine.match(os.path.basename(name))
        if found and not pid_alive(int(found.group(1))):
            try:
                os.unlink(name)
                n += 1
            except OSError:
                pass
    return n


def temp_beside(path: str | Path, suffix: str = "") -> Path:
    """A new, empty temporary file beside ``path`` with a name no other writer uses (the
    process id and a random part); first removes the leftovers of killed writers of the same
    file (:func:`clean_leftovers`). ``OSError`` when the folder cannot be written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    clean_leftovers(path)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.eha-{os.getpid()}-", suffix=suffix,
                                dir=path.parent)
    os.close(fd)
    return Path(name)


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
        tmp = temp_beside(path, f".part{path.suffix}")
    except OSError as exc:
        raise OutputError(f"{path}: could not be written ({exc.strerror or exc})") from None
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


@contextmanager
def _folder_lock(folder: Path) -> Iterator[None]:
    """An exclusive lock (``flock``) on ``folder`` itself while the block runs: writers of
    sets in one folder rename their files one set after the other."""
    import fcntl

    fd = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


@contextmanager
def atomic_set(paths: Sequence[str | Path]) -> Iterator[list[Path]]:
    """Temporary paths (:func:`temp_beside`) for files written together; when the block
    succeeds every file is flushed, then all are renamed into place while their folders are
    locked (two commands writing the same set never leave files of both); on any error, or
    when a destination is a folder, none is replaced and the temporary files are removed.

    Raises
    ------
    OutputError
        A file could not be written; the message names it and says none was replaced.
    """
    paths = [Path(p) for p in paths]
    tmps: list[Path] = []

    def fail(path: Path, why: str) -> OutputError:
        return OutputError(f"{path}: could not be written ({why}); none of "
                           f"{', '.join(p.name for p in paths)} was replaced")

    try:
        for p in paths:
            try:
                tmps.append(temp_beside(p, f".part{p.suffix}"))
            except OSError as exc:
                raise fail(p, exc.strerror or str(exc)) from None
        yield list(tmps)
        for p, tmp in zip(paths, tmps):
            if p.is_dir():
                raise fail(p, "it is a folder")
            try:
                with open(tmp, "rb+") as fh:
                    os.fsync(fh.fileno())
                os.chmod(tmp, FILE_MODE)
            except OSError as exc:
                raise fail(p, exc.strerror or str(exc)) from None
        with ExitStack() as locks:
            for folder in sorted({p.parent.resolve() for p in paths}):
                locks.enter_context(_folder_lock(folder))
            for p, tmp in zip(paths, tmps):
                try:
                    os.replace(tmp, p)
                except OSError as exc:  # a destination that changed meanwhile
                    raise OutputError(f"{p}: could not be written ({exc.strerror or exc}); "
                                      "the files before it in the set were replaced") from None
    finally:
        for tmp in tmps:
            tmp.unlink(missing_ok=True)


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


__all__ = ["atomic_path", "atomic_set", "write_atomic", "write_json", "temp_beside", "pid_alive",
           "clean_leftovers", "OutputError", "FILE_MODE"]
