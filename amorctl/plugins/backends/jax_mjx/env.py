"""The MJX tracking env as a :class:`~amorctl.core.vecenv.VectorEnv` (numpy in and out).

:class:`MjxTrackingEnv` wraps the pure functions of :class:`~.core.MjxTracking` (RSI, reference
advance, rewards, termination, auto-reset; physics in :mod:`.physics`) for the rest of amorctl:
a :class:`~amorctl.core.contracts.SnapshotEnv` (``get_state``/``set_state`` for exact resume) that
splits its envs over the local JAX devices, and the trainer's fused rollout (policy + env for T
steps as one jitted scan). Semantics and parity with torch-cpu: docs/backends.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from amorctl.core.contracts import Snapshot, survival_bonus_of
from amorctl.core.env_random import Seed
from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import frame_dim
from amorctl.core.observation import observation_layout
from amorctl.core.specs import CharacterSpec, ObjectiveSetSpec
from amorctl.core.vecenv import RewardSpace
from amorctl.core.weight_sampling import WeightSampler
from amorctl.motion.clips import MotionLibrary
from amorctl.plugins.backends.jax_mjx import devices
from amorctl.plugins.backends.jax_mjx.core import EnvState, MjxTracking, Selection, StepOut, _keys
from amorctl.plugins.backends.jax_mjx.weight_mix import WeightMix
from amorctl.registry import get_registry

__all__ = ["EnvState", "MjxTracking", "MjxTrackingEnv", "Selection", "StepOut"]


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
        weight_sampler: WeightSampler | None = None,
        fall_height_fraction: float = 1.0 / 3.0,
        termination_distance: float = 0.0,
        nthread: int = 0,
        clips: Sequence[int] | None = None,
        env_clips: np.ndarray | None = None,
        seed: int | None = 0,
    ) -> None:
        from amorctl.envs.tracking_checks import check_clips, check_library, check_weights

        registry = get_registry() if isinstance(character, str) or isinstance(objective_set, str) else None
        ch = registry.character(character) if isinstance(character, str) else character
        spec = registry.objective_set(objective_set) if isinstance(objective_set, str) else objective_set
        check_library(ch, library)
        if action_mode not in ("absolute", "residual"):
            raise AmorError(f"action_mode must be 'absolute' or 'residual', got {action_mode!r}")
        if max_episode_steps < 1:
            raise AmorError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        if num_envs < 1:
            raise AmorError(f"num_envs must be >= 1, got {num_envs}")
        self._check_clips = partial(check_clips, lib=library)
        self.character, self.library = ch, library
        objectives = spec.make(ch)
        m = len(spec.objectives)
        self.reward_space = RewardSpace(
            names=tuple(objectives.names),
            descriptions=tuple(objectives.descriptions),
            low=np.asarray(objectives.low, dtype=np.float64),
            high=np.asarray(objectives.high, dtype=np.float64),
            survival_bonus=survival_bonus_of(objectives),
        )
        fixed = None if fixed_weights is None else check_weights(fixed_weights, m)
        self.num_envs = n = int(num_envs)
        self.max_episode_steps = int(max_episode_steps)
        self.dt = 1.0 / ch.control_hz
        self.mesh = devices.local_mesh()
        if n % self.mesh.size:
            raise AmorError(f"num_envs = {n} must be a multiple of the {self.mesh.size} local JAX devices")
        self.core = MjxTracking(
            ch,
            library,
            objectives,
            num_envs=n,
            max_episode_steps=self.max_episode_steps,
            action_mode=action_mode,
            future_frames=tuple(int(o) for o in future_frames),
            fixed_weights=fixed,
            weight_mix=WeightMix() if weight_sampler is None else WeightMix.of_sampler(weight_sampler),
            fall_height_fraction=fall_height_fraction,
            termination_distance=termination_distance,
        )
        self.weight_sampler = weight_sampler  # its mix is drawn on the device (weight_mix.py)
        self.model = self.core.model
        self.fall_drop, self.future_frames = self.core.fall_drop, self.core.future_frames
        jn, e = ch.num_joints, len(ch.end_effectors)
        d = frame_dim(jn, e)
        self.obs_layout = observation_layout(d, jn, library.latent_dim, self.core.future_frames, m)
        self.obs_dim, self.action_dim = self.obs_layout["weights"].stop, jn
        self.all_valid_clips = np.flatnonzero(library.lengths >= 2)
        if len(self.all_valid_clips) == 0:
            raise AmorError("motion library has no clip with at least 2 frames")
        self.select_clips(clips, env_clips)
        self._seed: int | np.ndarray = 0 if seed is None else int(seed)
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
        return devices.to_host(self._require().weights).astype(np.float32)

    def _require(self) -> EnvState:
        if self.state is None:
            self.reset()
        assert self.state is not None
        return self.state

    def _place(self, state: EnvState) -> EnvState:
        """Split the per-env leaves over the devices (the delay buffer along its env axis)."""
        if self.mesh.size == 1:
            return state
        placed = self._shard(state._replace(delay=jnp.zeros(()), delay_head=jnp.zeros(()), key=jnp.zeros(())))
        return placed._replace(
            delay=devices.shard_envs(self.mesh, state.delay, axis=1),
            delay_head=devices.replicate(self.mesh, state.delay_head),
            key=devices.replicate(self.mesh, state.key),
        )

    def reset(self, seed: Seed = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start every env anew (RSI, fresh weights). Returns obs [N, D] float32, info. ``seed``:
        one int (the batch's key), or [N] ints (one key per env, as torch-cpu's per-env generators)."""
        if seed is not None and np.ndim(seed) == 1:  # one seed per env: per-env keys
            seeds = np.asarray(seed)
            if seeds.shape != (self.num_envs,) or seeds.dtype.kind not in "iu" or (seeds < 0).any():
                raise AmorError(f"per-env seeds: expected {self.num_envs} non-negative integers")
            self._seed = seeds
        elif seed is not None:
            self._seed = int(seed)
        self.diverged_total = 0
        self.state = self._place(self._reset(_keys(self._seed), self.sel))
        return devices.to_host(self.state.obs), {}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """One control step (see :class:`amorctl.core.vecenv.VectorEnv`; ``info`` as torch-cpu's)."""
        actions = np.asarray(actions, dtype=np.float32)
        if actions.shape != (self.num_envs, self.action_dim):
            raise AmorError(
                f"actions must have shape {(self.num_envs, self.action_dim)}, got {actions.shape}"
            )
        sel, actions = devices.to_global(self.mesh, (self.sel, jnp.asarray(actions)))
        self.state, out = self._step(self._require(), sel, actions)
        out = jax.tree_util.tree_map(devices.to_host, out)
        self.diverged_total += int(out.diverged.sum())
        info = {
            "final_obs": out.final_obs,
            "fell": out.fell,
            "far": out.far,
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
            valid=jnp.asarray(padded),
            num_valid=jnp.asarray(len(valid), jnp.int32),
            env_clips=jnp.asarray(per_env, jnp.int32),
            pinned=jnp.asarray(pinned),
            from_start=jnp.asarray(bool(from_start)),
        )

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
        leaves = [devices.to_host(x) for x in jax.tree_util.tree_leaves(self._require())]
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
                logp = mm.gaussian_log_prob(action, mean, log_std, xp=jnp)
                new, out = core.step(st, sel, action)
                trunc = out.truncated & ~out.terminated
                final_value = jnp.where(trunc[:, None], value_of(out.final_obs), 0.0)
                rec = (
                    st.obs,
                    action,
                    mean,
                    value,
                    logp,
                    final_value,
                    out.rewards,
                    st.weights,
                    out.terminated,
                    trunc,
                    out.diverged,
                )
                return new, rec

            keys = jax.random.split(key, num_steps)
            state, rec = jax.lax.scan(one, state, keys)
            obs, act, mean, val, logp, final_val, rew, w, term, trunc, div = rec
            last = value_of(state.obs)
            following = jnp.concatenate([val[1:], last[None]], axis=0)
            T, n = num_steps, core.num_envs
            batch = mm.Batch(
                obs=obs.reshape(T * n, -1),
                actions=act.reshape(T * n, -1),
                log_probs=logp.reshape(T * n),
                means=mean.reshape(T * n, -1),
                values=val.reshape(T * n, -1),
                weights=w.reshape(T * n, -1),
                rewards=rew,
                next_values=jnp.where(trunc[..., None], final_val, following),
                terminated=term,
                truncated=trunc,
                old_log_std=log_std,
            )
            return state, batch, jnp.sum(div)

        return jax.jit(rollout)

    def run_rollout(self, fn: Any, params: Any, norm: Any, key: jax.Array) -> tuple[Any, np.ndarray]:
        """Run a :meth:`fused_rollout` function on this env's state; returns (batch, current obs)."""
        sel = devices.to_global(self.mesh, self.sel)
        self.state, batch, diverged = fn(params, norm, self._require(), sel, key)
        self.diverged_total += int(devices.to_host(diverged))
        return batch, self.state.obs
