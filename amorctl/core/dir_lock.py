"""One writer per directory: the lock ``amorctl train`` and ``amorctl hlp train`` hold on the run
(or HLP) directory they write.

``<dir>/.amorctl.lock`` is locked with ``fcntl.flock`` (exclusive, non-blocking) and holds the
holder's PID, host, command and start time as JSON. A second writer is refused with one line
naming that PID. The kernel drops a flock when its process dies, however it dies (``kill -9``
included), so a lock file left behind by a killed process is simply taken over; its old content
then becomes a ``note:`` saying which process left it. The file is removed when the lock is
released. Why flock and not the ``filelock`` package: see docs/train.md ("One writer per run").
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from amorctl.core.errors import AmorError, AmorNote
from amorctl.core.files import check_writable, storage_error

LOCK_FILE = ".amorctl.lock"

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no flock; directories are not locked there
    fcntl = None  # type: ignore[assignment]


def pid_alive(pid: int) -> bool:
    """Whether a process with this PID exists on this machine."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def read_holder(path: Path) -> dict[str, Any]:
    """The JSON a lock file holds ({} when it is empty, unreadable or not ours)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _holder_text(holder: dict[str, Any]) -> str:
    pid = holder.get("pid")
    who = f"process {pid}" if isinstance(pid, int) else "another process"
    if holder.get("host") not in (None, socket.gethostname()):
        who += f" on {holder['host']}"
    return who


@contextlib.contextmanager
def dir_lock(folder: str | os.PathLike[str], what: str = "run directory") -> Iterator[Path]:
    """Hold the exclusive write lock of ``folder`` (created if missing) for the block.

    Args:
        folder: the directory to lock.
        what: how to name it in messages.

    Yields:
        the lock file's path.

    Raises:
        AmorError: another live process holds the lock (the message names its PID and the lock
            file), or the lock file cannot be created (a read-only folder, ...).
    """
    folder = Path(folder)
    path = folder / LOCK_FILE
    if fcntl is None:  # pragma: no cover
        yield path
        return
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd = _acquire(path, folder, what)
    except OSError as exc:
        raise AmorError(
            f"{path}: cannot create the lock file of the {what} ({exc.strerror or exc})"
        ) from None
    try:
        previous = read_holder(path)
        try:
            os.ftruncate(fd, 0)
            os.write(fd, _holder_json().encode())
        except OSError as exc:  # e.g. a full disk: one line naming the lock file
            raise (storage_error(exc, path) or exc) from None
        old_pid = previous.get("pid")
        if isinstance(old_pid, int) and old_pid != os.getpid():
            gone = "is no longer running" if not pid_alive(old_pid) else "no longer holds it"
            warnings.warn(
                AmorNote(
                    f"{path}: recovered a stale lock left by {_holder_text(previous)} "
                    f"(it {gone}; killed or crashed?)"
                ),
                stacklevel=3,
            )
        yield path
    finally:
        with contextlib.suppress(OSError):
            if _same_file(fd, path):  # never remove a lock file another process has made since
                path.unlink()
        os.close(fd)  # releases the flock


@contextlib.contextmanager
def writing_into(folder: str | os.PathLike[str], what: str, todo: str = "") -> Iterator[None]:
    """The boundary of a command that writes into ``folder``: refuse a read-only folder
    (:func:`~amorctl.core.files.check_writable`) and a second writer (:func:`dir_lock`) before any
    work starts; if the block fails and this call created ``folder``, remove it when it is empty.

    Raises:
        StorageError: ``folder`` is not writable.
        AmorError: another process holds its lock.
    """
    folder = Path(folder)
    created = [p for p in (folder, *folder.parents) if not p.exists()]  # deepest first
    check_writable(folder, what, todo)
    try:
        with dir_lock(folder, what):
            yield
    except BaseException:
        with contextlib.suppress(OSError):
            for made in created:
                made.rmdir()  # only when empty: a run that wrote files cleans up after itself
        raise


def _acquire(path: Path, folder: Path, what: str) -> int:
    """Open and flock ``path`` exclusively; its descriptor, or the one-line refusal naming the holder."""
    assert fcntl is not None
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            holder = read_holder(path)
            since = f", since {holder['started']}" if isinstance(holder.get("started"), str) else ""
            command = f": {holder['command']}" if isinstance(holder.get("command"), str) else ""
            pid = holder.get("pid")
            stop = f" (kill {pid})" if isinstance(pid, int) else ""
            raise AmorError(
                f"{folder} is in use by {_holder_text(holder)} (lock file {path}{since}{command}); "
                f"wait for it to finish or stop it{stop}, then run again; two writers would corrupt "
                f"the {what}"
            ) from None
        except BaseException:
            os.close(fd)
            raise
        if _same_file(fd, path):
            return fd
        os.close(fd)  # the holder removed the file between our open and our flock: lock the new one


def _same_file(fd: int, path: Path) -> bool:
    """Whether ``path`` still names the file open as ``fd``."""
    try:
        a, b = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _holder_json() -> str:
    return json.dumps(
        {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "command": " ".join(["amorctl", *sys.argv[1:]])[:300],
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
    )
