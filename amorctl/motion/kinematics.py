"""Forward kinematics of a character's MuJoCo model over whole clips.

A :class:`CharacterKinematics` knows where the free root and each actuated joint sit in ``qpos``
and evaluates body poses and the lowest point of the collision geometry for every frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.specs import CharacterSpec
from amorctl.sim.geom_bottom import geom_lowest_z
from amorctl.sim.model import load_model


@dataclass
class CharacterKinematics:
    """A compiled model plus the index maps motion processing needs."""

    spec: CharacterSpec
    model: mujoco.MjModel
    data: mujoco.MjData
    root_qpos: int  # qpos address of the free joint (position, then quaternion)
    joint_qpos: np.ndarray  # [J] qpos address of each actuated joint, character order
    joint_axes: np.ndarray  # [J, 3] hinge axis in the child body's frame
    joint_ranges: np.ndarray  # [J, 2] radians

    def body_id(self, name: str) -> int:
        bid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, name)
        if bid < 0:
            raise AmorError(f"{self.spec.mjcf_path}: no body named {name!r} in character {self.spec.name!r}")
        return int(bid)

    def qpos(self, root_pos: np.ndarray, root_quat: np.ndarray, joint_pos: np.ndarray) -> np.ndarray:
        """Full qpos vectors [T, nq] from root_pos [T, 3], root_quat [T, 4], joint_pos [T, J]."""
        num_frames = root_pos.shape[0]
        q = np.tile(self.model.qpos0, (num_frames, 1))
        q[:, self.root_qpos : self.root_qpos + 3] = root_pos
        q[:, self.root_qpos + 3 : self.root_qpos + 7] = root_quat
        q[:, self.joint_qpos] = joint_pos
        return q

    def body_poses(self, qpos: np.ndarray, bodies: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """World positions [T, B, 3] and quaternions [T, B, 4] of the named bodies."""
        ids = [self.body_id(b) for b in bodies]
        pos = np.zeros((qpos.shape[0], len(ids), 3))
        quat = np.zeros((qpos.shape[0], len(ids), 4))
        for t in range(qpos.shape[0]):
            self.data.qpos[:] = qpos[t]
            mujoco.mj_kinematics(self.model, self.data)
            pos[t] = self.data.xpos[ids]
            quat[t] = self.data.xquat[ids]
        return pos, quat

    def lowest_points(self, qpos: np.ndarray) -> np.ndarray:
        """[T] the lowest world z of the character's collision geometry in each frame."""
        out = np.zeros(qpos.shape[0])
        geoms = self.collision_geoms()
        for t in range(qpos.shape[0]):
            self.data.qpos[:] = qpos[t]
            mujoco.mj_kinematics(self.model, self.data)
            out[t] = min(self.geom_bottom(g) for g in geoms)
        return out

    def collision_geoms(self) -> list[int]:
        """Geoms of the character (not the world body) that take part in contacts."""
        m = self.model
        return [
            g
            for g in range(m.ngeom)
            if m.geom_bodyid[g] != 0
            and m.geom_type[g] != mujoco.mjtGeom.mjGEOM_PLANE
            and (m.geom_contype[g] or m.geom_conaffinity[g])
        ]

    def geom_bottom(self, g: int) -> float:
        """Lowest z of one geom: exact for primitives and meshes (:mod:`amorctl.sim.geom_bottom`)."""
        return geom_lowest_z(self.model, self.data, g)


def character_kinematics(spec: CharacterSpec) -> CharacterKinematics:
    """Compile the character's model and locate its free root and actuated joints."""
    model = load_model(spec)
    data = mujoco.MjData(model)
    root_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, spec.root_body)
    if root_body < 0 or model.body_jntnum[root_body] < 1:
        raise AmorError(f"{spec.mjcf_path}: root body {spec.root_body!r} not found or has no joint")
    root_joint = model.body_jntadr[root_body]
    if model.jnt_type[root_joint] != mujoco.mjtJoint.mjJNT_FREE:
        raise AmorError(f"{spec.mjcf_path}: root body {spec.root_body!r} has no free joint")
    adrs, axes, ranges = [], [], []
    for j in spec.joints:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j.name)
        if jid < 0:
            raise AmorError(f"{spec.mjcf_path}: no joint named {j.name!r} (character {spec.name!r})")
        adrs.append(model.jnt_qposadr[jid])
        axes.append(model.jnt_axis[jid].copy())
        ranges.append(j.range)
    return CharacterKinematics(
        spec=spec,
        model=model,
        data=data,
        root_qpos=int(model.jnt_qposadr[root_joint]),
        joint_qpos=np.asarray(adrs, dtype=np.int64),
        joint_axes=np.asarray(axes),
        joint_ranges=np.asarray(ranges, dtype=np.float64),
    )
