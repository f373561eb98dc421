"""The actor, the vector critic and the observation normalizer in flax, with torch-cpu's names.

The networks are flax ``linen`` ELU MLPs initialised as torch-cpu's (orthogonal, gain sqrt 2 on
hidden layers, 0.01 on the actor head, 1 on the critic head, zero biases). Parameters live in one
pytree ``{"actor": {"net": <flax params>, "log_std": [A]}, "critic": {"net": <flax params>}}``.
:func:`params_to_arrays` / :func:`arrays_to_params` convert it to and from the checkpoint arrays of
torch-cpu (``actor.net.0.weight`` [out, in], ``actor.net.0.bias``, ..., ``actor.log_std``,
``critic.net.<2i>.*``), so either backend's inference path loads either backend's checkpoints.

The normalizer's statistics stay float64 numpy on the host (exactly torch-cpu's parallel Welford
update); the jitted code receives ``(mean, std)`` float32 [D] with ``std = sqrt(var) + eps``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.running_moments import fold_moments
from amorctl.plugins.backends.host import LOG_STD, linear_param_name

Params = dict[str, Any]


class MLP(nn.Module):
    """ELU MLP ``in -> hidden... -> out`` (layers ``Dense_0`` ... ``Dense_L``)."""

    hidden: tuple[int, ...]
    out: int
    out_gain: float

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for width in self.hidden:
            x = nn.Dense(width, kernel_init=nn.initializers.orthogonal(math.sqrt(2.0)))(x)
            x = nn.elu(x)
        return nn.Dense(self.out, kernel_init=nn.initializers.orthogonal(self.out_gain))(x)


class Networks:
    """The actor and critic modules of one run: ``init(key) -> params``, pure apply functions."""

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        num_objectives: int,
        actor_hidden: Sequence[int],
        critic_hidden: Sequence[int],
        init_std: float,
    ) -> None:
        self.obs_dim, self.action_dim, self.num_objectives = obs_dim, action_dim, num_objectives
        self.actor = MLP(tuple(actor_hidden), action_dim, 0.01)
        self.critic = MLP(tuple(critic_hidden), num_objectives, 1.0)
        self.init_std = init_std

    def init(self, key: jax.Array) -> Params:
        """Fresh parameters (torch-cpu's initialisation scheme, JAX's random numbers)."""
        ka, kc = jax.random.split(key)
        x = jnp.zeros((1, self.obs_dim), jnp.float32)
        return {
            "actor": {
                "net": self.actor.init(ka, x)["params"],
                "log_std": jnp.full((self.action_dim,), math.log(self.init_std), jnp.float32),
            },
            "critic": {"net": self.critic.init(kc, x)["params"]},
        }

    def mean(self, params: Params, x: jax.Array) -> jax.Array:
        """Normalized obs [B, D] -> action means [B, A]."""
        return self.actor.apply({"params": params["actor"]["net"]}, x)

    def values(self, params: Params, x: jax.Array) -> jax.Array:
        """Normalized obs [B, D] -> values [B, m]."""
        return self.critic.apply({"params": params["critic"]["net"]}, x)


def normalize(obs: jax.Array, norm: tuple[jax.Array, jax.Array], clip: float) -> jax.Array:
    """``clip((obs - mean) / std, -clip, clip)`` with ``norm = (mean [D], std [D])`` float32."""
    mean, std = norm
    return jnp.clip((obs - mean) / std, -clip, clip)


class HostNormalizer:
    """Running mean/var of observations in float64 on the host (torch-cpu's ``RunningNormalizer``).

    ``mean`` [D], ``var`` [D], ``count`` [] float64; :meth:`update_moments` folds a batch given
    by its size, mean and (biased) variance, which the jitted iteration computes on the device.
    """

    def __init__(self, dim: int, clip: float = 10.0, eps: float = 1e-2) -> None:
        self.clip, self.eps = clip, eps
        self.mean = np.zeros(dim)
        self.var = np.ones(dim)
        self.count = np.zeros(())

    def update_moments(self, batch_count: int, batch_mean: np.ndarray, batch_var: np.ndarray) -> None:
        """Chan's parallel update with a batch's count, mean [D] and variance [D]."""
        if batch_count == 0:
            return
        batch_mean = np.asarray(batch_mean, np.float64)
        batch_var = np.asarray(batch_var, np.float64)
        mean, var, count = fold_moments(self.mean, self.var, self.count, batch_mean, batch_var, batch_count)
        self.mean, self.var, self.count = mean, var, np.asarray(count, np.float64)

    def update(self, x: np.ndarray) -> None:
        """Fold raw observations x [B, D] (float64 moments, as torch-cpu)."""
        x = np.asarray(x, np.float64).reshape(-1, self.mean.shape[0])
        self.update_moments(x.shape[0], x.mean(0), x.var(0))

    def device_stats(self) -> tuple[jax.Array, jax.Array]:
        """``(mean, sqrt(var) + eps)`` as float32 [D] (what the networks' inputs are scaled by)."""
        std = (np.sqrt(self.var) + self.eps).astype(np.float32)
        return jnp.asarray(self.mean.astype(np.float32)), jnp.asarray(std)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {
            "normalizer.mean": self.mean.copy(),
            "normalizer.var": self.var.copy(),
            "normalizer.count": np.asarray(self.count, np.float64).copy(),
        }

    def load_arrays(self, arrays: dict[str, np.ndarray]) -> None:
        for key in ("mean", "var", "count"):
            value = np.asarray(arrays[f"normalizer.{key}"], np.float64)
            shape = np.shape(getattr(self, key))
            if value.size != int(np.prod(shape)):  # safetensors stores the 0-d count as [1]
                raise AmorError(
                    f"checkpoint array normalizer.{key} has shape {value.shape}, expected {shape}"
                )
            setattr(self, key, value.reshape(shape).copy())


def _layer_names(net: dict[str, Any]) -> list[str]:
    return sorted(net, key=lambda name: int(name.split("_")[1]))


def params_to_arrays(params: Params) -> dict[str, np.ndarray]:
    """The parameter pytree as torch-cpu checkpoint arrays (``<net>.net.<2i>.weight`` [out, in])."""
    arrays: dict[str, np.ndarray] = {}
    for name in ("actor", "critic"):
        net = params[name]["net"]
        for i, layer in enumerate(_layer_names(net)):
            kernel, bias = net[layer]["kernel"], net[layer]["bias"]
            arrays[linear_param_name(name, i, "weight")] = np.asarray(kernel, np.float32).T.copy()
            arrays[linear_param_name(name, i, "bias")] = np.asarray(bias, np.float32).copy()
    arrays[LOG_STD] = np.asarray(params["actor"]["log_std"], np.float32).copy()
    return arrays


def arrays_to_params(arrays: dict[str, np.ndarray], like: Params) -> Params:
    """Inverse of :func:`params_to_arrays`, checked against the shapes of ``like``.

    Raises:
        AmorError: a missing array or one of another shape (another network configuration).
    """

    def get(key: str, shape: tuple[int, ...]) -> jax.Array:
        if key not in arrays:
            raise AmorError(f"checkpoint does not fit the run's network configuration: no array {key!r}")
        value = np.asarray(arrays[key], np.float32)
        if value.shape != shape:
            raise AmorError(
                f"checkpoint does not fit the run's network configuration: {key!r} has shape "
                f"{value.shape}, expected {shape}"
            )
        return jnp.asarray(value)

    out: Params = {}
    for name in ("actor", "critic"):
        net = like[name]["net"]
        layers = {}
        for i, layer in enumerate(_layer_names(net)):
            kernel_shape = tuple(net[layer]["kernel"].shape)
            layers[layer] = {
                "kernel": get(linear_param_name(name, i, "weight"), kernel_shape[::-1]).T,
                "bias": get(linear_param_name(name, i, "bias"), tuple(net[layer]["bias"].shape)),
            }
        expected = {linear_param_name(name, i, p) for i in range(len(layers)) for p in ("weight", "bias")}
        extra = {k for k in arrays if k.startswith(f"{name}.net.")} - expected
        if extra:
            raise AmorError(
                f"checkpoint does not fit the run's network configuration: unexpected {sorted(extra)[0]!r}"
            )
        out[name] = {"net": layers}
    out["actor"]["log_std"] = get(LOG_STD, tuple(like["actor"]["log_std"].shape))
    return out
