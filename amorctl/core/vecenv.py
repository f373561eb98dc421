"""The contract between environments and trainers: a batched, weight-conditioned vector env.

Any environment a MOPPO trainer drives follows :class:`VectorEnv` (the tracking env, the toy env
used by tests, and the MO-Gymnasium adapter). Shapes use N = num_envs, m = num_objectives.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class RewardSpace:
    """A description of the m objectives, index by index (as MO-Gymnasium documents it)."""

    names: tuple[str, ...]
    descriptions: tuple[str, ...]
    low: np.ndarray  # [m] per-step lower bound (may be -inf)
    high: np.ndarray  # [m] per-step upper bound (may be +inf)
    #: a bonus added to every objective on each transition that does not terminate (0: none)
    survival_bonus: float = 0.0

    @property
    def shape(self) -> tuple[int]:
        return (len(self.names),)


@runtime_checkable
class VectorEnv(Protocol):
    """N environments stepped together, auto-resetting, with vector rewards.

    The observation's last m entries are the weights ``w`` of each env's current episode, drawn
    from Dirichlet(1) at every episode start (or fixed, when the env was told to). ``weights``
    returns them as ``[N, m]``; read it *before* ``step`` to get the weights the step's rewards
    belong to, since an env that ends its episode in ``step`` starts a new one with new weights.
    """

    num_envs: int
    obs_dim: int
    action_dim: int
    reward_space: RewardSpace

    @property
    def weights(self) -> np.ndarray:
        """[N, m] float32: the weights of each env's current episode."""
        ...

    def reset(
        self, seed: int | Sequence[int] | np.ndarray | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start all envs anew. Returns obs [N, obs_dim] float32 and an info dict.

        ``seed``: None keeps the env's generator; one int reseeds the one generator the batch
        draws from; [N] ints (as Gymnasium's vector envs take them) give env i a generator of
        its own seeded with ``seed[i]``, so its episodes (start states, clip switches, noise,
        hazards) do not depend on the batch around it (:mod:`amorctl.core.env_random`).
        """
        ...

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Advance one control step with actions [N, action_dim].

        Returns:
            obs: [N, obs_dim] float32; for envs whose episode ended, the first obs of the next one.
            rewards: [N, m] float32 vector rewards of this transition.
            terminated: [N] bool, the episode ended in a terminal state (no bootstrapping).
            truncated: [N] bool, the episode hit its time limit (bootstrap from ``final_obs``).
            info: dict with at least ``final_obs`` [N, obs_dim] (the last obs of ended episodes,
                equal to ``obs`` elsewhere) and any diagnostic counters.
        """
        ...
