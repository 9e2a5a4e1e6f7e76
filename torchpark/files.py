"""Files written whole or not at all, and directories written by one run at a time.

Every file torchpark and its trainers write (checkpoints, tables, videos, pictures) is
written under a hidden temporary name in its own directory, flushed to disk, then moved over
its final name with ``os.replace`` (atomic on POSIX): a process killed at any instant, or a
full disk, leaves the final name holding the previous file whole, or nothing. A failed write
is an :class:`WriteError`, one line naming the file.

A run's directory is locked (an advisory ``fcntl`` lock through the ``filelock`` package, on
``.torchpark.lock`` inside it) for as long as the run writes into it; a second run is
refused by name, and the lock goes with the process however it ends.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import os
import secrets
from collections.abc import Callable, Iterator
from pathlib import Path

import filelock

LOCK_NAME = ".torchpark.lock"
# Temporary files carry this in their (hidden) names: .NAME.torchpark-tmp-HEX.SUFFIX
_TMP_MARK = ".torchpark-tmp-"


class WriteError(OSError):
    """A file could not be written (a full disk, a file size limit, no permission...); the
    file's previous content, if any, is untouched."""


class DirectoryInUse(ValueError):
    """Another process holds the run directory's lock."""


def _first_line(err: BaseException) -> str:
    """What went wrong, in one line: the system's words for an OSError ("No space left on
    device"), else the error's first line."""
    if isinstance(err, OSError) and err.strerror:
        return err.strerror
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def _fsync(path: Path, directory: bool = False) -> None:
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """Write ``path`` whole or not at all: yields a temporary path in the same directory,
    with the same suffix (so writers that read the format from it still do); once the block
    has written it, it is flushed to disk and moved over ``path``. If the block raises, or
    the move fails, the temporary file is removed and ``path`` is left as it was; an
    ``OSError`` (a full disk: ENOSPC; a size limit: EFBIG) becomes a :class:`WriteError`
    naming ``path``."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}{_TMP_MARK}{secrets.token_hex(4)}{path.suffix}")
    try:
        yield tmp
        _fsync(tmp)
        os.replace(tmp, path)
    except BaseException as err:
        tmp.unlink(missing_ok=True)
        if isinstance(err, OSError) and not isinstance(err, WriteError):
            raise WriteError(f"cannot write {str(path)!r}: {_first_line(err)}") from None
        raise
    with contextlib.suppress(OSError):  # the rename itself on disk (not every FS allows it)
        _fsync(path.parent, directory=True)


def write_file(path: str | Path, write: Callable[[Path], object]) -> Path:
    """``write(tmp)`` writes the file at ``tmp``; it lands at ``path`` whole (see
    :func:`replacing`). A writer that reports a failed write as RuntimeError (as writers
    that drive a native library or a subprocess may) is a :class:`WriteError` too. Returns
    ``path``."""
    path = Path(path)
    with replacing(path) as tmp:
        try:
            write(tmp)
        except RuntimeError as err:
            raise WriteError(f"cannot write {str(path)!r}: {_first_line(err)}") from None
    return path


def write_text(path: str | Path, text: str) -> Path:
    """``text`` (UTF-8) to ``path``, whole or not at all."""
    return write_file(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def write_csv(path: str | Path, rows: list[dict], fieldnames: list[str] | tuple[str, ...]
              ) -> Path:
    """``rows`` under a header of ``fieldnames`` (csv.DictWriter) to ``path``, whole or not
    at all."""
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=fieldnames)
    writer.writeheader()
    writer.writerows(rows)
    return write_text(path, text.getvalue())


def save_torch(obj: object, path: str | Path) -> Path:
    """``torch.save(obj)`` to ``path``, whole or not at all. Serialised in memory first:
    torch's own file writer reports a full disk as "unexpected pos", a plain write as the
    system's error (ENOSPC, EFBIG)."""
    import torch

    data = io.BytesIO()
    torch.save(obj, data)
    return write_file(path, lambda tmp: tmp.write_bytes(data.getbuffer()))


def stale_temporaries(directory: str | Path) -> list[Path]:
    """Temporary files that a killed writer left in ``directory``."""
    return sorted(Path(directory).glob(f".*{_TMP_MARK}*"))


@contextlib.contextmanager
def locked(directory: str | Path, name: str = "directory") -> Iterator[Path]:
    """Create ``directory`` (and its parents) and hold its lock for the block; yields the
    directory. :class:`DirectoryInUse` (a ValueError) naming ``name`` when another process
    holds it; ValueError when it cannot be made or written. Temporary files that a killed
    writer left there are removed once the lock is held (no one else writes them)."""
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ValueError(f"{name} {str(directory)!r} cannot be created: "
                         f"{_first_line(err)}") from None
    if not os.access(directory, os.W_OK | os.X_OK):
        raise ValueError(f"{name} {str(directory)!r} is not writable")
    lock = filelock.FileLock(directory / LOCK_NAME, timeout=0)
    try:
        lock.acquire()
    except filelock.Timeout:
        raise DirectoryInUse(f"{name} {str(directory)!r} is in use by another run (it holds "
                             f"{LOCK_NAME}): wait for it to end, or choose another "
                             f"directory") from None
    except OSError as err:
        raise ValueError(f"{name} {str(directory)!r} cannot be locked: "
                         f"{_first_line(err)}") from None
    try:
        for tmp in stale_temporaries(directory):
            tmp.unlink(missing_ok=True)
        yield directory
    finally:
        lock.release()


def directory_arg(text: str) -> Path:
    """A command line's directory argument (argparse ``type=``): a path, never empty (an
    empty ``--out ''`` would otherwise be the working directory, or nothing at all)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"must name a directory, got {text!r}")
    return Path(text)
