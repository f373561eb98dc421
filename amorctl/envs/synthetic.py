"""A small synthetic :class:`MotionLibrary` for tests and benchmarks (no mocap needed).

Each clip holds the character's standing pose at a fixed heading with a sinusoid added to every
actuated joint; end-effector poses come from MuJoCo forward kinematics of each frame, velocities
from finite differences, ``frames`` from :func:`amorctl.core.frame_layout.frame_features`, and
the latent ``z`` is a (sin, cos) phase code standing in for the motion VAE.
"""

from __future__ import annotations

import mujoco
import numpy as np

from amorctl.core.frame_layout import frame_features
from amorctl.core.geometry import quat_mul, yaw_quat
from amorctl.core.specs import CharacterSpec
from amorctl.motion.clips import ClipInfo, MotionLibrary


def synthetic_library(
    character: CharacterSpec,
    num_clips: int = 3,
    seconds: float = 2.0,
    amplitude: float = 0.15,
    seed: int = 0,
) -> MotionLibrary:
    """Swaying-in-place clips at the character's control rate.

    Args:
        character: the character the clips are for.
        num_clips: K clips, each with its own heading, frequency and phases.
        seconds: duration of each clip.
        amplitude: joint sinusoid amplitude, rad (clipped to the joint range).
        seed: seed of the random headings, frequencies and phases.
    """
    from amorctl.sim.batch_sim import BatchSim  # joint/root indexing of the compiled model

    rng = np.random.default_rng(seed)
    sim = BatchSim(character, num_envs=1, nthread=1)
    m = sim.model
    sim.close()
    d = mujoco.MjData(m)
    fps = float(character.control_hz)
    nf = round(seconds * fps) + 1
    q0 = m.qpos0[sim.root_qpos + 3 : sim.root_qpos + 7]
    body_ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in character.end_effectors]

    arrays: dict[str, list[np.ndarray]] = {k: [] for k in ("rp", "rq", "q", "ep", "eq")}
    clips = []
    for k in range(num_clips):
        rp, rq, q = _sway(rng, character, np.arange(nf) / fps, amplitude, q0)
        ep, eq = _body_poses(m, d, sim.root_qpos, sim.joint_qpos, body_ids, rp, rq, q)
        for key, val in zip(("rp", "rq", "q", "ep", "eq"), (rp, rq, q, ep, eq), strict=True):
            arrays[key].append(val)
        clips.append(
            ClipInfo(
                name=f"sway{k}",
                source="synthetic",
                sha256="",
                licence="CC0-1.0",
                start=k * nf,
                num_frames=nf,
                source_fps=fps,
            )
        )

    def cat(key: str) -> np.ndarray:
        return np.concatenate(arrays[key], axis=0)

    def grad(key: str) -> np.ndarray:
        return np.concatenate([np.gradient(a, 1.0 / fps, axis=0) for a in arrays[key]], axis=0)

    root_pos, root_quat, joint_pos, ee_pos, ee_quat = cat("rp"), cat("rq"), cat("q"), cat("ep"), cat("eq")
    zeros3 = np.zeros_like(root_pos)
    joint_vel, ee_lin_vel = grad("q"), grad("ep")
    frames = frame_features(
        root_pos, root_quat, zeros3, zeros3, joint_pos, joint_vel, ee_pos, ee_quat, ee_lin_vel
    )
    phase = 2 * np.pi * np.concatenate([np.arange(nf) / (nf - 1)] * num_clips)
    return MotionLibrary(
        character=character.name,
        fps=fps,
        joint_names=character.joint_names(),
        end_effectors=character.end_effectors,
        clips=tuple(clips),
        root_pos=root_pos,
        root_quat=root_quat,
        root_lin_vel=zeros3,
        root_ang_vel=zeros3.copy(),
        joint_pos=joint_pos,
        joint_vel=joint_vel,
        ee_pos=ee_pos,
        ee_quat=ee_quat,
        ee_lin_vel=ee_lin_vel,
        frames=frames.astype(np.float32),
        z=np.stack([np.sin(phase), np.cos(phase)], axis=-1).astype(np.float32),
        metadata={"synthetic": True},
    )


def _sway(
    rng: np.random.Generator, character: CharacterSpec, t: np.ndarray, amplitude: float, q0: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One clip at times ``t`` [T]: root positions [T, 3] (standing height, a random spot), root
    quaternions [T, 4] (the model's ``q0`` turned to a random heading) and joint angles [T, J] (the
    standing pose plus a sinusoid of random frequency and phases, clipped to the joint ranges)."""
    lo = np.array([j.range[0] for j in character.joints])
    hi = np.array([j.range[1] for j in character.joints])
    stand = np.array([character.standing_pose.get(j.name, 0.0) for j in character.joints])
    freq = rng.uniform(0.4, 1.0)
    phase = rng.uniform(0, 2 * np.pi, size=character.num_joints)
    q = np.clip(stand + amplitude * np.sin(2 * np.pi * freq * t[:, None] + phase), lo, hi)
    yaw = rng.uniform(-np.pi, np.pi)
    rq = np.tile(quat_mul(yaw_quat(np.array(yaw)), q0), (len(t), 1))
    rp = np.tile([rng.uniform(-1, 1), rng.uniform(-1, 1), character.standing_height], (len(t), 1))
    return rp, rq, q


def _body_poses(
    m: mujoco.MjModel,
    d: mujoco.MjData,
    root_qpos: int,
    joint_qpos: np.ndarray,
    body_ids: list[int],
    rp: np.ndarray,
    rq: np.ndarray,
    q: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """World positions [T, B, 3] and quaternions [T, B, 4] of ``body_ids`` at every frame, by
    forward kinematics of root positions ``rp`` [T, 3], root quaternions ``rq`` [T, 4] and joint
    angles ``q`` [T, J] (setup only, not a hot path)."""
    ep, eq = np.empty((len(q), len(body_ids), 3)), np.empty((len(q), len(body_ids), 4))
    for i in range(len(q)):
        d.qpos[:] = m.qpos0
        d.qpos[root_qpos : root_qpos + 3] = rp[i]
        d.qpos[root_qpos + 3 : root_qpos + 7] = rq[i]
        d.qpos[joint_qpos] = q[i]
        mujoco.mj_kinematics(m, d)
        ep[i], eq[i] = d.xpos[body_ids], d.xquat[body_ids]
    return ep, eq
