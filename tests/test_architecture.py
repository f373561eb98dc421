"""The architecture, checked on the source: the import graph of ``amorctl`` and its layers.

The graph is built with the standard library's ``ast`` only (nothing is imported):

- every ``import a.b`` and ``from a.b import c`` anywhere in a module (top level or inside a
  function) is an edge, to ``a.b.c`` when that is a module, else to ``a.b``; relative imports are
  resolved against the module's package;
- imports inside an ``if TYPE_CHECKING:`` block are ignored: they never run, and type-only
  references may point upwards (a protocol naming the type it returns);
- importing ``a.b.c`` also runs the package ``a.b``'s ``__init__``, but that implicit edge is not
  drawn: otherwise every package whose ``__init__`` re-exports a submodule would be a cycle.

See docs/architecture.md for the layers this test enforces.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "amorctl"

#: Layer rank of each top-level part of ``amorctl``: a module may import only from its own rank or
#: lower ones. ``amorctl`` itself (``__init__``: the version) and ``presets`` (data) sit at the bottom.
RANKS: dict[str, int] = {
    "amorctl": 0,
    "presets": 0,
    "core": 0,
    "registry": 1,
    "sim": 2,
    "motion": 3,
    # The plugin authors' facade re-exports the motion records format plugins return, so it sits
    # just above motion/; nothing below plugins/ imports it.
    "api": 4,
    "envs": 5,
    "plugins": 6,
    "train": 7,
    "analysis": 8,
    "tune": 9,
    "outputs": 10,
    # New features and the plugin authors' testing kit use every layer below the CLI.
    "hlp": 11,
    "deploy": 11,
    "testing": 11,
    "cli": 12,
    "__main__": 12,  # python -m amorctl (torchrun -m amorctl): the CLI entry point
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def modules() -> dict[str, Path]:
    """Every module of the package: dotted name -> file."""
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py")) if ".venv" not in p.parts}


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _import_nodes(tree: ast.AST) -> list[ast.Import | ast.ImportFrom]:
    """Import statements that run: everything except the bodies of ``if TYPE_CHECKING:``."""
    found: list[ast.Import | ast.ImportFrom] = []
    stack: list[ast.AST] = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            found.append(node)
            continue
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend(node.orelse)
            continue
        stack.extend(ast.iter_child_nodes(node))
    return found


def imports_of(name: str, path: Path, known: set[str]) -> set[str]:
    """The ``amorctl`` modules that module ``name`` (file ``path``) imports."""
    is_package = path.name == "__init__.py"
    package = name if is_package else name.rpartition(".")[0]
    targets: set[str] = set()
    for node in _import_nodes(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                base = alias.name
                while base and base not in known:
                    base = base.rpartition(".")[0]
                if base:
                    targets.add(base)
            continue
        if node.level:
            anchor = package.split(".")
            anchor = anchor[: len(anchor) - (node.level - 1)]
            base = ".".join([*anchor, *([node.module] if node.module else [])])
        else:
            base = node.module or ""
        if not (base == "amorctl" or base.startswith("amorctl.")):
            continue
        for alias in node.names:
            full = f"{base}.{alias.name}"
            if full in known:
                targets.add(full)
            elif base in known:
                targets.add(base)
    targets.discard(name)
    return {t for t in targets if t == "amorctl" or t.startswith("amorctl.")}


def import_graph() -> dict[str, set[str]]:
    mods = modules()
    known = set(mods)
    return {name: imports_of(name, path, known) for name, path in mods.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle as a list of modules (first == last), or None; iterative depth-first search."""
    white, grey, black = 0, 1, 2
    colour = dict.fromkeys(graph, white)
    for start in sorted(graph):
        if colour[start] != white:
            continue
        path = [start]
        iters = [iter(sorted(graph[start]))]
        colour[start] = grey
        while iters:
            nxt = next(iters[-1], None)
            if nxt is None:
                colour[path.pop()] = black
                iters.pop()
                continue
            if colour.get(nxt, black) == grey:
                return [*path[path.index(nxt) :], nxt]
            if colour.get(nxt, black) == white:
                colour[nxt] = grey
                path.append(nxt)
                iters.append(iter(sorted(graph[nxt])))
    return None


def layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "amorctl"


GRAPH = import_graph()


def test_the_graph_sees_the_package() -> None:
    assert len(GRAPH) > 50
    assert "amorctl.core.specs" in GRAPH["amorctl.registry"]
    assert "amorctl.motion.formats.base" in GRAPH["amorctl.motion.formats.npz"]
    # relative and `from package import module` forms resolve to the module
    assert "amorctl.plugins.objectives.tracking7_kernels" in GRAPH["amorctl.plugins.objectives.tracking7"]


def test_find_cycle_finds_one() -> None:
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_type_checking_imports_are_ignored(tmp_path: Path) -> None:
    src = tmp_path / "m.py"
    src.write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from amorctl.cli import main\n"
        "else:\n    from amorctl.core import errors\ndef f():\n    import amorctl.sim.model\n"
    )
    known = {"amorctl.cli.main", "amorctl.core.errors", "amorctl.sim.model", "amorctl.sim"}
    assert imports_of("amorctl.x.m", src, known) == {"amorctl.core.errors", "amorctl.sim.model"}


def test_import_graph_has_no_cycles() -> None:
    cycle = find_cycle(GRAPH)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_every_module_has_a_layer() -> None:
    unranked = sorted({layer(m) for m in GRAPH} - set(RANKS))
    assert not unranked, f"add these parts of amorctl to RANKS (and docs/architecture.md): {unranked}"


def test_core_imports_nothing_above_it() -> None:
    bad = [
        f"{m} -> {t}"
        for m, targets in GRAPH.items()
        if layer(m) == "core"
        for t in targets
        if layer(t) != "core" and t != "amorctl"
    ]
    assert not bad, "core/ imports from above it:\n" + "\n".join(bad)


def test_layers_import_only_downwards() -> None:
    bad = [
        f"{m} ({layer(m)}, rank {RANKS[layer(m)]}) -> {t} ({layer(t)}, rank {RANKS[layer(t)]})"
        for m, targets in sorted(GRAPH.items())
        if layer(m) in RANKS
        for t in sorted(targets)
        if layer(t) in RANKS and RANKS[layer(t)] > RANKS[layer(m)]
    ]
    assert not bad, "imports that go up the layers:\n" + "\n".join(bad)


def test_nothing_outside_plugins_imports_plugins() -> None:
    bad = [
        f"{m} -> {t}"
        for m, targets in sorted(GRAPH.items())
        if layer(m) != "plugins"
        for t in sorted(targets)
        if layer(t) == "plugins"
    ]
    assert not bad, "plugins are found through the registry, never imported:\n" + "\n".join(bad)


#: A tracking env's private state; outside envs/ analysis reads it through ``TrackingView``.
PRIVATE_ENV_ATTRS = ("library", "ref_idx", "ref_frames", "obs_layout", "clip_id")
#: Modules that implement a tracking env and its TrackingView (a backend's own), besides ``envs/``.
ENV_IMPLEMENTATIONS = (
    "amorctl/plugins/backends/*/env.py",
    "amorctl/plugins/backends/*/view.py",
    "amorctl/plugins/backends/jax_mjx/core.py",  # the pure MJX env that env.py wraps
)
#: Reads that match the pattern but are not a tracking env's: (file, code) -> why.
NOT_A_TRACKING_ENV = {
    ("amorctl/deploy/runtime_log.py", "runtime.sim.base_model"): "the deploy runtime's own simulator",
}


def private_read_lines(text: str) -> list[int]:
    """Line numbers of ``x.sim.<...>`` and ``x.<private attribute>`` reads in Python source, where
    ``x`` is not ``self`` (an object reading its own state is not reaching into an env)."""
    found = set()
    for node in ast.walk(ast.parse(text)):
        if not isinstance(node, ast.Attribute):
            continue
        sim_chain = isinstance(node.value, ast.Attribute) and node.value.attr == "sim"
        if not (node.attr in PRIVATE_ENV_ATTRS or sim_chain):
            continue
        owner = node.value.value if sim_chain else node.value
        if isinstance(owner, ast.Name) and owner.id == "self":
            continue
        found.add(node.lineno)
    return sorted(found)


def test_no_tracking_env_internals_outside_envs() -> None:
    """The grep for private attribute reads, on the syntax tree so that ``amorctl.sim.model`` in imports and
    strings does not count: only attribute reads like ``env.sim.data`` or ``inner.library``."""
    skip = {p for pattern in ENV_IMPLEMENTATIONS for p in ROOT.glob(pattern)}
    hits = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if PACKAGE / "envs" in path.parents or path in skip:
            continue
        rel = str(path.relative_to(ROOT))
        lines = path.read_text().splitlines()
        for n in private_read_lines("\n".join(lines)):
            code = lines[n - 1].strip()
            if not any(f == rel and c in code for f, c in NOT_A_TRACKING_ENV):
                hits.append(f"{rel}:{n}: {code}")
    assert not hits, "tracking-env internals read outside envs/ (use TrackingView):\n" + "\n".join(hits)


@pytest.mark.parametrize(
    "snippet, expected",
    [
        ("env.sim.data.qpos", [2]),
        ("inner.ref_idx + 1", [2]),
        ("view.reference_index()", []),
        ("a.sim", []),
        ("self.sim.data", []),
        ("self.library", []),
    ],
)
def test_private_read_detector(snippet: str, expected: list[int]) -> None:
    assert private_read_lines(f"import amorctl.sim.model\nx = {snippet}\n") == expected


OWN_PACKAGES = ("amorctl.plugins.characters", "amorctl.plugins.objectives")


def test_builtin_characters_and_objectives_use_only_the_public_api() -> None:
    """What plugin authors are told to do, the built-ins do: ``amorctl.api`` and their own package."""
    stickman = ROOT / "tests" / "plugins" / "amorctl-stickman" / "amorctl_stickman" / "__init__.py"
    checked = {m: p for m, p in modules().items() if m.startswith(OWN_PACKAGES)}
    checked["amorctl_stickman"] = stickman
    bad = [
        f"{m} -> {t}"
        for m, p in sorted(checked.items())
        for t in sorted(imports_of(m, p, set(GRAPH)))
        if t != "amorctl.api" and not t.startswith(OWN_PACKAGES)
    ]
    assert not bad, "plugins must import amorctl only through amorctl.api:\n" + "\n".join(bad)


def test_api_exports_every_spec_and_contract() -> None:
    import amorctl.api as api
    from amorctl.core import contracts, specs

    public = set(api.__all__)
    assert {"hookimpl", "MotionFormatSpec", "TrackingInputs", "FrameParts", "split_frame"} <= public
    for module in (specs, contracts):
        classes = {
            n for n, v in vars(module).items() if isinstance(v, type) and v.__module__ == module.__name__
        }
        assert classes <= public, f"{module.__name__}: not re-exported by amorctl.api: {classes - public}"
    assert all(hasattr(api, n) for n in api.__all__)


#: Longest a module may be: past this it does more than one job; split it (docs/architecture.md).
MAX_MODULE_LINES = 500


def test_no_module_is_over_500_lines() -> None:
    long = {
        str(path.relative_to(ROOT)): n
        for path in modules().values()
        if (n := len(path.read_text().splitlines())) > MAX_MODULE_LINES
    }
    assert not long, f"modules over {MAX_MODULE_LINES} lines (split them): " + ", ".join(
        f"{p} ({n})" for p, n in sorted(long.items())
    )


def test_docs_map_has_a_line_for_every_folder() -> None:
    """docs/architecture.md's map names every folder of ``amorctl/`` (a parent counts as named when
    one of its subfolders is, e.g. ``amorctl/templates/`` by ``amorctl/templates/plugin/``). The
    run directories under ``amorctl/pretrained/`` are data and are not listed one by one."""
    doc = (ROOT / "docs" / "architecture.md").read_text()
    map_text = doc.split("## Map", 1)[1].split("\n## ", 1)[0]
    listed = {line.split("`")[1] for line in map_text.splitlines() if line.startswith("| `")}
    folders = {
        f"{path.relative_to(ROOT).as_posix()}/"
        for path in [PACKAGE, *PACKAGE.rglob("*")]
        if path.is_dir()
        and "__pycache__" not in path.parts
        and any(path.iterdir())
        and PACKAGE / "pretrained" not in path.parents
    }
    missing = sorted(f for f in folders if not any(entry.startswith(f) for entry in listed))
    assert not missing, "docs/architecture.md map lacks a line for: " + ", ".join(missing)
    stale = sorted(e for e in listed if e.endswith("/") and e not in folders)
    assert not stale, "docs/architecture.md map names folders that do not exist: " + ", ".join(stale)
