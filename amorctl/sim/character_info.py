"""Describe a character: its spec plus what MuJoCo reports once the model compiles."""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any

from amorctl.core.specs import CharacterSpec
from amorctl.sim.model import load_model


def describe_character(spec: CharacterSpec) -> dict[str, Any]:
    """A JSON-ready description; DoF counts use MuJoCo's own names (nq, nv, nu)."""
    model = load_model(spec)
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
        "actuator_model": asdict(spec.actuator),
        "joints": [
            {
                "name": j.name,
                "group": j.group,
                "range": list(j.range),
                "range_deg": [math.degrees(j.range[0]), math.degrees(j.range[1])],
                "kp": j.kp,
                "kd": j.kd,
                "torque_limit": j.torque_limit,
                # what the compiled model simulates (the spec's value when it states one)
                "armature": float(model.dof_armature[model.jnt_dofadr[model.joint(j.name).id]]),
                "friction_coulomb": float(model.dof_frictionloss[model.jnt_dofadr[model.joint(j.name).id]]),
                "friction_viscous": float(model.dof_damping[model.jnt_dofadr[model.joint(j.name).id]]),
            }
            for j in spec.joints
        ],
        "licence": spec.licence,
    }
