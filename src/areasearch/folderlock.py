"""One process at a time in a results folder (``areasearch eval --out``, ``areasearch train --out``).

:func:`hold_folder` takes an exclusive ``fcntl.flock`` on the folder's lock file
(:data:`LOCK_FILE`) for as long as a command works in the folder. The lock belongs to the open file,
so the kernel releases it when the process ends in any way (a SIGKILL or a crash never leaves a
stale lock); the file's first line names the owner's pid, and a second process is refused at once
with one message naming the folder and that pid. On a clean exit the lock file is removed (after
the lock is taken, the file is checked to still be the one at the path, so removing it races with
no other process), and so are the folders :func:`hold_folder` created when they are left empty (a
command refused on bad input leaves nothing behind). A folder in which no lock file can be made (a
read-only file system, no write permission) is held without one: the command can only read there
(a finished evaluation is summarised), and a write it tries fails with one message.

:func:`check_folder_path` and :func:`check_file_path` say, before any work, why a folder could not
be made or a file written at a path (an existing file or folder there, a file where one of its
parents should be, a device, a named pipe or a socket that a write would replace, a path no system
call takes: :func:`areasearch.inputs.check_output_path`).

:func:`atomic_path` and :func:`write_atomic` write a whole file atomically: into a temporary file
beside it, fsync'ed, then renamed over it. A write that fails (file too large, disk full, read-only
file system) removes the temporary file, leaves the file as it was and raises one AreaSearchError
naming the path and the reason; a file that already holds the bytes is not written again, so a
finished folder on read-only media can still be summarised.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import os
import socket
import sys
from collections.abc import Iterator
from pathlib import Path

from .errors import AreaSearchError
from .inputs import MAX_NAME_BYTES, check_output_path, check_path, special_kind, write_error

LOCK_FILE = ".areasearch.lock"
"""Name of the lock file in a locked folder."""

_HELD: dict[str, int] = {}
"""Folders this process holds (resolved path -> nesting depth): holding one again is a no-op."""


class FolderInUse(AreaSearchError):
    """Another process holds the folder (:func:`hold_folder`)."""


def check_folder_path(folder: Path, what: str) -> None:
    """AreaSearchError unless a folder exists at ``folder`` or can be made there: ``"<folder>: <what>
    is an existing file; give a folder"``, or the parent that is a file."""
    folder = check_path(folder, what)
    try:
        kind = special_kind(os.stat(folder))
    except OSError:
        kind = None
    if kind is not None:
        raise AreaSearchError(f"{folder}: {what} is {kind}; give a folder")
    if folder.exists() and not folder.is_dir():
        raise AreaSearchError(f"{folder}: {what} is an existing file; give a folder")
    if os.path.lexists(folder) and not folder.exists():
        raise AreaSearchError(f"{folder}: {what} is a broken symbolic link or a link loop")
    for parent in folder.absolute().parents:
        if os.path.lexists(parent):
            if not parent.is_dir():
                raise AreaSearchError(f"{folder}: cannot make the folder there: {parent} is a file, not a folder")
            if not os.access(parent, os.W_OK | os.X_OK) and not folder.exists():
                raise AreaSearchError(f"{folder}: cannot make the folder there: {parent} is not writable")
            return


def check_file_path(path: Path, what: str) -> None:
    """AreaSearchError unless a file can be written at ``path``: not a folder, in a folder that exists
    (the message names a file standing where a parent folder should be), not a device, a named pipe
    or a socket (:func:`areasearch.inputs.check_output_path`: the atomic write would replace it)."""
    path = check_output_path(path, what)
    if path.is_dir():
        raise AreaSearchError(f"{path}: {what} path is a folder; give a file name")
    parent = path.parent
    if parent.is_dir():
        return
    for ancestor in path.absolute().parents:
        if os.path.lexists(ancestor):
            if not ancestor.is_dir():
                raise AreaSearchError(f"{path}: cannot write the {what} there: {ancestor} is a file, not a folder")
            break
    raise AreaSearchError(f"{parent}: folder for the {what} does not exist")


def _temporary(path: Path) -> Path:
    """The temporary file of an atomic write of ``path``: ``.<name>.tmp`` beside it, or a name made from
    a hash of the name when that would be longer than a file name may be."""
    name = f".{path.name}.tmp"
    if len(os.fsencode(name)) > MAX_NAME_BYTES:
        name = f".areasearch-{hashlib.sha256(os.fsencode(path.name)).hexdigest()[:16]}.tmp"
    return path.with_name(name)


@contextlib.contextmanager
def atomic_path(path: str | Path, what: str = "file") -> Iterator[Path]:
    """A temporary path beside ``path`` for the block to write the whole file to; when the block ends
    the file is fsync'ed and renamed over ``path``. ``path`` must not be a device, a named pipe or a
    socket (:func:`areasearch.inputs.check_output_path`). On an error (in the block or after it) the
    temporary file is removed and ``path`` is left as it was; an OSError becomes one AreaSearchError
    naming ``path`` and the reason (:func:`areasearch.inputs.write_error`)."""
    path = check_output_path(path, what)
    tmp = _temporary(path)
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY | os.O_CLOEXEC)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise AreaSearchError(write_error(path, exc, what)) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_atomic(path: str | Path, data: bytes, what: str = "file") -> Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_path`); a regular file there that already
    holds exactly ``data`` is left alone (nothing is written: a re-run on read-only media works)."""
    path = Path(path)
    with contextlib.suppress(OSError):
        if path.is_file() and path.stat().st_size == len(data) and path.read_bytes() == data:
            return path
    with atomic_path(path, what) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
    return path


def _owner(fd: int) -> str:
    """The pid in a lock file (its first line), or "unknown" (the owner has not written it yet)."""
    try:
        text = os.pread(fd, 200, 0).decode("utf-8", "replace")
    except OSError:
        return "unknown"
    first = text.split("\n", 1)[0].strip()
    return first if first.isdigit() else "unknown"


def _lock(path: Path, folder: Path) -> int:
    """An open descriptor of ``path`` holding an exclusive flock; FolderInUse when another process has it."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = _owner(fd)
            os.close(fd)
            raise FolderInUse(
                f"{folder}: in use by another areasearch process (pid {owner}); wait for it to end, or use "
                "another folder"
            ) from None
        except BaseException:
            os.close(fd)
            raise
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:  # else the owner removed it while releasing: take the new file
            return fd
        os.close(fd)


@contextlib.contextmanager
def hold_folder(folder: str | Path, what: str = "folder") -> Iterator[Path]:
    """Hold ``folder`` (made with its parents when missing) for this process while the block runs;
    FolderInUse naming the folder and the owner's pid when another process holds it. Nested holds of
    one folder in one process are allowed. On exit the lock is released and its file removed, and
    the folders made here are removed again when empty."""
    folder = Path(folder).expanduser()
    check_folder_path(folder, what)
    key = os.path.realpath(folder)
    if key in _HELD:
        _HELD[key] += 1
        try:
            yield folder
        finally:
            _HELD[key] -= 1
        return
    made = [p for p in (folder, *folder.absolute().parents) if not os.path.lexists(p)]
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_FILE
    try:
        fd = _lock(path, folder)
    except OSError as exc:
        if made or exc.errno not in (errno.EROFS, errno.EACCES, errno.EPERM):
            _remove_empty(made)
            raise AreaSearchError(write_error(path, exc, "lock file")) from None
        # no lock file can be made: read-only media or no write permission. This process cannot change the
        # folder, so it needs no lock to read it; any write it tries fails with its own message.
        _HELD[key] = 1
        try:
            yield folder
        finally:
            _HELD.pop(key, None)
        return
    except BaseException:
        _remove_empty(made)
        raise
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n{socket.gethostname()} {' '.join(sys.argv)[:500]}\n".encode(), 0)
        _HELD[key] = 1
        yield folder
    finally:
        _HELD.pop(key, None)
        with contextlib.suppress(OSError):
            os.unlink(path)  # still holding the lock: no other process can have taken this file
        os.close(fd)
        _remove_empty(made)


def _remove_empty(made: list[Path]) -> None:
    """Remove the folders in ``made`` (deepest first) that are empty."""
    for path in made:
        try:
            path.rmdir()
        except OSError:
            return
