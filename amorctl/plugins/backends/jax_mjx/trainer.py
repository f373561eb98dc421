"""MOPPO in JAX: the jax-mjx :class:`~amorctl.core.contracts.Trainer`.

One iteration is torch-cpu's (``torch_cpu/moppo.py``): rollout, GAE per objective, minibatch
updates, then the normalizer folds in the rollout's observations. Two rollout paths share one
jitted learning step (:func:`_learn`: GAE, ``lax.scan`` over epochs × minibatches, the
normalizer's batch moments, the metrics' reductions):

- **fused** — for :class:`~.env.MjxTrackingEnv`: the whole rollout (policy, MJX physics, rewards,
  auto-reset) is one ``lax.scan`` inside ``jit``; nothing but metrics leaves the device.
- **host** — for any other :class:`~amorctl.core.vecenv.VectorEnv` (the numpy toy envs, gym): the
  jitted policy acts, the env steps on the host, as torch-cpu does.

Devices: the env axis N of the env state and of the batch is sharded over a 1-D mesh of all
local devices (:mod:`.devices`); parameters and optimizer state are replicated. ``jit`` then
partitions the same program across the devices (GSPMD): per-env work runs where the env lives,
gradient and statistics reductions become all-reduces, so the update equals the one-device
update on the same batch up to float reduction order (tested with 2 CPU devices). With several
JAX processes (multi-host, :func:`.devices.initialize_distributed`) every process runs this same
program: host values (observations of numpy envs, keys, the normalizer) are lifted onto the
global mesh, sharded results read back with ``process_allgather`` (tested: 2 processes on one
machine give the 1-process 2-device update).

Checkpoints use torch-cpu's array names for the networks and the normalizer (so its inference
path loads them); the optax state, the JAX key, the current observations and episode statistics
are saved too, so ``--resume`` continues exactly.
"""

from __future__ import annotations

import time
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from amorctl.core import return_scale as rs
from amorctl.core.config import NetworkConfig, PPOConfig
from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.core.vecenv import VectorEnv, has_fused_rollout
from amorctl.plugins.backends.episode_window import EpisodeWindow
from amorctl.plugins.backends.host import check_env_meta, load_counters
from amorctl.plugins.backends.jax_mjx import devices
from amorctl.plugins.backends.jax_mjx import moppo_math as mm
from amorctl.plugins.backends.jax_mjx.networks import (
    HostNormalizer,
    Networks,
    Params,
    arrays_to_params,
    normalize,
    params_to_arrays,
)


# ---------------------------------------------------------------------------- jitted pieces
def policy_step(
    nets: Networks, clip: float, params: Params, norm: Any, obs: jax.Array, key: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """Sample actions for raw obs [N, D]: (action [N, A], mean [N, A], value [N, m], log-prob [N])."""
    x = normalize(obs, norm, clip)
    mean, value = nets.mean(params, x), nets.values(params, x)
    log_std = params["actor"]["log_std"]
    action = mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape, mean.dtype)
    return action, mean, value, mm.gaussian_log_prob(action, mean, log_std, xp=jnp)


def _learn(
    nets: Networks,
    optimizer: Any,
    cfg: mm.LossConfig,
    state: mm.TrainState,
    norm: Any,
    batch: mm.Batch,
    key: jax.Array,
    scale: rs.Moments | None,
    scale_updates: jax.Array,
) -> tuple[mm.TrainState, dict[str, Any]]:
    """GAE, all minibatch updates, and the reductions the metrics and the normalizer need.

    ``scale``: the running return statistics of ``return_norm`` (None when off), folded with this
    batch before the update as torch-cpu does; the folded ones come back as ``stats["scale"]``."""
    T, N, m = batch.rewards.shape
    adv, ret = mm.gae(
        batch.rewards,
        batch.values.reshape(T, N, m),
        batch.next_values,
        batch.terminated,
        batch.truncated,
        cfg.gamma,
        cfg.gae_lambda,
    )
    adv, ret = adv.reshape(T * N, m), ret.reshape(T * N, m)
    stds = None
    if scale is not None:
        rate = jnp.where(scale_updates == 0, 1.0, rs.RATE)
        scale = rs.fold(scale, rs.batch_moments(ret, adv, xp=jnp), rate)
        stds = (rs.return_std(scale, xp=jnp), rs.advantage_std(scale, xp=jnp))
    keys = jax.random.split(key, cfg.num_epochs)
    perms = jax.vmap(lambda k: jax.random.permutation(k, T * N))(keys)
    state, stats = mm.update(state, nets, optimizer, norm, batch, adv, ret, perms, cfg, stds)
    stats["scale"] = scale
    var = jnp.var(ret, axis=0)
    stats["explained_variance"] = jnp.where(var > 0, 1 - jnp.var(ret - batch.values, axis=0) / var, jnp.nan)
    stats["mean_reward"] = jnp.mean(batch.rewards, axis=(0, 1))
    stats["obs_mean"] = jnp.mean(batch.obs, axis=0)
    stats["obs_var"] = jnp.var(batch.obs, axis=0)
    return state, stats


class JaxMOPPOTrainer:
    """MOPPO for any ``VectorEnv`` (fused on the device for the MJX env); implements
    :class:`~amorctl.core.contracts.Trainer`."""

    def __init__(self, env: VectorEnv, network: NetworkConfig, ppo: PPOConfig, seed: int) -> None:
        self.env = env
        self.cfg = ppo
        self.names = tuple(env.reward_space.names)
        self.num_objectives = m = len(self.names)
        self.iteration_count = 0
        self.env_steps = 0
        self.mesh = devices.local_mesh()
        n = env.num_envs
        if n % self.mesh.size:
            raise AmorError(
                f"[env] num_envs = {n} must be a multiple of the {self.mesh.size} local JAX devices"
            )
        self.nets = Networks(
            env.obs_dim, env.action_dim, m, network.actor_hidden, network.critic_hidden, network.init_std
        )
        self.loss_cfg = mm.LossConfig.from_config(ppo, network.obs_clip)
        self.optimizer = mm.make_optimizer(ppo.learning_rate)
        key, init_key = jax.random.split(jax.random.PRNGKey(seed))
        params = self.nets.init(init_key)
        self.state = devices.replicate(self.mesh, mm.TrainState(params, self.optimizer.init(params)))
        self.key = key  # [2] uint32, the raw key format (saved as is)
        self.normalizer = HostNormalizer(env.obs_dim, clip=network.obs_clip)
        clip = network.obs_clip
        self._policy = jax.jit(partial(policy_step, self.nets, clip))
        self._mean = jax.jit(lambda p, nm, o: self.nets.mean(p, normalize(o, nm, clip)))
        self._values = jax.jit(lambda p, nm, o: self.nets.values(p, normalize(o, nm, clip)))
        self._learn = jax.jit(partial(_learn, self.nets, self.optimizer, self.loss_cfg))
        # a class attribute, so a wrapper (FixedWeights) that forwards attributes takes the host path
        self.fused = has_fused_rollout(env)
        if self.fused:
            self._rollout = env.fused_rollout(self.nets, clip, ppo.num_steps, self.mesh)  # type: ignore[attr-defined]

        obs, _ = env.reset(seed=seed)
        self.obs = np.asarray(obs, dtype=np.float32)  # [N, D]
        if ppo.normalize_obs:
            self.normalizer.update(self.obs)
        self.window = EpisodeWindow(n, m)  # running episode sums, the last finished episodes
        # [ppo] return_norm: running per-objective return statistics (core/return_scale.py)
        zeros, ones = np.zeros(m, np.float32), np.ones(m, np.float32)
        self.return_scale = None if ppo.return_norm == "off" else rs.Moments(zeros, ones, ones)
        self.return_scale_updates = 0

    # ------------------------------------------------------------------ small API
    @property
    def learning_rate(self) -> float:
        return float(mm.learning_rate(self.state.opt_state))

    @property
    def params(self) -> Params:
        return self.state.params

    def _g(self, tree: Any) -> Any:
        """Host or process-local inputs of a jitted call, lifted onto the mesh when several JAX
        processes share it (:func:`.devices.to_global`); unchanged in one process."""
        return devices.to_global(self.mesh, tree)

    def _next_key(self) -> jax.Array:
        self.key, sub = jax.random.split(self.key)
        return sub

    def reset_env(self, seed: int) -> None:
        """Restart every env episode with ``seed``; running episode sums start from zero."""
        obs, _ = self.env.reset(seed=seed)
        self.obs = np.asarray(obs, dtype=np.float32)
        self.window.restart(self.env.num_envs)

    def act(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """Actions [N, A] for raw observations [N, D] (the Gaussian mean when deterministic)."""
        norm = self.normalizer.device_stats()
        if deterministic:
            return np.asarray(self._mean(self.params, norm, jnp.asarray(obs, jnp.float32)))
        action, *_ = self._policy(self.params, norm, jnp.asarray(obs, jnp.float32), self._next_key())
        return np.asarray(action)

    def values(self, obs: np.ndarray) -> np.ndarray:
        """Critic values [N, m] for raw observations [N, D]."""
        return np.asarray(self._values(self.params, self.normalizer.device_stats(), jnp.asarray(obs)))

    # ------------------------------------------------------------------ rollouts
    def _host_rollout(self, norm: Any) -> tuple[mm.Batch, dict[str, float]]:
        """T host env steps with the jitted policy (torch-cpu's ``collect_rollout``)."""
        T, N, m = self.cfg.num_steps, self.env.num_envs, self.num_objectives
        bufs: dict[str, list[Any]] = {
            k: [] for k in ("obs", "act", "mean", "val", "logp", "next", "rew", "w")
        }
        term_buf = np.zeros((T, N), bool)
        trunc_buf = np.zeros((T, N), bool)
        t_env = t_policy = 0.0
        params = self.params
        for t in range(T):
            t0 = time.perf_counter()
            weights = np.asarray(self.env.weights, dtype=np.float32)
            obs = self._g(jnp.asarray(self.obs))
            action, mean, value, logp = self._policy(params, norm, obs, self._g(self._next_key()))
            action_np = np.asarray(action)
            t1 = time.perf_counter()
            next_obs, rewards, terminated, truncated, info = self.env.step(action_np)
            t2 = time.perf_counter()
            term_buf[t] = np.asarray(terminated, bool)
            trunc_buf[t] = np.asarray(truncated, bool) & ~term_buf[t]
            next_val = np.zeros((N, m), np.float32)
            if trunc_buf[t].any():  # bootstrap time-limited episodes from V(final_obs)
                final = self._g(jnp.asarray(np.asarray(info["final_obs"], np.float32)))
                next_val[trunc_buf[t]] = np.asarray(self._values(params, norm, final))[trunc_buf[t]]
            rewards = np.asarray(rewards, np.float32)
            for name, value_t in (
                ("obs", obs),
                ("act", action),
                ("mean", mean),
                ("val", value),
                ("logp", logp),
                ("next", next_val),
                ("rew", rewards),
                ("w", weights),
            ):
                bufs[name].append(value_t)
            self.window.record(rewards, weights, term_buf[t], trunc_buf[t])
            self.obs = np.asarray(next_obs, dtype=np.float32)
            t_env += t2 - t1
            t_policy += time.perf_counter() - t2 + t1 - t0
        t0 = time.perf_counter()
        last_values = self._values(params, norm, self._g(jnp.asarray(self.obs)))
        values = jnp.stack(bufs["val"])  # [T, N, m]
        following = jnp.concatenate([values[1:], last_values[None]], axis=0)
        trunc = self._g(jnp.asarray(trunc_buf))
        next_values = jnp.where(trunc[..., None], self._g(jnp.asarray(np.stack(bufs["next"]))), following)
        t_policy += time.perf_counter() - t0
        D, A = self.env.obs_dim, self.env.action_dim
        batch = mm.Batch(
            obs=jnp.stack(bufs["obs"]).reshape(T * N, D),
            actions=jnp.stack(bufs["act"]).reshape(T * N, A),
            log_probs=jnp.stack(bufs["logp"]).reshape(T * N),
            means=jnp.stack(bufs["mean"]).reshape(T * N, A),
            values=values.reshape(T * N, m),
            weights=self._g(jnp.asarray(np.stack(bufs["w"]).reshape(T * N, m))),
            rewards=self._g(jnp.asarray(np.stack(bufs["rew"]))),
            next_values=next_values,
            terminated=self._g(jnp.asarray(term_buf)),
            truncated=trunc,
            old_log_std=params["actor"]["log_std"],
        )
        return batch, {"env": t_env, "policy": t_policy}

    def _fused_rollout(self, norm: Any) -> tuple[mm.Batch, dict[str, float]]:
        """The env's jitted rollout; episode statistics from its rewards and episode ends."""
        t0 = time.perf_counter()
        key = self._g(self._next_key())
        batch, obs = self.env.run_rollout(self._rollout, self.params, norm, key)  # type: ignore[attr-defined]
        rewards = devices.to_host(batch.rewards).astype(np.float64)  # blocks until the rollout is done
        weights = devices.to_host(batch.weights).astype(np.float64).reshape(rewards.shape)
        terminated, truncated = devices.to_host(batch.terminated), devices.to_host(batch.truncated)
        elapsed = time.perf_counter() - t0
        for t in range(rewards.shape[0]):
            self.window.record(rewards[t], weights[t], terminated[t], truncated[t])
        self.obs = devices.to_host(obs).astype(np.float32)
        return batch, {"env": elapsed, "policy": 0.0}

    # ------------------------------------------------------------------ one iteration
    def iteration(self) -> dict[str, float]:
        """Rollout, returns and update (jitted), normalizer; returns this iteration's metrics."""
        start = time.perf_counter()
        norm = self._g(self.normalizer.device_stats())
        batch, times = self._fused_rollout(norm) if self.fused else self._host_rollout(norm)
        batch = devices.shard_batch(self.mesh, batch)
        t0 = time.perf_counter()
        scale = None if self.return_scale is None else self._g(self.return_scale)
        updates = jnp.asarray(self.return_scale_updates, jnp.int32)
        self.state, stats = self._learn(self.state, norm, batch, self._g(self._next_key()), scale, updates)
        stats = jax.tree_util.tree_map(devices.to_host, stats)
        if self.return_scale is not None:
            self.return_scale = rs.Moments(*(np.asarray(x, np.float32) for x in stats["scale"]))
            self.return_scale_updates += 1
        times["update"] = time.perf_counter() - t0
        if self.cfg.normalize_obs:
            self.normalizer.update_moments(batch.obs.shape[0], stats["obs_mean"], stats["obs_var"])
        self.env_steps += batch.obs.shape[0]
        self.iteration_count += 1
        elapsed = time.perf_counter() - start
        return self._metrics(batch.obs.shape[0], stats, times, elapsed)

    def _metrics(
        self, size: int, stats: dict[str, np.ndarray], times: dict[str, float], elapsed: float
    ) -> dict[str, float]:
        metrics: dict[str, float] = {
            "iteration": float(self.iteration_count),
            "env_steps": float(self.env_steps),
        }
        metrics["env_steps_per_s"] = size / max(elapsed, 1e-9)
        metrics["time/iteration_s"] = elapsed
        metrics["time/env_frac"] = times["env"] / elapsed
        metrics["time/network_frac"] = (times["policy"] + times["update"]) / elapsed
        metrics["time/update_frac"] = times["update"] / elapsed
        metrics["time/glue_frac"] = max(0.0, 1.0 - metrics["time/env_frac"] - metrics["time/network_frac"])
        for key in (
            "loss/total",
            "loss/policy",
            "loss/value",
            "loss/entropy",
            "kl",
            "approx_kl",
            "clip_fraction",
        ):
            metrics[key] = float(stats[key])
        metrics["learning_rate"] = self.learning_rate
        metrics["action_std"] = float(np.exp(np.asarray(self.params["actor"]["log_std"])).mean())
        metrics["bf16"] = 0.0  # jax-mjx trains in fp32
        metrics.update(self.window.metrics(self.names))
        if self.return_scale is not None:
            scale = self.return_scale
            ret_std, adv_std = rs.return_std(scale, xp=np), rs.advantage_std(scale, xp=np)
            for i, name in enumerate(self.names):
                metrics[f"return_scale/return_std/{name}"] = float(ret_std[i])
                metrics[f"return_scale/advantage_std/{name}"] = float(adv_std[i])
        for i, name in enumerate(self.names):
            metrics[f"reward/{name}"] = float(stats["mean_reward"][i])
            metrics[f"explained_variance/{name}"] = float(stats["explained_variance"][i])
        return metrics

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> Snapshot:
        """Weights and normalizer (torch-cpu's names), optax state, JAX key, obs, episode stats."""
        arrays = params_to_arrays(self.params)
        arrays.update(self.normalizer.to_arrays())
        leaves = jax.tree_util.tree_leaves(jax.device_get(self.state.opt_state))
        for i, leaf in enumerate(leaves):
            arrays[f"optimizer.{i}"] = np.asarray(leaf).copy()
        arrays["rng.jax"] = np.asarray(jax.device_get(self.key)).copy()
        arrays["obs"] = self.obs.copy()
        window_arrays, window_meta = self.window.state()
        arrays.update(window_arrays)
        if self.return_scale is not None:  # torch-cpu's names (float64 there, float32 here)
            for key, value in zip(rs.STATE_KEYS, self.return_scale, strict=True):
                arrays[f"return_scale.{key}"] = np.asarray(value, np.float32).copy()
        meta: dict[str, Any] = {
            "iteration": self.iteration_count,
            "env_steps": self.env_steps,
            "learning_rate": self.learning_rate,
            "optimizer": "optax.adam (inject_hyperparams)",
            "optimizer_leaves": len(leaves),
            **window_meta,
            "obs_dim": self.env.obs_dim,
            "action_dim": self.env.action_dim,
            "objectives": list(self.names),
        }
        if self.return_scale is not None:
            meta["return_scale_updates"] = self.return_scale_updates
        # safetensors checkpoints store 0-d arrays as [1]: write them so, and a fresh state matches
        arrays = {k: np.atleast_1d(v) for k, v in arrays.items()}
        layout = getattr(self.env, "obs_layout", None)
        if isinstance(layout, dict):
            meta["observation_layout"] = {k: [s.start, s.stop] for k, s in layout.items()}
        return Snapshot(arrays, meta)

    def load_state_dict(self, state: Snapshot) -> None:
        """Restore :meth:`state_dict`. Raises AmorError on a checkpoint of another shape, objective
        set or backend."""
        meta, arrays = state.meta, state.arrays
        check_env_meta(meta, self.env, self.names)
        if "rng.jax" not in arrays:
            raise AmorError("checkpoint was not written by the jax-mjx backend (no rng.jax array)")
        params = arrays_to_params(arrays, self.params)
        try:
            self.normalizer.load_arrays(arrays)
            treedef = jax.tree_util.tree_structure(self.state.opt_state)
            current = jax.tree_util.tree_leaves(self.state.opt_state)
            leaves = []
            for i, like in enumerate(current):
                value, shape = np.asarray(arrays[f"optimizer.{i}"]), np.shape(like)
                if value.size != int(np.prod(shape)):  # safetensors stores 0-d arrays as [1]
                    raise AmorError(f"checkpoint optimizer.{i} has shape {value.shape}, expected {shape}")
                leaves.append(jnp.asarray(value.reshape(shape), dtype=jnp.asarray(like).dtype))
            if int(meta.get("optimizer_leaves", -1)) != len(current):
                raise AmorError("checkpoint optimizer state does not fit this network configuration")
            opt_state = jax.tree_util.tree_unflatten(treedef, leaves)
            self.key = jnp.asarray(arrays["rng.jax"])
            self.obs = np.asarray(arrays["obs"], np.float32).copy()
            self.window.load_state(arrays, meta)
            if self.return_scale is not None:
                m = self.num_objectives
                saved = (arrays[f"return_scale.{k}"] for k in rs.STATE_KEYS)
                self.return_scale = rs.Moments(*(np.asarray(a, np.float32).reshape(m) for a in saved))
                self.return_scale_updates = int(meta["return_scale_updates"])
        except KeyError as exc:
            raise AmorError(f"checkpoint does not fit this network configuration: missing {exc}") from None
        self.state = devices.replicate(self.mesh, mm.TrainState(params, opt_state))
        load_counters(self, meta)
