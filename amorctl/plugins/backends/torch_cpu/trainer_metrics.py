"""The per-iteration metrics of :class:`~amorctl.plugins.backends.torch_cpu.moppo.MOPPOTrainer`
(names in docs/moppo.md); ``trainer`` is the trainer whose rollout ``batch`` they describe."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

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
    metrics["time/glue_frac"] = max(0.0, 1.0 - metrics["time/env_frac"] - metrics["time/network_frac"])
    metrics.update(stats)
    metrics["learning_rate"] = trainer.learning_rate
    metrics["action_std"] = float(torch.exp(trainer.actor.log_std.detach()).mean())
    assert batch.returns is not None
    filled = ~torch.isnan(trainer.recent_length)
    has = bool(filled.any())
    mean_reward = batch.rewards.mean(dim=(0, 1))
    for i, name in enumerate(trainer.names):
        metrics[f"return/{name}"] = float(trainer.recent_return[filled, i].mean()) if has else float("nan")
        metrics[f"reward/{name}"] = float(mean_reward[i])
        ret, val = batch.returns[:, i], batch.values[:, i]
        var = ret.var()
        metrics[f"explained_variance/{name}"] = (
            float(1 - (ret - val).var() / var) if var > 0 else float("nan")
        )
    metrics["return/scalarized"] = float(trainer.recent_scalar[filled].mean()) if has else float("nan")
    metrics["episode/length"] = float(trainer.recent_length[filled].mean()) if has else float("nan")
    metrics["episode/survival"] = float(trainer.recent_survived[filled].mean()) if has else float("nan")
    metrics["episodes"] = float(trainer.episodes)
    metrics.update(lever_metrics(trainer))
    return metrics


def lever_metrics(trainer: Any) -> dict[str, float]:
    """The levers' diagnostics (docs/moppo.md, Levers): the running per-objective return and
    advantage stds of ``return_norm``; the adaptive sampler's anchor-probability entropy
    (1 = uniform over the anchors) and its largest anchor probability and lag."""
    out: dict[str, float] = {}
    scale = trainer.return_scale
    if scale is not None:
        stds = zip(trainer.names, scale.return_std(), scale.advantage_std(), strict=True)
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
    ret, val = batch.returns.double(), batch.values.double()
    res = ret - val
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
