"""The backend-agnostic training interface: what a backend's trainer provides to the runner.

The runner (:mod:`amorctl.train.loop`) drives any backend through :class:`Trainer`: one call to
``iteration()`` collects a rollout and updates the networks; ``state_dict()`` returns everything
needed to continue bit-exactly as plain arrays plus JSON-ready metadata (:class:`State`), so
checkpoints are safetensors + JSON and never pickles. The torch-cpu backend implements it in
``amorctl/plugins/backends/torch_cpu/moppo.py``; a JAX backend implements the same methods.

Environments that can snapshot themselves implement :class:`SnapshotEnv` with the same
:class:`State` type, which lets ``--resume`` continue the rollout exactly where it stopped.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from amorctl.core.config import TrainConfig
from amorctl.core.vecenv import VectorEnv


@dataclass
class State:
    """A snapshot: named numpy arrays (stored in safetensors) and JSON-ready metadata."""

    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class Trainer(Protocol):
    """One backend's training loop, stepped one iteration at a time."""

    iteration_count: int  # iterations completed so far

    def iteration(self) -> dict[str, float]:
        """Collect one rollout, update the networks; return this iteration's metrics.

        Metric names are ``/``-separated (``loss/value``, ``return/up``, ``explained_variance/up``,
        ``env_steps_per_s``, ...), values are plain floats (NaN where undefined).
        """
        ...

    def state_dict(self) -> State:
        """Everything needed to continue training exactly: weights, normalizer, optimizer, RNG, the
        current observations and episode statistics."""
        ...

    def load_state_dict(self, state: State) -> None:
        """Restore a :meth:`state_dict` snapshot. Raises AmorError if it does not fit this trainer."""
        ...

    def reset_env(self, seed: int) -> None:
        """Restart every env episode with ``seed`` and take the new observations (used on resume
        when the env cannot snapshot itself)."""
        ...

    def act(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """Actions [N, action_dim] for observations [N, obs_dim] (the mean when deterministic)."""
        ...


@runtime_checkable
class SnapshotEnv(Protocol):
    """A :class:`~amorctl.core.vecenv.VectorEnv` that can save and restore its full state."""

    def get_state(self) -> State:
        """The env's complete state, RNG included, as arrays plus JSON-ready metadata."""
        ...

    def set_state(self, state: State) -> None:
        """Restore :meth:`get_state`; the next ``step`` then equals the one the snapshot was taken before."""
        ...


class TrainerFactory(Protocol):
    """What a backend object offers to the runner (``BackendSpec.make()`` returns such a backend)."""

    def make_trainer(self, env: VectorEnv, config: TrainConfig) -> Trainer: ...

    def load_policy(self, trainer_state: State, config: TrainConfig) -> Any:
        """An inference policy from a checkpoint: ``policy(obs) -> actions``, ``policy.values(obs)``."""
        ...
