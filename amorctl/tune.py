"""Run a trained policy with weights chosen after training: constant, scheduled w(t), or live.

This is the paper's core promise (Sections 1 and 7.2): one policy, conditioned on w, whose
trade-off is tuned after training without retraining. :class:`TuneEnv` is one environment of a
run, pinned to one motion, that the caller steps with any weights at every control step (through
:class:`~amorctl.envs.wrappers.FixedWeights`); :func:`run_tune` rolls it out under a constant w or a
:class:`~amorctl.schedule.Schedule` and records a :class:`TuneRollout`, which
:func:`write_rollout_mcap` logs with Foxglove schemas and :func:`plot_rollout` draws like the
paper's teaser / Fig. 7 (w(t) as stacked areas above the per-objective rewards). The live page
(``amorctl.live``) drives the same :class:`TuneEnv`. Usage: docs/tune.md.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from amorctl.envs.wrappers import FixedWeights
from amorctl.errors import AmorError
from amorctl.io import atomic_path
from amorctl.rollout import tracking_env
from amorctl.runner import TOY_CONTROL_HZ, check_compatible, load_policy, make_env
from amorctl.schedule import Schedule

# ---------------------------------------------------------------------------- one pinned env


@dataclass(frozen=True)
class StepRecord:
    """What one control step of a :class:`TuneEnv` did (env 0; J joints, B bodies, m objectives).

    Attributes:
        t: time of the observation the action was computed from, seconds.
        weights: [m] the weights the policy saw in that observation.
        action: [A] the policy's (deterministic) action.
        rewards: [m] the per-objective rewards of the step.
        terminated: the character fell or the simulation diverged (the env then restarted).
        joint_pos, joint_vel: [J] simulated joint state after the step (J = 0 without a character).
        ref_joint_pos: [J] the reference's joint positions at the frame the step reached.
        body_pos, body_quat: [B, 3], [B, 4] (w, x, y, z) world poses of the character's bodies.
        ref_body_pos, ref_body_quat: [B, 3], [B, 4] the same for the reference pose (the ghost).
    """

    t: float
    weights: np.ndarray
    action: np.ndarray
    rewards: np.ndarray
    terminated: bool
    joint_pos: np.ndarray
    joint_vel: np.ndarray
    ref_joint_pos: np.ndarray
    body_pos: np.ndarray
    body_quat: np.ndarray
    ref_body_pos: np.ndarray
    ref_body_quat: np.ndarray


class TuneEnv:
    """One environment of a trained run, pinned to one motion, stepped with caller-chosen weights.

    The run's env (``base``) is rebuilt from its resolved config with one env and no fixed
    weights; a tracking env is restricted to the chosen clip, starting at its first frame
    (``select_clips(..., from_start=True)``), and wrapped in :class:`FixedWeights` (``env``).
    :func:`run_tune` rolls ``base`` out with
    :func:`amorctl.rollout.rollout`; the live page steps it one control step at a time with
    :meth:`step`, which puts the weights into the observation the policy acts on, so a change
    reaches the policy at the very next control step.

    Args:
        run_dir: the run directory (``config.toml`` + ``checkpoints/``).
        motion: clip name (exact, unique prefix or suffix; see :mod:`amorctl.motion.resolve`);
            None: the dataset's first clip. Must be None for runs without motions (toy, gym).
        seed: seed of the env.

    Raises:
        AmorError: no run or checkpoint, a checkpoint for another env, an unknown motion.
    """

    def __init__(self, run_dir: str | Path, motion: str | None = None, seed: int = 0) -> None:
        self.run_dir = Path(run_dir)
        if not self.run_dir.is_dir():
            raise AmorError(f"{self.run_dir}: run directory not found")
        self.policy, config, ckpt = load_policy(self.run_dir)
        env_cfg = dataclasses.replace(config.env, num_envs=1, fixed_weights="")
        self.config = dataclasses.replace(config, env=env_cfg, run=dataclasses.replace(config.run, seed=seed))
        base: Any = make_env(self.config)
        check_compatible(ckpt, self.config, base)
        self.checkpoint = ckpt
        self.base = base
        self.names: tuple[str, ...] = tuple(base.reward_space.names)
        self.m = len(self.names)
        self.seed = seed
        self.tracking = tracking_env(base) is not None
        self.dt = float(base.dt) if self.tracking else 1.0 / TOY_CONTROL_HZ
        self.motions: tuple[str, ...] = tuple(c.name for c in base.library.clips) if self.tracking else ()
        self.clip_index = 0
        self.env = FixedWeights(base, np.full(self.m, 1.0 / self.m))
        if self.tracking:
            model = base.sim.model
            self.model: mujoco.MjModel | None = model
            self._data = mujoco.MjData(model)
            self.body_names: tuple[str, ...] = tuple(
                mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}"
                for b in range(1, model.nbody)
            )
        else:
            self.model = None
            self.body_names = ()
        self.motion: str | None = None
        self.steps = 0
        self.obs = np.zeros((1, base.obs_dim), dtype=np.float32)
        self.set_motion(motion)

    # --- motion and restart -----------------------------------------------------------------

    def set_motion(self, motion: str | None) -> None:
        """Pin the env to ``motion`` (None: the first clip) and restart. AmorError if unknown."""
        if not self.tracking:
            if motion is not None:
                raise AmorError(
                    f"run {self.run_dir} trains env kind {self.config.env.kind!r}, which has no motions; "
                    "leave out --motion"
                )
            self.restart()
            return
        from amorctl.motion.resolve import resolve_clip_index

        lib = self.base.library
        k = 0 if motion is None else resolve_clip_index(lib, motion)
        if lib.clips[k].num_frames < 2:
            raise AmorError(f"motion {lib.clips[k].name!r} has fewer than 2 frames")
        self.motion = lib.clips[k].name
        self.clip_index = k
        self.base.select_clips([k], from_start=True)
        self.env = FixedWeights(self.base, self.env.weights[0])
        self.restart()

    @property
    def motion_seconds(self) -> float:
        """Duration of the pinned clip (tracking), else of the run's episode, in seconds."""
        if self.tracking:
            lib = self.base.library
            return float(lib.clip_duration(lib.clips[self.clip_index]))
        return float(self.config.env.episode_seconds)

    def restart(self) -> None:
        """Start over at time 0 (tracking: at the pinned clip's first frame, in its reference state)."""
        obs, _ = self.env.reset(seed=self.seed)
        self.obs = np.asarray(obs, dtype=np.float32)
        self.steps = 0

    # --- stepping ---------------------------------------------------------------------------

    @property
    def t(self) -> float:
        """Seconds since the last restart or episode end (time of the current observation)."""
        return self.steps * self.dt

    def step(self, weights: np.ndarray) -> StepRecord:
        """One control step with ``weights`` [m] (on the simplex) in the policy's observation."""
        self.env.set_weights(weights)
        obs = self.obs.copy()
        obs[:, -self.m :] = self.env.weights  # what FixedWeights puts in every later observation
        seen = obs[0, -self.m :].astype(np.float64)
        t = self.t
        action = np.asarray(self.policy(obs), dtype=np.float32)
        next_obs, rewards, terminated, truncated, _ = self.env.step(action)
        self.obs = np.asarray(next_obs, dtype=np.float32)
        self.steps += 1
        done = bool(terminated[0])
        if done or bool(truncated[0]):  # the env restarted the episode (at the clip's start)
            self.steps = 0
        return StepRecord(
            t=t,
            weights=seen,
            action=action[0].copy(),
            rewards=np.asarray(rewards[0], dtype=np.float64),
            terminated=done,
            **self.poses(),
        )

    def poses(self) -> dict[str, np.ndarray]:
        """Joint state and world body poses of env 0 and of its reference (empty without a character)."""
        if not self.tracking:
            e1, e3, e4 = np.zeros(0), np.zeros((0, 3)), np.zeros((0, 4))
            return dict(joint_pos=e1, joint_vel=e1, ref_joint_pos=e1, body_pos=e3, body_quat=e4,
                        ref_body_pos=e3, ref_body_quat=e4)  # fmt: skip
        sim = self.base.sim
        f = int(self.base.ref_idx[0])
        body_pos, body_quat = self.body_poses(sim.qpos[0])
        ref_pos, ref_quat = self.body_poses(self.reference_qpos(f, sim.qpos[0]))
        return dict(
            joint_pos=sim.joint_pos()[0].copy(),
            joint_vel=sim.joint_vel()[0].copy(),
            ref_joint_pos=self.base.library.joint_pos[f].copy(),
            body_pos=body_pos,
            body_quat=body_quat,
            ref_body_pos=ref_pos,
            ref_body_quat=ref_quat,
        )

    def reference_qpos(self, frame: int, template: np.ndarray) -> np.ndarray:
        """qpos [nq] of the reference at library ``frame`` (other entries from ``template`` [nq])."""
        sim, lib = self.base.sim, self.base.library
        q = np.array(template, dtype=np.float64, copy=True)
        q[sim.root_qpos : sim.root_qpos + 3] = lib.root_pos[frame]
        q[sim.root_qpos + 3 : sim.root_qpos + 7] = lib.root_quat[frame]
        q[sim.joint_qpos] = lib.joint_pos[frame]
        return q

    def body_poses(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World poses [B, 3], [B, 4] (w, x, y, z) of every body but the world body for ``qpos`` [nq]."""
        assert self.model is not None
        self._data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self._data)
        return self._data.xpos[1:].copy(), self._data.xquat[1:].copy()

    def close(self) -> None:
        """Release the simulation."""
        close = getattr(self.base, "close", None)
        if callable(close):
            close()


# ---------------------------------------------------------------------------- a whole rollout


@dataclass
class TuneRollout:
    """A recorded rollout of one env (T control steps; shapes as in :class:`StepRecord`, stacked).

    Attributes:
        objective_names: the m objective names.
        motion: the pinned clip's name, or None.
        dt: control period, seconds.
        times: [T] observation times; weights [T, m]; actions [T, A]; rewards [T, m];
        terminated: [T] bool; joint_pos, joint_vel, ref_joint_pos: [T, J];
        body_pos, ref_body_pos: [T, B, 3]; body_quat, ref_body_quat: [T, B, 4].
        body_names: the B body names; joint_names: the J joint names.
        geoms: the character's geoms (:func:`geom_table`); episode_times: [T] seconds since the
            episode (and the schedule's clock) began, which differs from ``times`` after a fall.
        qpos, ref_qpos: [T, nq] simulator and reference poses (tracking runs; for videos).
    """

    objective_names: tuple[str, ...]
    motion: str | None
    dt: float
    times: np.ndarray
    weights: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    joint_pos: np.ndarray
    joint_vel: np.ndarray
    ref_joint_pos: np.ndarray
    body_pos: np.ndarray
    body_quat: np.ndarray
    ref_body_pos: np.ndarray
    ref_body_quat: np.ndarray
    body_names: tuple[str, ...] = ()
    joint_names: tuple[str, ...] = ()
    geoms: list[dict[str, Any]] = field(default_factory=list)
    episode_times: np.ndarray | None = None
    qpos: np.ndarray | None = None
    ref_qpos: np.ndarray | None = None

    @property
    def returns(self) -> np.ndarray:
        """[m] per-objective undiscounted returns (sums of the rewards)."""
        return self.rewards.sum(axis=0)

    def action_rate(self) -> np.ndarray:
        """[T] squared action change ||a_t - a_{t-1}||^2 per step (0 at the first step and after a
        restart): the quantity the ``smooth`` objective's action-rate term penalizes."""
        diff = np.zeros(len(self.times))
        if len(self.times) > 1:
            diff[1:] = ((self.actions[1:] - self.actions[:-1]) ** 2).sum(axis=1)
            diff[1:][self.terminated[:-1]] = 0.0
        return diff

    def returns_between(self, t0: float, t1: float) -> np.ndarray:
        """[m] mean per-step reward over the steps whose time lies in [t0, t1)."""
        sel = (self.times >= t0) & (self.times < t1)
        if not sel.any():
            return np.full(len(self.objective_names), np.nan)
        return self.rewards[sel].mean(axis=0)


def geom_table(model: mujoco.MjModel) -> list[dict[str, Any]]:
    """The visible geoms of a model for drawing: type name, body index (0-based, world excluded),
    local pos [3], quat [4] (w, x, y, z), MuJoCo size [3], rgba [4]. Planes are left out."""
    names = {
        int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
        int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
        int(mujoco.mjtGeom.mjGEOM_ELLIPSOID): "ellipsoid",
        int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
        int(mujoco.mjtGeom.mjGEOM_BOX): "box",
    }
    out = []
    for g in range(model.ngeom):
        kind = names.get(int(model.geom_type[g]))
        body = int(model.geom_bodyid[g])
        if kind is None or body == 0:
            continue
        out.append(
            dict(
                type=kind,
                body=body - 1,
                pos=model.geom_pos[g].copy(),
                quat=model.geom_quat[g].copy(),
                size=model.geom_size[g].copy(),
                rgba=model.geom_rgba[g].copy(),
            )
        )
    return out


def run_tune(
    tenv: TuneEnv,
    weights: np.ndarray | Schedule,
    seconds: float | None = None,
    *,
    stop_on_fall: bool = True,
) -> TuneRollout:
    """Roll the pinned motion out from its start under constant weights or a schedule.

    The stepping is :func:`amorctl.rollout.rollout` on ``tenv.base`` (one env); this adds the
    world body poses of the character and of the reference, from the recorded ``qpos`` and
    reference frames, for the MCAP log and the plot.

    Args:
        tenv: the env.
        weights: [m] constant weights on the simplex, or a schedule (its keyframes for the
            pinned motion if it has them), evaluated at each observation's time since the start.
        seconds: rollout length; default the motion's duration (the episode's for toy runs).
        stop_on_fall: end the rollout at the first termination (fall or divergence); otherwise
            the motion (and the schedule's clock) starts over and the rollout goes on.

    Returns:
        the recorded :class:`TuneRollout` (T = ceil(seconds / dt) steps, fewer after a fall).
    """
    from amorctl.rollout import rollout

    seconds = tenv.motion_seconds if seconds is None else float(seconds)
    if not np.isfinite(seconds) or seconds <= 0:
        raise AmorError(f"--seconds must be a positive number, got {seconds}")
    n_steps = max(1, int(np.ceil(seconds / tenv.dt - 1e-9)))
    if not isinstance(weights, Schedule):
        weights = np.asarray(weights, dtype=np.float64)
        if weights.shape != (tenv.m,):
            raise AmorError(f"weights have shape {weights.shape}; expected ({tenv.m},)")
    ro = rollout(
        tenv.policy,
        tenv.base,
        weights,
        episodes=1 if stop_on_fall else n_steps + 1,
        seed=tenv.seed,
        max_steps=n_steps,
        record_qpos=tenv.tracking,
    )
    assert ro.rewards is not None and ro.weights is not None and ro.actions is not None
    assert ro.terminated is not None and ro.done is not None
    steps = ro.num_steps
    # time of each step's observation: seconds since its episode began
    t_ep = np.zeros(steps)
    for k in range(1, steps):
        t_ep[k] = 0.0 if ro.done[k - 1, 0] else t_ep[k - 1] + ro.dt
    empty = np.zeros((steps, 0))
    joint_pos = joint_vel = ref_joint_pos = empty
    body_pos = ref_body_pos = np.zeros((steps, 0, 3))
    body_quat = ref_body_quat = np.zeros((steps, 0, 4))
    joint_names: tuple[str, ...] = ()
    qpos = ref_qpos = None
    if tenv.tracking:
        assert ro.qpos is not None and ro.frame_index is not None and ro.joint_pos is not None
        sim, lib = tenv.base.sim, tenv.base.library
        joint_names = tuple(lib.joint_names)
        qpos = ro.qpos[:, 0]
        joint_pos = qpos[:, sim.joint_qpos]
        joint_vel = np.gradient(joint_pos, ro.dt, axis=0) if steps > 1 else np.zeros_like(joint_pos)
        frames = ro.frame_index[:, 0]
        ref_joint_pos = lib.joint_pos[frames]
        poses = [tenv.body_poses(q) for q in qpos]
        ref_poses = [
            tenv.body_poses(tenv.reference_qpos(int(f), q)) for f, q in zip(frames, qpos, strict=True)
        ]
        body_pos = np.stack([p for p, _ in poses])
        body_quat = np.stack([q for _, q in poses])
        ref_body_pos = np.stack([p for p, _ in ref_poses])
        ref_body_quat = np.stack([q for _, q in ref_poses])
    model = tenv.model
    return TuneRollout(
        objective_names=tenv.names,
        motion=tenv.motion,
        dt=ro.dt,
        times=np.arange(steps) * ro.dt,
        weights=ro.weights[:, 0].astype(np.float64),
        actions=ro.actions[:, 0],
        rewards=ro.rewards[:, 0].astype(np.float64),
        terminated=ro.terminated[:, 0].copy(),
        joint_pos=joint_pos,
        joint_vel=joint_vel,
        ref_joint_pos=ref_joint_pos,
        body_pos=body_pos,
        body_quat=body_quat,
        ref_body_pos=ref_body_pos,
        ref_body_quat=ref_body_quat,
        body_names=tenv.body_names,
        joint_names=joint_names,
        geoms=geom_table(model) if model is not None else [],
        episode_times=t_ep,
        qpos=qpos,
        ref_qpos=ref_qpos,
    )


# ---------------------------------------------------------------------------- MCAP log


def _readable(tmp: Path) -> None:
    """Give a finished temporary output the permissions a plain ``open()`` would (mkstemp's are 0600)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)


#: Topics of the rollout log (see docs/tune.md).
TOPIC_TF = "/tf"
TOPIC_SCENE = "/character"
TOPIC_JOINTS = "/joint_states"
TOPIC_REF_JOINTS = "/reference/joint_states"
TOPIC_ACTIONS = "/actions"
TOPIC_WEIGHTS = "/weights"
TOPIC_REWARDS = "/rewards"
WORLD_FRAME = "world"
REF_PREFIX = "ref/"


def _named_schema(title: str, names: tuple[str, ...]) -> dict[str, Any]:
    return {
        "title": title,
        "type": "object",
        "properties": {"t": {"type": "number"}, **{n: {"type": "number"} for n in names}},
    }


def _joint_schema(title: str) -> dict[str, Any]:
    arr = {"type": "array", "items": {"type": "number"}}
    return {
        "title": title,
        "type": "object",
        "properties": {
            "name": {"type": "array", "items": {"type": "string"}},
            "position": arr,
            "velocity": arr,
        },
    }


def write_rollout_mcap(
    rollout: TuneRollout, path: str | Path, metadata: dict[str, str] | None = None
) -> None:
    """Write the rollout as an MCAP file that plays in Foxglove, atomically.

    Channels (one message per control step unless said otherwise; log time = step time in ns):
    ``/tf`` foxglove.FrameTransforms (world -> each body, and world -> ``ref/<body>`` for the
    reference), ``/character`` foxglove.SceneUpdate (once: the geoms as cubes, spheres and
    cylinders attached to the body frames, the reference's translucent), ``/joint_states`` and
    ``/reference/joint_states`` (JSON: name, position, velocity), ``/actions`` (JSON: values),
    ``/weights`` and ``/rewards`` (JSON: t and one number per objective name, so Foxglove's Plot
    panel plots ``/weights.up``). Runs without a character have only the last three.
    """
    import foxglove
    from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel
    from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Timestamp, Vector3

    names = rollout.objective_names
    ns = (np.round(rollout.times * 1e9)).astype(np.int64) + 1  # log times > 0
    with atomic_path(path) as tmp:
        ctx = foxglove.Context()
        with foxglove.open_mcap(tmp, allow_overwrite=True, context=ctx) as writer:
            writer.write_metadata(
                "amorctl.tune",
                {"objectives": ",".join(names), "motion": rollout.motion or "", "dt": repr(rollout.dt),
                 **(metadata or {})},
            )  # fmt: skip
            actions = foxglove.Channel(
                TOPIC_ACTIONS,
                schema={"title": "amorctl.Actions", "type": "object",
                        "properties": {"t": {"type": "number"}, "values": {"type": "array"}}},
                context=ctx,
            )  # fmt: skip
            w_ch = foxglove.Channel(
                TOPIC_WEIGHTS, schema=_named_schema("amorctl.Weights", names), context=ctx
            )
            r_ch = foxglove.Channel(
                TOPIC_REWARDS, schema=_named_schema("amorctl.Rewards", names), context=ctx
            )
            character = len(rollout.body_names) > 0
            if character:
                tf = FrameTransformsChannel(TOPIC_TF, context=ctx)
                scene = SceneUpdateChannel(TOPIC_SCENE, context=ctx)
                joints = foxglove.Channel(
                    TOPIC_JOINTS, schema=_joint_schema("amorctl.JointState"), context=ctx
                )
                ref_joints = foxglove.Channel(
                    TOPIC_REF_JOINTS, schema=_joint_schema("amorctl.JointState"), context=ctx
                )
                scene.log(_scene_update(rollout), log_time=int(ns[0]))
            jn = list(rollout.joint_names)
            for k, t in enumerate(rollout.times):
                lt = int(ns[k])
                actions.log({"t": float(t), "values": rollout.actions[k].tolist()}, log_time=lt)
                w_ch.log(
                    {"t": float(t), **dict(zip(names, rollout.weights[k].tolist(), strict=True))}, log_time=lt
                )
                r_ch.log(
                    {"t": float(t), **dict(zip(names, rollout.rewards[k].tolist(), strict=True))}, log_time=lt
                )
                if not character:
                    continue
                stamp = Timestamp(sec=int(lt // 1_000_000_000), nsec=int(lt % 1_000_000_000))
                transforms = []
                for prefix, pos, quat in (
                    ("", rollout.body_pos[k], rollout.body_quat[k]),
                    (REF_PREFIX, rollout.ref_body_pos[k], rollout.ref_body_quat[k]),
                ):
                    for b, body in enumerate(rollout.body_names):
                        p, q = pos[b], quat[b]
                        transforms.append(
                            FrameTransform(
                                timestamp=stamp,
                                parent_frame_id=WORLD_FRAME,
                                child_frame_id=prefix + body,
                                translation=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                                rotation=Quaternion(
                                    x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0])
                                ),
                            )
                        )
                tf.log(FrameTransforms(transforms=transforms), log_time=lt)
                joints.log(
                    {"name": jn, "position": rollout.joint_pos[k].tolist(),
                     "velocity": rollout.joint_vel[k].tolist()},
                    log_time=lt,
                )  # fmt: skip
                ref_joints.log(
                    {"name": jn, "position": rollout.ref_joint_pos[k].tolist(), "velocity": []}, log_time=lt
                )
        _readable(tmp)


def _scene_update(rollout: TuneRollout) -> Any:
    """One foxglove.SceneUpdate drawing every geom on its body frame (character and reference)."""
    from foxglove.messages import (
        Color,
        CubePrimitive,
        CylinderPrimitive,
        Pose,
        Quaternion,
        SceneEntity,
        SceneUpdate,
        SpherePrimitive,
        Vector3,
    )

    entities = []
    for prefix, alpha_scale in (("", 1.0), (REF_PREFIX, 0.3)):
        for b, body in enumerate(rollout.body_names):
            cubes, spheres, cylinders = [], [], []
            for g in rollout.geoms:
                if g["body"] != b:
                    continue
                p, q, s, c = g["pos"], g["quat"], g["size"], g["rgba"]
                pose = Pose(
                    position=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                    orientation=Quaternion(x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0])),
                )
                rgba = (0.4, 0.7, 1.0, 0.3) if prefix else tuple(float(v) for v in c)
                color = Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3] * (1.0 if prefix else alpha_scale))
                if g["type"] == "box":
                    size = Vector3(x=2 * float(s[0]), y=2 * float(s[1]), z=2 * float(s[2]))
                    cubes.append(CubePrimitive(pose=pose, size=size, color=color))
                elif g["type"] in ("sphere", "ellipsoid"):
                    r = [float(s[0])] * 3 if g["type"] == "sphere" else [float(v) for v in s]
                    size = Vector3(x=2 * r[0], y=2 * r[1], z=2 * r[2])
                    spheres.append(SpherePrimitive(pose=pose, size=size, color=color))
                else:  # capsule / cylinder: radius s[0], half-length s[1] along the local z axis
                    extra = 2 * float(s[0]) if g["type"] == "capsule" else 0.0
                    size = Vector3(x=2 * float(s[0]), y=2 * float(s[0]), z=2 * float(s[1]) + extra)
                    cylinders.append(
                        CylinderPrimitive(pose=pose, size=size, bottom_scale=1.0, top_scale=1.0, color=color)
                    )
            entities.append(
                SceneEntity(
                    frame_id=prefix + body,
                    id=prefix + body,
                    frame_locked=True,
                    cubes=cubes,
                    spheres=spheres,
                    cylinders=cylinders,
                )
            )
    return SceneUpdate(entities=entities)


def read_rollout_mcap(path: str | Path) -> dict[str, list[Any]]:
    """Decoded messages by topic of a rollout log, in log order: JSON channels as dicts,
    protobuf (Foxglove schema) channels as protobuf messages. Uses only ``mcap`` readers."""
    import json

    from mcap.decoder import DecoderFactory as McapDecoderFactory
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    class _JsonDecoders(McapDecoderFactory):
        def decoder_for(self, message_encoding: str, schema: Any) -> Any:
            return json.loads if message_encoding == "json" else None

    out: dict[str, list[Any]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory(), _JsonDecoders()])
        for _schema, channel, _message, decoded in reader.iter_decoded_messages(log_time_order=True):
            out.setdefault(channel.topic, []).append(decoded)
    return out


# ---------------------------------------------------------------------------- plot


def plot_rollout(rollout: TuneRollout, path: str | Path, title: str = "") -> None:
    """PNG of w(t) as stacked areas (top) over the per-objective rewards r_i(t) (bottom), atomically.

    The paper's teaser / Fig. 7 style: the colour of an objective is the same in both panels, so
    a reader sees which reward moves when its weight does.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = rollout.objective_names
    colors = plt.get_cmap("tab10")(np.arange(len(names)) % 10)
    fig, (ax_w, ax_r) = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True, height_ratios=[1, 1.4])
    t = rollout.times
    ax_w.stackplot(t, rollout.weights.T, labels=list(names), colors=colors, step="post", alpha=0.9)
    ax_w.set_ylim(0, 1)
    ax_w.set_ylabel("weights w(t)")
    ax_w.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    for i, name in enumerate(names):
        ax_r.plot(t, rollout.rewards[:, i], color=colors[i], lw=1.2, label=name)
    ax_r.set_ylabel("reward r_i(t)")
    ax_r.set_xlabel("time (s)")
    for tt in t[rollout.terminated]:
        ax_r.axvline(tt, color="k", ls=":", lw=1)
    ax_w.set_title(title or f"amorctl tune — {rollout.motion or 'run'}")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
        _readable(tmp)
    plt.close(fig)
