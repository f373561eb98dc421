"""Import paths of amorctl 0.1.0 that moved: they still work until 0.3.0, with a warning.

amorctl 0.1.0 declared no public API, so its plugins imported from wherever a name lived
(``amorctl.specs``, ``amorctl.registry.hookimpl``, ...). From 0.2.0 the public API is
:mod:`amorctl.api` (docs/plugins.md, "Compatibility"); the old paths listed here keep working
until :data:`REMOVED_IN`, and each use issues a :class:`MovedWarning` naming the new path.

One mechanism serves both forms a path can take:

- a module that moved or was split (:data:`MOVED_MODULES`): :func:`install` puts a finder at the
  end of ``sys.meta_path``, so ``import amorctl.specs`` gives a stand-in module whose attributes
  are looked up, when used, in the modules that hold them now;
- a name that left a module that still exists: that module sets
  ``__getattr__ = moved_names(__name__, {name: new_module})``.

New modules are imported by name only when an old path is used, so this module (in ``core/``)
depends on nothing above it.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence
from types import ModuleType
from typing import Any

#: the release that drops every path below
REMOVED_IN = "0.3.0"

#: module path of 0.1.0 -> the modules its names are in now, searched in order
MOVED_MODULES: dict[str, tuple[str, ...]] = {
    "amorctl.specs": ("amorctl.core.specs", "amorctl.core.contracts"),
    "amorctl.errors": ("amorctl.core.errors",),
    "amorctl.config": ("amorctl.core.config",),
    "amorctl.geometry": ("amorctl.core.geometry",),
    "amorctl.io": ("amorctl.core.files",),
    "amorctl.schedule": ("amorctl.core.schedule",),
    "amorctl.trainer": ("amorctl.core.contracts",),
    "amorctl.vecenv": ("amorctl.core.vecenv",),
    "amorctl.weights": ("amorctl.core.weights",),
    "amorctl.envs.tracking_inputs": ("amorctl.core.frame_layout",),
    "amorctl.envs.batch_sim": ("amorctl.sim.batch_sim",),
    "amorctl.character_info": ("amorctl.sim.character_info",),
    "amorctl.plugins.characters.actuators": ("amorctl.sim.actuators",),
    "amorctl.motion.importers": (
        "amorctl.motion.formats",
        "amorctl.motion.formats.base",
        "amorctl.core.specs",
    ),
    "amorctl.motion.bvh": ("amorctl.motion.formats.bvh",),
    "amorctl.motion.deepmimic": ("amorctl.motion.formats.deepmimic",),
    "amorctl.motion.npz": ("amorctl.motion.formats.npz",),
    "amorctl.motion.ik": ("amorctl.motion.retarget.ik",),
    "amorctl.checkpoint": ("amorctl.train.checkpoint",),
    "amorctl.runner": (
        "amorctl.train.loop",
        "amorctl.train.rundir",
        "amorctl.train.metrics",
        "amorctl.envs.factory",
    ),
    "amorctl.pareto": ("amorctl.analysis.front",),
    "amorctl.rollout": ("amorctl.analysis.rollout",),
    "amorctl.schemas": ("amorctl.analysis.schemas",),
    "amorctl.evaluation": (
        "amorctl.analysis.eval_env",
        "amorctl.analysis.sweeps",
        "amorctl.analysis.tracking_metrics",
        "amorctl.analysis.level_sweep",
    ),
    "amorctl.live": ("amorctl.tune.live",),
    "amorctl.plots": ("amorctl.outputs.plots",),
    "amorctl.render": ("amorctl.outputs.video",),
    "amorctl.rollout_mcap": ("amorctl.outputs.mcap_log",),
}
MOVED_MODULES["amorctl.analysis.evaluation"] = MOVED_MODULES["amorctl.evaluation"]

#: names of those modules that were renamed (same fields or methods): old path -> new path
RENAMED: dict[str, str] = {
    "amorctl.trainer.State": "amorctl.core.contracts.Snapshot",
    "amorctl.trainer.TrainerFactory": "amorctl.core.contracts.Backend",
    "amorctl.envs.tracking_inputs.ObjectiveFunction": "amorctl.core.contracts.ObjectiveSet",
    "amorctl.motion.importers.Importer": "amorctl.core.specs.MotionFormatSpec",
}


class MovedWarning(DeprecationWarning):
    """An import path of amorctl 0.1.0 that moved was used: ``old`` (``amorctl.specs.JointSpec``)
    is ``new`` now (``amorctl.api.JointSpec``)."""

    def __init__(self, old: str, new: str) -> None:
        super().__init__(old, new)
        self.old, self.new = old, new

    def __str__(self) -> str:
        module, _, name = self.new.rpartition(".")
        return (
            f"{self.old} moved: import {name} from {module} "
            f"(deprecated since 0.2.0; the old path goes in {REMOVED_IN})"
        )


def _new_path(new_name: str, value: Any, found_in: str) -> str:
    """Where to import ``new_name`` from now: :mod:`amorctl.api` for what plugins use, else the
    module that defines it (or, for a constant, the one it was found in)."""
    home = getattr(value, "__module__", None)
    if new_name in getattr(importlib.import_module("amorctl.api"), "__all__", ()):
        return f"amorctl.api.{new_name}"
    if isinstance(home, str) and home.startswith("amorctl."):
        return f"{home}.{new_name}"
    return f"{found_in}.{new_name}"


def _resolve(old: str, name: str, modules: Sequence[str]) -> Any:
    """``name`` (or what it was renamed to) from the first of ``modules`` that has it, with a
    :class:`MovedWarning` (which, like any warning, is shown once per place in the caller's code)."""
    renamed_in, _, new_name = RENAMED.get(f"{old}.{name}", name).rpartition(".")
    for module_name in (renamed_in,) if renamed_in else modules:
        module = importlib.import_module(module_name)
        if new_name in vars(module):  # not through the module's own moved names
            value = vars(module)[new_name]
            warnings.warn(
                MovedWarning(f"{old}.{name}", _new_path(new_name, value, module_name)), stacklevel=3
            )
            return value
    raise AttributeError(
        f"module {old!r} has no attribute {name!r} (its names moved to {', '.join(modules)}; "
        f"the public API is amorctl.api: docs/plugins.md)"
    )


def moved_names(module_name: str, names: Mapping[str, str]) -> Callable[[str], Any]:
    """A module-level ``__getattr__`` for names that left ``module_name``: ``names`` maps each to
    the module that holds it now; each use warns (once per place in the caller's code)."""

    def __getattr__(name: str) -> Any:
        if name not in names:
            raise AttributeError(f"module {module_name!r} has no attribute {name!r}")
        return _resolve(module_name, name, (names[name],))

    return __getattr__


class _MovedModule(ModuleType):
    """The stand-in for a module path of 0.1.0: attributes come from the modules that hold them now."""

    def __init__(self, name: str, targets: tuple[str, ...]) -> None:
        super().__init__(name, f"Deprecated: moved to {', '.join(targets)} (removed in {REMOVED_IN}).")
        self.__moved_to__ = targets

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return _resolve(self.__name__, name, self.__moved_to__)


class _MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds the module paths of :data:`MOVED_MODULES` (last on ``sys.meta_path``: a real module of
    the same name always wins)."""

    def find_spec(
        self, fullname: str, path: Any = None, target: Any = None
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname not in MOVED_MODULES:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        return _MovedModule(spec.name, MOVED_MODULES[spec.name])

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run: the stand-in resolves its names on first use."""


def install() -> None:
    """Make the old module paths importable (once per process; ``amorctl/__init__`` calls it)."""
    if not any(isinstance(finder, _MovedFinder) for finder in sys.meta_path):
        sys.meta_path.append(_MovedFinder())
