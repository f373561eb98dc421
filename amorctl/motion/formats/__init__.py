"""Motion file formats, looked up by name or file suffix through the plugin registry.

A format is a :class:`~amorctl.core.specs.MotionFormatSpec` registered by a plugin's
``amorctl_register_motion_formats`` hook; the built-in ones (:mod:`.deepmimic`, :mod:`.bvh`,
:mod:`.npz`) are plugins named in ``[project.entry-points.amorctl]`` like any third-party format.
An importer turns one file into a :class:`SourceMotion` (to be retargeted) or a
:class:`CharacterMotion` (already in a character's joints).
"""

from __future__ import annotations

from pathlib import Path

from amorctl.core.errors import AmorError
from amorctl.motion.formats.base import ImportOptions, MotionFormatSpec, file_sha256
from amorctl.motion.source import CharacterMotion, SourceMotion
from amorctl.registry import get_registry

__all__ = [
    "ImportOptions",
    "MotionFormatSpec",
    "file_sha256",
    "get_importer",
    "import_file",
    "importers",
    "infer_format",
]


def importers() -> dict[str, MotionFormatSpec]:
    """All registered motion formats by name."""
    registry = get_registry()
    return {name: registry.motion_format(name) for name in registry.names("motion-format")}


def get_importer(fmt: str) -> MotionFormatSpec:
    """The format of that name; AmorError listing the known ones otherwise."""
    known = importers()
    if fmt not in known:
        raise AmorError(f"unknown motion format {fmt!r}; known formats: {', '.join(sorted(known))}")
    return known[fmt]


def infer_format(path: Path) -> str:
    """The format implied by a file's suffix (``.txt``/``.json`` DeepMimic, ``.bvh``, ``.npz``).

    Raises:
        AmorError: no format, or more than one, claims the suffix.
    """
    suffix = path.suffix.lower()
    claims = sorted(spec.name for spec in importers().values() if suffix in spec.suffixes)
    if not claims:
        raise AmorError(f"{path}: cannot tell the motion format from the suffix {suffix!r}; pass --format")
    if len(claims) > 1:
        raise AmorError(
            f"{path}: the suffix {suffix!r} is claimed by formats {', '.join(claims)}; pass --format"
        )
    return claims[0]


def import_file(path: Path, fmt: str | None, options: ImportOptions) -> SourceMotion | CharacterMotion:
    """Load one motion file with the named (or inferred) importer.

    Raises:
        AmorError: the file is missing, the format unknown, or the file defective.
        TypeError: the importer returned something other than a motion record (a plugin bug).
    """
    path = Path(path)
    if not path.is_file():
        raise AmorError(f"{path}: motion file not found")
    importer = get_importer(fmt) if fmt else get_importer(infer_format(path))
    motion = importer.load(path, options)
    if not isinstance(motion, (SourceMotion, CharacterMotion)):
        raise TypeError(
            f"motion format {importer.name!r} returned {type(motion).__name__} for {path}, "
            "expected SourceMotion or CharacterMotion"
        )
    return motion
