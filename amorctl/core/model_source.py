"""Where a character's model file comes from: a path, or a lazy reference resolved on first use.

A plugin gives ``CharacterSpec.mjcf_path`` as a :data:`ModelSource`. Paths are used as they are;
a zero-argument callable (e.g. :func:`package_model`: a file inside another installed package) is
called only when the model is first needed (compiling it, checking it, exporting it), so loading
the plugin registry never touches a model file and a missing model fails only the commands that
use that character, with one :class:`~amorctl.core.errors.AmorError` line naming the character
and the file or package (docs/plugins.md, "Model files").
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from amorctl.core.errors import AmorError

#: What a plugin may give as a character's model file: a path, or a zero-argument callable that
#: returns one when the model is first needed (e.g. :class:`PackageModel`, a model shipped by
#: another installed package), so registering the character touches no file.
ModelSource = Path | str | Callable[[], Path | str]


def find_package_file(package: str, *parts: str) -> Path:
    """The path of a file shipped inside an installed package, found without importing it.

    Raises:
        AmorError: the package is not installed, or the file is not in it.
    """
    try:
        found = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        found = None
    if found is None or not found.submodule_search_locations:
        raise AmorError(f"package {package!r} is not installed (pip install it): it holds {'/'.join(parts)}")
    for root in found.submodule_search_locations:
        path = Path(root).joinpath(*parts)
        if path.exists():
            return path
    raise AmorError(f"package {package!r} has no file {'/'.join(parts)}")


@dataclass(frozen=True)
class PackageModel:
    """A lazy reference to a model file inside another installed package: calling it finds the
    file (:func:`find_package_file`). Give it as ``CharacterSpec.mjcf_path``."""

    package: str
    parts: tuple[str, ...]

    def __call__(self) -> Path:
        return find_package_file(self.package, *self.parts)

    def __str__(self) -> str:
        return f"{'/'.join(self.parts)} in package {self.package}"


def package_model(package: str, *parts: str) -> PackageModel:
    """``package_model("robot_descriptions_pkg", "t1", "t1.xml")``: a :class:`PackageModel`."""
    return PackageModel(package, tuple(parts))


def describe_model_source(source: ModelSource) -> str:
    """A model source as text, without resolving it (listings, error messages)."""
    return (
        str(source)
        if isinstance(source, (Path, str, PackageModel))
        else f"<{getattr(source, '__qualname__', type(source).__name__)}()>"
    )


def resolve_model_source(source: ModelSource, character: str) -> Path:
    """The model path of ``source``: a path as it is; a callable is called (once per spec, by
    :class:`CharacterSpec`) and its file must exist.

    Raises:
        AmorError: the callable fails or names no file; one line naming the character.
    """
    if isinstance(source, (Path, str)):
        return Path(source)
    what = describe_model_source(source)
    try:
        path = source()
    except AmorError as exc:
        raise AmorError(f"character {character!r}: model file {what}: {exc}") from None
    except Exception as exc:  # a plugin's resolver: any failure is the user's missing model
        raise AmorError(
            f"character {character!r}: model file {what} cannot be resolved ({type(exc).__name__}: {exc})"
        ) from None
    if not isinstance(path, (Path, str)) or not Path(path).is_file():
        raise AmorError(
            f"character {character!r}: model file {what} resolved to {path!r}, which is not a file"
        )
    return Path(path)


class _ModelPathField:
    """The ``mjcf_path`` field of :class:`CharacterSpec`: keeps the plugin's :data:`ModelSource`
    and resolves it on first read (then cached), so registration never touches the file."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.source, self.resolved = f"_{name}_source", f"_{name}_resolved"

    def __get__(self, obj: Any, objtype: type | None = None) -> Path:
        if obj is None:
            raise AttributeError("mjcf_path")  # dataclasses: the field has no default
        cached = obj.__dict__.get(self.resolved)
        if cached is None:
            cached = resolve_model_source(obj.__dict__[self.source], obj.name)
            obj.__dict__[self.resolved] = cached
        return cached

    def __set__(self, obj: Any, value: ModelSource) -> None:
        obj.__dict__[self.source] = value
        obj.__dict__.pop(self.resolved, None)
