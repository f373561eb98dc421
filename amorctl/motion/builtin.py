"""The built-in motion sets: the 20 DeepMimic clips shipped in the ``pybullet_data`` package."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from amorctl.core.errors import AmorError

BUILTIN_SETS: tuple[str, ...] = ("deepmimic",)


def pybullet_data_path() -> Path | None:
    """The ``pybullet_data`` folder, found without importing pybullet itself; None if absent."""
    spec = importlib.util.find_spec("pybullet_data")
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))


def deepmimic_clips() -> list[tuple[str, Path]]:
    """(short name, path) of every built-in DeepMimic clip, sorted by name.

    ``humanoid3d_walk.txt`` -> ``walk``; ``walker/turn_left0.txt`` -> ``walker/turn_left0``.
    """
    root = pybullet_data_path()
    if root is None:
        raise AmorError("the built-in DeepMimic clips need the 'pybullet' package (pip install pybullet)")
    motions = root / "data" / "motions"
    clips = [(p.stem.removeprefix("humanoid3d_"), p) for p in motions.glob("humanoid3d_*.txt")]
    clips += [(f"walker/{p.stem}", p) for p in (motions / "walker").glob("*.txt")]
    if not clips:
        raise AmorError(f"{motions}: no DeepMimic clips found in the installed pybullet_data")
    return sorted(clips)


def builtin_clips(name: str) -> list[tuple[str, Path]]:
    """The clips of a built-in set by its name."""
    if name == "deepmimic":
        return deepmimic_clips()
    raise AmorError(f"unknown built-in motion set {name!r}; known: {', '.join(BUILTIN_SETS)}")


def source_label(path: Path) -> str:
    """A path as recorded in datasets: relative to pybullet_data when it lies inside it."""
    root = pybullet_data_path()
    try:
        if root is not None:
            return "pybullet_data/" + Path(path).resolve().relative_to(root.resolve()).as_posix()
    except ValueError:
        pass
    return str(path)
