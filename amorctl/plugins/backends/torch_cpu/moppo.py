"""MOPPO (the AMOR paper, Section 4) on PyTorch, CPU. One file, read top to bottom.

Per iteration:

1. **Rollout**: T steps of N envs. The actor ``pi(a | s, c, w)`` samples Gaussian actions; the
   critic ``V(s, c, w)`` gives m values per state. Each env's weights ``w`` (Dirichlet(1) per
   episode, the last m observation entries) are recorded per step. Truncated episodes store
   ``V(final_obs)`` to bootstrap from.
2. **Returns**: GAE per objective over ``[T, N, m]`` (:func:`gae.gae`).
3. **Update**: ``num_epochs`` passes over shuffled minibatches. The vector advantage is scalarized
   per sample as ``A·w``, normalized with the minibatch's mean and std, and drives the PPO
   clipped surrogate; the value loss is the (optionally clipped) squared error over all m
   critic outputs; an entropy bonus; one Adam step on the sum, with the actor's and the critic's
   gradient norms clipped separately (so large value errors do not shrink the policy step). The
   learning rate optionally adapts to keep the KL near ``desired_kl`` (as rsl_rl does).
4. **Normalizer**: the running observation mean/std is frozen during an iteration (so the rollout
   and the update see the same inputs) and folds in the iteration's observations at its end.

Data-parallel (``torchrun``, docs/distributed.md): each rank steps its own ``N / world size`` envs
and every rank holds the same networks. Per minibatch step the advantage normalization uses the
mean and std over all ranks' minibatches, and the gradients (each rank's minibatch mean, weighted
by its sample count) and the loss statistics are summed in one all-reduce, so every rank takes the
same Adam step and the adaptive learning rate follows the all-reduced KL. The normalizer folds in
the moments of all ranks' observations; metrics are reduced over ranks. This is the 1-process
update on the union of the ranks' minibatches (up to float rounding). Without a process group
none of it runs and the single-process arithmetic is unchanged.

Shapes: T = ``num_steps``, N = envs, D = obs dim, A = action dim, m = objectives, B = T·N.
bf16: network forward/backward run under CPU autocast; weights, the Gaussian log-probabilities,
the ratio and all losses stay float32.
"""

from __future__ import annotations

import contextlib
import hashlib
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from amorctl.core.config import NetworkConfig, PPOConfig
from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.core.vecenv import VectorEnv
from amorctl.plugins.backends.torch_cpu.gae import gae
from amorctl.plugins.backends.torch_cpu.networks import (
    Actor,
    Critic,
    RunningNormalizer,
    gaussian_entropy,
    gaussian_log_prob,
    load_modules,
    modules_to_arrays,
)

EPISODE_WINDOW = 100  # episode statistics are means over this many most recent episodes
LR_MIN, LR_MAX = 1e-6, 1e-2  # bounds of the adaptive learning rate
CHECK_EVERY = 10  # data-parallel: compare the ranks' parameters every this many iterations
#: Per-env episode accumulators and recent-episode windows, saved in checkpoints for exact resume.
EPISODE_STATS = (
    "ep_return",
    "ep_scalar",
    "ep_length",
    "recent_return",
    "recent_scalar",
    "recent_length",
    "recent_survived",
)


class Replicas:
    """The ``torch.distributed`` default process group a data-parallel trainer averages over.

    Every collective is timed (``seconds``), so the iteration's communication share is measured.
    """

    def __init__(self) -> None:
        import torch.distributed as dist

        self.dist = dist
        self.rank = dist.get_rank()
        self.size = dist.get_world_size()
        self.seconds = 0.0

    def _run(self, fn: Any, *args: Any, **kwargs: Any) -> None:
        t0 = time.perf_counter()
        try:
            fn(*args, **kwargs)
        except RuntimeError as exc:  # a peer died or timed out: one clear line, never a hang
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise AmorError(
                f"rank {self.rank}/{self.size}: MOPPO {getattr(fn, '__name__', 'collective')} failed, "
                f"another rank died or stopped answering: {first}",
                exit_code=3,
            ) from None
        self.seconds += time.perf_counter() - t0

    def sum_(self, tensor: torch.Tensor) -> torch.Tensor:
        """All-reduce ``tensor`` in place (sum over ranks); returns it."""
        self._run(self.dist.all_reduce, tensor, op=self.dist.ReduceOp.SUM)
        return tensor

    def broadcast_modules(self, modules: dict[str, nn.Module]) -> None:
        """Overwrite every rank's parameters and buffers with rank 0's."""
        for module in modules.values():
            for tensor in module.state_dict().values():
                self._run(self.dist.broadcast, tensor, src=0)

    def check_identical(self, modules: dict[str, nn.Module], iteration: int) -> None:
        """Raise AmorError unless every rank holds byte-identical parameters and buffers."""
        digest = hashlib.sha256()
        for module in modules.values():
            for key, tensor in module.state_dict().items():
                digest.update(key.encode() + tensor.detach().contiguous().numpy().tobytes())
        words = torch.from_numpy(np.frombuffer(digest.digest(), dtype=np.int64).copy())
        low, high = words.clone(), words.clone()
        self._run(self.dist.all_reduce, low, op=self.dist.ReduceOp.MIN)
        self._run(self.dist.all_reduce, high, op=self.dist.ReduceOp.MAX)
        if not torch.equal(low, high):
            raise AmorError(
                f"data-parallel training: the ranks' parameters differ at iteration {iteration} "
                "(non-deterministic kernels or a lost update); stopping instead of training on"
            )


@dataclass
class Batch:
    """One rollout, flattened to B = T·N samples (``rewards``/``values`` keep [T, N, m] views)."""

    obs: torch.Tensor  # [B, D] raw observations (normalized inside the networks' call)
    actions: torch.Tensor  # [B, A]
    log_probs: torch.Tensor  # [B] log pi_old(a | s)
    means: torch.Tensor  # [B, A] pi_old's action means (for the analytic KL)
    values: torch.Tensor  # [B, m] V_old(s)
    weights: torch.Tensor  # [B, m] each sample's episode weights
    rewards: torch.Tensor  # [T, N, m]
    next_values: torch.Tensor  # [T, N, m] V(s_{t+1}): next rollout value, or V(final_obs) if truncated
    terminated: torch.Tensor  # [T, N] bool
    truncated: torch.Tensor  # [T, N] bool
    old_log_std: torch.Tensor  # [A]
    advantages: torch.Tensor | None = None  # [B, m] per-objective GAE (set by compute_returns)
    returns: torch.Tensor | None = None  # [B, m] value targets (set by compute_returns)


class MOPPOTrainer:
    """MOPPO for any ``VectorEnv``; implements :class:`~amorctl.core.contracts.Trainer`."""

    def __init__(
        self,
        env: VectorEnv,
        network: NetworkConfig,
        ppo: PPOConfig,
        seed: int,
        bf16: bool = False,
        distributed: bool = False,
    ) -> None:
        self.env = env
        self.cfg = ppo
        self.bf16 = bf16  # autocast the networks to bf16 (the backend resolves precision = "auto")
        self.names = tuple(env.reward_space.names)
        self.num_objectives = len(self.names)
        self.iteration_count = 0
        self.env_steps = 0
        self.learning_rate = ppo.learning_rate
        self.generator = torch.Generator().manual_seed(seed)  # action noise and minibatch order
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            self.actor = Actor(env.obs_dim, env.action_dim, network.actor_hidden, network.init_std)
            self.critic = Critic(env.obs_dim, self.num_objectives, network.critic_hidden)
        self.normalizer = RunningNormalizer(env.obs_dim, clip=network.obs_clip)
        self.params = [*self.actor.parameters(), *self.critic.parameters()]
        self.optimizer = torch.optim.Adam(self.params, lr=self.learning_rate)
        # data-parallel over the default process group: rank 0's initial networks on every rank
        self.replicas = Replicas() if distributed else None
        self.world_size = 1 if self.replicas is None else self.replicas.size
        if self.replicas is not None:
            self.replicas.broadcast_modules(self._modules())

        obs, _ = env.reset(seed=seed)
        self.obs = torch.tensor(obs, dtype=torch.float32)  # [N, D] the current observations
        if ppo.normalize_obs:
            self._update_normalizer(self.obs)  # first estimate from the reset states
        n, m = env.num_envs, self.num_objectives
        self.ep_return = torch.zeros(n, m, dtype=torch.float64)  # running per-objective sums
        self.ep_scalar = torch.zeros(n, dtype=torch.float64)  # running sum of r·w
        self.ep_length = torch.zeros(n, dtype=torch.int64)
        self.recent_return = torch.full((EPISODE_WINDOW, m), float("nan"), dtype=torch.float64)
        self.recent_scalar = torch.full((EPISODE_WINDOW,), float("nan"), dtype=torch.float64)
        self.recent_length = torch.full((EPISODE_WINDOW,), float("nan"), dtype=torch.float64)
        self.recent_survived = torch.full((EPISODE_WINDOW,), float("nan"), dtype=torch.float64)
        self.recent_ptr = 0
        self.episodes = 0

    def reset_env(self, seed: int) -> None:
        """Restart every env episode with ``seed``; running episode sums start from zero."""
        obs, _ = self.env.reset(seed=seed)
        self.obs = torch.tensor(obs, dtype=torch.float32)
        n, m = self.env.num_envs, self.num_objectives  # sized anew: a resume may change N per rank
        self.ep_return = torch.zeros(n, m, dtype=torch.float64)
        self.ep_scalar = torch.zeros(n, dtype=torch.float64)
        self.ep_length = torch.zeros(n, dtype=torch.int64)
        if self.replicas is not None:  # another world size restarts: one fresh noise stream per rank
            self.generator.manual_seed(seed)

    @torch.no_grad()
    def _update_normalizer(self, obs: torch.Tensor) -> None:
        """Fold observations [B, D] into the normalizer: this rank's, or all ranks' moments."""
        if self.replicas is None:
            self.normalizer.update(obs)
            return
        x = obs.to(torch.float64).reshape(-1, self.env.obs_dim)
        count_sum = torch.cat([torch.tensor([float(x.shape[0])], dtype=torch.float64), x.sum(0)])
        sums = self.replicas.sum_(count_sum)
        count = float(sums[0])
        if count == 0:
            return
        mean = sums[1:] / count
        var = self.replicas.sum_(((x - mean) ** 2).sum(0)) / count
        self.normalizer.fold(mean, var, count)

    # ------------------------------------------------------------------ networks
    def _autocast(self) -> contextlib.AbstractContextManager[Any]:
        if self.bf16:
            return torch.autocast("cpu", dtype=torch.bfloat16)
        return contextlib.nullcontext()

    def _forward(self, obs: torch.Tensor, critic: bool = True) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Raw obs [B, D] -> (action mean [B, A], values [B, m] or None), float32 outputs."""
        x = self.normalizer(obs)
        with self._autocast():
            mean = self.actor(x)
            values = self.critic(x) if critic else None
        return mean.float(), (values.float() if values is not None else None)

    @torch.no_grad()
    def act(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """Actions [N, A] for raw observations [N, D] (the Gaussian mean when deterministic)."""
        mean, _ = self._forward(torch.as_tensor(obs, dtype=torch.float32), critic=False)
        if not deterministic:
            mean = mean + torch.exp(self.actor.log_std) * torch.randn(mean.shape, generator=self.generator)
        return mean.numpy()

    @torch.no_grad()
    def values(self, obs: np.ndarray) -> np.ndarray:
        """Critic values [N, m] for raw observations [N, D]."""
        _, v = self._forward(torch.as_tensor(obs, dtype=torch.float32))
        assert v is not None
        return v.numpy()

    # ------------------------------------------------------------------ 1. rollout
    @torch.no_grad()
    def collect_rollout(self) -> tuple[Batch, dict[str, float]]:
        """Step the envs ``num_steps`` times with the current policy; returns the batch (advantages
        not yet filled in) and the time spent in the env and in the policy's forward passes."""
        T, N, m = self.cfg.num_steps, self.env.num_envs, self.num_objectives
        D, A = self.env.obs_dim, self.env.action_dim
        obs_buf = torch.zeros(T, N, D)
        act_buf = torch.zeros(T, N, A)
        mean_buf = torch.zeros(T, N, A)
        logp_buf = torch.zeros(T, N)
        val_buf = torch.zeros(T, N, m)
        next_val_buf = torch.zeros(T, N, m)
        rew_buf = torch.zeros(T, N, m)
        w_buf = torch.zeros(T, N, m)
        term_buf = torch.zeros(T, N, dtype=torch.bool)
        trunc_buf = torch.zeros(T, N, dtype=torch.bool)
        std = torch.exp(self.actor.log_std)
        t_env = t_policy = 0.0

        for t in range(T):
            t0 = time.perf_counter()
            weights = torch.tensor(self.env.weights, dtype=torch.float32)  # w of this step's episode (a copy)
            mean, value = self._forward(self.obs)
            assert value is not None
            action = mean + std * torch.randn(mean.shape, generator=self.generator)
            t1 = time.perf_counter()
            obs, rewards, terminated, truncated, info = self.env.step(action.numpy())
            t2 = time.perf_counter()
            obs_buf[t], act_buf[t], mean_buf[t], val_buf[t], w_buf[t] = self.obs, action, mean, value, weights
            logp_buf[t] = gaussian_log_prob(action, mean, self.actor.log_std)
            rew_buf[t] = torch.as_tensor(rewards, dtype=torch.float32)
            term_buf[t] = torch.as_tensor(terminated, dtype=torch.bool)
            trunc_buf[t] = torch.as_tensor(truncated, dtype=torch.bool) & ~term_buf[t]
            if trunc_buf[t].any():  # bootstrap time-limited episodes from V(final_obs)
                final = torch.as_tensor(info["final_obs"], dtype=torch.float32)[trunc_buf[t]]
                _, final_values = self._forward(final)
                next_val_buf[t][trunc_buf[t]] = final_values
            self._track_episodes(rew_buf[t], weights, term_buf[t], trunc_buf[t])
            self.obs = torch.tensor(obs, dtype=torch.float32)
            t_env += t2 - t1
            t_policy += time.perf_counter() - t2 + t1 - t0

        t0 = time.perf_counter()
        _, last_values = self._forward(self.obs)  # V of the state after the rollout
        assert last_values is not None
        following = torch.cat([val_buf[1:], last_values[None]], dim=0)  # V(s_{t+1}) where the episode goes on
        next_val_buf = torch.where(trunc_buf[..., None], next_val_buf, following)
        t_policy += time.perf_counter() - t0
        self.env_steps += T * N * self.world_size  # all ranks' env steps (equal N per rank)
        batch = Batch(
            obs=obs_buf.reshape(T * N, D),
            actions=act_buf.reshape(T * N, A),
            log_probs=logp_buf.reshape(T * N),
            means=mean_buf.reshape(T * N, A),
            values=val_buf.reshape(T * N, m),
            weights=w_buf.reshape(T * N, m),
            rewards=rew_buf,
            next_values=next_val_buf,
            terminated=term_buf,
            truncated=trunc_buf,
            old_log_std=self.actor.log_std.detach().clone(),
        )
        return batch, {"env": t_env, "policy": t_policy}

    def _track_episodes(
        self, rewards: torch.Tensor, weights: torch.Tensor, terminated: torch.Tensor, truncated: torch.Tensor
    ) -> None:
        """Accumulate undiscounted per-objective episode returns; log the episodes that ended."""
        self.ep_return += rewards.double()
        self.ep_scalar += (rewards * weights).sum(-1).double()
        self.ep_length += 1
        ended = terminated | truncated
        k = int(ended.sum())
        if k == 0:
            return
        slots = (self.recent_ptr + torch.arange(k)) % EPISODE_WINDOW
        self.recent_return[slots] = self.ep_return[ended]
        self.recent_scalar[slots] = self.ep_scalar[ended]
        self.recent_length[slots] = self.ep_length[ended].double()
        self.recent_survived[slots] = (~terminated[ended]).double()
        self.recent_ptr = int((self.recent_ptr + k) % EPISODE_WINDOW)
        self.episodes += k
        self.ep_return[ended] = 0.0
        self.ep_scalar[ended] = 0.0
        self.ep_length[ended] = 0

    # ------------------------------------------------------------------ 2. returns
    def compute_returns(self, batch: Batch) -> None:
        """GAE per objective over [T, N, m]; fills ``batch.advantages`` and ``batch.returns`` [B, m]."""
        T, N, m = batch.rewards.shape
        advantages, returns = gae(
            batch.rewards,
            batch.values.reshape(T, N, m),
            batch.next_values,
            batch.terminated,
            batch.truncated,
            self.cfg.gamma,
            self.cfg.gae_lambda,
        )
        batch.advantages, batch.returns = advantages.reshape(T * N, m), returns.reshape(T * N, m)

    # ------------------------------------------------------------------ 3. update
    def minibatch_loss(self, batch: Batch, idx: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The MOPPO loss on the samples ``idx`` of ``batch``; returns (loss, detached stats)."""
        assert batch.advantages is not None and batch.returns is not None, "call compute_returns first"
        mean, values = self._forward(batch.obs[idx])
        assert values is not None
        log_std = self.actor.log_std
        log_prob = gaussian_log_prob(batch.actions[idx], mean, log_std)
        log_ratio = log_prob - batch.log_probs[idx]
        ratio = torch.exp(log_ratio)

        # scalarize the vector advantage with each sample's own weights, normalize per minibatch
        adv = (batch.advantages[idx] * batch.weights[idx]).sum(-1)
        if self.replicas is None:
            adv = (adv - adv.mean()) / (adv.std(correction=0) + 1e-8)
        else:  # the moments of the union of all ranks' minibatches
            a = adv.detach().double()
            n, total, squares = self.replicas.sum_(
                torch.stack([torch.tensor(float(a.numel()), dtype=torch.float64), a.sum(), (a * a).sum()])
            )
            adv_mean = total / n
            adv_std = torch.sqrt(torch.clamp(squares / n - adv_mean * adv_mean, min=0.0))
            adv = (adv - adv_mean.float()) / (adv_std.float() + 1e-8)
        clip = self.cfg.clip_coef
        policy_loss = torch.max(-adv * ratio, -adv * torch.clamp(ratio, 1 - clip, 1 + clip)).mean()

        # value loss over all m objectives
        returns, old_values = batch.returns[idx], batch.values[idx]
        value_err = (values - returns) ** 2
        if self.cfg.clip_value_loss:
            clipped = old_values + torch.clamp(values - old_values, -clip, clip)
            value_err = torch.max(value_err, (clipped - returns) ** 2)
        value_loss = 0.5 * value_err.mean()

        entropy = gaussian_entropy(log_std)
        loss = policy_loss + self.cfg.value_coef * value_loss - self.cfg.entropy_coef * entropy

        with torch.no_grad():
            old_std, new_std = torch.exp(batch.old_log_std), torch.exp(log_std)
            kl = (
                (
                    log_std
                    - batch.old_log_std
                    + (old_std**2 + (batch.means[idx] - mean) ** 2) / (2 * new_std**2)
                    - 0.5
                )
                .sum(-1)
                .mean()
            )
            stats = {
                "loss/total": loss.detach(),
                "loss/policy": policy_loss.detach(),
                "loss/value": value_loss.detach(),
                "loss/entropy": entropy.detach(),
                "kl": kl,
                "approx_kl": ((ratio - 1) - log_ratio).mean(),
                "clip_fraction": ((ratio - 1).abs() > clip).float().mean(),
            }
        return loss, stats

    def minibatch_plan(self, size: int) -> list[torch.Tensor]:
        """The sample indices of every minibatch step of one update, in order (``num_epochs``
        shuffles of ``range(size)``, each cut into ``num_minibatches`` parts)."""
        plan: list[torch.Tensor] = []
        for _ in range(self.cfg.num_epochs):
            order = torch.randperm(size, generator=self.generator)
            plan.extend(order.tensor_split(self.cfg.num_minibatches))
        return plan

    def update(self, batch: Batch, plan: list[torch.Tensor] | None = None) -> dict[str, float]:
        """``num_epochs`` passes of minibatch Adam steps; returns stats averaged over minibatches.

        ``plan`` (default :meth:`minibatch_plan`) fixes the minibatches, e.g. to compare a
        data-parallel update with the 1-process update on the same samples."""
        plan = self.minibatch_plan(batch.obs.shape[0]) if plan is None else plan
        sums: dict[str, float] = {}
        count = 0
        for idx in plan:
            loss, stats = self.minibatch_loss(batch, idx)
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            if self.replicas is not None:
                stats = self._average_gradients(stats, len(idx))
            nn.utils.clip_grad_norm_(self.actor.parameters(), self.cfg.max_grad_norm)
            nn.utils.clip_grad_norm_(self.critic.parameters(), self.cfg.max_grad_norm)
            self.optimizer.step()
            if self.cfg.lr_schedule == "adaptive":
                self._adapt_learning_rate(float(stats["kl"]))
            for key, value in stats.items():
                sums[key] = sums.get(key, 0.0) + float(value)
            count += 1
        return {key: value / count for key, value in sums.items()}

    def _average_gradients(self, stats: dict[str, torch.Tensor], n: int) -> dict[str, torch.Tensor]:
        """Data-parallel: replace this rank's gradients and minibatch statistics (means over its
        ``n`` samples) by the sample-weighted means over all ranks, in one all-reduce."""
        assert self.replicas is not None
        grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in self.params]
        values = torch.stack([v.float() for v in stats.values()])
        flat = torch.cat([*(g.reshape(-1) for g in grads), values, torch.ones(1)]) * float(n)
        self.replicas.sum_(flat)
        flat = flat / flat[-1]
        offset = 0
        for p, g in zip(self.params, grads, strict=True):
            p.grad = flat[offset : offset + g.numel()].view_as(g).clone()
            offset += g.numel()
        return {key: flat[offset + i] for i, key in enumerate(stats)}

    def _adapt_learning_rate(self, kl: float) -> None:
        """rsl_rl's rule: divide by 1.5 above 2·desired_kl, multiply by 1.5 below desired_kl/2."""
        if kl > 2.0 * self.cfg.desired_kl:
            self.learning_rate = max(LR_MIN, self.learning_rate / 1.5)
        elif 0.0 < kl < 0.5 * self.cfg.desired_kl:
            self.learning_rate = min(LR_MAX, self.learning_rate * 1.5)
        for group in self.optimizer.param_groups:
            group["lr"] = self.learning_rate

    # ------------------------------------------------------------------ one iteration
    def iteration(self) -> dict[str, float]:
        """Rollout, returns, update, normalizer; returns this iteration's metrics."""
        start = time.perf_counter()
        comm_before = 0.0 if self.replicas is None else self.replicas.seconds
        batch, times = self.collect_rollout()
        self.compute_returns(batch)
        t0 = time.perf_counter()
        stats = self.update(batch)
        times["update"] = time.perf_counter() - t0
        if self.cfg.normalize_obs:
            self._update_normalizer(batch.obs)
        self.iteration_count += 1
        if self.replicas is None:
            elapsed = time.perf_counter() - start
            return self._metrics(batch, stats, times, elapsed)
        if self.iteration_count % CHECK_EVERY == 0:
            self.replicas.check_identical(self._modules(), self.iteration_count)
        metrics = self._metrics(batch, stats, times, time.perf_counter() - start)
        metrics.update(self._reduced_metrics(batch))
        elapsed = time.perf_counter() - start
        metrics["time/iteration_s"] = elapsed
        metrics["env_steps_per_s"] = batch.obs.shape[0] * self.world_size / max(elapsed, 1e-9)
        metrics["time/comm_frac"] = (self.replicas.seconds - comm_before) / elapsed
        return metrics

    @torch.no_grad()
    def _reduced_metrics(self, batch: Batch) -> dict[str, float]:
        """Data-parallel: episode statistics, mean rewards and explained variances over all ranks
        (one all-reduce); each rank's window holds its own last ``EPISODE_WINDOW`` episodes."""
        assert self.replicas is not None and batch.returns is not None
        m = self.num_objectives
        filled = ~torch.isnan(self.recent_length)
        ret, val = batch.returns.double(), batch.values.double()
        res = ret - val
        parts = [
            torch.tensor([float(filled.sum()), self.episodes, ret.shape[0]], dtype=torch.float64),
            self.recent_return[filled].sum(0),  # [m]
            torch.stack([self.recent_scalar[filled].sum(), self.recent_length[filled].sum()]),
            self.recent_survived[filled].sum().reshape(1),
            batch.rewards.double().sum(dim=(0, 1)),  # [m]
            ret.sum(0),
            (ret * ret).sum(0),
            res.sum(0),
            (res * res).sum(0),
        ]
        total = self.replicas.sum_(torch.cat(parts))
        k, episodes, b = (float(v) for v in total[:3])
        ep_ret, (ep_scalar, ep_len), ep_surv = total[3 : 3 + m], total[3 + m : 5 + m], float(total[5 + m])
        rew, r1, r2, e1, e2 = total[6 + m :].reshape(5, m)
        nan = float("nan")
        out: dict[str, float] = {"episodes": episodes}
        for i, name in enumerate(self.names):
            out[f"return/{name}"] = float(ep_ret[i]) / k if k else nan
            out[f"reward/{name}"] = float(rew[i]) / b
            var_ret = float(r2[i]) / b - (float(r1[i]) / b) ** 2
            var_res = float(e2[i]) / b - (float(e1[i]) / b) ** 2
            out[f"explained_variance/{name}"] = 1 - var_res / var_ret if var_ret > 0 else nan
        out["return/scalarized"] = float(ep_scalar) / k if k else nan
        out["episode/length"] = float(ep_len) / k if k else nan
        out["episode/survival"] = ep_surv / k if k else nan
        return out

    def _metrics(
        self, batch: Batch, stats: dict[str, float], times: dict[str, float], elapsed: float
    ) -> dict[str, float]:
        metrics: dict[str, float] = {
            "iteration": float(self.iteration_count),
            "env_steps": float(self.env_steps),
        }
        metrics["env_steps_per_s"] = batch.obs.shape[0] / max(elapsed, 1e-9)
        metrics["time/iteration_s"] = elapsed
        metrics["time/env_frac"] = times["env"] / elapsed
        metrics["time/network_frac"] = (times["policy"] + times["update"]) / elapsed
        metrics["time/glue_frac"] = max(0.0, 1.0 - metrics["time/env_frac"] - metrics["time/network_frac"])
        metrics.update(stats)
        metrics["learning_rate"] = self.learning_rate
        metrics["action_std"] = float(torch.exp(self.actor.log_std.detach()).mean())
        assert batch.returns is not None
        filled = ~torch.isnan(self.recent_length)
        has = bool(filled.any())
        mean_reward = batch.rewards.mean(dim=(0, 1))
        for i, name in enumerate(self.names):
            metrics[f"return/{name}"] = float(self.recent_return[filled, i].mean()) if has else float("nan")
            metrics[f"reward/{name}"] = float(mean_reward[i])
            ret, val = batch.returns[:, i], batch.values[:, i]
            var = ret.var()
            metrics[f"explained_variance/{name}"] = (
                float(1 - (ret - val).var() / var) if var > 0 else float("nan")
            )
        metrics["return/scalarized"] = float(self.recent_scalar[filled].mean()) if has else float("nan")
        metrics["episode/length"] = float(self.recent_length[filled].mean()) if has else float("nan")
        metrics["episode/survival"] = float(self.recent_survived[filled].mean()) if has else float("nan")
        metrics["episodes"] = float(self.episodes)
        return metrics

    # ------------------------------------------------------------------ checkpoints
    def _modules(self) -> dict[str, nn.Module]:
        """The networks and the normalizer by checkpoint prefix."""
        return {"actor": self.actor, "critic": self.critic, "normalizer": self.normalizer}

    def state_dict(self) -> Snapshot:
        """Weights, normalizer, Adam state, RNG, current observations and episode statistics
        (this rank's; the training loop merges the ranks' snapshots into one checkpoint)."""
        if self.replicas is not None:
            self.replicas.check_identical(self._modules(), self.iteration_count)
        arrays = modules_to_arrays(self._modules())
        optim = self.optimizer.state_dict()
        for index, slot in optim["state"].items():
            for key, tensor in slot.items():
                arrays[f"optimizer.{index}.{key}"] = torch.as_tensor(tensor).numpy().copy()
        arrays["rng.torch"] = self.generator.get_state().numpy().copy()
        arrays["obs"] = self.obs.numpy().copy()
        for key in EPISODE_STATS:
            arrays[f"episodes.{key}"] = getattr(self, key).numpy().copy()
        meta = {
            "iteration": self.iteration_count,
            "env_steps": self.env_steps,
            "learning_rate": self.learning_rate,
            "optimizer_param_groups": optim["param_groups"],
            "optimizer_state_keys": {str(i): sorted(s) for i, s in optim["state"].items()},
            "recent_ptr": self.recent_ptr,
            "episodes": self.episodes,
            "obs_dim": self.env.obs_dim,
            "action_dim": self.env.action_dim,
            "objectives": list(self.names),
        }
        return Snapshot(arrays, meta)

    def load_state_dict(self, state: Snapshot) -> None:
        """Restore :meth:`state_dict`. Raises AmorError on a checkpoint of another shape or objective set."""
        meta, arrays = state.meta, state.arrays
        expect = {
            "obs_dim": self.env.obs_dim,
            "action_dim": self.env.action_dim,
            "objectives": list(self.names),
        }
        for key, value in expect.items():
            if meta.get(key) != value:
                raise AmorError(f"checkpoint has {key} = {meta.get(key)!r}, this environment has {value!r}")
        try:
            load_modules(self._modules(), arrays)
            optim_state: dict[int, dict[str, torch.Tensor]] = {}
            for index, keys in meta["optimizer_state_keys"].items():
                optim_state[int(index)] = {
                    k: torch.from_numpy(arrays[f"optimizer.{index}.{k}"].copy()) for k in keys
                }
            self.optimizer.load_state_dict(
                {"state": optim_state, "param_groups": meta["optimizer_param_groups"]}
            )
            self.generator.set_state(torch.from_numpy(arrays["rng.torch"].copy()))
            self.obs = torch.from_numpy(arrays["obs"].copy())
            for key in EPISODE_STATS:
                setattr(self, key, torch.from_numpy(arrays[f"episodes.{key}"].copy()))
        except (KeyError, RuntimeError, ValueError) as exc:
            raise AmorError(f"checkpoint does not fit this network configuration: {exc}") from None
        self.iteration_count = int(meta["iteration"])
        self.env_steps = int(meta["env_steps"])
        self.learning_rate = float(meta["learning_rate"])
        self.recent_ptr = int(meta["recent_ptr"])
        self.episodes = int(meta["episodes"])
