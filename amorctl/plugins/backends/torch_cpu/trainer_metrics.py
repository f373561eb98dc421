"""The per-iteration metrics of :class:`~amorctl.plugins.backends.torch_cpu.moppo.MOPPOTrainer`
(names in docs/moppo.md) and the episode bookkeeping they read; ``trainer`` is the trainer whose
rollout ``batch`` they describe."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from amorctl.plugins.backends.torch_cpu.batch import Batch


@torch.no_grad()
def record_episodes(
    trainer: Any,
    rewards: torch.Tensor,
    weights: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
) -> None:
    """Accumulate one step's undiscounted per-objective returns [N, m] (and ``r·w``) into the
    trainer's running episode sums; move the episodes that ended into its recent-episode window."""
    trainer.ep_return += rewards.double()
    trainer.ep_scalar += (rewards * weights).sum(-1).double()
    trainer.ep_length += 1
    ended = terminated | truncated
    k = int(ended.sum())
    if k == 0:
        return
    window = trainer.recent_length.shape[0]
    slots = (trainer.recent_ptr + torch.arange(k)) % window
    trainer.recent_return[slots] = trainer.ep_return[ended]
    trainer.recent_scalar[slots] = trainer.ep_scalar[ended]
    trainer.recent_length[slots] = trainer.ep_length[ended].double()
    trainer.recent_survived[slots] = (~terminated[ended]).double()
    trainer.recent_ptr = int((trainer.recent_ptr + k) % window)
    trainer.episodes += k
    trainer.ep_return[ended] = 0.0
    trainer.ep_scalar[ended] = 0.0
    trainer.ep_length[ended] = 0


def local_metrics(
    trainer: Any, batch: Batch, stats: dict[str, float], times: dict[str, float], elapsed: float
) -> dict[str, float]:
    """This rank's metrics of one iteration (docs/moppo.md): timing, the update's statistics,
    per-objective returns, rewards and critic explained variance, episode length and survival."""
    metrics: dict[str, float] = {
        "iteration": float(trainer.iteration_count),
        "env_steps": float(trainer.env_steps),
    }
    metrics["env_steps_per_s"] = batch.obs.shape[0] / max(elapsed, 1e-9)
    metrics["time/iteration_s"] = elapsed
    metrics["time/env_frac"] = times["env"] / elapsed
    metrics["time/network_frac"] = (times["policy"] + times["update"]) / elapsed
    metrics["time/glue_frac"] = max(0.0, 1.0 - metrics["time/env_frac"] - metrics["time/network_frac"])
    metrics.update(stats)
    metrics["learning_rate"] = trainer.learning_rate
    metrics["action_std"] = float(torch.exp(trainer.actor.log_std.detach()).mean())
    assert batch.returns is not None
    filled = ~torch.isnan(trainer.recent_length)
    has = bool(filled.any())
    mean_reward = batch.rewards.mean(dim=(0, 1))
    returns, values = trainer.objective_view(batch.returns), trainer.objective_view(batch.values)
    for i, name in enumerate(trainer.names):
        metrics[f"return/{name}"] = float(trainer.recent_return[filled, i].mean()) if has else float("nan")
        metrics[f"reward/{name}"] = float(mean_reward[i])
        metrics[f"explained_variance/{name}"] = _explained_variance(returns[:, i], values[:, i])
    if len(trainer.channel_names) > len(trainer.names):  # survival_channel: the bonus's own critic
        survival = _explained_variance(batch.returns[:, -1], batch.values[:, -1])
        metrics["explained_variance/survival"] = survival
    metrics["return/scalarized"] = float(trainer.recent_scalar[filled].mean()) if has else float("nan")
    metrics["episode/length"] = float(trainer.recent_length[filled].mean()) if has else float("nan")
    metrics["episode/survival"] = float(trainer.recent_survived[filled].mean()) if has else float("nan")
    metrics["episodes"] = float(trainer.episodes)
    metrics.update(lever_metrics(trainer))
    return metrics


def _explained_variance(returns: torch.Tensor, values: torch.Tensor) -> float:
    """1 - Var(R - V) / Var(R) over a batch [B] (NaN when the returns are constant)."""
    var = returns.var()
    return float(1 - (returns - values).var() / var) if var > 0 else float("nan")


def lever_metrics(trainer: Any) -> dict[str, float]:
    """The levers' diagnostics (docs/moppo.md, Levers): the running per-objective return and
    advantage stds of ``return_norm``; the adaptive sampler's anchor-probability entropy
    (1 = uniform over the anchors) and its largest anchor probability and lag."""
    out: dict[str, float] = {}
    scale = trainer.return_scale
    if scale is not None:
        stds = zip(trainer.channel_names, scale.return_std(), scale.advantage_std(), strict=True)
        for name, ret_std, adv_std in stds:
            out[f"return_scale/return_std/{name}"] = float(ret_std)
            out[f"return_scale/advantage_std/{name}"] = float(adv_std)
    if trainer.feedback is not None:
        sampler = trainer.feedback.sampler
        p = sampler.anchor_probabilities()
        out["weights/anchor_entropy"] = float(-(p * np.log(p)).sum() / np.log(len(p))) if len(p) > 1 else 1.0
        out["weights/anchor_p_max"] = float(p.max())
        out["weights/lag_max"] = float(sampler.lag.max())
    return out


# ------------------------------------------------------------------ checkpoints


@torch.no_grad()
def reduced_metrics(trainer: Any, batch: Batch) -> dict[str, float]:
    """Data-parallel: episode statistics, mean rewards and explained variances over all ranks
    (one all-reduce); each rank's window holds its own last ``EPISODE_WINDOW`` episodes."""
    assert trainer.replicas is not None and batch.returns is not None
    m = trainer.num_objectives
    filled = ~torch.isnan(trainer.recent_length)
    ret = trainer.objective_view(batch.returns).double()
    res = ret - trainer.objective_view(batch.values).double()
    parts = [
        torch.tensor([float(filled.sum()), trainer.episodes, ret.shape[0]], dtype=torch.float64),
        trainer.recent_return[filled].sum(0),  # [m]
        torch.stack([trainer.recent_scalar[filled].sum(), trainer.recent_length[filled].sum()]),
        trainer.recent_survived[filled].sum().reshape(1),
        batch.rewards.double().sum(dim=(0, 1)),  # [m]
        ret.sum(0),
        (ret * ret).sum(0),
        res.sum(0),
        (res * res).sum(0),
    ]
    total = trainer.replicas.sum_(torch.cat(parts))
    k, episodes, b = (float(v) for v in total[:3])
    ep_ret, (ep_scalar, ep_len), ep_surv = total[3 : 3 + m], total[3 + m : 5 + m], float(total[5 + m])
    rew, r1, r2, e1, e2 = total[6 + m :].reshape(5, m)
    nan = float("nan")
    out: dict[str, float] = {"episodes": episodes}
    for i, name in enumerate(trainer.names):
        out[f"return/{name}"] = float(ep_ret[i]) / k if k else nan
        out[f"reward/{name}"] = float(rew[i]) / b
        var_ret = float(r2[i]) / b - (float(r1[i]) / b) ** 2
        var_res = float(e2[i]) / b - (float(e1[i]) / b) ** 2
        out[f"explained_variance/{name}"] = 1 - var_res / var_ret if var_ret > 0 else nan
    out["return/scalarized"] = float(ep_scalar) / k if k else nan
    out["episode/length"] = float(ep_len) / k if k else nan
    out["episode/survival"] = ep_surv / k if k else nan
    return out
