"""A trained jax-mjx policy for inference: the :class:`~amorctl.core.contracts.Policy` of a checkpoint.

The checkpoint's network arrays have torch-cpu's names, so the same snapshot also loads as
torch-cpu's ``TorchPolicy``; both give the same actions within float32 rounding (tested, 1e-5).
"""

from __future__ import annotations

from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from amorctl.core.config import NetworkConfig
from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.plugins.backends.host import LOG_STD, export_snapshot, linear_param_name
from amorctl.plugins.backends.jax_mjx.networks import (
    HostNormalizer,
    Networks,
    arrays_to_params,
    normalize,
    params_to_arrays,
)


class JaxPolicy:
    """``policy(obs [N, D]) -> actions [N, A]`` (the Gaussian mean); ``values(obs) -> [N, m]``."""

    def __init__(self, state: Snapshot, network: NetworkConfig) -> None:
        meta = state.meta
        try:
            obs_dim, action_dim = int(meta["obs_dim"]), int(meta["action_dim"])
            self.objectives: tuple[str, ...] = tuple(meta["objectives"])
        except KeyError as exc:
            raise AmorError(f"checkpoint metadata lacks {exc}") from None
        self.obs_dim, self.action_dim = obs_dim, action_dim
        m = len(self.objectives)
        self.network = network
        self.nets = Networks(
            obs_dim, action_dim, m, network.actor_hidden, network.critic_hidden, network.init_std
        )
        self.params = arrays_to_params(state.arrays, self.nets.init(jax.random.PRNGKey(0)))
        self.normalizer = HostNormalizer(obs_dim, clip=network.obs_clip)
        try:
            self.normalizer.load_arrays(state.arrays)
        except KeyError as exc:
            raise AmorError(f"checkpoint lacks the normalizer array {exc}") from None
        self._norm = self.normalizer.device_stats()
        layout = meta.get("observation_layout") or {"weights": [obs_dim - m, obs_dim]}
        self._layout = {k: (int(a), int(b)) for k, (a, b) in layout.items()}
        clip = network.obs_clip
        self._mean = jax.jit(lambda p, nm, o: self.nets.mean(p, normalize(o, nm, clip)))
        self._values = jax.jit(lambda p, nm, o: self.nets.values(p, normalize(o, nm, clip)))

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions [N, A] float32 for raw observations [N, D]."""
        return np.asarray(self._mean(self.params, self._norm, jnp.asarray(obs, jnp.float32)))

    def values(self, obs: np.ndarray) -> np.ndarray:
        """Critic values [N, m] float32 for raw observations [N, D]."""
        return np.asarray(self._values(self.params, self._norm, jnp.asarray(obs, jnp.float32)))

    @property
    def observation_layout(self) -> Mapping[str, tuple[int, int]]:
        """Named ``(start, stop)`` slices of the observation (at least ``weights``)."""
        return dict(self._layout)

    def export_arrays(self) -> Snapshot:
        """The inference parameters under the backend-neutral names torch-cpu's ``TorchPolicy``
        exports (``normalizer/mean``, ``normalizer/scale`` = sqrt(var) + eps, ``actor/log_std``,
        ``<net>/<i>/weight`` [out, in] and ``<net>/<i>/bias``), float32, format
        ``amorctl-mlp-policy/1``."""
        arrays: dict[str, np.ndarray] = {
            "normalizer/mean": self.normalizer.mean.astype(np.float32),
            "normalizer/scale": (np.sqrt(self.normalizer.var) + self.normalizer.eps).astype(np.float32),
        }
        named = params_to_arrays(self.params)
        arrays["actor/log_std"] = named[LOG_STD]
        counts = {}
        for name in ("actor", "critic"):
            i = 0
            while linear_param_name(name, i, "weight") in named:
                arrays[f"{name}/{i}/weight"] = named[linear_param_name(name, i, "weight")]
                arrays[f"{name}/{i}/bias"] = named[linear_param_name(name, i, "bias")]
                i += 1
            counts[name] = i
        return export_snapshot(self, arrays, counts)
