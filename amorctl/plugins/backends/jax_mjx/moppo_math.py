"""MOPPO's math as pure JAX functions over a training-state pytree (torch-cpu's ``moppo.py``, jitted).

- :func:`gae` — GAE per objective, ``lax.scan`` backwards over T.
- :func:`minibatch_loss` — ``A·w`` scalarization, minibatch normalization, clipped surrogate,
  (clipped) vector value loss over all m outputs, entropy bonus, the analytic KL for the
  adaptive learning rate; minibatches may be padded (``mask``) so unequal splits
  (torch's ``tensor_split``) keep static shapes.
- :func:`update` — ``num_epochs`` × ``num_minibatches`` Adam steps as one ``lax.scan``: actor and
  critic gradient norms clipped separately, then optax Adam with the learning rate adapted by
  rsl_rl's KL rule after every step (as torch-cpu does).

Shapes: T steps, N envs, B = T·N samples, D obs, A actions, m objectives, k minibatches,
M = ceil(B / k) padded minibatch size.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from amorctl.core.ppo_math import (
    adapt_learning_rate,
    approx_kl,
    clipped_surrogate,
    gaussian_entropy,
    gaussian_kl,
    gaussian_log_prob,
)
from amorctl.plugins.backends.jax_mjx.networks import Networks, Params, normalize


@dataclass(frozen=True)
class LossConfig:
    """The PPO settings the jitted math reads (hashable: a static argument)."""

    gamma: float
    gae_lambda: float
    clip_coef: float
    clip_value_loss: bool
    value_coef: float
    entropy_coef: float
    max_grad_norm: float
    desired_kl: float
    min_learning_rate: float
    adaptive_lr: bool
    num_epochs: int
    num_minibatches: int
    obs_clip: float
    return_norm: str = "off"

    @classmethod
    def from_config(cls, ppo: Any, obs_clip: float) -> LossConfig:
        return cls(
            gamma=ppo.gamma,
            gae_lambda=ppo.gae_lambda,
            clip_coef=ppo.clip_coef,
            clip_value_loss=ppo.clip_value_loss,
            value_coef=ppo.value_coef,
            entropy_coef=ppo.entropy_coef,
            max_grad_norm=ppo.max_grad_norm,
            desired_kl=ppo.desired_kl,
            min_learning_rate=ppo.min_learning_rate,
            adaptive_lr=ppo.lr_schedule == "adaptive",
            num_epochs=ppo.num_epochs,
            num_minibatches=ppo.num_minibatches,
            obs_clip=obs_clip,
            return_norm=ppo.return_norm,
        )


class Batch(NamedTuple):
    """One rollout flattened to B samples (rewards etc. keep [T, N, ...])."""

    obs: jax.Array  # [B, D] raw
    actions: jax.Array  # [B, A]
    log_probs: jax.Array  # [B]
    means: jax.Array  # [B, A]
    values: jax.Array  # [B, m]
    weights: jax.Array  # [B, m]
    rewards: jax.Array  # [T, N, m]
    next_values: jax.Array  # [T, N, m]
    terminated: jax.Array  # [T, N] bool
    truncated: jax.Array  # [T, N] bool
    old_log_std: jax.Array  # [A]


class TrainState(NamedTuple):
    """Everything the update changes: parameters and the optax Adam state (with the learning rate)."""

    params: Params
    opt_state: Any


def make_optimizer(learning_rate: float) -> optax.GradientTransformation:
    """Adam (torch's defaults: betas 0.9/0.999, eps 1e-8) with an injectable learning rate."""
    return optax.inject_hyperparams(optax.adam)(learning_rate=learning_rate, b1=0.9, b2=0.999, eps=1e-8)


def learning_rate(opt_state: Any) -> jax.Array:
    return opt_state.hyperparams["learning_rate"]


def with_learning_rate(opt_state: Any, lr: Any) -> Any:
    hyper = dict(opt_state.hyperparams)
    hyper["learning_rate"] = jnp.asarray(lr, jnp.float32)
    return opt_state._replace(hyperparams=hyper)


# ---------------------------------------------------------------------------- math
def gae(
    rewards: jax.Array,
    values: jax.Array,
    next_values: jax.Array,
    terminated: jax.Array,
    truncated: jax.Array,
    gamma: float,
    lam: float,
) -> tuple[jax.Array, jax.Array]:
    """Advantages and returns [T, N, m] (torch-cpu's ``gae.gae``, see there for the arguments)."""
    extra = (1,) * (rewards.ndim - 2)
    not_terminal = (~terminated).astype(rewards.dtype).reshape(*terminated.shape, *extra)
    goes_on = (~(terminated | truncated)).astype(rewards.dtype).reshape(*terminated.shape, *extra)
    deltas = rewards + gamma * not_terminal * next_values - values

    def back(running: jax.Array, xs: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        delta, cont = xs
        running = delta + gamma * lam * cont * running
        return running, running

    _, advantages = jax.lax.scan(back, jnp.zeros_like(rewards[0]), (deltas, goes_on), reverse=True)
    return advantages, advantages + values


def minibatch_loss(
    params: Params,
    nets: Networks,
    norm: tuple[jax.Array, jax.Array],
    mb: dict[str, jax.Array],
    cfg: LossConfig,
    stds: tuple[jax.Array, jax.Array] | None = None,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """The MOPPO loss on one (possibly padded) minibatch; returns (loss, stats).

    ``mb`` holds ``obs`` [M, D], ``actions``, ``means`` [M, A], ``log_probs`` [M], ``values``,
    ``weights``, ``advantages``, ``returns`` [M, m], ``old_log_std`` [A] and ``mask`` [M] (1 for
    real samples). All means and the advantage normalization run over the real samples only.
    ``stds``: the running return and advantage stds [m] of ``return_norm``
    (:mod:`amorctl.core.return_scale`); None for the paper's loss.
    """
    mask = mb["mask"]
    count = jnp.sum(mask)

    def avg(x: jax.Array) -> jax.Array:
        return jnp.sum(x * mask) / count

    x = normalize(mb["obs"], norm, cfg.obs_clip)
    mean = nets.mean(params, x)
    values = nets.values(params, x)
    log_std = params["actor"]["log_std"]
    log_prob = gaussian_log_prob(mb["actions"], mean, log_std, xp=jnp)
    log_ratio = log_prob - mb["log_probs"]
    ratio = jnp.exp(log_ratio)

    vector_adv = mb["advantages"]
    if stds is not None and cfg.return_norm == "value+advantage":
        vector_adv = vector_adv / stds[1]
    adv = jnp.sum(vector_adv * mb["weights"], axis=-1)
    adv_mean = avg(adv)
    adv_std = jnp.sqrt(avg((adv - adv_mean) ** 2))
    adv = (adv - adv_mean) / (adv_std + 1e-8)
    clip = cfg.clip_coef
    policy_loss = avg(clipped_surrogate(adv, ratio, clip, xp=jnp))

    returns, old_values = mb["returns"], mb["values"]
    sigma = 1.0 if stds is None else stds[0]  # errors in units of each objective's return std
    value_err = ((values - returns) / sigma) ** 2
    if cfg.clip_value_loss:
        clipped = old_values + jnp.clip(values - old_values, -clip * sigma, clip * sigma)
        value_err = jnp.maximum(value_err, ((clipped - returns) / sigma) ** 2)
    value_loss = 0.5 * avg(jnp.mean(value_err, axis=-1))

    entropy = gaussian_entropy(log_std, xp=jnp)
    loss = policy_loss + cfg.value_coef * value_loss - cfg.entropy_coef * entropy

    sg = jax.lax.stop_gradient
    kl_each = gaussian_kl(mb["means"], mb["old_log_std"], sg(mean), sg(log_std), xp=jnp)
    ratio_, log_ratio_ = sg(ratio), sg(log_ratio)
    stats = {
        "loss/total": sg(loss),
        "loss/policy": sg(policy_loss),
        "loss/value": sg(value_loss),
        "loss/entropy": sg(entropy),
        "kl": avg(kl_each),
        "approx_kl": avg(approx_kl(ratio_, log_ratio_)),
        "clip_fraction": avg((jnp.abs(ratio_ - 1) > clip).astype(jnp.float32)),
    }
    return loss, stats


def clip_by_norm(tree: Any, max_norm: float) -> Any:
    """torch's ``clip_grad_norm_``: scale by ``min(1, max_norm / (||tree|| + 1e-6))``."""
    leaves = jax.tree_util.tree_leaves(tree)
    norm = jnp.sqrt(sum(jnp.sum(g * g) for g in leaves))
    scale = jnp.minimum(1.0, max_norm / (norm + 1e-6))
    return jax.tree_util.tree_map(lambda g: g * scale, tree)


def clipped_grads(
    params: Params,
    nets: Networks,
    norm: Any,
    mb: dict[str, jax.Array],
    cfg: LossConfig,
    stds: tuple[jax.Array, jax.Array] | None = None,
) -> tuple[Params, dict[str, jax.Array]]:
    """Gradients of :func:`minibatch_loss`, the actor's and the critic's norms clipped separately."""
    grads, stats = jax.grad(minibatch_loss, has_aux=True)(params, nets, norm, mb, cfg, stds)
    grads = {
        "actor": clip_by_norm(grads["actor"], cfg.max_grad_norm),
        "critic": clip_by_norm(grads["critic"], cfg.max_grad_norm),
    }
    return grads, stats


def minibatch_layout(size: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Positions [k, M] into a permutation of ``size`` samples and their mask [k, M], splitting
    as ``torch.tensor_split`` does (the first ``size % k`` minibatches one sample larger)."""
    q, r = divmod(size, k)
    width = q + (1 if r else 0)
    pos = np.zeros((k, width), np.int32)
    mask = np.zeros((k, width), np.float32)
    start = 0
    for i in range(k):
        n = q + (1 if i < r else 0)
        pos[i, :n] = np.arange(start, start + n)
        mask[i, :n] = 1.0
        start += n
    return pos, mask


def update(
    state: TrainState,
    nets: Networks,
    optimizer: optax.GradientTransformation,
    norm: tuple[jax.Array, jax.Array],
    batch: Batch,
    advantages: jax.Array,
    returns: jax.Array,
    perms: jax.Array,
    cfg: LossConfig,
    stds: tuple[jax.Array, jax.Array] | None = None,
) -> tuple[TrainState, dict[str, jax.Array]]:
    """All epochs of minibatch Adam steps as one scan; ``perms`` [num_epochs, B] orders the samples
    (``stds``: :func:`minibatch_loss`'s).

    Returns the new state and every stat averaged over the minibatches (as torch-cpu's ``update``).
    """
    size = batch.obs.shape[0]
    pos, mask = minibatch_layout(size, cfg.num_minibatches)
    samples = {
        "obs": batch.obs,
        "actions": batch.actions,
        "means": batch.means,
        "log_probs": batch.log_probs,
        "values": batch.values,
        "weights": batch.weights,
        "advantages": advantages,
        "returns": returns,
    }
    idx = perms[:, pos].reshape(-1, pos.shape[1])  # [epochs * k, M]
    masks = jnp.tile(jnp.asarray(mask), (cfg.num_epochs, 1))

    def step(st: TrainState, xs: tuple[jax.Array, jax.Array]) -> tuple[TrainState, dict[str, jax.Array]]:
        ids, m = xs
        mb = {key: value[ids] for key, value in samples.items()}
        mb["mask"], mb["old_log_std"] = m, batch.old_log_std
        grads, stats = clipped_grads(st.params, nets, norm, mb, cfg, stds)
        updates, opt_state = optimizer.update(grads, st.opt_state, st.params)
        params = optax.apply_updates(st.params, updates)
        if cfg.adaptive_lr:
            opt_state = with_learning_rate(
                opt_state,
                adapt_learning_rate(
                    learning_rate(opt_state),
                    stats["kl"],
                    cfg.desired_kl,
                    xp=jnp,
                    lr_min=cfg.min_learning_rate,
                ),
            )
        return TrainState(params, opt_state), stats

    state, stats = jax.lax.scan(step, state, (idx, masks))
    return state, {key: jnp.mean(value) for key, value in stats.items()}
