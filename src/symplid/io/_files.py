"""One way to write a file and one way to read a run's file, whatever the file system does.

Writing (:func:`write_bytes`, :func:`write_text`, :func:`write_with`)
--------------------------------------------------------------------
The content is made in memory first (a netCDF file, an archive, a figure, text), then written
to a hidden temporary file in the target's folder, flushed to the disk (``fsync``) and renamed
over the target (``os.replace``, atomic on POSIX). A reader therefore sees the old file or the
new one, never half of one. The file system's faults become one-line exceptions and the
temporary file is removed:

* a folder that cannot be written (``EACCES``, ``EPERM``, ``EROFS``: a read-only output folder
  or disk) is the user's to fix: :class:`UnwritableError`, a
  :class:`~symplid.model._data.DataError` (exit code 2 on the command line);
* a full disk, a file-size limit or an input/output error (``ENOSPC``, ``EDQUOT``, ``EFBIG``,
  ``EIO``) is the environment's: :class:`StorageError` (exit code 1).

Making the content in memory keeps library writers (HDF5 under netCDF, zlib, PNG) away from a
failing disk: HDF5 handled a write that failed with ``EFBIG`` badly (an unreadable temporary
file left behind, or a crash). ``SIGXFSZ``, whose default action kills a process that passes
its file-size limit, is ignored while writing, so that ``write()`` fails with ``EFBIG``
instead (Python ignores it from the start; a host program may not).

Reading (:func:`read_with`)
---------------------------
Any file that is missing, empty, truncated or otherwise unreadable becomes one
:class:`RunFolderError` line naming the file and what to do (``remedy``).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import io
import json
import os
import signal
import threading
import time
import tomllib
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO, TypeVar

from symplid.model._data import DataError

__all__ = [
    "UNREADABLE",
    "FolderLock",
    "FolderLockedError",
    "RunFolderError",
    "StorageError",
    "UnwritableError",
    "make_folder",
    "read_with",
    "write_bytes",
    "write_fault",
    "write_text",
    "write_with",
]

T = TypeVar("T")

#: errno values that mean "this place cannot be written": the user chose it, the user fixes it.
USER_FAULTS = frozenset({errno.EACCES, errno.EPERM, errno.EROFS})


class RunFolderError(DataError):
    """A run folder (or one of its files) that cannot be used: missing, unfinished, unreadable,
    not writable, ..."""


class UnwritableError(RunFolderError):
    """A file or folder that cannot be written: permission denied or a read-only file system."""


class StorageError(Exception):
    """The disk failed a write: full (``ENOSPC``, ``EDQUOT``), a file-size limit (``EFBIG``), an
    input/output error. Not the user's mistake: the command line exits with code 1."""

    exit_code = 1


def write_fault(path: Path, err: OSError) -> Exception:
    """The one-line exception for an ``OSError`` met while writing ``path``."""
    why = os.strerror(err.errno) if err.errno else str(err)
    if err.errno in USER_FAULTS:
        return UnwritableError(f"{path}: cannot write here ({why}); choose another output "
                               "folder or make this one writable")
    return StorageError(f"{path}: writing failed ({why}); free some space (or raise the file-"
                        "size limit) and run the command again")


@contextlib.contextmanager
def _file_size_signal_ignored() -> Iterator[None]:
    """``SIGXFSZ`` ignored (``write()`` then fails with ``EFBIG`` instead of killing us)."""
    if threading.current_thread() is not threading.main_thread():
        yield  # handlers can be set only in the main thread; Python ignores it already
        return
    old = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGXFSZ, old)


def make_folder(path: str | os.PathLike) -> Path:
    """``mkdir -p``, with the file system's refusals as one-line exceptions."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise RunFolderError(f"{path}: exists and is not a folder") from None
    except OSError as err:
        raise write_fault(path, err) from None
    return path


def write_bytes(path: str | os.PathLike, data: bytes, durable: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically and durably (see the module docstring).

    ``durable=False`` skips the two ``fsync`` calls (about 20 ms on a busy disk): the file is
    still whole or absent for every reader and survives its process however it ends, but a
    crash of the whole system may leave it empty or short. For files written often whose
    loss is detected and repaired (the sampler's chunk files, :mod:`symplid.io._chunks`).
    """
    path = Path(path)
    make_folder(path.parent)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with _file_size_signal_ignored():
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view):]
                if durable:
                    os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(tmp, path)
    except BaseException as err:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        if isinstance(err, OSError):
            raise write_fault(path, err) from None
        raise
    if durable:
        _sync_folder(path.parent)
    return path


def _sync_folder(folder: Path) -> None:
    """Make the rename durable (best effort: not every file system syncs folders)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write UTF-8 ``text`` atomically (:func:`write_bytes`)."""
    return write_bytes(path, text.encode("utf-8"))


def write_with(path: str | os.PathLike, produce: Callable[[BinaryIO], object],
               durable: bool = True) -> Path:
    """``produce(buffer)`` writes the content into memory; then :func:`write_bytes`."""
    buffer = io.BytesIO()
    produce(buffer)
    return write_bytes(path, buffer.getvalue(), durable)


#: What readers raise on a damaged file (HDF5 and JSON, TOML, ZIP and NumPy archives).
UNREADABLE = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, UnicodeDecodeError,
              json.JSONDecodeError, tomllib.TOMLDecodeError, RuntimeError)


def read_with(path: str | os.PathLike, reader: Callable[[Path], T], remedy: str) -> T:
    """``reader(path)``, with a missing, empty or unreadable file as one
    :class:`RunFolderError` line: ``<path>: <what is wrong>; <remedy>``.

    A reader's own one-line :class:`~symplid.model._data.DataError` (a data file's bad row,
    which names the file) gets ``remedy`` appended.
    """
    path = Path(path)
    try:
        if path.stat().st_size == 0:
            raise RunFolderError(f"{path}: the file is empty; {remedy}")
        return reader(path)
    except RunFolderError:
        raise
    except DataError as err:
        raise RunFolderError(f"{err}; {remedy}") from None
    except FileNotFoundError:
        raise RunFolderError(f"{path}: no such file; {remedy}") from None
    except UNREADABLE as err:
        raise RunFolderError(f"{path}: unreadable ({_first_line(err, path)}); {remedy}") from None


def _first_line(err: BaseException, path: Path) -> str:
    text = str(err).strip().splitlines()
    line = text[0].rstrip(" (") if text else type(err).__name__
    return line.removeprefix(f"{path}: ").split(". ")[0]  # its first sentence


# ----------------------------------------------------------------------------- the folder lock
class FolderLockedError(RunFolderError):
    """Another process holds the folder's lock (a run is writing it now)."""


class FolderLock:
    """An exclusive ``flock`` on ``<folder>/.lock``, held while one process writes the folder.

    The kernel releases it when the holder closes it or dies (even by SIGKILL), so a lock is
    never stale. The holder's pid is written into the file, for the message of those refused;
    the holder removes the file when it is done (a process that opened it just before checks,
    once it holds the lock, that the file it locked is still the one in the folder).
    """

    NAME = ".lock"

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        self.path = self.folder / self.NAME
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        """True while this object holds the lock."""
        return self._fd is not None

    def acquire(self) -> None:
        """Take the lock now, or raise :class:`FolderLockedError` (one line) at once."""
        for _ in range(5):
            if self._fd is not None:
                return
            self._try_acquire()
        raise FolderLockedError(f"{self.folder}: its lock file keeps changing; another "
                                "process is writing this run folder")

    def _try_acquire(self) -> None:
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            raise write_fault(self.folder, err) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise FolderLockedError(
                f"{self.folder}: another symplid process{self._holder()} is writing this run "
                "folder now; wait until it ends, or choose another output folder") from None
        try:  # the holder before us may have removed the file after we opened it
            current = os.stat(self.path)
        except FileNotFoundError:
            current = None
        mine = os.fstat(fd)
        if current is None or (current.st_ino, current.st_dev) != (mine.st_ino, mine.st_dev):
            os.close(fd)
            return
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd

    def release(self) -> None:
        """Give the lock up: the file is removed, then closed (which releases it)."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            with contextlib.suppress(OSError):
                self.path.unlink()
            os.close(fd)

    def held_elsewhere(self) -> bool:
        """True when another process (or another :class:`FolderLock`) holds the lock."""
        if self._fd is not None:
            return False
        try:
            fd = os.open(self.path, os.O_RDONLY)
        except OSError:
            return False
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        finally:
            os.close(fd)  # closing releases the shared lock taken to probe
        return False

    def holder(self) -> int | None:
        """The pid written by the holder (None when unknown)."""
        with contextlib.suppress(OSError, ValueError, IndexError):
            return int(self.path.read_text().split()[0])
        return None

    def _holder(self) -> str:
        """`` (pid N)`` for the message of a refusal; the holder writes its pid just after it
        takes the lock, so an empty file is read again for a moment."""
        for _ in range(50):
            pid = self.holder()
            if pid is not None:
                return f" (pid {pid})"
            time.sleep(0.01)
        return ""

    def __del__(self) -> None:
        self.release()
