"""The per-user cache of preprocessed built-in datasets (``amorctl train`` uses it)."""

from __future__ import annotations

import os
from pathlib import Path

from amorctl.motion.preprocess import Progress, preprocess
from amorctl.motion.vae import VaeConfig

CACHE_ENV = "AMORCTL_CACHE_DIR"
#: Bumped whenever preprocessing changes what it writes, so stale cached datasets are rebuilt.
PIPELINE_VERSION = 1


def cache_dir() -> Path:
    """``$AMORCTL_CACHE_DIR`` or ``~/.cache/amorctl``."""
    env = os.environ.get(CACHE_ENV)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "amorctl"


def default_dataset(character: str, progress: Progress | None = None, vae: VaeConfig | None = None) -> Path:
    """The built-in DeepMimic dataset for ``character``, preprocessed on first use.

    Path: ``<cache>/datasets/<character>-deepmimic-v<PIPELINE_VERSION>.mcap``. Written atomically,
    so concurrent first uses at worst both build it.
    """
    path = cache_dir() / "datasets" / f"{character}-deepmimic-v{PIPELINE_VERSION}.mcap"
    if not path.is_file():
        preprocess(
            [], character=character, out=path, builtin="deepmimic", vae=vae or VaeConfig(), progress=progress
        )
    return path
