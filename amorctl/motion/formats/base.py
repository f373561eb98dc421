"""What every motion importer shares: the options it receives, its spec, the file hash.

Importers (built-in or from plugins) import from here, never from the package
:mod:`amorctl.motion.formats`, which looks them up through the plugin registry.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from amorctl.core.specs import ImportOptions, MotionFormatSpec

__all__ = ["ImportOptions", "MotionFormatSpec", "file_sha256"]


def file_sha256(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
