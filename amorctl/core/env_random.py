"""Where a vector env's random numbers come from: one generator for the batch, or one per env.

A :class:`~amorctl.core.vecenv.VectorEnv` reset with one integer seed draws every env's random
numbers (start states, clip switches, noise, hazards, weights) from ONE generator, in batch order
(:class:`BatchRandom`): what training uses, but env i's episodes then depend on how many envs the
batch has and on when the others reset. Reset with one seed per env (``reset(seed=[s_0, ...,
s_{N-1}])``, as Gymnasium's vector envs take them), env i draws from a generator of its own seeded
with ``s_i`` (:class:`PerEnvRandom`), so its episodes depend on ``s_i`` and its own actions alone,
whatever the batch around it: sweeps split across processes rely on it (docs/distributed.md).

Both follow :class:`EnvRandom`: every draw names the envs it is for (``ids`` [k]) and returns one
value (or row) per id. Shapes: N = envs, k = envs drawing, m = objectives.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.weights import sample_dirichlet

Seed = int | Sequence[int] | np.ndarray | None


class EnvRandom(Protocol):
    """Random draws for the envs ``ids`` [k] (int indices into the batch)."""

    def random(self, ids: np.ndarray) -> np.ndarray:
        """[k] float64 uniform on [0, 1)."""
        ...

    def uniform(self, ids: np.ndarray, low: float, high: float) -> np.ndarray:
        """[k] float64 uniform on [low, high)."""
        ...

    def normal(self, ids: np.ndarray) -> np.ndarray:
        """[k] float64 standard normal."""
        ...

    def integers(self, ids: np.ndarray, high: int | np.ndarray) -> np.ndarray:
        """[k] int64 uniform on [0, high) (``high`` one bound, or [k] bounds)."""
        ...

    def dirichlet(self, ids: np.ndarray, m: int) -> np.ndarray:
        """[k, m] float32 Dirichlet(1) weights (:func:`~amorctl.core.weights.sample_dirichlet`)."""
        ...

    def state(self) -> Any:
        """JSON-ready state; :func:`restore_random` rebuilds the generator(s) from it."""
        ...


class BatchRandom:
    """One generator for the whole batch: a draw for k envs takes the next k numbers."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def random(self, ids: np.ndarray) -> np.ndarray:
        return self.rng.random(len(ids))

    def uniform(self, ids: np.ndarray, low: float, high: float) -> np.ndarray:
        return self.rng.uniform(low, high, size=len(ids))

    def normal(self, ids: np.ndarray) -> np.ndarray:
        return self.rng.normal(size=len(ids))

    def integers(self, ids: np.ndarray, high: int | np.ndarray) -> np.ndarray:
        return self.rng.integers(0, high, size=len(ids))

    def dirichlet(self, ids: np.ndarray, m: int) -> np.ndarray:
        return sample_dirichlet(self.rng, len(ids), m)

    def state(self) -> dict[str, Any]:
        """numpy's ``bit_generator.state`` (what env snapshots always stored under ``rng``)."""
        return self.rng.bit_generator.state


class PerEnvRandom:
    """One generator per env (``numpy.random.default_rng(seeds[i])``); env i draws from its own.

    Args:
        seeds: [N] non-negative integer seeds, one per env.
    """

    def __init__(self, seeds: Sequence[int] | np.ndarray) -> None:
        self.gens = [np.random.default_rng(int(s)) for s in seeds]

    def _each(self, ids: np.ndarray, draw: Any) -> np.ndarray:
        return np.array([draw(self.gens[i]) for i in np.asarray(ids, dtype=np.int64)])

    def random(self, ids: np.ndarray) -> np.ndarray:
        return self._each(ids, lambda g: g.random()).astype(np.float64)

    def uniform(self, ids: np.ndarray, low: float, high: float) -> np.ndarray:
        return self._each(ids, lambda g: g.uniform(low, high)).astype(np.float64)

    def normal(self, ids: np.ndarray) -> np.ndarray:
        return self._each(ids, lambda g: g.normal()).astype(np.float64)

    def integers(self, ids: np.ndarray, high: int | np.ndarray) -> np.ndarray:
        ids = np.asarray(ids, dtype=np.int64)
        highs = np.broadcast_to(np.asarray(high, dtype=np.int64), ids.shape)
        return np.array([self.gens[i].integers(0, h) for i, h in zip(ids, highs, strict=True)], np.int64)

    def dirichlet(self, ids: np.ndarray, m: int) -> np.ndarray:
        rows = [sample_dirichlet(self.gens[i], 1, m)[0] for i in np.asarray(ids, dtype=np.int64)]
        return np.array(rows, dtype=np.float32).reshape(len(rows), m)

    def state(self) -> dict[str, Any]:
        """``{"per_env": [bit_generator.state of env 0, ...]}``."""
        return {"per_env": [g.bit_generator.state for g in self.gens]}


def env_random(seed: Seed, num_envs: int) -> BatchRandom | PerEnvRandom:
    """The draws of a ``reset(seed)``: one seed (or None: fresh entropy) → :class:`BatchRandom`;
    ``num_envs`` seeds → :class:`PerEnvRandom`.

    Raises:
        AmorError: a seed list of another length, or a negative or non-integer seed.
    """
    if seed is None or np.ndim(seed) == 0:
        return BatchRandom(np.random.default_rng(None if seed is None else int(seed)))  # type: ignore[arg-type]
    seeds = np.asarray(seed)
    if seeds.shape != (num_envs,):
        raise AmorError(f"per-env seeds: expected {num_envs} seeds, one per env, got shape {seeds.shape}")
    if seeds.dtype.kind not in "iu" or (seeds < 0).any():
        raise AmorError("per-env seeds must be non-negative integers")
    return PerEnvRandom(seeds)


def is_per_env(seed: Seed) -> bool:
    """Whether ``seed`` is one seed per env (a sequence) rather than one seed for the batch."""
    return seed is not None and np.ndim(seed) == 1


def restore_random(state: Any) -> BatchRandom | PerEnvRandom:
    """The generator(s) of an :meth:`EnvRandom.state` (a snapshot's ``rng`` metadata)."""
    if isinstance(state, dict) and "per_env" in state:
        out = PerEnvRandom([])
        for saved in state["per_env"]:
            g = np.random.default_rng()
            g.bit_generator.state = saved
            out.gens.append(g)
        return out
    rng = np.random.default_rng()
    rng.bit_generator.state = state
    return BatchRandom(rng)
