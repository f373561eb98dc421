"""``amorctl plugins new``: write a ready plugin package from the templates in ``amorctl/templates``.

The package: ``pyproject.toml`` with the ``amorctl`` entry point, the module with the hook,
``tests/`` using :mod:`amorctl.testing`, a README; a character plugin also gets ``model.xml``
(a copy of the ``humanoid36`` model, to be replaced by the robot's own).
"""

from __future__ import annotations

import re
import shutil
from importlib.resources import files
from pathlib import Path

from amorctl import __version__
from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_write_text
from amorctl.registry import get_registry

KINDS = ("character", "objectives", "backend")
_NAME = re.compile(r"^[a-z][a-z0-9_-]{1,40}$")


def package_names(name: str) -> tuple[str, str]:
    """(distribution name, module name) of a plugin called ``name``."""
    return f"amorctl-{name}", "amorctl_" + name.replace("-", "_")


def _template(name: str) -> str:
    return (files("amorctl") / "templates" / "plugin" / f"{name}.tmpl").read_text()


def new_plugin(name: str, kind: str, out: Path) -> list[Path]:
    """Write the package for plugin ``name`` of ``kind`` into ``out`` (must not exist); returns the files.

    Raises:
        AmorError: a bad name or kind, ``out`` exists, or the name is taken by an installed plugin.
    """
    if not _NAME.match(name):
        raise AmorError(
            f"plugin name {name!r}: use 2-41 lowercase letters, digits, '-' or '_', starting with a letter"
        )
    if kind not in KINDS:
        raise AmorError(f"--kind {kind!r}: choose one of {', '.join(KINDS)}")
    if out.exists():
        raise AmorError(f"{out}: already exists (choose another --out)")
    registry = get_registry()
    registry_kind = {"character": "character", "objectives": "objective-set", "backend": "backend"}[kind]
    if name in registry.names(registry_kind):
        raise AmorError(f"plugin name {name!r}: a {registry_kind} of that name is already installed")
    package, module = package_names(name)
    model = None
    if kind == "character":
        model = registry.character("humanoid36").mjcf_path  # a model that stands: the author replaces it
    subs = {
        "__PACKAGE__": package,
        "__MODULE__": module,
        "__NAME__": name,
        "__KIND__": kind,
        "__AMORCTL_VERSION__": __version__,
    }

    def render(text: str) -> str:
        for key, value in subs.items():
            text = text.replace(key, value)
        return text

    written = {
        out / "pyproject.toml": render(_template("pyproject.toml")),
        out / "README.md": render(_template("README.md")),
        out / module / "__init__.py": render(_template(f"{kind}.py")),
        out / "tests" / f"test_{module}.py": render(_template(f"test_{kind}.py")),
    }
    staging = out.with_name(out.name + ".partial")
    shutil.rmtree(staging, ignore_errors=True)
    try:
        for path, text in written.items():
            target = staging / path.relative_to(out)
            target.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(target, text)
        if model is not None:
            shutil.copyfile(model, staging / module / "model.xml")
        staging.rename(out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    extra = [out / module / "model.xml"] if model is not None else []
    return sorted([*written, *extra])
