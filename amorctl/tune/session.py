"""Run a trained policy with weights chosen after training: constant, scheduled w(t), or live.

This is the paper's core promise (Sections 1 and 7.2): one policy, conditioned on w, whose
trade-off is tuned after training without retraining. :class:`PinnedMotion` is one environment of a
run, pinned to one motion, that the caller steps with any weights at every control step (through
:class:`~amorctl.envs.wrappers.FixedWeights`); :func:`run_tune` rolls it out under a constant w or a
:class:`~amorctl.core.schedule.Schedule` and records a :class:`TuneRollout`, which
:func:`amorctl.outputs.mcap_log.write_rollout_mcap` logs with Foxglove schemas and
:func:`amorctl.outputs.plots.plot_rollout` draws like the
paper's teaser / Fig. 7 (w(t) as stacked areas above the per-objective rewards). The live page
(``amorctl.tune.live``) drives the same :class:`PinnedMotion`. Usage: docs/tune.md.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from amorctl.analysis.rollout import Rollout, rollout
from amorctl.core.contracts import TrackingView, tracking_view
from amorctl.core.errors import AmorError
from amorctl.core.levers import TRAINING_ONLY_ENV
from amorctl.core.schedule import Schedule
from amorctl.core.vecenv import close_env
from amorctl.envs.factory import TOY_CONTROL_HZ, make_env
from amorctl.envs.wrappers import FixedWeights
from amorctl.motion.resolve import resolve_name
from amorctl.train.rundir import RunDir, check_compatible

# ---------------------------------------------------------------------------- one pinned env


@dataclass(frozen=True)
class StepRecord:
    """What one control step of a :class:`PinnedMotion` did (env 0; J joints, B bodies, m objectives).

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


class PinnedMotion:
    """One environment of a trained run, pinned to one motion, stepped with caller-chosen weights.

    The run's env (``base``) is rebuilt from its resolved config with one env and no fixed
    weights; a tracking env is restricted to the chosen clip, starting at its first frame
    (``select_clips(..., from_start=True)``), and wrapped in :class:`FixedWeights` (``env``).
    :func:`run_tune` rolls ``base`` out with
    :func:`amorctl.analysis.rollout.rollout`; the live page steps it one control step at a time with
    :meth:`step`, which puts the weights into the observation the policy acts on, so a change
    reaches the policy at the very next control step.

    Args:
        run_dir: the run directory (``config.toml`` + ``checkpoints/``).
        motion: clip name (exact, unique prefix or suffix; see :mod:`amorctl.motion.resolve`);
            None: the dataset's first clip. Must be None for runs without motions (toy, gym).
        seed: seed of the env.
        dataset: held-out motion dataset to track instead of the run's (``tune --data``; clips
            re-encoded with the run's VAE, see :mod:`amorctl.motion.heldout`).

    Raises:
        AmorError: no run or checkpoint, a checkpoint for another env, an unknown motion, a
            dataset that does not fit the run.
    """

    def __init__(
        self, run_dir: str | Path, motion: str | None = None, seed: int = 0, dataset: Path | None = None
    ) -> None:
        self.run_dir = Path(run_dir)
        run = RunDir.open(self.run_dir)
        config = run.config_for_data(dataset)  # --data: the run's dataset moved, or held-out clips
        ckpt = run.checkpoint()
        self.policy = run.policy_of(ckpt)
        env_cfg = dataclasses.replace(config.env, num_envs=1, fixed_weights="", **TRAINING_ONLY_ENV)
        self.config = dataclasses.replace(config, env=env_cfg, run=dataclasses.replace(config.run, seed=seed))
        base: Any = make_env(self.config)
        check_compatible(ckpt, self.config, base)
        self.checkpoint = ckpt
        self.base = base
        self.names: tuple[str, ...] = tuple(base.reward_space.names)
        self.m = len(self.names)
        self.seed = seed
        self.view: TrackingView | None = tracking_view(base)
        self.tracking = self.view is not None
        self.dt = float(self.view.dt) if self.view is not None else 1.0 / TOY_CONTROL_HZ
        self.motions: tuple[str, ...] = self.view.clip_names if self.view is not None else ()
        self.clip_index = 0
        self.env = FixedWeights(base, np.full(self.m, 1.0 / self.m))
        if self.view is not None:
            model = self.view.model
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
        view = self.view
        if view is None:
            if motion is not None:
                raise AmorError(
                    f"run {self.run_dir} trains env kind {self.config.env.kind!r}, which has no motions; "
                    "leave out --motion"
                )
            self.restart()
            return
        names = view.clip_names
        k = (
            0
            if motion is None
            else names.index(resolve_name(motion, names, f"the {view.character.name} dataset"))
        )
        if view.clip_frame_counts[k] < 2:
            raise AmorError(f"motion {names[k]!r} has fewer than 2 frames")
        self.motion = names[k]
        self.clip_index = k
        view.select_clips([k], from_start=True)
        self.env = FixedWeights(self.base, self.env.weights[0])
        self.restart()

    @property
    def motion_seconds(self) -> float:
        """Duration of the pinned clip (tracking), else of the run's episode, in seconds."""
        if self.view is not None:
            return float(self.view.clip_seconds[self.clip_index])
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
        view = self.view
        if view is None:
            e1, e3, e4 = np.zeros(0), np.zeros((0, 3)), np.zeros((0, 4))
            return dict(
                joint_pos=e1,
                joint_vel=e1,
                ref_joint_pos=e1,
                body_pos=e3,
                body_quat=e4,
                ref_body_pos=e3,
                ref_body_quat=e4,
            )
        frame = view.reference_index()[:1]
        body_pos, body_quat = self.body_poses(view.qpos()[0])
        ref_pos, ref_quat = self.body_poses(view.reference_qpos(frame)[0])
        return dict(
            joint_pos=view.joint_pos()[0],
            joint_vel=view.joint_vel()[0],
            ref_joint_pos=view.reference_joint_pos(frame)[0],
            body_pos=body_pos,
            body_quat=body_quat,
            ref_body_pos=ref_pos,
            ref_body_quat=ref_quat,
        )

    def body_poses(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World poses [B, 3], [B, 4] (w, x, y, z) of every body but the world body for ``qpos`` [nq]."""
        assert self.model is not None
        self._data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self._data)
        return self._data.xpos[1:].copy(), self._data.xquat[1:].copy()

    def close(self) -> None:
        """Release the simulation."""
        close_env(self.base)


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
    tenv: PinnedMotion,
    weights: np.ndarray | Schedule,
    seconds: float | None = None,
    *,
    stop_on_fall: bool = True,
) -> TuneRollout:
    """Roll the pinned motion out from its start under constant weights or a schedule.

    The stepping is :func:`amorctl.analysis.rollout.rollout` on ``tenv.base`` (one env); this adds
    the simulated and reference poses (qpos for videos, world body poses for the MCAP log and the
    plot) from the recorded qpos and reference frames, read through the env's tracking view.

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
        body_names=tenv.body_names,
        geoms=geom_table(model) if model is not None else [],
        episode_times=t_ep,
        **_pose_arrays(tenv, ro),
    )


def _pose_arrays(tenv: PinnedMotion, ro: Rollout) -> dict[str, Any]:
    """The joint, body and qpos arrays of a :class:`TuneRollout` of env 0 of ``ro`` (empty
    ``[T, 0, ...]`` arrays and no qpos for runs without a character)."""
    steps, view = ro.num_steps, tenv.view
    if view is None:
        empty, e3, e4 = np.zeros((steps, 0)), np.zeros((steps, 0, 3)), np.zeros((steps, 0, 4))
        return dict(
            joint_pos=empty,
            joint_vel=empty,
            ref_joint_pos=empty,
            body_pos=e3,
            body_quat=e4,
            ref_body_pos=e3,
            ref_body_quat=e4,
            joint_names=(),
            qpos=None,
            ref_qpos=None,
        )
    assert ro.qpos is not None and ro.frame_index is not None and ro.qpos_joint_pos is not None
    qpos = ro.qpos[:, 0]
    frames = ro.frame_index[:, 0]
    ref_qpos = view.reference_qpos(frames)
    joint_pos = ro.qpos_joint_pos[:, 0]
    poses = [tenv.body_poses(q) for q in qpos]
    ref_poses = [tenv.body_poses(q) for q in ref_qpos]
    return dict(
        joint_pos=joint_pos,
        joint_vel=np.gradient(joint_pos, ro.dt, axis=0) if steps > 1 else np.zeros_like(joint_pos),
        ref_joint_pos=view.reference_joint_pos(frames),
        body_pos=np.stack([p for p, _ in poses]),
        body_quat=np.stack([q for _, q in poses]),
        ref_body_pos=np.stack([p for p, _ in ref_poses]),
        ref_body_quat=np.stack([q for _, q in ref_poses]),
        joint_names=view.joint_names,
        qpos=qpos,
        ref_qpos=ref_qpos,
    )
