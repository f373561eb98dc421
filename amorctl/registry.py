"""The plugin registry: pluggy hookspecs, entry-point loading, lookup by name.

Every plugin, built-in or third-party, is a module named by an entry point in the ``amorctl``
group. It implements one or more of the hooks below (characters, objective sets, backends,
motion formats, commands); each hook receives a ``register`` callback and calls it once per thing
it provides (register-callback style, as in ``llm``). Plugin authors import ``hookimpl`` (this
module's :data:`impl`) and the spec types from :mod:`amorctl.api`; built-ins below ``api`` in the
layers use :data:`impl`.

Environment variables:
    AMORCTL_BLOCK_PLUGINS  comma-separated entry-point names (or distribution names) not to load.
    AMORCTL_TRACE_HOOKS    if set to 1, every hook call and registration is traced on stderr.
"""

from __future__ import annotations

import os
import sys
import warnings
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib.metadata import EntryPoint, entry_points
from types import ModuleType
from typing import Any

import pluggy

from amorctl.core.errors import AmorError
from amorctl.core.moved import REMOVED_IN, MovedWarning, moved_names
from amorctl.core.specs import (
    BackendSpec,
    CharacterSpec,
    CommandSpec,
    LazyCharacter,
    MotionFormatSpec,
    ObjectiveSetSpec,
)

PROJECT = "amorctl"
ENTRY_POINT_GROUP = "amorctl"
BLOCK_ENV = "AMORCTL_BLOCK_PLUGINS"
TRACE_ENV = "AMORCTL_TRACE_HOOKS"

hookspec = pluggy.HookspecMarker(PROJECT)
#: the marker of hook implementations (``amorctl.api.hookimpl``; ``amorctl.registry.hookimpl``
#: was its 0.1.0 path and warns until 0.3.0)
impl = pluggy.HookimplMarker(PROJECT)
__getattr__ = moved_names(__name__, {"hookimpl": "amorctl.api"})


class HookSpecs:
    """One hook per plugin kind."""

    @hookspec
    def amorctl_register_characters(self, register: Callable[[CharacterSpec | LazyCharacter], None]) -> None:
        """Call ``register(spec)`` once for every :class:`CharacterSpec` (or :class:`LazyCharacter`,
        built on first use) this plugin provides."""

    @hookspec
    def amorctl_register_objective_sets(self, register: Callable[[ObjectiveSetSpec], None]) -> None:
        """Call ``register(spec)`` once for every :class:`ObjectiveSetSpec` this plugin provides."""

    @hookspec
    def amorctl_register_backends(self, register: Callable[[BackendSpec], None]) -> None:
        """Call ``register(spec)`` once for every :class:`BackendSpec` this plugin provides."""

    @hookspec
    def amorctl_register_motion_formats(self, register: Callable[[MotionFormatSpec], None]) -> None:
        """Call ``register(spec)`` once for every :class:`MotionFormatSpec` (file importer) this
        plugin provides; ``amorctl preprocess`` picks one by ``--format`` or by file suffix."""

    @hookspec
    def amorctl_register_commands(self, register: Callable[[CommandSpec], None]) -> None:
        """Call ``register(spec)`` once for every :class:`CommandSpec` (a ``typer.Typer`` app or a
        click command or group) this plugin adds to the ``amorctl`` command line."""


#: plugin kind -> (hook name, spec type or types)
KINDS: dict[str, tuple[str, type | tuple[type, ...]]] = {
    "character": ("amorctl_register_characters", (CharacterSpec, LazyCharacter)),
    "objective-set": ("amorctl_register_objective_sets", ObjectiveSetSpec),
    "backend": ("amorctl_register_backends", BackendSpec),
    "motion-format": ("amorctl_register_motion_formats", MotionFormatSpec),
    "command": ("amorctl_register_commands", CommandSpec),
}


@dataclass(frozen=True)
class Provided:
    """One registered thing: a row of ``amorctl plugins``."""

    name: str
    kind: str
    package: str
    version: str
    plugin: str  # the entry-point (plugin module) name


@dataclass(frozen=True)
class PluginProblem:
    """A plugin that did not load (blocked by the user, or broken), or one that loaded through an
    import path that moved (deprecated; in :attr:`Registry.deprecated`)."""

    plugin: str
    package: str
    version: str
    status: str  # "blocked" | "broken" | "deprecated" (loaded, but uses an import path that moved)
    error: str = ""


@dataclass
class Registry:
    """Everything the installed plugins registered, by kind and name."""

    items: dict[str, dict[str, Any]] = field(default_factory=lambda: {k: {} for k in KINDS})
    provided: list[Provided] = field(default_factory=list)
    problems: list[PluginProblem] = field(default_factory=list)
    deprecated: list[PluginProblem] = field(default_factory=list)

    def names(self, kind: str) -> list[str]:
        return sorted(self.items[kind])

    def get(self, kind: str, name: str) -> Any:
        """The spec of one registered thing; unknown names raise :class:`AmorError`. A
        :class:`LazyCharacter` is built here, once (its failure is an AmorError naming it)."""
        try:
            item = self.items[kind][name]
        except KeyError:
            installed = ", ".join(self.names(kind)) or "none"
            raise AmorError(f"unknown {kind} {name!r} (installed: {installed})") from None
        if isinstance(item, LazyCharacter):
            item = self.items[kind][name] = _build_lazy(item, self._plugin_of(kind, name))
        return item

    def _plugin_of(self, kind: str, name: str) -> str:
        return next((p.plugin for p in self.provided if p.kind == kind and p.name == name), "?")

    def character(self, name: str) -> CharacterSpec:
        return self.get("character", name)

    def objective_set(self, name: str) -> ObjectiveSetSpec:
        return self.get("objective-set", name)

    def backend(self, name: str) -> BackendSpec:
        return self.get("backend", name)

    def motion_format(self, name: str) -> MotionFormatSpec:
        return self.get("motion-format", name)

    def command(self, name: str) -> CommandSpec:
        return self.get("command", name)


def _build_lazy(lazy: LazyCharacter, plugin: str) -> CharacterSpec:
    """Build a :class:`LazyCharacter`'s spec; any failure becomes one AmorError naming it."""
    try:
        spec = lazy.build()
    except AmorError as exc:
        if f"character {lazy.name!r}" in str(exc):  # already names it (e.g. a missing model file)
            raise
        raise AmorError(f"character {lazy.name!r} (plugin {plugin!r}): {exc}") from None
    except Exception as exc:  # the plugin's own code: report it, never a traceback
        raise AmorError(
            f"character {lazy.name!r} (plugin {plugin!r}) could not be built: {type(exc).__name__}: {exc}"
        ) from None
    if not isinstance(spec, CharacterSpec) or spec.name != lazy.name:
        got = getattr(spec, "name", type(spec).__name__)
        raise AmorError(f"character {lazy.name!r} (plugin {plugin!r}): its build returned {got!r}")
    return spec


def _blocked_names() -> set[str]:
    return {n.strip() for n in os.environ.get(BLOCK_ENV, "").split(",") if n.strip()}


def _dist_of(ep: EntryPoint) -> tuple[str, str]:
    dist = getattr(ep, "dist", None)
    if dist is None:
        return ("unknown", "")
    return (dist.metadata["Name"] or "unknown", dist.version or "")


def _trace(message: str) -> None:
    if os.environ.get(TRACE_ENV, "") not in ("", "0"):
        print(f"[amorctl hooks] {message}", file=sys.stderr)


def load_registry(
    eps: Iterable[EntryPoint] | None = None,
    extra_plugins: Iterable[tuple[str, ModuleType | object, str, str]] = (),
) -> Registry:
    """Load plugins and collect what they register.

    Args:
        eps: entry points to load; defaults to the installed ``amorctl`` group.
        extra_plugins: (plugin name, module-or-object, package, version) registered directly,
            used by tests to add fake plugins.

    Raises:
        AmorError: two plugins register the same name for one kind.
    """
    pm = pluggy.PluginManager(PROJECT)
    pm.add_hookspecs(HookSpecs)
    if os.environ.get(TRACE_ENV, "") not in ("", "0"):
        pm.trace.root.setwriter(lambda msg: print(f"[amorctl hooks] {msg}", end="", file=sys.stderr))
        pm.enable_tracing()

    registry = Registry()
    if eps is None:
        eps = entry_points(group=ENTRY_POINT_GROUP)
    origin: dict[str, tuple[str, str]] = {}  # plugin name -> (package, version)
    loaded: list[tuple[str, object]] = []
    for name, obj, package, version in [*_import_plugins(eps, registry), *extra_plugins]:
        origin[name] = (package, version)
        loaded.append((name, obj))

    for name, obj in loaded:
        if pm.has_plugin(name) or pm.is_registered(obj):
            continue  # the same module named by two entry points registers once
        pm.register(obj, name=name)
    pm.check_pending()

    for kind, (hook_name, spec_type) in KINDS.items():
        for name, obj in loaded:
            if not pm.is_registered(obj) or pm.get_name(obj) != name:
                continue
            others = [p for p in pm.get_plugins() if p is not obj]
            caller = pm.subset_hook_caller(hook_name, remove_plugins=others)
            package, version = origin[name]
            try:
                with _recording_moved(registry, name, package, version):
                    caller(register=_registrar(registry, kind, spec_type, name, package, version))
            except AmorError:
                raise
            except Exception as exc:
                registry.problems.append(
                    PluginProblem(name, package, version, "broken", f"{type(exc).__name__}: {exc}")
                )
    return registry


def _import_plugins(eps: Iterable[EntryPoint], registry: Registry) -> list[tuple[str, object, str, str]]:
    """Import every entry point's module (by name order), except blocked ones; blocked and broken
    plugins are recorded in ``registry.problems``. Returns (name, module, package, version) rows."""
    blocked = _blocked_names()
    imported: list[tuple[str, object, str, str]] = []
    for ep in sorted(eps, key=lambda e: e.name):
        package, version = _dist_of(ep)
        if ep.name in blocked or package in blocked:
            registry.problems.append(PluginProblem(ep.name, package, version, "blocked"))
            _trace(f"blocked plugin {ep.name!r} from {package}")
            continue
        try:
            with _recording_moved(registry, ep.name, package, version):
                module = ep.load()
        except Exception as exc:  # a broken plugin must not take the others down
            registry.problems.append(
                PluginProblem(ep.name, package, version, "broken", f"{type(exc).__name__}: {exc}")
            )
            _trace(f"plugin {ep.name!r} from {package} failed to import: {exc}")
            continue
        imported.append((ep.name, module, package, version))
    return imported


@contextmanager
def _recording_moved(registry: Registry, plugin: str, package: str, version: str) -> Iterator[None]:
    """Record the :class:`~amorctl.core.moved.MovedWarning` s the plugin's code raises (import
    paths of 0.1.0 it still uses) as one line of ``registry.deprecated``, for ``amorctl plugins``
    to show; other warnings pass on as usual."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", MovedWarning)
        yield
    moved = sorted(
        {f"{w.message.old} -> {w.message.new}" for w in caught if isinstance(w.message, MovedWarning)}
    )
    if moved:
        error = f"imports paths that moved and go in {REMOVED_IN}: {', '.join(moved)}"
        registry.deprecated.append(PluginProblem(plugin, package, version, "deprecated", error))
    for w in caught:
        if not isinstance(w.message, MovedWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)


def _registrar(
    registry: Registry, kind: str, spec_type: type | tuple[type, ...], plugin: str, package: str, version: str
) -> Callable[[Any], None]:
    def register(spec: Any) -> None:
        if not isinstance(spec, spec_type):
            want = " or ".join(
                t.__name__ for t in (spec_type if isinstance(spec_type, tuple) else (spec_type,))
            )
            raise TypeError(f"{kind} plugins must register {want}, got {type(spec).__name__}")
        existing = registry.items[kind].get(spec.name)
        if existing is not None:
            first = next(p for p in registry.provided if p.kind == kind and p.name == spec.name)
            raise AmorError(
                f"duplicate {kind} {spec.name!r}: registered by package {first.package!r} "
                f"(plugin {first.plugin!r}) and by package {package!r} (plugin {plugin!r})"
            )
        registry.items[kind][spec.name] = spec
        registry.provided.append(Provided(spec.name, kind, package, version, plugin))
        _trace(f"{plugin} ({package}) registered {kind} {spec.name!r}")

    return register


def load_plugin(plugin: str) -> Registry:
    """A registry of the single installed plugin whose entry point is named ``plugin`` (what a
    tool that needs one plugin loads, e.g. the torch-free deploy runtime its objective set,
    without importing every other plugin and what they import).

    Raises:
        AmorError: no installed plugin of that name, or it is blocked or broken.
    """
    eps = [ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name == plugin]
    if not eps:
        raise AmorError(f"plugin {plugin!r} is not installed")
    registry = load_registry(eps)
    for problem in registry.problems:
        raise AmorError(
            f"plugin {plugin!r} ({problem.package}) is {problem.status}: {problem.error}".rstrip(": ")
        )
    return registry


_CACHED: Registry | None = None


def get_registry() -> Registry:
    """The registry of installed plugins, loaded once per process."""
    global _CACHED
    if _CACHED is None:
        _CACHED = load_registry()
    return _CACHED


def reset_registry() -> None:
    """Forget the cached registry (tests change the environment between loads)."""
    global _CACHED
    _CACHED = None
