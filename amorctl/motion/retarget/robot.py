"""Robot clips (already in the character's joints, e.g. ``.npz``): floor lift and a foot report.

Such clips are not retargeted, so there is no key-point error to report. What can go wrong is
contact: the clip may have been recorded on another floor height, with another foot model, or
drift. :func:`finish_robot_clip` lifts the root where the collision geometry (meshes exactly,
see :mod:`amorctl.sim.geom_bottom`) goes below z = 0, and reports the deepest penetration before
the lift, the largest hover of the lower foot, and the feet's sliding speed while in contact.
"""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np

from amorctl.motion.kinematics import CharacterKinematics
from amorctl.motion.retarget.common import lift_to_floor
from amorctl.motion.source import CharacterMotion
from amorctl.sim.geom_bottom import collision_geoms, geom_lowest_z

#: A foot counts as in contact when its lowest point is this close to the floor, m.
CONTACT_HEIGHT = 0.02


def _foot_geoms(kin: CharacterKinematics, body: str) -> list[int]:
    """Collision geoms of a foot body and of the bodies below it (toes)."""
    m = kin.model
    root = kin.body_id(body)
    under = {root}
    for b in range(root + 1, m.nbody):
        if m.body_parentid[b] in under:
            under.add(b)
    return [g for g in collision_geoms(m) if m.geom_bodyid[g] in under]


def foot_report(motion: CharacterMotion, kin: CharacterKinematics) -> dict[str, float]:
    """Per clip: lowest point [m] over the clip, foot contact fraction, sliding speed in contact (m/s).

    ``lowest_point_min`` < 0 is penetration; ``lower_foot_hover_max`` is the largest height of
    the lower foot above the floor (feet both in the air, e.g. jumps, count too).
    """
    m, d = kin.model, kin.data
    feet = list(kin.spec.end_effectors[2:])
    geoms = {f: _foot_geoms(kin, f) for f in feet}
    every = collision_geoms(m)
    qpos = kin.qpos(motion.root_pos, motion.root_quat, motion.joint_pos)
    num = qpos.shape[0]
    low = np.zeros(num)
    foot_low = np.zeros((num, len(feet)))
    foot_xy = np.zeros((num, len(feet), 2))
    ids = [kin.body_id(f) for f in feet]
    for t in range(num):
        d.qpos[:] = qpos[t]
        mujoco.mj_kinematics(m, d)
        low[t] = min(geom_lowest_z(m, d, g) for g in every)
        for k, f in enumerate(feet):
            foot_low[t, k] = min((geom_lowest_z(m, d, g) for g in geoms[f]), default=float(d.xpos[ids[k], 2]))
        foot_xy[t] = d.xpos[ids, :2]
    contact = foot_low < CONTACT_HEIGHT
    fps = 1.0 / float(np.mean(np.diff(motion.times))) if num > 1 else 0.0
    slide = []
    for k in range(len(feet)):
        both = contact[1:, k] & contact[:-1, k]
        if both.any():
            v = np.linalg.norm(np.diff(foot_xy[:, k], axis=0), axis=-1) * fps
            slide.append(float(v[both].mean()))
    return {
        "lowest_point_min": float(low.min()),
        "foot_penetration_max": float(max(0.0, -foot_low.min())),
        "lower_foot_hover_max": float(max(0.0, foot_low.min(axis=1).max())),
        "foot_contact_fraction": float(contact.any(axis=1).mean()),
        "foot_sliding": float(np.mean(slide)) if slide else 0.0,
    }


def finish_robot_clip(motion: CharacterMotion, kin: CharacterKinematics) -> CharacterMotion:
    """Lift the clip onto the floor; record the foot report before and after in ``stats``.

    ``retarget_error`` stays 0 (the joints were used as given); ``stats["method"]`` says so.
    """
    before = foot_report(motion, kin)
    out, lift = lift_to_floor(motion, kin)
    after = foot_report(out, kin)
    stats = dict(motion.stats)
    stats.update(
        method="none (robot clip in the character's joints)",
        penetration_before_lift_m=before["foot_penetration_max"],
        lowest_point_before_lift_m=before["lowest_point_min"],
        floor_lift_max=float(lift.max()),
        floor_lift_frames=int((lift > 0).sum()),
        **after,
    )
    return replace(out, stats=stats)
