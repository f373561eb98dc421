"""The HLP trainer: PPO on the HLP's reward, driving a frozen AMOR policy through its weights.

Every control step: the HLP observes s_t, c_t (the AMOR observation without its weights), samples
logits u ~ N(mu, sigma) and w_t = softmax(u) (every ``decision_interval`` steps; held between);
``FixedWeights.set_weights(w_t)`` puts w_t where training put w (the observation's last m entries)
and the frozen policy acts on that observation deterministically; the reward source scores the
transition. After ``num_steps`` decisions per env the reward source learns (the discriminator's k
steps) and PPO updates the HLP. ``state_dict`` holds everything (networks, normalizer, optimizer,
generators, current observation, window history, replay buffer), so a resumed run is bit-exact.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from amorctl.core.contracts import Policy, Snapshot
from amorctl.core.errors import AmorError
from amorctl.core.gae import gae
from amorctl.core.ppo_math import gaussian_entropy, gaussian_kl, gaussian_log_prob
from amorctl.hlp.config import HlpConfig
from amorctl.hlp.policy import HlpActorCritic
from amorctl.hlp.ppo import ppo_loss
from amorctl.hlp.rewards import RewardSource
from amorctl.hlp.state import (
    generator_array,
    load_generator,
    load_module,
    load_optimizer,
    module_arrays,
    optimizer_arrays,
)


def weight_entropy(w: np.ndarray) -> np.ndarray:
    """-sum w log w [N] of weights [N, m] (0 log 0 = 0): log m for uniform, 0 for a corner."""
    w = np.asarray(w, dtype=np.float64)
    return -(w * np.log(np.where(w > 0, w, 1.0))).sum(-1)


class HlpTrainer:
    """PPO for pi_H on top of a frozen low-level policy.

    Args:
        env: a ``FixedWeights``-wrapped env of the AMOR run (its ``set_weights`` takes [N, m]).
        llp: the frozen AMOR :class:`~amorctl.core.contracts.Policy` (only called, never updated).
        config: the HLP config.
        reward: the reward source.
    """

    def __init__(self, env: Any, llp: Policy, config: HlpConfig, reward: RewardSource) -> None:
        self.env, self.llp, self.config, self.reward = env, llp, config, reward
        self.names = tuple(env.reward_space.names)
        self.m = m = len(self.names)
        if llp.obs_dim != env.obs_dim:
            raise AmorError(
                f"the frozen policy takes {llp.obs_dim} observation entries, the env gives {env.obs_dim}"
            )
        p, seed = config.policy, config.run.seed
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            self.model = HlpActorCritic(
                env.obs_dim - m, m, p.actor_hidden, p.critic_hidden, p.init_std, p.obs_clip
            )
        self.opt = torch.optim.Adam(self.model.parameters(), lr=config.ppo.learning_rate)
        self.gen = torch.Generator().manual_seed(seed)
        self.rng = np.random.default_rng(seed + 1)
        self.iteration_count = 0
        self.env_steps = 0
        n = env.num_envs
        obs, _ = env.reset(seed=seed)
        self.obs = np.asarray(obs, dtype=np.float32)
        self.reward.start(self.obs)
        self.ep_return = np.zeros(n)
        self.ep_length = np.zeros(n, dtype=np.int64)
        self.done_returns: list[float] = []
        self.done_lengths: list[float] = []

    # --- acting ----------------------------------------------------------------------------------
    def llp_step(
        self, w: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """One control step of the frozen policy under weights w [N, m]."""
        self.env.set_weights(w)
        obs = self.obs.copy()
        obs[:, -self.m :] = w  # what set_weights puts into every following observation
        actions = self.llp(obs)
        return self.env.step(actions)

    def iteration(self) -> dict[str, float]:
        """One rollout of ``num_steps`` decisions per env, k D steps, one PPO update; metrics."""
        cfg, model = self.config, self.model
        t_len, n, m, k = cfg.ppo.num_steps, self.env.num_envs, self.m, cfg.env.decision_interval
        gamma = cfg.ppo.gamma
        began = time.perf_counter()
        hobs = np.zeros((t_len, n, model.obs_dim), dtype=np.float32)
        logits = np.zeros((t_len, n, m), dtype=np.float32)
        logp = np.zeros((t_len, n), dtype=np.float32)
        values = np.zeros((t_len, n), dtype=np.float32)
        next_values = np.zeros((t_len, n), dtype=np.float32)
        rewards = np.zeros((t_len, n), dtype=np.float64)
        terminated = np.zeros((t_len, n), dtype=np.float32)
        ended = np.zeros((t_len, n), dtype=np.float32)
        ws = np.zeros((t_len, n, m), dtype=np.float32)
        step_rewards: list[np.ndarray] = []
        for t in range(t_len):
            h = self.obs[:, :-m]
            with torch.no_grad():
                hobs[t] = model.normalizer(torch.as_tensor(h)).numpy()
            w, u, lp, v = model.act(h, self.gen)
            model.normalizer.update(torch.as_tensor(h))
            logits[t], logp[t], values[t], ws[t] = u, lp, v, w
            open_ = np.ones(n, dtype=bool)  # envs whose decision block has not ended an episode
            final = self.obs
            discount = 1.0  # rewards of a block are discounted within it; gamma^k between decisions
            for _ in range(k):
                obs, r_vec, term, trunc, info = self.llp_step(w)
                done = term | trunc
                final_obs = np.asarray(info["final_obs"], dtype=np.float32)
                r = self.reward.step(obs, r_vec, final_obs, done)
                step_rewards.append(r)
                rewards[t] += np.where(open_, discount * r, 0.0)
                self.ep_return += r
                self.ep_length += 1
                for i in np.flatnonzero(done):
                    self.done_returns.append(float(self.ep_return[i]))
                    self.done_lengths.append(float(self.ep_length[i]))
                self.ep_return[done], self.ep_length[done] = 0.0, 0
                newly = open_ & done
                terminated[t][newly] = term[newly]
                ended[t][newly] = 1.0
                final = np.where(open_[:, None], final_obs, final)  # an ended block keeps its end
                open_ &= ~done
                discount *= gamma
                self.obs = np.asarray(obs, dtype=np.float32)
                self.env_steps += n
            with torch.no_grad():
                next_values[t] = model.value(model.normalizer(torch.as_tensor(final[:, :-m]))).numpy()
        gamma_k = gamma**k
        term, stop = terminated > 0, ended > 0
        adv, ret = gae(rewards, values, next_values, term, stop & ~term, gamma_k, cfg.ppo.gae_lambda)
        adv, ret = adv.astype(np.float32), ret.astype(np.float32)
        collect_s = time.perf_counter() - began
        metrics = self.reward.update(self.rng)
        metrics.update(self._update(hobs, logits, logp, adv, ret, values))
        self.iteration_count += 1
        r_all = np.concatenate(step_rewards)
        w_flat = ws.reshape(-1, m)
        metrics.update(
            {
                "iteration": float(self.iteration_count),
                "env_steps": float(self.env_steps),
                "env_steps_per_s": t_len * k * n / max(collect_s, 1e-9),
                "reward/mean": float(r_all.mean()),
                "episode/return": float(np.mean(self.done_returns)) if self.done_returns else float("nan"),
                "episode/length": float(np.mean(self.done_lengths)) if self.done_lengths else float("nan"),
                "episodes": float(len(self.done_returns)),
                "w/entropy": float(weight_entropy(w_flat).mean()),
                **{f"w/{name}": float(w_flat[:, i].mean()) for i, name in enumerate(self.names)},
            }
        )
        self.done_returns, self.done_lengths = [], []
        return metrics

    def _update(
        self,
        hobs: np.ndarray,
        logits: np.ndarray,
        logp: np.ndarray,
        adv: np.ndarray,
        ret: np.ndarray,
        values: np.ndarray,
    ) -> dict[str, float]:
        cfg = self.config.ppo
        x = torch.as_tensor(hobs.reshape(-1, hobs.shape[-1]))
        u = torch.as_tensor(logits.reshape(-1, logits.shape[-1]))
        old = torch.as_tensor(logp.reshape(-1))
        a = torch.as_tensor(adv.reshape(-1))
        r = torch.as_tensor(ret.reshape(-1))
        total = x.shape[0]
        size = total // cfg.num_minibatches
        with torch.no_grad():  # the rollout's policy (the same parameters and normalized inputs)
            old_mean, old_log_std = self.model.mean(x), self.model.log_std.detach().clone()
        sums: dict[str, float] = {}
        count = 0
        for _ in range(cfg.num_epochs):
            perm = torch.randperm(total, generator=self.gen)
            for b in range(cfg.num_minibatches):
                idx = perm[b * size : (b + 1) * size]
                mu, log_std = self.model.mean(x[idx]), self.model.log_std
                loss, stats = ppo_loss(
                    gaussian_log_prob(u[idx], mu, log_std, xp=torch),
                    old[idx],
                    a[idx],
                    self.model.value(x[idx]),
                    r[idx],
                    gaussian_entropy(log_std, xp=torch),
                    cfg.clip_coef,
                    cfg.value_coef,
                    cfg.entropy_coef,
                )
                with torch.no_grad():  # as MOPPO's: the minibatch's policy against the rollout's
                    kl = gaussian_kl(old_mean[idx], old_log_std, mu, log_std, xp=torch)
                stats["kl"] = float(kl.mean())
                self.opt.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(self.model.parameters(), cfg.max_grad_norm)
                self.opt.step()
                stats["total"] = loss.item()
                for key, v in stats.items():
                    sums[key] = sums.get(key, 0.0) + v
                count += 1
        out = {
            f"loss/{k}": v / count for k, v in sums.items() if k in ("policy", "value", "entropy", "total")
        }
        out["kl"] = sums["kl"] / count  # analytic, as MOPPO's
        out["approx_kl"] = sums["approx_kl"] / count
        out["clip_fraction"] = sums["clip_fraction"] / count
        out["logit_std"] = self.model.log_std.exp().mean().item()
        var = float(np.var(ret))
        out["explained_variance"] = float(1 - np.var(ret - values) / var) if var > 0 else float("nan")
        return out

    # --- state -----------------------------------------------------------------------------------
    def state_dict(self) -> Snapshot:
        """Networks, normalizer, optimizer, generators, observation, episode counters, reward state."""
        arrays = module_arrays("hlp", self.model)
        opt_arrays, opt_meta = optimizer_arrays("hlp_opt", self.opt)
        arrays.update(opt_arrays)
        arrays["torch_generator"] = generator_array(self.gen)
        arrays["obs"] = self.obs.copy()
        arrays["ep_return"] = self.ep_return.copy()
        arrays["ep_length"] = self.ep_length.copy()
        rs = self.reward.state()
        arrays.update({f"reward/{k}": v for k, v in rs.arrays.items()})
        meta = {
            "iteration": self.iteration_count,
            "env_steps": self.env_steps,
            "hlp_opt": opt_meta,
            "rng": self.rng.bit_generator.state,
            "reward": rs.meta,
            "objectives": list(self.names),
            "obs_dim": int(self.env.obs_dim),
        }
        return Snapshot(arrays, meta)

    def load_state_dict(self, state: Snapshot) -> None:
        """Restore :meth:`state_dict`; AmorError when it does not fit."""
        a, meta = state.arrays, state.meta
        if list(meta.get("objectives", [])) != list(self.names) or meta.get("obs_dim") != self.env.obs_dim:
            raise AmorError(
                f"HLP checkpoint is for objectives {meta.get('objectives')} / obs {meta.get('obs_dim')}, "
                f"this run has {list(self.names)} / {self.env.obs_dim}"
            )
        load_module("hlp", self.model, a)
        load_optimizer("hlp_opt", self.opt, a, meta["hlp_opt"])
        load_generator(self.gen, a["torch_generator"])
        self.rng = np.random.default_rng()
        self.rng.bit_generator.state = meta["rng"]
        self.obs = np.asarray(a["obs"], dtype=np.float32).copy()
        self.ep_return = np.asarray(a["ep_return"]).copy()
        self.ep_length = np.asarray(a["ep_length"]).copy()
        self.reward.load(
            Snapshot({k[7:]: v for k, v in a.items() if k.startswith("reward/")}, meta["reward"])
        )
        self.iteration_count = int(meta["iteration"])
        self.env_steps = int(meta["env_steps"])
