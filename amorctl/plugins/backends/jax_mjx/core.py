"""The pure motion-tracking environment on MJX: ``reset(key) -> state`` / ``step(state, a)``.

The semantics are torch-cpu's :class:`amorctl.envs.tracking_env.TrackingEnv` (docs/environment.md):
RSI at a random clip and frame, ``w ~ Dirichlet(1)`` per env per episode (or the ``[weights]``
mixture, :mod:`.weight_mix`, or fixed weights), the
reference advancing one frame per control step and jumping to the start of a new random clip at
its clip's end, the fall rule, divergence (non-finite state or ``|q̇| > 1e3``: terminated,
rewards zeroed), truncation at ``max_episode_steps``, auto-reset, and the same observation
layout. Rewards come from the same objective set called with ``xp = jax.numpy`` and the frame
vectors from :func:`amorctl.core.frame_layout.frame_features` (no second copy of either).

Physics (:class:`~.physics.MjxPhysics`): ``substeps`` MJX steps per control step, vmapped over
envs, inside ``lax.scan``, with the servo model of servo characters in every substep. MJX runs in
float32 (the C env in float64); the solver's warm start is MJX's own ``qacc_warmstart``, carried
in the state. What differs from MuJoCo C and by how much: docs/backends.md.
"""

from __future__ import annotations

from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from amorctl.core.frame_layout import STATE_ARRAYS, TrackingInputs, frame_features, split_frame
from amorctl.core.geometry import quat_conj, quat_rotate
from amorctl.core.specs import CharacterSpec
from amorctl.core.termination import far_from_reference
from amorctl.motion.clips import MotionLibrary
from amorctl.plugins.backends.jax_mjx import weight_mix
from amorctl.plugins.backends.jax_mjx.physics import MjxPhysics
from amorctl.plugins.backends.jax_mjx.weight_mix import WeightMix
from amorctl.sim.batch_sim import MAX_QVEL

xp = jnp
PAPER_DRAW = WeightMix()  # Dirichlet(1), the paper's per-episode draw


def _split(key: jax.Array, num: int) -> jax.Array:
    """``num`` new keys: [num, 2] from the batch's key [2], or [num, N, 2] from per-env keys [N, 2]
    (``reset`` with one seed per env: every env draws from its own key)."""
    if key.ndim == 1:
        return jax.random.split(key, num)
    return jnp.swapaxes(jax.vmap(lambda k: jax.random.split(k, num))(key), 0, 1)


def _draw(key: jax.Array, n: int, fn: Any) -> jax.Array:
    """``fn(key, shape)`` for N envs: one draw of shape (N,) from the batch's key, or one scalar
    draw per env from per-env keys (then env i's numbers do not depend on the batch around it)."""
    if key.ndim == 1:
        return fn(key, (n,))
    return jax.vmap(lambda k: fn(k, ()))(key)


def _keys(seed: int | np.ndarray) -> jax.Array:
    """The key [2] of one seed, or per-env keys [N, 2] of [N] seeds (all 64 bits of each used)."""
    if np.ndim(seed) == 0:
        return jax.random.PRNGKey(int(seed))
    s = np.asarray(seed, np.uint64)
    hi, lo = jnp.asarray((s >> np.uint64(32)).astype(np.uint32)), jnp.asarray(s.astype(np.uint32))
    return jax.vmap(lambda h, low: jax.random.fold_in(jax.random.PRNGKey(h), low))(hi, lo)


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
    far: jax.Array
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
        weight_mix: WeightMix = PAPER_DRAW,
        termination_distance: float = 0.0,
    ) -> None:
        ch = character
        self.character, self.objectives = ch, objectives
        self.m = len(objectives.names)
        self.num_envs = num_envs
        self.max_episode_steps = max_episode_steps
        self.action_mode = action_mode
        self.future_frames = future_frames
        self.fixed_weights = None if fixed_weights is None else jnp.asarray(fixed_weights, jnp.float32)
        self.weight_mix = weight_mix
        self.fall_drop = float(fall_height_fraction) * ch.standing_height
        self.termination_distance = float(termination_distance)
        self.physics = phys = MjxPhysics(ch)
        self.dt = 1.0 / ch.control_hz
        self.servo, self.substeps, self.latency = phys.servo, phys.substeps, phys.latency
        self.root_qpos, self.root_dof = phys.root_qpos, phys.root_dof
        self.joint_qpos, self.joint_dof = phys.joint_qpos, phys.joint_dof
        self.num_joints, self.num_ee = phys.num_joints, phys.num_ee
        self.joint_low = jnp.asarray([j.range[0] for j in ch.joints], jnp.float32)
        self.joint_high = jnp.asarray([j.range[1] for j in ch.joints], jnp.float32)

        lib = library
        f32 = partial(jnp.asarray, dtype=jnp.float32)
        self.lib = {k: f32(getattr(lib, k)) for k in STATE_ARRAYS}
        ref = frame_features(*(getattr(lib, k) for k in STATE_ARRAYS))  # float64 numpy as the C env
        self.ref_frames = f32(ref)
        self.context_frames = f32(lib.frames)
        self.latents = f32(lib.z)
        self.clip_starts = jnp.asarray(lib.starts, jnp.int32)
        self.clip_ends = jnp.asarray(lib.starts + lib.lengths, jnp.int32)

    @property
    def model(self) -> mujoco.MjModel:
        """The MuJoCo model MJX simulates (:attr:`MjxPhysics.model`)."""
        return self.physics.model

    @property
    def template(self) -> Any:
        """An mjx.Data of one env at the model's defaults (what RSI fills in)."""
        return self.physics.template

    # ------------------------------------------------------------------ pieces
    def _sample_weights(self, key: jax.Array, n: int) -> jax.Array:
        if self.fixed_weights is not None:
            return jnp.broadcast_to(self.fixed_weights, (n, self.m))
        if not self.weight_mix.plain:
            return weight_mix.draw(key, n, self.m, self.weight_mix)
        ones = jnp.ones(self.m)
        return _draw(key, n, lambda k, shape: jax.random.dirichlet(k, ones, shape)).astype(jnp.float32)

    def _start_clips(self, key: jax.Array, sel: Selection, at_start: jax.Array) -> tuple[jax.Array, ...]:
        """(clip [N], start frame [N], clip end [N]) of a new random clip for every env."""
        k1, k2 = _split(key, 2)
        n = self.num_envs
        drawn = sel.valid[_draw(k1, n, lambda k, shape: jax.random.randint(k, shape, 0, sel.num_valid))]
        clips = jnp.where(sel.pinned, sel.env_clips, drawn)
        start, end = self.clip_starts[clips], self.clip_ends[clips]
        offset = jnp.floor(_draw(k2, n, jax.random.uniform) * (end - start - 1)).astype(jnp.int32)
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
        key, k1, k2 = _split(key, 3)
        st = self._fresh(k1, sel, k2)
        n, jn = self.num_envs, self.num_joints
        delay = jnp.broadcast_to(st["target_prev"], (self.latency + 1, n, jn))
        frames = self.sim_frames(st["data"], st["ee_pos"], st["ee_quat"], st["ee_lin_vel"])
        obs = self.observe(frames, st)
        return EnvState(**st, delay=delay, delay_head=jnp.zeros((), jnp.int32), obs=obs, key=key)

    def step(self, state: EnvState, sel: Selection, actions: jax.Array) -> tuple[EnvState, StepOut]:
        """One control step of every env, with auto-reset (torch-cpu's ``TrackingEnv.step``)."""
        n, e = self.num_envs, self.num_ee
        nxt = state.ref_idx + 1
        actions = actions.astype(jnp.float32)
        target = actions if self.action_mode == "absolute" else self.lib["joint_pos"][nxt] + actions
        target = jnp.clip(target, self.joint_low, self.joint_high)
        data, torque, sens, (delay, head) = self.physics.control_step(
            state.data, state.delay, state.delay_head, target
        )
        ee = sens[:, self.physics.ee_adr]  # [N, E, 10], amorctl's sensors looked up by name
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
        far = far_from_reference(inputs.sim, inputs.ref, self.termination_distance, xp)
        terminated = fell | far | diverged
        rewards = self.objectives(inputs, (~terminated).astype(jnp.float32), xp=xp)
        rewards = jnp.where(diverged[:, None], 0.0, rewards).astype(jnp.float32)

        episode_steps = state.episode_steps + 1
        truncated = (episode_steps >= self.max_episode_steps) & ~terminated
        key, k_clip, k_reset, k_w = _split(state.key, 4)
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
            obs,
            rewards,
            terminated,
            truncated,
            final_obs,
            fell & ~diverged,
            far & ~fell & ~diverged,
            diverged,
            switched,
        )
