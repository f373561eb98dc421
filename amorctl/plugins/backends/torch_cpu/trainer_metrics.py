"""The per-iteration metrics of :class:`~amorctl.plugins.backends.torch_cpu.moppo.MOPPOTrainer`
(names in docs/moppo.md) and the episode bookkeeping they read; ``trainer`` is the trainer whose
rollout ``batch`` they describe."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from amorctl.plugins.backends.episode_window import window_metrics
from amorctl.plugins.backends.torch_cpu.batch import Batch


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
    metrics["time/update_frac"] = times["update"] / elapsed  # of the network share: the minibatch updates
    metrics["time/glue_frac"] = max(0.0, 1.0 - metrics["time/env_frac"] - metrics["time/network_frac"])
    metrics.update(stats)
    metrics["learning_rate"] = trainer.learning_rate
    metrics["action_std"] = float(torch.exp(trainer.actor.log_std.detach()).mean())
    metrics["bf16"] = float(trainer.bf16)  # the precision the backend chose (1: bf16 autocast)
    assert batch.returns is not None
    mean_reward = batch.rewards.mean(dim=(0, 1))
    returns, values = trainer.objective_view(batch.returns), trainer.objective_view(batch.values)
    metrics.update(trainer.window.metrics(trainer.names))
    for i, name in enumerate(trainer.names):
        metrics[f"reward/{name}"] = float(mean_reward[i])
        metrics[f"explained_variance/{name}"] = _explained_variance(returns[:, i], values[:, i])
    if len(trainer.channel_names) > len(trainer.names):  # survival_channel: the bonus's own critic
        survival = _explained_variance(batch.returns[:, -1], batch.values[:, -1])
        metrics["explained_variance/survival"] = survival
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
    (one all-reduce of named sums); each rank's window holds its own last episodes."""
    assert trainer.replicas is not None and batch.returns is not None
    ret = trainer.objective_view(batch.returns).double()
    res = ret - trainer.objective_view(batch.values).double()
    parts = {f"window.{k}": torch.from_numpy(v) for k, v in trainer.window.sums().items()}
    parts |= {
        "samples": torch.tensor([float(ret.shape[0])], dtype=torch.float64),
        "reward": batch.rewards.double().sum(dim=(0, 1)),  # [m]
        "ret": ret.sum(0),
        "ret_sq": (ret * ret).sum(0),
        "res": res.sum(0),
        "res_sq": (res * res).sum(0),
    }
    total = reduce_named(trainer.replicas.sum_, parts)
    window = {k.removeprefix("window."): v.numpy() for k, v in total.items() if k.startswith("window.")}
    out = window_metrics(window, trainer.names)
    b = float(total["samples"][0])
    for i, name in enumerate(trainer.names):
        out[f"reward/{name}"] = float(total["reward"][i]) / b
        var_ret = float(total["ret_sq"][i]) / b - (float(total["ret"][i]) / b) ** 2
        var_res = float(total["res_sq"][i]) / b - (float(total["res"][i]) / b) ** 2
        out[f"explained_variance/{name}"] = 1 - var_res / var_ret if var_ret > 0 else float("nan")
    return out


def reduce_named(sum_: Any, parts: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """All-reduce named float64 tensors in one call (``sum_`` of their concatenation) and hand
    them back by name, each in its own shape."""
    flat = sum_(torch.cat([p.reshape(-1) for p in parts.values()]))
    out, start = {}, 0
    for name, p in parts.items():
        out[name] = flat[start : start + p.numel()].reshape(p.shape)
        start += p.numel()
    return out
