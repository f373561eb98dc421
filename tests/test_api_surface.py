"""The public API (``amorctl.api``) and the promise around it (docs/plugins.md, "Compatibility").

- The names in ``amorctl.api.__all__`` and their signatures match ``tests/api_surface.json``: a
  change fails here until it is recorded in CHANGELOG.md and the snapshot is rewritten
  (``AMORCTL_UPDATE_API_SURFACE=1 python -m pytest tests/test_api_surface.py``).
- Every import path of amorctl 0.1.0 that moved still works, with a warning naming the new path
  (``amorctl/core/moved.py``); a plugin written against 0.1.0 loads and ``amorctl plugins`` says
  which paths to change.
- The version in pyproject.toml is the installed one and CHANGELOG.md's newest release.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import json
import os
import re
import sys
import textwrap
import warnings
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any

import pytest

import amorctl
import amorctl.api as api
from amorctl.cli.main import main
from amorctl.core.config import read_toml
from amorctl.core.moved import MOVED_MODULES, REMOVED_IN, RENAMED, MovedWarning

ROOT = Path(__file__).resolve().parents[1]
SNAPSHOT = Path(__file__).with_name("api_surface.json")
UPDATE_ENV = "AMORCTL_UPDATE_API_SURFACE"


# ---------------------------------------------------------------------------- the surface
def _signature(obj: Any) -> str:
    """``inspect.signature`` as text, a default that is a module without its file path."""
    try:
        text = str(inspect.signature(obj))
    except (TypeError, ValueError):
        return "(?)"
    return re.sub(r"<module '([\w.]+)' from '[^']*'>", r"<module '\1'>", text)


def _class_lines(cls: type) -> list[str]:
    """A class's public surface: its constructor (not for protocols), then its fields and public
    methods and properties, from every amorctl class in its MRO."""
    lines = [] if getattr(cls, "_is_protocol", False) else [f"__init__{_signature(cls)}"]
    seen: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not klass.__module__.startswith("amorctl"):
            continue
        for attr, annotation in vars(klass).get("__annotations__", {}).items():
            if not attr.startswith("_"):
                seen[attr] = f"{attr}: {annotation}"
        for attr, value in vars(klass).items():
            if attr.startswith("_"):
                continue
            if isinstance(value, property):
                seen[attr] = f"{attr}: property"
            elif isinstance(value, (staticmethod, classmethod)):
                seen[attr] = f"{attr}{_signature(getattr(cls, attr))} [{type(value).__name__}]"
            elif inspect.isfunction(value):
                seen[attr] = f"{attr}{_signature(value)}"
    return lines + [seen[k] for k in sorted(seen)]


def api_surface() -> dict[str, list[str]]:
    """Every name of ``amorctl.api.__all__``: what it is and its signature (classes: members)."""
    surface: dict[str, list[str]] = {}
    for name in sorted(api.__all__):
        obj = getattr(api, name)
        if name == "__version__":
            surface[name] = ["str"]
        elif isinstance(obj, type):
            protocol = getattr(obj, "_is_protocol", False)
            kind = "dataclass" if dataclasses.is_dataclass(obj) else "protocol" if protocol else "class"
            surface[name] = [kind, *_class_lines(obj)]
        elif inspect.isfunction(obj) or inspect.isbuiltin(obj):
            surface[name] = [f"function{_signature(obj)}"]
        elif isinstance(obj, (tuple, frozenset, dict, str, int, float)):
            surface[name] = [f"{type(obj).__name__} = {obj!r}"]
        elif name == "hookimpl":
            surface[name] = [f"HookimplMarker(project_name={obj.project_name!r})"]
        else:  # a type alias
            surface[name] = [f"{type(obj).__name__}: {obj!r}"]
    return surface


def test_the_public_api_matches_its_snapshot() -> None:
    surface = api_surface()
    text = json.dumps(surface, indent=1, sort_keys=True) + "\n"
    assert " at 0x" not in text, "an address in the surface: it would differ between runs"
    if os.environ.get(UPDATE_ENV, "") not in ("", "0"):
        SNAPSHOT.write_text(text)
    recorded = json.loads(SNAPSHOT.read_text())
    changes = [f"+ {n}" for n in sorted(surface.keys() - recorded.keys())]
    changes += [f"- {n}" for n in sorted(recorded.keys() - surface.keys())]
    for name in sorted(surface.keys() & recorded.keys()):
        for line in sorted(set(recorded[name]) - set(surface[name])):
            changes.append(f"{name}: - {line}")
        for line in sorted(set(surface[name]) - set(recorded[name])):
            changes.append(f"{name}: + {line}")
    assert not changes, (
        "amorctl.api changed (a plugin author's code may break). If intended, record it in "
        f"CHANGELOG.md and rewrite the snapshot with {UPDATE_ENV}=1:\n" + "\n".join(changes)
    )


def test_the_surface_records_signatures() -> None:
    """The snapshot would catch a changed parameter, not only a removed name."""
    surface = api_surface()
    assert surface["hookimpl"][0].startswith("HookimplMarker")
    assert "__init__(name: 'str', command: 'Any', help: 'str' = '') -> None" in surface["CommandSpec"]
    assert any(line.startswith("make_env(self, *, character: 'str'") for line in surface["Backend"])
    assert surface["package_model"][0].startswith("function(package: 'str'")
    assert surface["KEYPOINTS"][0].startswith("tuple = ('root',")


# ---------------------------------------------------------------------------- moved paths
def test_every_moved_module_resolves_to_modules_that_exist() -> None:
    for old, targets in MOVED_MODULES.items():
        for target in targets:
            importlib.import_module(target)  # a target moved again: update core/moved.py
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # importing the old path alone does not warn
            assert importlib.import_module(old).__name__ == old
    for old, new in RENAMED.items():
        module, _, name = new.rpartition(".")
        assert hasattr(importlib.import_module(module), name), old


#: What plugins imported in 0.1.0 (and a name of each other moved module): old path -> new object.
OLD_IMPORTS = {
    "amorctl.specs.CharacterSpec": "amorctl.api.CharacterSpec",
    "amorctl.specs.JointSpec": "amorctl.api.JointSpec",
    "amorctl.specs.ActuatorModel": "amorctl.api.ActuatorModel",
    "amorctl.specs.Backend": "amorctl.api.Backend",
    "amorctl.registry.hookimpl": "amorctl.api.hookimpl",
    "amorctl.core.specs.Backend": "amorctl.api.Backend",
    "amorctl.errors.AmorError": "amorctl.api.AmorError",
    "amorctl.trainer.Trainer": "amorctl.api.Trainer",
    "amorctl.trainer.State": "amorctl.api.Snapshot",
    "amorctl.envs.tracking_inputs.TrackingInputs": "amorctl.api.TrackingInputs",
    "amorctl.envs.tracking_inputs.ObjectiveFunction": "amorctl.api.ObjectiveSet",
    "amorctl.motion.importers.Importer": "amorctl.api.MotionFormatSpec",
    "amorctl.vecenv.VectorEnv": "amorctl.api.VectorEnv",
    "amorctl.config.TrainConfig": "amorctl.api.TrainConfig",
    "amorctl.geometry.quat_mul": "amorctl.core.geometry.quat_mul",
    "amorctl.io.atomic_write_text": "amorctl.core.files.atomic_write_text",
    "amorctl.runner.train_run": "amorctl.train.loop.train_run",
    "amorctl.runner.make_env": "amorctl.envs.factory.make_env",
    "amorctl.pareto.hypervolume": "amorctl.analysis.front.hypervolume",
    "amorctl.evaluation.make_eval_env": "amorctl.analysis.eval_env.make_eval_env",
    "amorctl.plugins.characters.actuators.servo_torque": "amorctl.sim.actuators.servo_torque",
}


def _get(path: str) -> Any:
    module, _, name = path.rpartition(".")
    return getattr(importlib.import_module(module), name)


@pytest.mark.parametrize("old", OLD_IMPORTS)
def test_an_old_path_gives_the_new_object_and_warns_with_the_new_path(old: str) -> None:
    new = OLD_IMPORTS[old]
    with pytest.warns(MovedWarning) as caught:
        value = _get(old)
    assert value is _get(new)
    new_module, _, new_name = new.rpartition(".")
    (message,) = {str(w.message) for w in caught}
    assert message == (
        f"{old} moved: import {new_name} from {new_module} "
        f"(deprecated since 0.2.0; the old path goes in {REMOVED_IN})"
    )


def test_a_name_that_was_removed_is_an_import_error_naming_the_public_api() -> None:
    import amorctl.runner

    with pytest.raises(AttributeError, match=r"'amorctl.runner' has no attribute 'load_policy'.*amorctl.api"):
        amorctl.runner.load_policy  # noqa: B018
    with pytest.raises(ImportError):
        from amorctl.specs import NoSuchThing  # noqa: F401


def test_the_warning_points_at_the_callers_line() -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        from amorctl.specs import CharacterSpec  # noqa: F401
    assert [Path(w.filename).name for w in caught] == [Path(__file__).name]


#: a plugin as amorctl 0.1.0's docs showed it (tests/plugins/amorctl-stickman at 0.1.0)
PLUGIN_0_1_0 = """
from amorctl.registry import hookimpl
from amorctl.specs import ActuatorModel, CharacterSpec, JointSpec

SPEC = CharacterSpec(
    name="oldman12",
    description="a plugin written against amorctl 0.1.0",
    mjcf_path=MODEL,
    root_body="root",
    joints=tuple(
        JointSpec(name=n, group=g, range=(-1.0, 1.0), kp=40.0, kd=4.0, torque_limit=20.0)
        for n, g in [("left_shoulder", "upper"), ("left_elbow", "upper"), ("right_shoulder", "upper"),
                     ("right_elbow", "upper"), ("left_hip_x", "lower"), ("left_hip_y", "lower"),
                     ("left_knee", "lower"), ("left_ankle", "feet"), ("right_hip_x", "lower"),
                     ("right_hip_y", "lower"), ("right_knee", "lower"), ("right_ankle", "feet")]
    ),
    end_effectors=("left_hand", "right_hand", "left_foot", "right_foot"),
    actuator=ActuatorModel(kind="pd"),
    standing_height=0.865,
    min_standing_height=0.3,
    keypoints={"root": "root", "head": "torso", "left_hand": "left_hand", "right_hand": "right_hand",
               "left_foot": "left_foot", "right_foot": "right_foot"},
    licence="MIT",
)


@hookimpl
def amorctl_register_characters(register):
    register(SPEC)
"""


def test_a_plugin_written_for_0_1_0_loads_and_is_reported_as_deprecated(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    from amorctl import registry as reg

    stickman = importlib.import_module("amorctl_stickman")
    model = Path(stickman.__file__).with_name("stickman12.xml")
    (tmp_path / "amorctl_oldman.py").write_text(f"MODEL = {str(model)!r}\n" + textwrap.dedent(PLUGIN_0_1_0))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "amorctl_oldman", raising=False)
    old = EntryPoint(name="oldman", value="amorctl_oldman", group="amorctl")
    monkeypatch.setattr(reg, "_CACHED", reg.load_registry([*entry_points(group="amorctl"), old]))

    assert main(["characters", "show", "oldman12", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["name"] == "oldman12"
    assert main(["plugins", "--json"]) == 0
    (problem,) = [p for p in json.loads(capsys.readouterr().out)["problems"] if p["plugin"] == "oldman"]
    assert problem["status"] == "deprecated"
    assert problem["error"] == (
        f"imports paths that moved and go in {REMOVED_IN}: "
        "amorctl.registry.hookimpl -> amorctl.api.hookimpl, "
        "amorctl.specs.ActuatorModel -> amorctl.api.ActuatorModel, "
        "amorctl.specs.CharacterSpec -> amorctl.api.CharacterSpec, "
        "amorctl.specs.JointSpec -> amorctl.api.JointSpec"
    )
    assert main(["plugins"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "deprecated plugin 'oldman' from package 'unknown' : imports paths that moved" in out


# ---------------------------------------------------------------------------- the release
def test_the_version_is_pyprojects_and_the_changelogs_newest_release() -> None:
    version = read_toml(ROOT / "pyproject.toml")["project"]["version"]
    assert amorctl.__version__ == api.__version__ == version, "reinstall: pip install -e ."
    releases = re.findall(r"^## \[?(\d+\.\d+\.\d+)\]?", (ROOT / "CHANGELOG.md").read_text(), re.M)
    assert releases[0] == version and "0.1.0" in releases

    def release(v: str) -> tuple[int, ...]:
        return tuple(int(p) for p in v.split("."))

    assert release(version) < release(REMOVED_IN), f"release {version}: remove core/moved.py's paths"
