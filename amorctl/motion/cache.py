"""The per-user cache of preprocessed datasets (``amorctl train`` uses it for the built-in clips).

Every cached file ``F`` has a sidecar ``F.sha256`` with the SHA-256 of its bytes, written when it
was built. Each use checks the file against it: a cached file that was damaged or edited since
(a crash of the disk, a stray tool, a truncated copy) is rebuilt with a ``note:`` line instead of
failing the command. A file cached before sidecars existed is checked once by its own content
hashes (:func:`~amorctl.motion.dataset.load_dataset`) and then gets its sidecar. A cache folder
nothing can be written into is refused with one line before any preprocessing starts.
"""

from __future__ import annotations

import contextlib
import os
import warnings
from collections.abc import Callable
from pathlib import Path

from amorctl.core.errors import AmorError, AmorNote
from amorctl.core.files import atomic_write_text, check_writable, file_sha256
from amorctl.motion.dataset import load_dataset
from amorctl.motion.preprocess import Progress, preprocess
from amorctl.motion.vae import VaeConfig

CACHE_ENV = "AMORCTL_CACHE_DIR"
#: Bumped whenever preprocessing changes what it writes, so stale cached datasets are rebuilt.
PIPELINE_VERSION = 1
#: suffix of the file holding a cached file's SHA-256
HASH_SUFFIX = ".sha256"


def cache_dir() -> Path:
    """``$AMORCTL_CACHE_DIR`` or ``~/.cache/amorctl``."""
    env = os.environ.get(CACHE_ENV)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "amorctl"


def default_dataset(character: str, progress: Progress | None = None, vae: VaeConfig | None = None) -> Path:
    """The built-in DeepMimic dataset for ``character``, preprocessed on first use (and again when
    the cached file is found damaged: :func:`cached`).

    Path: ``<cache>/datasets/<character>-deepmimic-v<PIPELINE_VERSION>.mcap``. Written atomically,
    so concurrent first uses at worst both build it.
    """
    path = cache_dir() / "datasets" / f"{character}-deepmimic-v{PIPELINE_VERSION}.mcap"

    def build(out: Path) -> None:
        preprocess(
            [], character=character, out=out, builtin="deepmimic", vae=vae or VaeConfig(), progress=progress
        )

    return cached(path, build, "the built-in dataset (a few minutes)")


def cached(path: Path, build: Callable[[Path], None], what: str = "it") -> Path:
    """``path`` when it is there and matches its recorded SHA-256; else build it (``build(path)``
    writes it atomically) and record its hash.

    Args:
        path: the cached file.
        build: writes the file at the path it is given.
        what: how to name the rebuild in the note ("the built-in dataset (minutes)").

    Raises:
        StorageError: the cache folder is not writable and the file must be built.
    """
    record = path.with_name(path.name + HASH_SUFFIX)
    if path.is_file():
        damage = _damage(path, record)
        if damage is None:
            return path
        warnings.warn(
            AmorNote(f"{path}: the cached file is damaged ({damage}); rebuilding {what}"), stacklevel=2
        )
    check_writable(path.parent, "dataset cache", f"make it writable or set {CACHE_ENV} to a writable folder")
    record.unlink(missing_ok=True)  # no stale hash beside a file being rebuilt
    build(path)
    atomic_write_text(record, file_sha256(path) + "\n")
    return path


def _damage(path: Path, record: Path) -> str | None:
    """What is wrong with a cached file (None: nothing): checked against its recorded SHA-256, or
    by its own content hashes when it has no record yet (then the record is written)."""
    try:
        expected = record.read_text(encoding="utf-8").strip() if record.is_file() else None
        if expected is not None:
            actual = file_sha256(path)
            return (
                None if actual == expected else "its SHA-256 differs from the one recorded when it was built"
            )
    except OSError as exc:
        return f"unreadable: {exc.strerror or exc}"
    try:  # cached before hash records existed: the dataset's own hashes decide, once
        load_dataset(path)
    except AmorError as err:
        return str(err).removeprefix(f"{path}: ")
    with contextlib.suppress(AmorError, OSError):  # a read-only cache still serves its verified file
        atomic_write_text(record, file_sha256(path) + "\n")
    return None
