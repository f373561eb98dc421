"""Plugin registry behaviour: built-ins, fakes of every kind, duplicates, broken and blocked plugins."""

from __future__ import annotations

import types
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import typer

from amorctl.api import hookimpl
from amorctl.core.errors import AmorError
from amorctl.core.specs import (
    ActuatorModel,
    BackendSpec,
    CharacterSpec,
    CommandSpec,
    ImportOptions,
    JointSpec,
    MotionFormatSpec,
    ObjectiveSetSpec,
)
from amorctl.registry import HookSpecs, load_registry


def _character(name: str) -> CharacterSpec:
    return CharacterSpec(
        name=name,
        description="fake",
        mjcf_path=Path("/nonexistent.xml"),
        root_body="root",
        joints=(JointSpec("j", "upper", (-1.0, 1.0), 1.0, 0.1, 1.0),),
        end_effectors=(),
        actuator=ActuatorModel(kind="pd"),
        standing_height=1.0,
        min_standing_height=0.5,
        keypoints={},
    )


def _plugin(**hooks) -> types.ModuleType:
    module = types.ModuleType("fake_amorctl_plugin")
    for name, function in hooks.items():
        setattr(module, name, hookimpl(function))
    return module


@dataclass
class _Dist:
    name: str
    version: str

    @property
    def metadata(self) -> dict[str, str]:
        return {"Name": self.name}


@dataclass
class _EntryPoint:
    """Quacks like importlib.metadata.EntryPoint for the loader."""

    name: str
    target: object
    dist: _Dist

    def load(self) -> object:
        if isinstance(self.target, Exception):
            raise self.target
        return self.target


def _ep(name: str, target: object, package: str = "fake-pkg", version: str = "1.2.3") -> _EntryPoint:
    return _EntryPoint(name, target, _Dist(package, version))


def test_every_hook_is_documented_and_one_per_kind() -> None:
    hooks = [n for n in vars(HookSpecs) if n.startswith("amorctl_")]
    assert sorted(hooks) == [
        "amorctl_register_backends",
        "amorctl_register_characters",
        "amorctl_register_commands",
        "amorctl_register_motion_formats",
        "amorctl_register_objective_sets",
    ]
    for name in hooks:
        assert getattr(HookSpecs, name).__doc__, name


def test_fake_plugins_of_every_kind_register() -> None:
    objective_set = ObjectiveSetSpec("fake7", "fake objectives", ("a", "b"), make=lambda c: None)
    backend = BackendSpec("fake-backend", "fake backend", make=lambda **kw: None)
    fmt = MotionFormatSpec("fakefmt", (".fake",), load=lambda path, options: None)
    command = CommandSpec("fake-cmd", typer.Typer())
    plugin = _plugin(
        amorctl_register_characters=lambda register: register(_character("fakechar")),
        amorctl_register_objective_sets=lambda register: register(objective_set),
        amorctl_register_backends=lambda register: register(backend),
        amorctl_register_motion_formats=lambda register: register(fmt),
        amorctl_register_commands=lambda register: register(command),
    )
    registry = load_registry(eps=[_ep("fakeplugin", plugin, "fake-pkg", "9.9")])
    assert registry.names("character") == ["fakechar"]
    assert registry.objective_set("fake7") is objective_set
    assert registry.backend("fake-backend") is backend
    assert registry.motion_format("fakefmt") is fmt
    assert registry.command("fake-cmd") is command
    rows = {(p.name, p.kind, p.package, p.version) for p in registry.provided}
    assert rows == {
        ("fakechar", "character", "fake-pkg", "9.9"),
        ("fake7", "objective-set", "fake-pkg", "9.9"),
        ("fake-backend", "backend", "fake-pkg", "9.9"),
        ("fakefmt", "motion-format", "fake-pkg", "9.9"),
        ("fake-cmd", "command", "fake-pkg", "9.9"),
    }


def test_unknown_name_lists_installed() -> None:
    plugin = _plugin(amorctl_register_characters=lambda register: register(_character("b")))
    registry = load_registry(eps=[_ep("p", plugin)])
    with pytest.raises(AmorError, match=r"unknown character 'nope' \(installed: b\)"):
        registry.character("nope")
    with pytest.raises(AmorError, match=r"unknown backend 'x' \(installed: none\)"):
        registry.backend("x")


def test_duplicate_names_are_an_error_naming_both_packages() -> None:
    first = _plugin(amorctl_register_characters=lambda register: register(_character("dup")))
    second = _plugin(amorctl_register_characters=lambda register: register(_character("dup")))
    with pytest.raises(AmorError) as info:
        load_registry(eps=[_ep("a", first, "pkg-one"), _ep("b", second, "pkg-two")])
    message = str(info.value)
    assert "duplicate character 'dup'" in message
    assert "pkg-one" in message and "pkg-two" in message


def test_broken_plugin_is_reported_and_the_rest_loads() -> None:
    good = _plugin(amorctl_register_characters=lambda register: register(_character("good")))
    registry = load_registry(
        eps=[
            _ep("broken", ImportError("no module named 'missing_dep'"), "broken-pkg", "0.1"),
            _ep("ok", good),
        ]
    )
    assert registry.names("character") == ["good"]
    (problem,) = registry.problems
    assert (problem.plugin, problem.package, problem.status) == ("broken", "broken-pkg", "broken")
    assert "missing_dep" in problem.error


def test_plugin_whose_hook_raises_is_reported() -> None:
    def explode(register) -> None:
        raise RuntimeError("boom")

    good = _plugin(amorctl_register_characters=lambda register: register(_character("good")))
    registry = load_registry(
        eps=[_ep("bad", _plugin(amorctl_register_characters=explode), "bad-pkg"), _ep("ok", good)]
    )
    assert registry.names("character") == ["good"]
    assert registry.problems[0].package == "bad-pkg" and "boom" in registry.problems[0].error


def test_blocked_plugins_are_not_loaded(monkeypatch: pytest.MonkeyPatch) -> None:
    loaded = []

    def register_chars(register) -> None:
        loaded.append(True)
        register(_character("blocked_char"))

    monkeypatch.setenv("AMORCTL_BLOCK_PLUGINS", "blockme, other")
    registry = load_registry(eps=[_ep("blockme", _plugin(amorctl_register_characters=register_chars))])
    assert registry.names("character") == []
    assert loaded == []
    assert registry.problems[0].status == "blocked"


def test_trace_env_traces_hook_calls(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    monkeypatch.setenv("AMORCTL_TRACE_HOOKS", "1")
    plugin = _plugin(amorctl_register_characters=lambda register: register(_character("traced")))
    load_registry(eps=[_ep("tp", plugin, "trace-pkg")])
    err = capsys.readouterr().err
    assert "amorctl_register_characters" in err
    assert "registered character 'traced'" in err


def test_misspelled_hook_fails_loudly() -> None:
    from pluggy import PluginValidationError

    plugin = _plugin(amorctl_register_charactors=lambda register: None)
    with pytest.raises(PluginValidationError):
        load_registry(eps=[_ep("typo", plugin)])


def test_registering_the_wrong_type_is_reported() -> None:
    plugin = _plugin(amorctl_register_characters=lambda register: register("not a spec"))
    registry = load_registry(eps=[_ep("wrong", plugin, "wrong-pkg")])
    assert "CharacterSpec" in registry.problems[0].error


def test_builtins_come_through_the_entry_point_group() -> None:
    registry = load_registry()
    builtin = {(p.name, p.kind) for p in registry.provided if p.package == "amorctl"}
    assert {
        ("humanoid36", "character"),
        ("biped20", "character"),
        ("tracking7", "objective-set"),
        ("torch-cpu", "backend"),
        ("deepmimic", "motion-format"),
        ("bvh", "motion-format"),
        ("npz", "motion-format"),
    } <= builtin


def _csv_format(name: str = "csvmotion", suffixes: tuple[str, ...] = (".csvm",)) -> MotionFormatSpec:
    """A fake third-party format: ``x,y,z`` root positions per line at 30 Hz, no joints."""
    from amorctl.motion.source import SourceMotion, deepmimic_skeleton

    def load(path: Path, options: ImportOptions) -> SourceMotion:
        rows = np.loadtxt(path, delimiter=",", ndmin=2)
        quat = np.zeros((len(rows), 13, 4))
        quat[..., 0] = 1.0
        return SourceMotion(
            name=options.name or path.stem, source=str(path), sha256="0" * 64, licence=options.licence,
            skeleton=deepmimic_skeleton(), times=np.arange(len(rows)) / 30.0, root_pos=rows,
            local_quat=quat, source_fps=30.0,
        )  # fmt: skip

    return MotionFormatSpec(name, suffixes, load=load, description="fake CSV root track")


@pytest.fixture
def with_plugins(monkeypatch: pytest.MonkeyPatch):
    """Make ``get_registry()`` return the installed plugins plus the given fake ones."""
    from importlib.metadata import entry_points

    from amorctl import registry as reg

    def install(*plugins: tuple[str, object]) -> None:
        eps = [*entry_points(group=reg.ENTRY_POINT_GROUP), *(_ep(n, p, "fake-fmt-pkg") for n, p in plugins)]
        monkeypatch.setattr(reg, "_CACHED", load_registry(eps=eps))

    yield install
    reg.reset_registry()


def test_fake_motion_format_plugin_imports_files_like_a_builtin(tmp_path: Path, with_plugins) -> None:
    from amorctl.motion.formats import import_file, importers, infer_format

    plugin = _plugin(amorctl_register_motion_formats=lambda register: register(_csv_format()))
    with_plugins(("csvfmt", plugin))
    assert {"deepmimic", "bvh", "npz", "csvmotion"} <= set(importers())
    path = tmp_path / "hop.csvm"
    path.write_text("0,0,1\n0.1,0,1.2\n0.2,0,1\n")
    assert infer_format(path) == "csvmotion"
    motion = import_file(path, None, ImportOptions())
    assert motion.name == "hop"
    np.testing.assert_allclose(motion.root_pos[:, 2], [1.0, 1.2, 1.0])
    np.testing.assert_allclose(motion.times, [0.0, 1 / 30, 2 / 30])


def test_two_formats_claiming_one_suffix_need_format(tmp_path: Path, with_plugins) -> None:
    from amorctl.motion.formats import import_file, infer_format

    bvh2 = _csv_format("bvh2", (".bvh",))
    with_plugins(("bvh2fmt", _plugin(amorctl_register_motion_formats=lambda register: register(bvh2))))
    with pytest.raises(AmorError, match=r"claimed by formats bvh, bvh2; pass --format"):
        infer_format(tmp_path / "a.bvh")
    path = tmp_path / "a.bvh"
    path.write_text("1,2,3\n")
    assert import_file(path, "bvh2", ImportOptions()).root_pos.tolist() == [[1.0, 2.0, 3.0]]


def test_a_format_returning_the_wrong_type_is_a_plugin_bug(tmp_path: Path, with_plugins) -> None:
    from amorctl.motion.formats import import_file

    bad = MotionFormatSpec("badfmt", (".bad",), load=lambda path, options: {"not": "a motion"})
    with_plugins(("badfmt", _plugin(amorctl_register_motion_formats=lambda register: register(bad))))
    path = tmp_path / "x.bad"
    path.write_text("x")
    with pytest.raises(TypeError, match="'badfmt' returned dict"):
        import_file(path, None, ImportOptions())


def test_blocking_a_builtin_format_removes_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("AMORCTL_BLOCK_PLUGINS", "npz")
    registry = load_registry()
    assert "npz" not in registry.names("motion-format")
    assert {"bvh", "deepmimic"} <= set(registry.names("motion-format"))


def test_the_motion_format_example_in_the_docs_works(tmp_path: Path, with_plugins) -> None:
    """docs/plugins.md's format plugin, run as written: registered, inferred, imported."""
    import re

    from amorctl.motion.formats import import_file

    doc = (Path(__file__).resolve().parents[1] / "docs" / "plugins.md").read_text()
    (code,) = [b for b in re.findall(r"```python\n(.*?)```", doc, re.S) if "register_motion_formats" in b]
    module = types.ModuleType("docs_rootcsv_plugin")
    exec(compile(code, "docs/plugins.md", "exec"), module.__dict__)
    with_plugins(("rootcsv", module))
    path = tmp_path / "jump.rootcsv"
    path.write_text("0,0,0.9\n0,0,1.1\n")
    motion = import_file(path, None, ImportOptions())
    assert motion.name == "jump" and len(motion.sha256) == 64
    np.testing.assert_allclose(motion.root_pos[:, 2], [0.9, 1.1])
