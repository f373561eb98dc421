"""Describe a character: its spec plus what MuJoCo reports once the model compiles.

The actuation numbers are read from the model the simulation builds
(:func:`amorctl.sim.batch_sim.build_model`), not from the spec's informational fields: per joint
the armature, Coulomb friction (``frictionloss``) and viscous friction (``damping``) MuJoCo
simulates, and for PD characters the position actuator's gain, damping and force limit; a servo
character's law (computed by amorctl) uses the spec's ``kp``, ``kd`` and ``torque_limit``.
"""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np

from amorctl.core.specs import CharacterSpec


def standing_targets(character: CharacterSpec) -> np.ndarray:
    """[J] the standing pose (joints not listed are 0)."""
    return np.array([character.standing_pose.get(j, 0.0) for j in character.joint_names()])


def fmt_list(names: list[str], limit: int = 4) -> str:
    """The first ``limit`` names, and how many more (one report line)."""
    return ", ".join(names[:limit]) + (f" (+{len(names) - limit} more)" if len(names) > limit else "")


def _uniform_or_range(values: list[float]) -> float | list[float]:
    """One number when every joint has it, else ``[min, max]`` (per-joint values: ``joints``)."""
    lo, hi = min(values), max(values)
    return lo if lo == hi else [lo, hi]


def simulated_actuation(spec: CharacterSpec, model: mujoco.MjModel) -> list[dict[str, float]]:
    """Per spec joint, what the compiled ``model`` simulates: ``armature``, ``friction_coulomb``,
    ``friction_viscous`` and (PD characters: the position actuator's) ``kp``, ``kd``,
    ``torque_limit``."""
    from amorctl.sim.batch_sim import _joint_actuator

    rows = []
    for j in spec.joints:
        jid = model.joint(j.name).id
        dof = int(model.jnt_dofadr[jid])
        row = {
            "armature": float(model.dof_armature[dof]),
            "friction_coulomb": float(model.dof_frictionloss[dof]),
            "friction_viscous": float(model.dof_damping[dof]),
            "kp": j.kp,
            "kd": j.kd,
            "torque_limit": j.torque_limit,
        }
        if spec.actuator.kind == "pd":
            a = _joint_actuator(model, jid)
            gear = abs(float(model.actuator_gear[a, 0])) or 1.0
            row["kp"] = float(model.actuator_gainprm[a, 0]) * gear
            row["kd"] = float(-model.actuator_biasprm[a, 2]) * gear
            if model.actuator_forcelimited[a]:
                row["torque_limit"] = float(np.abs(model.actuator_forcerange[a]).max()) * gear
        rows.append(row)
    return rows


def describe_character(spec: CharacterSpec) -> dict[str, Any]:
    """A JSON-ready description; DoF counts use MuJoCo's own names (nq, nv, nu)."""
    from amorctl.sim.batch_sim import build_model

    model = build_model(spec)
    sim = simulated_actuation(spec, model)
    act = spec.actuator
    return {
        "name": spec.name,
        "description": spec.description,
        "mjcf": str(spec.mjcf_path),
        "root_body": spec.root_body,
        "nq": int(model.nq),
        "nv": int(model.nv),
        "nu": int(model.nu),
        "num_joints": spec.num_joints,
        "total_mass": float(model.body_subtreemass[0]),
        "physics_hz": spec.physics_hz,
        "control_hz": spec.control_hz,
        "substeps": spec.substeps,
        "end_effectors": list(spec.end_effectors),
        "keypoints": dict(spec.keypoints),
        "standing_height": spec.standing_height,
        "min_standing_height": spec.min_standing_height,
        "scale_profile": spec.scale_profile,
        "add_floor": spec.add_floor,
        # as simulated: the joint properties from the compiled model (one number, or [min, max])
        "actuator_model": {
            "kind": act.kind,
            "armature": _uniform_or_range([r["armature"] for r in sim]),
            "friction_coulomb": _uniform_or_range([r["friction_coulomb"] for r in sim]),
            "friction_viscous": _uniform_or_range([r["friction_viscous"] for r in sim]),
            "no_load_speed": act.no_load_speed,
            "latency_steps": act.latency_steps,
        },
        "joints": [
            {
                "name": j.name,
                "group": j.group,
                "range": list(j.range),
                "range_deg": [math.degrees(j.range[0]), math.degrees(j.range[1])],
                **row,
            }
            for j, row in zip(spec.joints, sim, strict=True)
        ],
        "licence": spec.licence,
    }
