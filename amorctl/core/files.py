"""Atomic file output (a temporary file beside the target, flushed to disk, renamed over it), the
one-line report of a write the storage refused (disk full, quota, read-only), and the probe that
finds a read-only directory before any work starts."""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from amorctl.core.errors import AmorError

#: errno of a write the storage refused -> how to say it (the errors a full disk, an exhausted
#: quota, a read-only mount or missing permissions give on write, fsync, rename or create)
STORAGE_ERRNOS = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large for the file system",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
}
#: those that only a write gives (EACCES / EPERM may come from reading too)
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS})


class StorageError(AmorError):
    """A write that the storage refused (disk full, quota, read-only, permissions): ``path`` is the
    file or folder, ``reason`` the errno's wording, ``fix`` what to do ("free space there").
    Nothing partial is left where it is raised."""

    def __init__(self, path: str | os.PathLike[str], reason: str, message: str, fix: str = "") -> None:
        super().__init__(message)
        self.path = Path(path)
        self.reason = reason
        self.fix = fix or "make it writable"


def storage_error(exc: OSError, path: str | os.PathLike[str] | None = None) -> StorageError | None:
    """The :class:`StorageError` for ``exc`` when it is a refused write (None otherwise): names the
    file (``path``, else the one the OS named) and what to do."""
    reason = STORAGE_ERRNOS.get(exc.errno or 0)
    if reason is None:
        return None
    where = Path(path) if path is not None else Path(exc.filename or "?")
    full = exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
    fix = "free space there" if full else "make it writable"
    return StorageError(
        where, reason, f"{where}: cannot write ({reason}); {fix} (or write elsewhere) and run again", fix
    )


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path in the target's directory; on success flush it to disk (fsync) and
    rename it onto ``path``.

    If the body raises (or is interrupted), the temporary file is removed and ``path`` is left as
    it was, so readers never see a half-written file.

    Raises:
        StorageError: the storage refused the write (disk full, quota, read-only, permissions),
            in the body, the flush or the rename; ``path`` is unchanged and no temporary is left.
    """
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    except OSError as exc:
        raise (storage_error(exc, target) or exc) from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        _fsync(tmp)  # a full disk may only say so here (delayed allocation, network file systems)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600 files; give the usual permissions
        os.replace(tmp, target)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        err = storage_error(exc, target)
        if err is None:
            raise
        raise err from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _fsync(path: Path) -> None:
    """Flush ``path``'s data to the storage (so a rename never publishes a file the disk lacks)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (:func:`atomic_path`)."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def file_sha256(path: str | os.PathLike[str]) -> str:
    """SHA-256 of a file's bytes (hex), read in 1 MiB chunks."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def check_writable(folder: str | os.PathLike[str], what: str, todo: str = "") -> None:
    """Refuse a folder nothing can be written into, before any work that would write there starts.

    Probes by creating (and removing) a temporary file in ``folder``, or in its nearest existing
    parent when it does not exist yet (it will be created there): permission bits alone do not
    tell (root ignores them; a read-only mount refuses root too).

    Args:
        folder: where the command will write.
        what: how to name it to the user (e.g. "run directory", "dataset cache").
        todo: what to do instead (default: make it writable or choose another place).

    Raises:
        StorageError: one line naming the folder, the reason and what to do.
    """
    probe_in = Path(folder)
    while not probe_in.exists() and probe_in.parent != probe_in:
        probe_in = probe_in.parent
    try:
        if not probe_in.is_dir():
            return  # a file in the way: the command's own check names it
        fd, name = tempfile.mkstemp(prefix=".amorctl-write-probe.", dir=probe_in)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        reason = STORAGE_ERRNOS.get(exc.errno or 0, exc.strerror or str(exc))
        fix = todo or "make it writable or choose another place"
        raise StorageError(
            folder, reason, f"{folder}: the {what} is not writable ({reason}); {fix}"
        ) from None
