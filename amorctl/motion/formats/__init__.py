"""The importer interface and the registry of importers by format name.

An importer turns one file into a :class:`SourceMotion` (to be retargeted) or a
:class:`CharacterMotion` (already in a character's joints). Built-in formats register here on
import; a plugin adds one with :func:`register_importer`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from amorctl.core.errors import AmorError
from amorctl.motion.source import CharacterMotion, SourceMotion


@dataclass(frozen=True)
class ImportOptions:
    """What an importer may need besides the file.

    name: clip name to give (default: the file stem); joint_map: path of a TOML joint map (BVH);
    character: target character name (formats already in a character's joints check against it);
    joint_names: that character's actuated joints, in order; root_body: its root body name;
    licence: recorded in the dataset.
    """

    name: str | None = None
    joint_map: Path | None = None
    character: str | None = None
    joint_names: tuple[str, ...] = ()
    root_body: str | None = None
    licence: str = "unknown (user-supplied file)"
    extra: dict[str, Any] = field(default_factory=dict)


Loader = Callable[[Path, ImportOptions], "SourceMotion | CharacterMotion"]


@dataclass(frozen=True)
class Importer:
    """A file format: its name, the file suffixes that imply it, and the loader."""

    name: str
    suffixes: tuple[str, ...]
    load: Loader
    description: str = ""


_IMPORTERS: dict[str, Importer] = {}


def register_importer(importer: Importer) -> None:
    """Add a format; a second importer with the same name is an error."""
    if importer.name in _IMPORTERS and _IMPORTERS[importer.name] is not importer:
        raise AmorError(f"motion importer {importer.name!r} is registered twice")
    _IMPORTERS[importer.name] = importer


def _ensure_builtins() -> None:
    # Importing the modules registers them.
    from amorctl.motion.formats import bvh, deepmimic, npz  # noqa: F401


def importers() -> dict[str, Importer]:
    """All registered importers by format name."""
    _ensure_builtins()
    return dict(_IMPORTERS)


def get_importer(fmt: str) -> Importer:
    """The importer for a format name; AmorError listing the known ones otherwise."""
    known = importers()
    if fmt not in known:
        raise AmorError(f"unknown motion format {fmt!r}; known formats: {', '.join(sorted(known))}")
    return known[fmt]


def infer_format(path: Path) -> str:
    """The format implied by a file's suffix (``.txt``/``.json`` DeepMimic, ``.bvh``, ``.npz``)."""
    suffix = path.suffix.lower()
    for imp in importers().values():
        if suffix in imp.suffixes:
            return imp.name
    raise AmorError(f"{path}: cannot tell the motion format from the suffix {suffix!r}; pass --format")


def import_file(path: Path, fmt: str | None, options: ImportOptions) -> SourceMotion | CharacterMotion:
    """Load one motion file with the named (or inferred) importer."""
    path = Path(path)
    if not path.is_file():
        raise AmorError(f"{path}: motion file not found")
    importer = get_importer(fmt) if fmt else get_importer(infer_format(path))
    return importer.load(path, options)


def file_sha256(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
