"""Resolve a ``--motion NAME`` argument against clip names (shared by every command taking one)."""

from __future__ import annotations

from collections.abc import Sequence

from amorctl.core.errors import AmorError
from amorctl.motion.clips import ClipInfo, MotionLibrary


def resolve_name(query: str, names: Sequence[str], where: str = "the dataset") -> str:
    """The clip name ``query`` means: an exact name, else the one name it prefixes, else the one
    name it ends (at a ``/`` or ``_`` boundary or the whole last part). AmorError listing the
    candidates when it is ambiguous, or every name when nothing matches."""
    if query in names:
        return query
    prefix = [n for n in names if n.startswith(query)]
    if len(prefix) == 1:
        return prefix[0]
    suffix = [n for n in names if n.endswith(query)]
    if not prefix and len(suffix) == 1:
        return suffix[0]
    matches = prefix or suffix
    if matches:
        raise AmorError(f"motion {query!r} is ambiguous in {where}: it matches {', '.join(sorted(matches))}")
    raise AmorError(f"no motion {query!r} in {where}; clips: {', '.join(sorted(names))}")


def resolve_clip(library: MotionLibrary, query: str) -> ClipInfo:
    """The clip of ``library`` that ``query`` names (see :func:`resolve_name`)."""
    name = resolve_name(query, [c.name for c in library.clips], f"the {library.character} dataset")
    return next(c for c in library.clips if c.name == name)
