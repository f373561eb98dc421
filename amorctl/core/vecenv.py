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

    Optional, each read through one function here: ``close()`` for an env that holds threads or
    files (:func:`close_env`); ``diverged_total``, the steps whose simulation blew up since the
    last ``reset`` (:func:`diverged_total`); ``weight_sampler``, the
    :class:`~amorctl.core.weight_sampling.WeightSampler` its episodes draw ``w`` from, which an
    adaptive sampler needs fed back (:func:`weight_sampler_of`); a fused rollout
    (:class:`FusedRolloutEnv`).
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


def close_env(env: object) -> None:
    """End ``env``: call its ``close()`` when it has one (optional in :class:`VectorEnv`)."""
    close = getattr(env, "close", None)
    if callable(close):
        close()


@runtime_checkable
class FusedRolloutEnv(Protocol):
    """An env that rolls out policy and physics in one compiled call (the jax-mjx MJX env): the
    trainer asks it for that call instead of stepping it, and the runner does not wrap it."""

    def fused_rollout(self, nets: Any, clip: float, num_steps: int, mesh: Any) -> Any:
        """A compiled ``(params, norm, env_state, selection, key) -> (env_state, batch)`` of
        ``num_steps`` steps of policy and env."""
        ...


def has_fused_rollout(env: object) -> bool:
    """Whether ``env``'s own class is a :class:`FusedRolloutEnv`. A wrapper that forwards
    attributes to the env inside it is not: its fused rollout would bypass the wrapper."""
    return callable(getattr(type(env), "fused_rollout", None))


def diverged_total(env: object) -> int:
    """Env steps whose simulation blew up since the last reset (0 for an env without a simulator)."""
    return int(getattr(env, "diverged_total", 0) or 0)


def weight_sampler_of(env: object) -> Any:
    """The env's weight sampler (optional in :class:`VectorEnv`), or None."""
    return getattr(env, "weight_sampler", None)


def teacher_of(env: object) -> Any:
    """The :class:`~amorctl.core.contracts.Teacher` a distillation run's env carries (the training
    loop attaches it for ``[distill] teachers``), or None."""
    return getattr(env, "teacher", None)
