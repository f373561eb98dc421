"""MOPPO (the AMOR paper, Section 4) on PyTorch, CPU. The algorithm reads top to bottom here;
the rollout batch (``batch.py``), data-parallel collectives (``replicas.py``), metrics and episode
bookkeeping (``trainer_metrics.py``), checkpoint state (``trainer_state.py``) and the levers of
docs/moppo.md (``return_scale.py``, ``survival_channel.py``, ``weight_feedback.py``) live beside it.

Per iteration:

1. **Rollout**: T steps of N envs. The actor ``pi(a | s, c, w)`` samples Gaussian actions; the
   critic ``V(s, c, w)`` gives m values per state. Each env's weights ``w`` (Dirichlet(1) per
   episode, the last m observation entries) are recorded per step. Truncated episodes store
   ``V(final_obs)`` to bootstrap from.
2. **Returns**: GAE per objective over ``[T, N, m]`` (:func:`amorctl.core.gae.gae`).
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

Levers (docs/moppo.md, off by default = the paper): ``[ppo] return_norm`` scales each objective's
value error (and optionally its advantage) by running statistics; ``[ppo] survival_channel`` gives
the survival bonus its own critic and advantage channel (``survival_channel.py``); with an adaptive
``[weights]`` sampler the env exposes as ``env.weight_sampler``, each finished episode's
predicted and achieved scalarized returns are fed back to it.

Shapes: T = ``num_steps``, N = envs, D = obs dim, A = action dim, m = objectives, B = T·N.
bf16: network forward/backward run under CPU autocast; weights, the Gaussian log-probabilities,
the ratio and all losses stay float32.
"""

from __future__ import annotations

import contextlib
import time
from typing import Any

import numpy as np
import torch
from torch import nn

from amorctl.core.config import NetworkConfig, PPOConfig
from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.core.gae import gae
from amorctl.core.ppo_math import (
    adapt_learning_rate,
    approx_kl,
    clipped_surrogate,
    gaussian_entropy,
    gaussian_kl,
    gaussian_log_prob,
)
from amorctl.core.torch_norm import RunningNormalizer
from amorctl.core.vecenv import VectorEnv, weight_sampler_of
from amorctl.plugins.backends.episode_window import EpisodeWindow
from amorctl.plugins.backends.torch_cpu.batch import Batch
from amorctl.plugins.backends.torch_cpu.networks import Actor, Critic
from amorctl.plugins.backends.torch_cpu.replicas import Replicas
from amorctl.plugins.backends.torch_cpu.return_scale import ReturnScale
from amorctl.plugins.backends.torch_cpu.survival_channel import (
    channel_values,
    channel_weights,
    objective_values,
    split_rewards,
)
from amorctl.plugins.backends.torch_cpu.trainer_metrics import local_metrics, reduced_metrics
from amorctl.plugins.backends.torch_cpu.trainer_state import load_trainer_state, trainer_state
from amorctl.plugins.backends.torch_cpu.weight_feedback import WeightFeedback

__all__ = ["Batch", "MOPPOTrainer", "Replicas"]

CHECK_EVERY = 10  # data-parallel: compare the ranks' parameters every this many iterations


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
            self.survival_critic = (
                Critic(env.obs_dim, 1, network.critic_hidden) if ppo.survival_channel else None
            )
        self.survival_bonus = float(env.reward_space.survival_bonus)
        if self.survival_critic is not None and not self.survival_bonus > 0:
            raise AmorError(
                "[ppo] survival_channel = true needs objectives that share a survival bonus "
                f"(this env's reward_space.survival_bonus is {self.survival_bonus})"
            )
        #: critic channels: the m objectives, plus the survival bonus with ``survival_channel``
        self.channel_names = self.names + (("survival",) if self.survival_critic is not None else ())
        self.normalizer = RunningNormalizer(env.obs_dim, clip=network.obs_clip)
        self.params = [*self.actor.parameters(), *self._critic_parameters()]
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
        self.window = EpisodeWindow(n, m)  # running episode sums, the last finished episodes
        # the levers (docs/moppo.md, Levers): per-objective return scaling, adaptive weight sampling
        norm = ppo.return_norm
        channels = len(self.channel_names)
        advantage = norm == "value+advantage"
        self.return_scale = None if norm == "off" else ReturnScale(channels, advantage=advantage)
        sampler = weight_sampler_of(env)
        adaptive = sampler is not None and bool(sampler.adaptive)
        self.feedback = WeightFeedback(sampler, n, ppo.gamma) if adaptive else None

    def reset_env(self, seed: int) -> None:
        """Restart every env episode with ``seed``; running episode sums start from zero."""
        obs, _ = self.env.reset(seed=seed)
        self.obs = torch.tensor(obs, dtype=torch.float32)
        n = self.env.num_envs  # sized anew: a resume may change N per rank
        self.window.restart(n)
        if self.feedback is not None:
            self.feedback.reset(n)
        if self.replicas is not None:  # another world size restarts: one fresh noise stream per rank
            self.generator.manual_seed(seed)

    @torch.no_grad()
    def _update_normalizer(self, obs: torch.Tensor) -> None:
        """Fold observations [B, D] into the normalizer: this rank's, or all ranks' moments."""
        if self.replicas is None:
            self.normalizer.update(obs)
        else:
            self.replicas.fold_normalizer(self.normalizer, obs)

    # ------------------------------------------------------------------ networks
    def _autocast(self) -> contextlib.AbstractContextManager[Any]:
        if self.bf16:
            return torch.autocast("cpu", dtype=torch.bfloat16)
        return contextlib.nullcontext()

    def _critic_parameters(self) -> list[nn.Parameter]:
        """The critic's parameters, and the survival critic's with ``survival_channel``."""
        extra = [] if self.survival_critic is None else list(self.survival_critic.parameters())
        return [*self.critic.parameters(), *extra]

    def _forward(self, obs: torch.Tensor, critic: bool = True) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Raw obs [B, D] -> (action mean [B, A], channel values [B, C] or None), float32 outputs.

        C = m, or m + 1 with ``survival_channel`` (see :func:`survival_channel.channel_values`)."""
        x = self.normalizer(obs)
        with self._autocast():
            mean = self.actor(x)
            values = self.critic(x) if critic else None
            survival = self.survival_critic(x) if critic and self.survival_critic is not None else None
        if values is not None:
            values = values.float()
            if survival is not None:  # V - S in float32
                values = channel_values(values, survival.float())
        return mean.float(), values

    def objective_view(self, channels: torch.Tensor) -> torch.Tensor:
        """Channel quantities [..., C] -> per-objective ones [..., m] (values, returns)."""
        return channels if self.survival_critic is None else objective_values(channels)

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
        return self.objective_view(v).numpy()

    # ------------------------------------------------------------------ 1. rollout
    @torch.no_grad()
    def collect_rollout(self) -> tuple[Batch, dict[str, float]]:
        """Step the envs ``num_steps`` times with the current policy; returns the batch (advantages
        not yet filled in) and the time spent in the env and in the policy's forward passes."""
        T, N, m = self.cfg.num_steps, self.env.num_envs, self.num_objectives
        D, A, C = self.env.obs_dim, self.env.action_dim, len(self.channel_names)
        obs_buf = torch.zeros(T, N, D)
        act_buf = torch.zeros(T, N, A)
        mean_buf = torch.zeros(T, N, A)
        logp_buf = torch.zeros(T, N)
        val_buf = torch.zeros(T, N, C)
        next_val_buf = torch.zeros(T, N, C)
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
            logp_buf[t] = gaussian_log_prob(action, mean, self.actor.log_std, xp=torch)
            rew_buf[t] = torch.as_tensor(rewards, dtype=torch.float32)
            term_buf[t] = torch.as_tensor(terminated, dtype=torch.bool)
            trunc_buf[t] = torch.as_tensor(truncated, dtype=torch.bool) & ~term_buf[t]
            if trunc_buf[t].any():  # bootstrap time-limited episodes from V(final_obs)
                final = torch.as_tensor(info["final_obs"], dtype=torch.float32)[trunc_buf[t]]
                _, final_values = self._forward(final)
                next_val_buf[t][trunc_buf[t]] = final_values
            self.window.record(rew_buf[t].numpy(), weights.numpy(), term_buf[t].numpy(), trunc_buf[t].numpy())
            if self.feedback is not None:
                self.feedback.step(
                    weights,
                    self.objective_view(value),
                    rew_buf[t],
                    term_buf[t],
                    trunc_buf[t],
                    self.objective_view(next_val_buf[t]),
                )
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
            values=val_buf.reshape(T * N, C),
            weights=w_buf.reshape(T * N, m),
            rewards=rew_buf,
            next_values=next_val_buf,
            terminated=term_buf,
            truncated=trunc_buf,
            old_log_std=self.actor.log_std.detach().clone(),
        )
        return batch, {"env": t_env, "policy": t_policy}

    # ------------------------------------------------------------------ 2. returns
    def compute_returns(self, batch: Batch) -> None:
        """GAE per channel over [T, N, C]; fills ``batch.advantages`` and ``batch.returns`` [B, C]
        (C = m, or m + 1 with ``survival_channel``: the objectives without the bonus, the bonus)."""
        rewards = batch.rewards
        if self.survival_critic is not None:
            rewards = split_rewards(rewards, batch.terminated, self.survival_bonus)
        T, N, C = rewards.shape
        advantages, returns = gae(
            rewards,
            batch.values.reshape(T, N, C),
            batch.next_values,
            batch.terminated,
            batch.truncated,
            self.cfg.gamma,
            self.cfg.gae_lambda,
            xp=torch,
        )
        batch.advantages, batch.returns = advantages.reshape(T * N, C), returns.reshape(T * N, C)
        if self.return_scale is not None:
            self._update_return_scale(batch.returns, batch.advantages)

    @torch.no_grad()
    def _update_return_scale(self, returns: torch.Tensor, advantages: torch.Tensor) -> None:
        """Fold the rollout's targets and advantages [B, C] into the return scale (data-parallel:
        the moments of all ranks' samples, so every rank scales alike)."""
        assert self.return_scale is not None
        if self.replicas is None:
            self.return_scale.update(returns, advantages)
        else:
            self.return_scale.update_moments(*self.replicas.return_moments(returns, advantages))

    # ------------------------------------------------------------------ 3. update
    def minibatch_loss(self, batch: Batch, idx: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The MOPPO loss on the samples ``idx`` of ``batch``; returns (loss, detached stats)."""
        mean, values = self._forward(batch.obs[idx])
        assert values is not None
        return self.reward_loss(batch, idx, mean, values)

    def reward_loss(
        self, batch: Batch, idx: torch.Tensor, mean: torch.Tensor, values: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """MOPPO's loss (clipped surrogate, value loss, entropy bonus) on the samples ``idx``, given
        the actor's means [k, A] and the critic's channel values [k, C] of their observations."""
        assert batch.advantages is not None and batch.returns is not None, "call compute_returns first"
        log_std = self.actor.log_std
        log_prob = gaussian_log_prob(batch.actions[idx], mean, log_std, xp=torch)
        log_ratio = log_prob - batch.log_probs[idx]
        ratio = torch.exp(log_ratio)

        adv = self.scalarized_advantage(batch, idx)
        clip = self.cfg.clip_coef
        policy_loss = clipped_surrogate(adv, ratio, clip, xp=torch).mean()

        value_loss = self.value_loss(values, batch, idx)
        entropy = gaussian_entropy(log_std, xp=torch)
        loss = policy_loss + self.cfg.value_coef * value_loss - self.cfg.entropy_coef * entropy

        with torch.no_grad():
            kl = gaussian_kl(batch.means[idx], batch.old_log_std, mean, log_std, xp=torch).mean()
            stats = {
                "loss/total": loss.detach(),
                "loss/policy": policy_loss.detach(),
                "loss/value": value_loss.detach(),
                "loss/entropy": entropy.detach(),
                "kl": kl,
                "approx_kl": approx_kl(ratio, log_ratio).mean(),
                "clip_fraction": ((ratio - 1).abs() > clip).float().mean(),
            }
        return loss, stats

    def value_loss(self, values: torch.Tensor, batch: Batch, idx: torch.Tensor) -> torch.Tensor:
        """Half the mean squared error of the critic's values [k, C] against the returns of the
        samples ``idx``, over all C channels (in units of each channel's return std when scaled),
        clipped around the rollout's values as PPO does with ``clip_value_loss``."""
        assert batch.returns is not None, "call compute_returns first"
        returns, old_values = batch.returns[idx], batch.values[idx]
        clip, scale = self.cfg.clip_coef, self.return_scale
        if scale is None:  # the paper's loss, in the objectives' own units
            value_err = (values - returns) ** 2
            if self.cfg.clip_value_loss:
                clipped = old_values + torch.clamp(values - old_values, -clip, clip)
                value_err = torch.max(value_err, (clipped - returns) ** 2)
        else:
            sigma = scale.return_std()  # [m]
            value_err = ((values - returns) / sigma) ** 2
            if self.cfg.clip_value_loss:
                clipped = old_values + torch.clamp(values - old_values, -clip * sigma, clip * sigma)
                value_err = torch.max(value_err, ((clipped - returns) / sigma) ** 2)
        return 0.5 * value_err.mean()

    def scalarized_advantage(self, batch: Batch, idx: torch.Tensor) -> torch.Tensor:
        """The policy's advantage [k] of the samples ``idx``: each sample's vector advantage
        scalarized with its own weights (``A·w``, or ``(A / s)·w`` with ``return_norm =
        "value+advantage"``; the survival channel has weight ``survival_weight``), then normalized
        with the minibatch's (all ranks') mean and std."""
        assert batch.advantages is not None, "call compute_returns first"
        vector_adv = batch.advantages[idx]
        if self.return_scale is not None and self.return_scale.advantage:
            vector_adv = vector_adv / self.return_scale.advantage_std()
        weights = batch.weights[idx]
        if self.survival_critic is not None:
            weights = channel_weights(weights, self.cfg.survival_weight)
        adv = (vector_adv * weights).sum(-1)
        if self.replicas is None:
            return (adv - adv.mean()) / (adv.std(correction=0) + 1e-8)
        a = adv.detach().double()  # the moments of the union of all ranks' minibatches
        n, total, squares = self.replicas.sum_(
            torch.stack([torch.tensor(float(a.numel()), dtype=torch.float64), a.sum(), (a * a).sum()])
        )
        adv_mean = total / n
        adv_std = torch.sqrt(torch.clamp(squares / n - adv_mean * adv_mean, min=0.0))
        return (adv - adv_mean.float()) / (adv_std.float() + 1e-8)

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
                stats = self.replicas.average_gradients(self.params, stats, len(idx))
            nn.utils.clip_grad_norm_(self.actor.parameters(), self.cfg.max_grad_norm)
            nn.utils.clip_grad_norm_(self._critic_parameters(), self.cfg.max_grad_norm)
            self.optimizer.step()
            if self.cfg.lr_schedule == "adaptive":
                self._adapt_learning_rate(float(stats["kl"]))
            for key, value in stats.items():
                sums[key] = sums.get(key, 0.0) + float(value)
            count += 1
        return {key: value / count for key, value in sums.items()}

    def _adapt_learning_rate(self, kl: float) -> None:
        """rsl_rl's rule: divide by 1.5 above 2·desired_kl, multiply by 1.5 below desired_kl/2."""
        self.learning_rate = float(
            adapt_learning_rate(
                self.learning_rate, kl, self.cfg.desired_kl, lr_min=self.cfg.min_learning_rate
            )
        )
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
            return local_metrics(self, batch, stats, times, elapsed)
        if self.iteration_count % CHECK_EVERY == 0:
            self.replicas.check_identical(self._modules(), self.iteration_count)
        metrics = local_metrics(self, batch, stats, times, time.perf_counter() - start)
        metrics.update(reduced_metrics(self, batch))
        elapsed = time.perf_counter() - start
        metrics["time/iteration_s"] = elapsed
        metrics["env_steps_per_s"] = batch.obs.shape[0] * self.world_size / max(elapsed, 1e-9)
        metrics["time/comm_frac"] = (self.replicas.seconds - comm_before) / elapsed
        return metrics

    def _modules(self) -> dict[str, nn.Module]:
        """The networks and the normalizer by checkpoint prefix."""
        modules: dict[str, nn.Module] = {
            "actor": self.actor,
            "critic": self.critic,
            "normalizer": self.normalizer,
        }
        if self.survival_critic is not None:  # training state only: inference reads actor and critic
            modules["survival_critic"] = self.survival_critic
        return modules

    def state_dict(self) -> Snapshot:
        """Weights, normalizer, Adam state, RNG, current observations and episode statistics
        (this rank's; the training loop merges the ranks' snapshots into one checkpoint)."""
        return trainer_state(self)

    def load_state_dict(self, state: Snapshot) -> None:
        """Restore :meth:`state_dict`. Raises AmorError on a checkpoint of another shape or objective set."""
        load_trainer_state(self, state)
