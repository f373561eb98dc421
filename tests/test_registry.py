"""Plugin registry behaviour: built-ins, fakes of every kind, duplicates, broken and blocked plugins."""

from __future__ import annotations

import types
from dataclasses import dataclass
from pathlib import Path

import pytest

from amorctl.core.errors import AmorError
from amorctl.core.specs import ActuatorModel, BackendSpec, CharacterSpec, JointSpec, ObjectiveSetSpec
from amorctl.registry import HookSpecs, hookimpl, load_registry


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
        "amorctl_register_objective_sets",
    ]
    for name in hooks:
        assert getattr(HookSpecs, name).__doc__, name


def test_fake_plugins_of_every_kind_register() -> None:
    objective_set = ObjectiveSetSpec("fake7", "fake objectives", ("a", "b"), make=lambda c: None)
    backend = BackendSpec("fake-backend", "fake backend", make=lambda **kw: None)
    plugin = _plugin(
        amorctl_register_characters=lambda register: register(_character("fakechar")),
        amorctl_register_objective_sets=lambda register: register(objective_set),
        amorctl_register_backends=lambda register: register(backend),
    )
    registry = load_registry(eps=[_ep("fakeplugin", plugin, "fake-pkg", "9.9")])
    assert registry.names("character") == ["fakechar"]
    assert registry.objective_set("fake7") is objective_set
    assert registry.backend("fake-backend") is backend
    rows = {(p.name, p.kind, p.package, p.version) for p in registry.provided}
    assert rows == {
        ("fakechar", "character", "fake-pkg", "9.9"),
        ("fake7", "objective-set", "fake-pkg", "9.9"),
        ("fake-backend", "backend", "fake-pkg", "9.9"),
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
    builtin = {p.name: p.package for p in registry.provided if p.package == "amorctl"}
    assert {"humanoid36", "biped20"} <= set(builtin)
