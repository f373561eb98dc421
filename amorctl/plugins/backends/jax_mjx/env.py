"""The motion-tracking environment on MJX: pure ``reset(key) -> state`` / ``step(state, a)``.

The semantics are torch-cpu's :class:`amorctl.envs.tracking_env.TrackingEnv` (docs/environment.md):
RSI at a random clip and frame, ``w ~ Dirichlet(1)`` per env per episode (or fixed weights), the
reference advancing one frame per control step and jumping to the start of a new random clip at
its clip's end, the fall rule, divergence (non-finite state or ``|q̇| > 1e3``: terminated,
rewards zeroed), truncation at ``max_episode_steps``, auto-reset, and the same observation
layout. Rewards come from the same objective set called with ``xp = jax.numpy`` and the frame
vectors from :func:`amorctl.core.frame_layout.frame_features` (no second copy of either).

Physics: ``substeps`` MJX steps per control step, vmapped over envs, inside ``lax.scan``. PD
characters set the position actuators' targets; servo characters (biped20) compute the PD torque
on the command delayed by ``latency_steps`` physics steps, clipped by the torque–speed curve
(:func:`amorctl.sim.actuators.servo_torque` with ``xp = jax.numpy``) in every substep, inside the
jitted scan. MJX runs in float32 (the C env in float64); the solver's warm start is MJX's own
``qacc_warmstart``, carried in the state. What differs from MuJoCo C and by how much:
docs/backends.md.

:class:`MjxTrackingEnv` wraps the pure functions as a :class:`~amorctl.core.vecenv.VectorEnv`
(numpy in and out, a :class:`~amorctl.core.contracts.SnapshotEnv`) and offers the trainer a fused
rollout (policy + env for T steps as one jitted scan).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import TrackingInputs, frame_dim, frame_features, split_frame
from amorctl.core.geometry import quat_conj, quat_rotate
from amorctl.core.specs import CharacterSpec, ObjectiveSetSpec
from amorctl.core.vecenv import RewardSpace
from amorctl.motion.clips import MotionLibrary
from amorctl.registry import get_registry
from amorctl.sim.actuators import servo_torque
from amorctl.sim.batch_sim import MAX_QVEL, build_model

xp = jnp


class EnvState(NamedTuple):
    """The whole env state (N envs); every field is a JAX array."""

    data: Any  # mjx.Data, leaves [N, ...]
    ref_idx: jax.Array  # [N] int32, library frame the current state corresponds to
    clip_end: jax.Array  # [N] int32, exclusive end of that frame's clip
    clip_id: jax.Array  # [N] int32
    episode_steps: jax.Array  # [N] int32
    weights: jax.Array  # [N, m]
    target_prev: jax.Array  # [N, J] a_{t-1}
    target_prev2: jax.Array  # [N, J] a_{t-2}
    joint_vel_prev: jax.Array  # [N, J]
    ee_pos: jax.Array  # [N, E, 3]
    ee_quat: jax.Array  # [N, E, 4]
    ee_lin_vel: jax.Array  # [N, E, 3]
    delay: jax.Array  # [k + 1, N, J] pending servo commands (k = 0 and unused for PD)
    delay_head: jax.Array  # [] int32, the slot the next push writes
    obs: jax.Array  # [N, D] the current observation
    key: jax.Array  # [2] uint32


class Selection(NamedTuple):
    """Which clips episodes draw (``select_clips``), as arrays the jitted code reads."""

    valid: jax.Array  # [C] int32 clip indices, padded with the first
    num_valid: jax.Array  # [] int32
    env_clips: jax.Array  # [N] int32, -1 where not pinned
    pinned: jax.Array  # [] bool, env_clips in force
    from_start: jax.Array  # [] bool


class StepOut(NamedTuple):
    obs: jax.Array
    rewards: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    final_obs: jax.Array
    fell: jax.Array
    diverged: jax.Array
    switched: jax.Array


class MjxTracking:
    """The pure env of one character, library and objective set (static arrays live on the device)."""

    def __init__(
        self,
        character: CharacterSpec,
        library: MotionLibrary,
        objectives: Any,
        *,
        num_envs: int,
        max_episode_steps: int,
        action_mode: str,
        future_frames: tuple[int, ...],
        fixed_weights: np.ndarray | None,
        fall_height_fraction: float,
    ) -> None:
        ch = character
        self.character, self.objectives = ch, objectives
        self.m = len(objectives.names)
        self.num_envs = num_envs
        self.max_episode_steps = max_episode_steps
        self.action_mode = action_mode
        self.future_frames = future_frames
        self.fixed_weights = None if fixed_weights is None else jnp.asarray(fixed_weights, jnp.float32)
        self.fall_drop = float(fall_height_fraction) * ch.standing_height
        self.model = model = build_model(ch)
        self.mx = mjx.put_model(model)
        self.substeps = ch.substeps
        self.dt = 1.0 / ch.control_hz
        self.servo = ch.actuator.kind == "servo"
        root = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, ch.root_body)
        free = int(model.body_jntadr[root])
        self.root_qpos, self.root_dof = int(model.jnt_qposadr[free]), int(model.jnt_dofadr[free])
        jids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in ch.joint_names()]
        if min(jids) < 0:
            raise AmorError(f"character {ch.name!r}: a joint of its spec is not in its MJCF")
        self.joint_qpos = jnp.asarray(model.jnt_qposadr[jids], jnp.int32)
        self.joint_dof = jnp.asarray(model.jnt_dofadr[jids], jnp.int32)
        acts = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, j) for j in ch.joint_names()]
        self.actuators = jnp.asarray(acts, jnp.int32)
        self.gear = jnp.asarray(model.actuator_gear[acts, 0], jnp.float32)
        self.num_joints, self.num_ee = len(jids), len(ch.end_effectors)
        self.joint_low = jnp.asarray([j.range[0] for j in ch.joints], jnp.float32)
        self.joint_high = jnp.asarray([j.range[1] for j in ch.joints], jnp.float32)
        if self.servo:
            self.kp = jnp.asarray([j.kp for j in ch.joints], jnp.float32)
            self.kd = jnp.asarray([j.kd for j in ch.joints], jnp.float32)
            self.torque_limit = jnp.asarray([j.torque_limit for j in ch.joints], jnp.float32)
            self.no_load_speed = ch.actuator.no_load_speed
            self.latency = int(ch.actuator.latency_steps)
        else:
            self.latency = 0
        template = mjx.make_data(self.mx)
        self.template = template

        lib = library
        f32 = partial(jnp.asarray, dtype=jnp.float32)
        self.lib = {
            k: f32(getattr(lib, k))
            for k in ("root_pos", "root_quat", "root_lin_vel", "root_ang_vel", "joint_pos", "joint_vel",
                      "ee_pos", "ee_quat", "ee_lin_vel")
        }  # fmt: skip
        ref = frame_features(
            lib.root_pos,
            lib.root_quat,
            lib.root_lin_vel,
            lib.root_ang_vel,
            lib.joint_pos,
            lib.joint_vel,
            lib.ee_pos,
            lib.ee_quat,
            lib.ee_lin_vel,
        )  # fmt: skip  (float64 numpy, as the C env, then float32)
        self.ref_frames = f32(ref)
        self.context_frames = f32(lib.frames)
        self.latents = f32(lib.z)
        self.clip_starts = jnp.asarray(lib.starts, jnp.int32)
        self.clip_ends = jnp.asarray(lib.starts + lib.lengths, jnp.int32)

    # ------------------------------------------------------------------ pieces
    def _sample_weights(self, key: jax.Array, n: int) -> jax.Array:
        if self.fixed_weights is not None:
            return jnp.broadcast_to(self.fixed_weights, (n, self.m))
        return jax.random.dirichlet(key, jnp.ones(self.m), (n,)).astype(jnp.float32)

    def _start_clips(self, key: jax.Array, sel: Selection, at_start: jax.Array) -> tuple[jax.Array, ...]:
        """(clip [N], start frame [N], clip end [N]) of a new random clip for every env."""
        k1, k2 = jax.random.split(key)
        n = self.num_envs
        drawn = sel.valid[jax.random.randint(k1, (n,), 0, sel.num_valid)]
        clips = jnp.where(sel.pinned, sel.env_clips, drawn)
        start, end = self.clip_starts[clips], self.clip_ends[clips]
        offset = jnp.floor(jax.random.uniform(k2, (n,)) * (end - start - 1)).astype(jnp.int32)
        offset = jnp.where(at_start, 0, jnp.minimum(offset, end - start - 2))
        return clips, start + offset, end

    def _rsi_data(self, frames: jax.Array) -> Any:
        """mjx.Data [N] at the library ``frames`` [N] (RSI; time 0, no warm start)."""
        lib, n = self.lib, self.num_envs
        quat = lib["root_quat"][frames]
        quat = quat / jnp.linalg.norm(quat, axis=-1, keepdims=True)
        q0, v0 = self.root_qpos, self.root_dof
        qpos = jnp.broadcast_to(self.template.qpos, (n, self.model.nq))
        qpos = qpos.at[:, q0 : q0 + 3].set(lib["root_pos"][frames]).at[:, q0 + 3 : q0 + 7].set(quat)
        qpos = qpos.at[:, self.joint_qpos].set(lib["joint_pos"][frames])
        qvel = jnp.zeros((n, self.model.nv), jnp.float32)
        ang_local = quat_rotate(quat_conj(lib["root_quat"][frames], xp), lib["root_ang_vel"][frames], xp)
        qvel = qvel.at[:, v0 : v0 + 3].set(lib["root_lin_vel"][frames]).at[:, v0 + 3 : v0 + 6].set(ang_local)
        qvel = qvel.at[:, self.joint_dof].set(lib["joint_vel"][frames])
        data = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (n, *jnp.shape(x))), self.template)
        return data.replace(qpos=qpos, qvel=qvel)

    def _fresh(self, key: jax.Array, sel: Selection, weights_key: jax.Array) -> dict[str, Any]:
        """A newly reset copy of every env (the caller keeps it where an episode ends)."""
        clips, frames, end = self._start_clips(key, sel, sel.from_start)
        lib = self.lib
        jp = lib["joint_pos"][frames]
        return {
            "data": self._rsi_data(frames),
            "ref_idx": frames,
            "clip_end": end,
            "clip_id": clips,
            "episode_steps": jnp.zeros(self.num_envs, jnp.int32),
            "weights": self._sample_weights(weights_key, self.num_envs),
            "target_prev": jp,
            "target_prev2": jp,
            "joint_vel_prev": lib["joint_vel"][frames],
            "ee_pos": lib["ee_pos"][frames],
            "ee_quat": lib["ee_quat"][frames],
            "ee_lin_vel": lib["ee_lin_vel"][frames],
        }

    def _root(self, data: Any) -> tuple[jax.Array, ...]:
        q0, v0 = self.root_qpos, self.root_dof
        quat = data.qpos[:, q0 + 3 : q0 + 7]
        ang = quat_rotate(quat, data.qvel[:, v0 + 3 : v0 + 6], xp)
        return data.qpos[:, q0 : q0 + 3], quat, data.qvel[:, v0 : v0 + 3], ang

    def sim_frames(self, data: Any, ee_pos: jax.Array, ee_quat: jax.Array, ee_vel: jax.Array) -> jax.Array:
        """[N, Df] heading-frame features of the simulated state."""
        pos, quat, lin, ang = self._root(data)
        jp, jv = data.qpos[:, self.joint_qpos], data.qvel[:, self.joint_dof]
        return frame_features(pos, quat, lin, ang, jp, jv, ee_pos, ee_quat, ee_vel, xp)

    def observe(self, frames: jax.Array, st: dict[str, Any]) -> jax.Array:
        """Observations [N, D] (the layout of ``obs_layout``)."""
        nxt = st["ref_idx"] + 1
        parts = [frames, st["target_prev"], st["target_prev2"], self.context_frames[nxt], self.latents[nxt]]
        last = st["clip_end"] - 1
        parts += [self.context_frames[jnp.minimum(nxt + o, last)] for o in self.future_frames]
        parts.append(st["weights"])
        return jnp.concatenate(parts, axis=-1).astype(jnp.float32)

    # ------------------------------------------------------------------ pure API
    def reset(self, key: jax.Array, sel: Selection) -> EnvState:
        """Every env anew (RSI, fresh weights)."""
        key, k1, k2 = jax.random.split(key, 3)
        st = self._fresh(k1, sel, k2)
        n, jn = self.num_envs, self.num_joints
        delay = jnp.broadcast_to(st["target_prev"], (self.latency + 1, n, jn))
        frames = self.sim_frames(st["data"], st["ee_pos"], st["ee_quat"], st["ee_lin_vel"])
        obs = self.observe(frames, st)
        return EnvState(**st, delay=delay, delay_head=jnp.zeros((), jnp.int32), obs=obs, key=key)

    def _physics(self, state: EnvState, target: jax.Array) -> tuple[Any, jax.Array, jax.Array, jax.Array]:
        """``substeps`` MJX steps toward PD targets [N, J]: (data, torque [N, S, J], sensors of the
        last substep [N, S_d], delay buffer, head)."""
        step = jax.vmap(mjx.step, in_axes=(None, 0))
        jn = self.num_joints

        def sub(carry: tuple[Any, jax.Array, jax.Array], _: Any) -> tuple[Any, tuple[jax.Array, jax.Array]]:
            data, delay, head = carry
            if self.servo:
                delay = delay.at[head].set(target)
                head = (head + 1) % (self.latency + 1)
                cmd = delay[head]  # the command of `latency` physics steps ago
                q, qd = data.qpos[:, self.joint_qpos], data.qvel[:, self.joint_dof]
                tau = servo_torque(cmd, q, qd, self.kp, self.kd, self.torque_limit, self.no_load_speed, xp=xp)
                ctrl = data.ctrl.at[:, self.actuators].set(tau / self.gear)
                data = step(self.mx, data.replace(ctrl=ctrl))
            else:
                ctrl = data.ctrl.at[:, self.actuators].set(target)
                data = step(self.mx, data.replace(ctrl=ctrl))
                nsens = self.num_ee * 10
                tau = data.sensordata[:, nsens : nsens + jn] * self.gear
            return (data, delay, head), (tau, data.sensordata)

        (data, delay, head), (torque, sens) = jax.lax.scan(
            sub, (state.data, state.delay, state.delay_head), None, length=self.substeps
        )
        return data, jnp.swapaxes(torque, 0, 1), sens[-1], (delay, head)

    def step(self, state: EnvState, sel: Selection, actions: jax.Array) -> tuple[EnvState, StepOut]:
        """One control step of every env, with auto-reset (torch-cpu's ``TrackingEnv.step``)."""
        n, e = self.num_envs, self.num_ee
        nxt = state.ref_idx + 1
        actions = actions.astype(jnp.float32)
        target = actions if self.action_mode == "absolute" else self.lib["joint_pos"][nxt] + actions
        target = jnp.clip(target, self.joint_low, self.joint_high)
        data, torque, sens, (delay, head) = self._physics(state, target)
        ee = sens[:, : e * 10].reshape(n, e, 10)
        ee_pos, ee_quat, ee_vel = ee[..., 0:3], ee[..., 3:7], ee[..., 7:10]
        frames = self.sim_frames(data, ee_pos, ee_quat, ee_vel)
        ref = self.ref_frames[nxt]
        joint_vel = data.qvel[:, self.joint_dof]
        inputs = TrackingInputs(
            sim=split_frame(frames, self.num_joints, e, xp),
            ref=split_frame(ref, self.num_joints, e, xp),
            torque=torque,
            pd_target=target,
            pd_target_prev=state.target_prev,
            pd_target_prev2=state.target_prev2,
            joint_acc=(joint_vel - state.joint_vel_prev) / self.dt,
        )
        finite = (
            jnp.all(jnp.isfinite(data.qpos), axis=1)
            & jnp.all(jnp.isfinite(data.qvel), axis=1)
            & jnp.all(jnp.isfinite(ee), axis=(1, 2))
        )
        diverged = ~finite | jnp.any(jnp.abs(data.qvel) > MAX_QVEL, axis=1)
        fell = frames[:, 0] < ref[:, 0] - self.fall_drop
        terminated = fell | diverged
        rewards = self.objectives(inputs, (~terminated).astype(jnp.float32), xp=xp)
        rewards = jnp.where(diverged[:, None], 0.0, rewards).astype(jnp.float32)

        episode_steps = state.episode_steps + 1
        truncated = (episode_steps >= self.max_episode_steps) & ~terminated
        key, k_clip, k_reset, k_w = jax.random.split(state.key, 4)
        switched = nxt >= state.clip_end - 1  # reached its clip's last frame: a new clip from its start
        clips, starts, ends = self._start_clips(k_clip, sel, jnp.asarray(True))
        st = {
            "data": data,
            "ref_idx": jnp.where(switched, starts, nxt),
            "clip_end": jnp.where(switched, ends, state.clip_end),
            "clip_id": jnp.where(switched, clips, state.clip_id),
            "episode_steps": episode_steps,
            "weights": state.weights,
            "target_prev": target,
            "target_prev2": state.target_prev,
            "joint_vel_prev": joint_vel,
            "ee_pos": ee_pos,
            "ee_quat": ee_quat,
            "ee_lin_vel": ee_vel,
        }
        obs = self.observe(frames, st)
        done = terminated | truncated
        fresh = self._fresh(k_reset, sel, k_w)
        fresh_frames = self.sim_frames(fresh["data"], fresh["ee_pos"], fresh["ee_quat"], fresh["ee_lin_vel"])
        fresh_obs = self.observe(fresh_frames, fresh)

        def pick(new: Any, old: Any) -> Any:
            mask = done.reshape((n,) + (1,) * (jnp.ndim(old) - 1))
            return jnp.where(mask, new, old)

        st = jax.tree_util.tree_map(pick, fresh, st)
        # pending servo commands of reset envs become their initial pose
        delay = jnp.where(done[None, :, None], fresh["target_prev"][None], delay)
        final_obs = jnp.where(diverged[:, None], fresh_obs, obs)
        obs = jnp.where(done[:, None], fresh_obs, obs)
        new = EnvState(**st, delay=delay, delay_head=head, obs=obs, key=key)
        return new, StepOut(
            obs, rewards, terminated, truncated, final_obs, fell & ~diverged, diverged, switched
        )


class MjxTrackingEnv:
    """The MJX tracking env as a :class:`~amorctl.core.vecenv.VectorEnv` (+ snapshots, fused rollouts).

    Arguments are :class:`~amorctl.envs.tracking_env.TrackingEnv`'s (``nthread`` is accepted and
    ignored: MJX parallelizes over the devices). ``num_envs`` must be a multiple of the number of
    local JAX devices; the env axis is split across them.
    """

    def __init__(
        self,
        character: CharacterSpec | str,
        library: MotionLibrary,
        objective_set: ObjectiveSetSpec | str = "tracking7",
        *,
        num_envs: int = 256,
        max_episode_steps: int = 500,
        action_mode: str = "absolute",
        future_frames: tuple[int, ...] = (),
        fixed_weights: np.ndarray | None = None,
        fall_height_fraction: float = 1.0 / 3.0,
        nthread: int = 0,
        clips: Sequence[int] | None = None,
        env_clips: np.ndarray | None = None,
        seed: int | None = 0,
    ) -> None:
        from amorctl.envs.tracking_env import _check_clips, _check_library, _check_weights
        from amorctl.plugins.backends.jax_mjx import devices

        registry = get_registry() if isinstance(character, str) or isinstance(objective_set, str) else None
        ch = registry.character(character) if isinstance(character, str) else character
        spec = registry.objective_set(objective_set) if isinstance(objective_set, str) else objective_set
        _check_library(ch, library)
        if action_mode not in ("absolute", "residual"):
            raise AmorError(f"action_mode must be 'absolute' or 'residual', got {action_mode!r}")
        if max_episode_steps < 1:
            raise AmorError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        if num_envs < 1:
            raise AmorError(f"num_envs must be >= 1, got {num_envs}")
        self._check_clips = partial(_check_clips, lib=library)
        self.character, self.library = ch, library
        objectives = spec.make(ch)
        m = len(spec.objectives)
        self.reward_space = RewardSpace(
            names=tuple(objectives.names),
            descriptions=tuple(objectives.descriptions),
            low=np.asarray(objectives.low, dtype=np.float64),
            high=np.asarray(objectives.high, dtype=np.float64),
        )
        fixed = None if fixed_weights is None else _check_weights(fixed_weights, m)
        self.num_envs = n = int(num_envs)
        self.max_episode_steps = int(max_episode_steps)
        self.dt = 1.0 / ch.control_hz
        self.mesh = devices.local_mesh()
        if n % self.mesh.size:
            raise AmorError(f"num_envs = {n} must be a multiple of the {self.mesh.size} local JAX devices")
        self.core = MjxTracking(
            ch, library, objectives, num_envs=n, max_episode_steps=self.max_episode_steps,
            action_mode=action_mode, future_frames=tuple(int(o) for o in future_frames),
            fixed_weights=fixed, fall_height_fraction=fall_height_fraction,
        )  # fmt: skip
        self.model = self.core.model
        jn, e = ch.num_joints, len(ch.end_effectors)
        d = frame_dim(jn, e)
        self.obs_layout: dict[str, slice] = {}
        o = 0
        for name, size in (
            ("proprio", d), ("prev_targets", 2 * jn), ("ref_frame", d), ("latent", library.latent_dim),
            ("future_frames", d * len(self.core.future_frames)), ("weights", m),
        ):  # fmt: skip
            self.obs_layout[name] = slice(o, o + size)
            o += size
        self.obs_dim, self.action_dim = o, jn
        self.all_valid_clips = np.flatnonzero(library.lengths >= 2)
        if len(self.all_valid_clips) == 0:
            raise AmorError("motion library has no clip with at least 2 frames")
        self.select_clips(clips, env_clips)
        self._seed = 0 if seed is None else int(seed)
        self.diverged_total = 0
        shard = partial(devices.shard_envs, self.mesh)
        self._reset = jax.jit(self.core.reset)
        self._step = jax.jit(self.core.step)
        self._shard = shard
        self.state: EnvState | None = None

    # ------------------------------------------------------------------ VectorEnv
    @property
    def weights(self) -> np.ndarray:
        """[N, m] float32: each env's current episode weights."""
        return np.asarray(self._require().weights, np.float32).copy()

    def _require(self) -> EnvState:
        if self.state is None:
            self.reset()
        assert self.state is not None
        return self.state

    def _place(self, state: EnvState) -> EnvState:
        """Split the per-env leaves over the devices (the delay buffer along its env axis)."""
        if self.mesh.size == 1:
            return state
        from amorctl.plugins.backends.jax_mjx import devices

        placed = self._shard(state._replace(delay=jnp.zeros(()), delay_head=jnp.zeros(()), key=jnp.zeros(())))
        return placed._replace(
            delay=devices.shard_envs(self.mesh, state.delay, axis=1),
            delay_head=devices.replicate(self.mesh, state.delay_head),
            key=devices.replicate(self.mesh, state.key),
        )

    def reset(self, seed: int | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start every env anew (RSI, fresh weights). Returns obs [N, D] float32, info."""
        if seed is not None:
            self._seed = int(seed)
        self.diverged_total = 0
        self.state = self._place(self._reset(jax.random.PRNGKey(self._seed), self.sel))
        return np.asarray(self.state.obs), {}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """One control step (see :class:`amorctl.core.vecenv.VectorEnv`; ``info`` as torch-cpu's)."""
        actions = np.asarray(actions, dtype=np.float32)
        if actions.shape != (self.num_envs, self.action_dim):
            raise AmorError(
                f"actions must have shape {(self.num_envs, self.action_dim)}, got {actions.shape}"
            )
        self.state, out = self._step(self._require(), self.sel, jnp.asarray(actions))
        out = jax.device_get(out)
        self.diverged_total += int(out.diverged.sum())
        info = {
            "final_obs": out.final_obs,
            "fell": out.fell,
            "diverged": out.diverged,
            "diverged_total": self.diverged_total,
            "clip_switched": out.switched,
        }
        return out.obs, out.rewards, out.terminated, out.truncated, info

    def select_clips(
        self,
        clips: Sequence[int] | None = None,
        env_clips: np.ndarray | None = None,
        from_start: bool = False,
    ) -> None:
        """Restrict which clips episodes use from the next reset on (torch-cpu's ``select_clips``)."""
        valid = (
            self.all_valid_clips if clips is None else self._check_clips(np.asarray(clips, np.int64).ravel())
        )
        pinned = env_clips is not None
        per_env = np.full(self.num_envs, -1, np.int64)
        if pinned:
            per_env = self._check_clips(np.asarray(env_clips, np.int64).ravel())
            if per_env.shape != (self.num_envs,):
                raise AmorError(f"env_clips must have one clip per env ({self.num_envs}), got {per_env.size}")
        padded = np.full(len(self.library.clips), valid[0], np.int32)
        padded[: len(valid)] = valid
        self.valid_clips, self.env_clips, self.from_start = (
            valid,
            per_env if pinned else None,
            bool(from_start),
        )
        self.sel = Selection(
            valid=jnp.asarray(padded), num_valid=jnp.asarray(len(valid), jnp.int32),
            env_clips=jnp.asarray(per_env, jnp.int32), pinned=jnp.asarray(pinned),
            from_start=jnp.asarray(bool(from_start)),
        )  # fmt: skip

    def tracking_view(self) -> Any:
        """The :class:`~amorctl.core.contracts.TrackingView` analysis reads this env through."""
        from amorctl.plugins.backends.jax_mjx.view import MjxTrackingView

        return MjxTrackingView(self)

    def close(self) -> None:
        """Nothing to release (kept for the VectorEnv lifecycle)."""

    # ------------------------------------------------------------------ snapshots
    def get_state(self) -> Snapshot:
        """The whole env state: every leaf of :class:`EnvState` as ``state/<i>`` (numpy), the clip
        selection and ``diverged_total`` in the metadata."""
        leaves = jax.tree_util.tree_leaves(jax.device_get(self._require()))
        arrays = {f"state/{i}": np.atleast_1d(np.asarray(x)).copy() for i, x in enumerate(leaves)}
        meta = {
            "backend": "jax-mjx",
            "leaves": len(leaves),
            "diverged_total": self.diverged_total,
            "valid_clips": [int(c) for c in self.valid_clips],
            "env_clips": None if self.env_clips is None else [int(c) for c in self.env_clips],
            "from_start": self.from_start,
        }
        return Snapshot(arrays, meta)

    def set_state(self, state: Snapshot) -> None:
        """Restore :meth:`get_state` (from an env built with the same arguments)."""
        current = self._require()
        leaves = jax.tree_util.tree_leaves(current)
        if state.meta.get("leaves") != len(leaves):
            raise AmorError("env snapshot was not taken from this jax-mjx env (its state layout differs)")
        restored = []
        for i, like in enumerate(leaves):
            value = np.asarray(state.arrays.get(f"state/{i}"))
            shape = tuple(np.shape(like))
            if value.size != int(np.prod(shape)):
                raise AmorError(f"env snapshot array state/{i} has shape {value.shape}, expected {shape}")
            restored.append(jnp.asarray(value.reshape(shape), dtype=like.dtype))
        meta = state.meta
        self.select_clips(meta.get("valid_clips"), meta.get("env_clips"), bool(meta.get("from_start", False)))
        self.state = self._place(
            jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(current), restored)
        )
        self.diverged_total = int(meta.get("diverged_total", 0))

    # ------------------------------------------------------------------ fused rollouts
    def fused_rollout(self, nets: Any, clip: float, num_steps: int, mesh: Any) -> Any:
        """A jitted ``(params, norm, env_state, selection, key) -> (env_state, batch)``: T steps of
        policy and env as one ``lax.scan`` (what the trainer's fused path runs)."""
        from amorctl.plugins.backends.jax_mjx import moppo_math as mm
        from amorctl.plugins.backends.jax_mjx.networks import normalize

        core = self.core

        def rollout(params: Any, norm: Any, state: EnvState, sel: Selection, key: jax.Array) -> Any:
            log_std = params["actor"]["log_std"]

            def value_of(obs: jax.Array) -> jax.Array:
                return nets.values(params, normalize(obs, norm, clip))

            def one(st: EnvState, k: jax.Array) -> tuple[EnvState, tuple[Any, ...]]:
                x = normalize(st.obs, norm, clip)
                mean, value = nets.mean(params, x), nets.values(params, x)
                action = mean + jnp.exp(log_std) * jax.random.normal(k, mean.shape, mean.dtype)
                logp = mm.gaussian_log_prob(action, mean, log_std)
                new, out = core.step(st, sel, action)
                trunc = out.truncated & ~out.terminated
                final_value = jnp.where(trunc[:, None], value_of(out.final_obs), 0.0)
                rec = (st.obs, action, mean, value, logp, final_value, out.rewards, st.weights,
                       out.terminated, trunc, out.diverged)  # fmt: skip
                return new, rec

            keys = jax.random.split(key, num_steps)
            state, rec = jax.lax.scan(one, state, keys)
            obs, act, mean, val, logp, final_val, rew, w, term, trunc, div = rec
            last = value_of(state.obs)
            following = jnp.concatenate([val[1:], last[None]], axis=0)
            T, n = num_steps, core.num_envs
            batch = mm.Batch(
                obs=obs.reshape(T * n, -1), actions=act.reshape(T * n, -1), log_probs=logp.reshape(T * n),
                means=mean.reshape(T * n, -1), values=val.reshape(T * n, -1), weights=w.reshape(T * n, -1),
                rewards=rew, next_values=jnp.where(trunc[..., None], final_val, following),
                terminated=term, truncated=trunc, old_log_std=log_std,
            )  # fmt: skip
            return state, batch, jnp.sum(div)

        return jax.jit(rollout)

    def run_rollout(self, fn: Any, params: Any, norm: Any, key: jax.Array) -> tuple[Any, np.ndarray]:
        """Run a :meth:`fused_rollout` function on this env's state; returns (batch, current obs)."""
        self.state, batch, diverged = fn(params, norm, self._require(), self.sel, key)
        self.diverged_total += int(diverged)
        return batch, self.state.obs
