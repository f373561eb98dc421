"""Build a :class:`~amorctl.core.specs.CharacterSpec` from a model file as it comes.

:func:`character_from_mjcf` reads what the model knows (joint order, ranges, actuator gains,
torque limits, armature and friction, the free root, the timestep, a standing keyframe and the
standing height by forward kinematics) and asks only for what it cannot know: which joints are
upper body, lower body or feet, which bodies are the hands and feet, and which is the head.
The answer is cached per model file in :func:`plugin_cache_dir` so that registering the
character (every ``amorctl`` command loads every plugin) does not compile meshes each time.

:func:`package_file` finds a file inside another installed package without importing it, so a
plugin can point at a model shipped by a robot-description package.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

import mujoco
import numpy as np

from amorctl import __version__
from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_write_text
from amorctl.core.specs import (
    JOINT_GROUPS,
    ActuatorModel,
    CharacterSpec,
    JointGroup,
    JointSpec,
    ModelSource,
    find_package_file,
    resolve_model_source,
    set_mjcf_reader,
)
from amorctl.sim.geom_bottom import lowest_point

CACHE_ENV = "AMORCTL_CACHE_DIR"
#: Range given to a hinge that has neither a joint limit nor a control range, rad.
UNLIMITED_RANGE = (-math.pi, math.pi)


def plugin_cache_dir(plugin: str = "") -> Path:
    """A per-user directory a plugin may keep derived files in (created on demand).

    ``$AMORCTL_CACHE_DIR/plugins/<plugin>`` or ``~/.cache/amorctl/plugins/<plugin>``.
    """
    env = os.environ.get(CACHE_ENV)
    root = Path(env).expanduser() if env else Path.home() / ".cache" / "amorctl"
    path = root / "plugins" / plugin if plugin else root / "plugins"
    path.mkdir(parents=True, exist_ok=True)
    return path


def package_file(package: str, *parts: str) -> Path:
    """The path of a file shipped inside an installed package, found without importing it (now;
    :func:`~amorctl.core.specs.package_model` is the lazy form for ``CharacterSpec.mjcf_path``).

    Raises:
        AmorError: the package is not installed, or the file is not in it.
    """
    return find_package_file(package, *parts)


def _group_of(joint: str, groups: Mapping[str, JointGroup]) -> JointGroup | None:
    """The group of a joint: an exact key first, else the first matching fnmatch pattern."""
    if joint in groups:
        return groups[joint]
    for pattern, group in groups.items():
        if fnmatch.fnmatchcase(joint, pattern):
            return group
    return None


def _read_model(path: Path) -> mujoco.MjModel:
    if not path.is_file():
        raise AmorError(f"{path}: model file not found")
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        raise AmorError(f"{path}: MuJoCo could not compile it: {exc}") from None


def _free_root(model: mujoco.MjModel, path: Path) -> str:
    for j in range(model.njnt):
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            return model.body(int(model.jnt_bodyid[j])).name
    raise AmorError(f"{path}: the model has no free joint (a floating root body is required)")


def _actuated_hinges(model: mujoco.MjModel, path: Path) -> list[tuple[int, int]]:
    """(joint id, actuator id) of every actuated hinge, in qpos order."""
    out = []
    for a in range(model.nu):
        if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
            raise AmorError(f"{path}: actuator {model.actuator(a).name!r} does not drive a joint")
        j = int(model.actuator_trnid[a, 0])
        if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
            raise AmorError(f"{path}: actuator {model.actuator(a).name!r} drives a non-hinge joint")
        out.append((j, a))
    out.sort(key=lambda ja: int(model.jnt_qposadr[ja[0]]))
    return out


def _joint_table(model: mujoco.MjModel, path: Path) -> list[dict[str, Any]]:
    """What the model says about each actuated hinge (JSON-ready)."""
    rows = []
    for j, a in _actuated_hinges(model, path):
        name = model.joint(j).name
        gear = abs(float(model.actuator_gear[a, 0])) or 1.0
        gain, bias = model.actuator_gainprm[a], model.actuator_biasprm[a]
        position = (
            model.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED
            and model.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_AFFINE
        )
        limits = []
        if model.actuator_forcelimited[a]:
            limits.append(float(np.abs(model.actuator_forcerange[a]).max()) * gear)
        if model.jnt_actfrclimited[j]:
            limits.append(float(np.abs(model.jnt_actfrcrange[j]).max()))
        if model.jnt_limited[j]:
            rng = [float(x) for x in model.jnt_range[j]]
        elif model.actuator_ctrllimited[a]:
            rng = [float(x) for x in model.actuator_ctrlrange[a]]
        else:
            rng = list(UNLIMITED_RANGE)
        dof = int(model.jnt_dofadr[j])
        rows.append(
            {
                "name": name,
                "actuator": model.actuator(a).name,
                "kind": "position" if position else "motor",
                "kp": float(gain[0]) * gear if position else None,
                "kd": float(-bias[2]) * gear if position else None,
                "torque_limit": min(limits) if limits else None,
                "range": rng,
                "armature": float(model.dof_armature[dof]),
                "friction_coulomb": float(model.dof_frictionloss[dof]),
                "friction_viscous": float(model.dof_damping[dof]),
            }
        )
    if not rows:
        raise AmorError(f"{path}: the model has no actuators")
    return rows


def _standing(model: mujoco.MjModel, keyframe: str | None, path: Path) -> tuple[dict[str, float], float]:
    """(joint -> angle of the keyframe, root height with the lowest collision point at z = 0)."""
    data = mujoco.MjData(model)
    if keyframe is not None and model.nkey:
        kid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, keyframe) if keyframe else 0
        if kid < 0:
            raise AmorError(f"{path}: no keyframe named {keyframe!r}")
        mujoco.mj_resetDataKeyframe(model, data, kid)
    elif keyframe:
        raise AmorError(f"{path}: no keyframe named {keyframe!r} (the model has none)")
    mujoco.mj_kinematics(model, data)
    root_joint = next(j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE)
    root_z = float(data.qpos[model.jnt_qposadr[root_joint] + 2])
    height = root_z - lowest_point(model, data)
    pose = {}
    for j in range(model.njnt):
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE:
            angle = float(data.qpos[model.jnt_qposadr[j]])
            if angle != 0.0:
                pose[model.joint(j).name] = angle
    return pose, height


def _cache_key(path: Path, keyframe: str | None) -> str:
    st = path.stat()
    raw = json.dumps([str(path.resolve()), st.st_mtime_ns, st.st_size, keyframe, __version__, 1])
    return hashlib.sha256(raw.encode()).hexdigest()[:24]


def read_mjcf(path: Path, keyframe: str | None = "", cache: bool = True) -> dict[str, Any]:
    """What :func:`character_from_mjcf` needs from the file (JSON-ready), cached per file version.

    ``keyframe``: "" for the model's first keyframe (if any), a name, or None for qpos0.
    """
    path = Path(path)
    if not path.is_file():
        raise AmorError(f"{path}: model file not found")
    cached = plugin_cache_dir("from_mjcf") / f"{_cache_key(path, keyframe)}.json" if cache else None
    if cached is not None and cached.is_file():
        try:
            return json.loads(cached.read_text())
        except (OSError, ValueError):
            pass  # a damaged cache entry is rebuilt below
    model = _read_model(path)
    pose, height = _standing(model, keyframe, path)
    info = {
        "root_body": _free_root(model, path),
        "joints": _joint_table(model, path),
        "timestep": float(model.opt.timestep),
        "standing_pose": pose,
        "standing_height": height,
        "mass": float(model.body_subtreemass[0]),
        "bodies": [model.body(b).name for b in range(model.nbody)],
    }
    if cached is not None:
        atomic_write_text(cached, json.dumps(info))
    return info


def character_from_mjcf(
    path: ModelSource,
    *,
    name: str,
    groups: Mapping[str, JointGroup],
    end_effectors: tuple[str, str, str, str],
    keypoints: Mapping[str, str],
    description: str = "",
    kind: Literal["pd", "servo"] = "pd",
    gains: Mapping[str, tuple[float, float]] | None = None,
    torque_limits: Mapping[str, float] | None = None,
    keyframe: str | None = "",
    physics_hz: int | None = None,
    control_hz: int = 50,
    min_standing_fraction: float = 0.8,
    scale_profile: str = "robot",
    objective_scales: Mapping[str, Mapping[str, float]] | None = None,
    add_floor: bool = True,
    licence: str = "",
    cache: bool = True,
) -> CharacterSpec:
    """A CharacterSpec whose joints, gains, limits and standing pose come from the model file.

    Args:
        path: the MJCF, or a lazy :data:`~amorctl.core.specs.ModelSource` (resolved now; see
            :func:`~amorctl.core.specs.package_model` for models inside other packages, and
            :class:`~amorctl.core.specs.LazyCharacter` to defer the whole call to first use).
        name: the character's name.
        groups: joint name or fnmatch pattern -> "upper" | "lower" | "feet"; exact names win, then
            the first matching pattern in order (e.g. ``{"*Hip*": "lower", "*": "upper"}``).
        end_effectors: body names (left hand, right hand, left foot, right foot).
        keypoints: at least ``head``; ``root`` defaults to the free root's body and the hands and
            feet to ``end_effectors``.
        kind: "pd" (position actuators with the gains below) or "servo".
        gains: joint name or pattern -> (kp, kd) overriding the model's position-actuator gains;
            required for joints whose actuator is a motor.
        torque_limits: joint name or pattern -> N·m overriding the model's force limits; required
            for joints the model does not limit.
        keyframe: the standing keyframe: "" = the model's first (if it has any), a name, or None
            for the model's qpos0. Its joint angles become ``standing_pose`` and its root height,
            with the lowest collision point on the floor, ``standing_height``.
        physics_hz: default: the model's own rate (``1 / timestep``), rounded.
        min_standing_fraction: ``min_standing_height = fraction * standing_height``.

    Raises:
        AmorError: naming the file and what is missing (ungrouped joints, a joint without gains or
            torque limit, an end effector or key point body the model lacks).
    """
    path = resolve_model_source(path, name)
    info = read_mjcf(path, keyframe, cache=cache)
    joints = _joint_specs(path, name, info, groups, gains, torque_limits)
    root = info["root_body"]
    full_keypoints = _keypoints(path, name, info, end_effectors, keypoints)
    rate = physics_hz or max(1, round(1.0 / info["timestep"]))
    if rate % control_hz:
        raise AmorError(
            f"{path}: physics rate {rate} Hz is not a multiple of control_hz {control_hz} "
            "(pass physics_hz=...)"
        )
    height = float(info["standing_height"])
    actuated = {j.name for j in joints}
    return CharacterSpec(
        name=name,
        description=description
        or f"{path.stem} ({info['mass']:.1f} kg): free root + {len(joints)} actuated hinges",
        mjcf_path=path,
        root_body=root,
        joints=tuple(joints),
        end_effectors=tuple(end_effectors),
        actuator=ActuatorModel(kind=kind),
        standing_height=round(height, 6),
        min_standing_height=round(min_standing_fraction * height, 4),
        keypoints=full_keypoints,
        scale_profile=scale_profile,
        objective_scales=dict(objective_scales or {}),
        standing_pose={k: v for k, v in info["standing_pose"].items() if k in actuated},
        physics_hz=int(rate),
        control_hz=int(control_hz),
        licence=licence,
        add_floor=add_floor,
    )


def _joint_specs(
    path: Path,
    name: str,
    info: dict[str, Any],
    groups: Mapping[str, JointGroup],
    gains: Mapping[str, tuple[float, float]] | None,
    torque_limits: Mapping[str, float] | None,
) -> list[JointSpec]:
    """The actuated joints of :func:`read_mjcf`'s ``info``, each with its group, gains and torque
    limit (the arguments first, then the model's); one AmorError listing every joint without a
    group, gains or torque limit."""
    joints: list[JointSpec] = []
    ungrouped, no_gain, no_limit = [], [], []
    for row in info["joints"]:
        jname = row["name"]
        group = _group_of(jname, groups)
        if group is None:
            ungrouped.append(jname)
            continue
        if group not in JOINT_GROUPS:
            raise AmorError(
                f"{path}: joint {jname!r}: group {group!r} is not one of {', '.join(JOINT_GROUPS)}"
            )
        kp_kd = _group_of(jname, gains or {}) or ((row["kp"], row["kd"]) if row["kp"] is not None else None)
        limit = _group_of(jname, torque_limits or {}) or row["torque_limit"]
        if kp_kd is None:
            no_gain.append(jname)
        if limit is None:
            no_limit.append(jname)
        if kp_kd is None or limit is None:
            continue
        joints.append(
            JointSpec(
                name=jname,
                group=group,
                range=(row["range"][0], row["range"][1]),
                kp=float(kp_kd[0]),
                kd=float(kp_kd[1]),
                torque_limit=float(limit),
                armature=row["armature"],
                friction_coulomb=row["friction_coulomb"],
                friction_viscous=row["friction_viscous"],
            )
        )
    problems = []
    if ungrouped:
        problems.append(f"no group for joint(s) {', '.join(ungrouped)} (pass groups=...)")
    if no_gain:
        problems.append(f"no PD gains for motor-driven joint(s) {', '.join(no_gain)} (pass gains=...)")
    if no_limit:
        problems.append(f"no torque limit for joint(s) {', '.join(no_limit)} (pass torque_limits=...)")
    if problems:
        raise AmorError(f"{path}: character {name!r}: {'; '.join(problems)}")
    return joints


def _keypoints(
    path: Path,
    name: str,
    info: dict[str, Any],
    end_effectors: tuple[str, str, str, str],
    keypoints: Mapping[str, str],
) -> dict[str, str]:
    """Every key point's body: the root, hands and feet by default, then ``keypoints`` (which
    must name a ``head``); AmorError for a body the model lacks."""
    root = info["root_body"]
    full_keypoints = {
        "root": root,
        "left_hand": end_effectors[0],
        "right_hand": end_effectors[1],
        "left_foot": end_effectors[2],
        "right_foot": end_effectors[3],
        **dict(keypoints),
    }
    if "head" not in full_keypoints:
        raise AmorError(f"{path}: character {name!r}: keypoints needs a 'head' body")
    unknown = sorted({b for b in (*end_effectors, *full_keypoints.values()) if b not in info["bodies"]})
    if unknown:
        raise AmorError(
            f"{path}: character {name!r}: no body named {', '.join(map(repr, unknown))} in the model"
        )
    return full_keypoints


set_mjcf_reader(character_from_mjcf)  # CharacterSpec.from_mjcf calls it (core/ cannot import MuJoCo)
