"""The files a MuJoCo model reads, found as MuJoCo finds them, and the licence that comes with them.

A deploy bundle carries its character's model (docs/deploy.md): the MJCF, every ``<include>``d
file, and every asset file the model references (meshes, skins and height fields under
``meshdir``, textures and cube-map faces under ``texturedir``; ``assetdir`` sets both), copied
byte for byte with their layout relative to each other, so the copy compiles to the same model
wherever it is. Includes are looked up as MuJoCo 4 does: relative to the main file's directory,
else to the including file's. :func:`model_files` lists them; the caller checks the copy by
compiling it (``amorctl.deploy.export_meta``).

Absolute paths in a model (an absolute ``meshdir``, ``file`` or include) would keep a copy tied to
this machine: they are refused, naming the file and what to change.
"""

from __future__ import annotations

import os
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import mujoco

from amorctl.core.errors import AmorError

#: File names (any suffix) taken for a model's licence, searched from the model's directory up.
LICENCE_STEMS = ("LICENSE", "LICENCE", "COPYING", "NOTICE")


@dataclass(frozen=True)
class ModelFiles:
    """What a model reads.

    Attributes:
        mjcf: the main model file (absolute).
        files: every file the model reads: the MJCF, its includes, then its assets (absolute).
        licences: licence files found beside the model or above it (absolute; may be empty).
        root: the deepest directory holding all of them: copy each to ``dest / path.relative_to(root)``.
    """

    mjcf: Path
    files: tuple[Path, ...]
    licences: tuple[Path, ...]
    root: Path

    def relative(self, path: Path) -> Path:
        """``path`` relative to :attr:`root`."""
        return path.relative_to(self.root)


def _refuse_absolute(xml: Path, what: str, value: str) -> None:
    if os.path.isabs(value):
        raise AmorError(
            f"{xml}: {what} {value!r} is an absolute path, so a copy of the model would still read it "
            "from this machine: make it relative to the model file"
        )


def _includes(main: Path) -> list[Path]:
    """The main file and every file it includes, recursively, in reading order."""
    base = main.parent
    out: list[Path] = []

    def visit(xml: Path) -> None:
        out.append(xml)
        try:
            tree = ET.parse(xml)
        except (ET.ParseError, OSError) as exc:
            raise AmorError(f"{xml}: cannot read it as XML: {exc}") from None
        for el in tree.iter("include"):
            name = el.get("file", "")
            _refuse_absolute(xml, "<include> file", name)
            found = next((p for p in (base / name, xml.parent / name) if p.is_file()), None)
            if found is None:
                raise AmorError(f"{xml}: includes {name!r}, which is not there (looked in {base})")
            if found.resolve() not in {p.resolve() for p in out}:
                visit(found)

    visit(main)
    return out


def _assets(main: Path) -> list[Path]:
    """The asset files of the parsed model (includes expanded by MuJoCo), resolved."""
    try:
        spec = mujoco.MjSpec.from_file(str(main))
    except ValueError as exc:
        raise AmorError(f"{main}: MuJoCo could not parse it: {exc}") from None
    for what, folder in (("meshdir", spec.meshdir), ("texturedir", spec.texturedir)):
        _refuse_absolute(main, f"<compiler> {what}", folder)
    wanted: list[tuple[str, str, str]] = []  # (element, file, folder)
    for kind, elements in (("mesh", spec.meshes), ("skin", spec.skins), ("hfield", spec.hfields)):
        wanted += [(kind, e.file, spec.meshdir) for e in elements if e.file]
    for tex in spec.textures:
        names = [tex.file, *list(tex.cubefiles)]
        wanted += [("texture", n, spec.texturedir) for n in names if n]
    out = []
    for kind, name, folder in wanted:
        _refuse_absolute(main, f"<{kind}> file", name)
        candidates = (main.parent / folder / name, main.parent / name)
        found = next((p for p in candidates if p.is_file()), None)
        if found is None:
            raise AmorError(f"{main}: its <{kind}> file {name!r} is not in {main.parent / folder}")
        out.append(found)
    return out


def _licences(start: Path) -> tuple[Path, ...]:
    """Licence files of the nearest directory, from ``start`` up, that has any; the search stops
    below an import root (a ``sys.path`` entry such as site-packages) and at the file system root."""
    roots = {Path(p).resolve() for p in sys.path if p}
    folder = start
    while folder not in roots and folder.parent != folder:
        found = sorted(
            p for p in folder.iterdir() if p.is_file() and p.name.upper().startswith(LICENCE_STEMS)
        )
        if found:
            return tuple(found)
        folder = folder.parent
    return ()


def model_files(mjcf: Path) -> ModelFiles:
    """Every file ``mjcf`` reads, and its licence (see the module docstring).

    Raises:
        AmorError: the file or a file it references is missing or unreadable, or a reference is an
            absolute path.
    """
    main = Path(mjcf).resolve()
    if not main.is_file():
        raise AmorError(f"{main}: model file not found")
    files: list[Path] = []
    for path in [*_includes(main), *_assets(main)]:
        path = path.resolve()
        if path not in files:
            files.append(path)
    licences = _licences(main.parent)
    root = Path(os.path.commonpath([str(p.parent) for p in (*files, *licences)]))
    return ModelFiles(mjcf=main, files=tuple(files), licences=licences, root=root)
