"""The environments and weight vectors of an evaluation: the run's env resized, optionally
restricted to named motions, and the weight vectors a sweep evaluates.

Shared by :mod:`amorctl.analysis.sweeps` (``amorctl pareto``, ``evaluate --sweep``) and
:mod:`amorctl.analysis.tracking_metrics` (``amorctl evaluate``). Tracking envs are read and
restricted through their :class:`~amorctl.core.contracts.TrackingView` only.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from amorctl.core.config import TrainConfig
from amorctl.core.contracts import tracking_view
from amorctl.core.errors import AmorError
from amorctl.core.levers import TRAINING_ONLY_ENV
from amorctl.core.vecenv import VectorEnv, close_env
from amorctl.core.weights import sample_dirichlet, simplex_grid
from amorctl.envs.factory import make_env
from amorctl.motion.resolve import resolve_name

ALL_MOTIONS = "all"  # the group name when no --motion is given (episodes draw clips at random)

Progress = Callable[[int, int], None]


def check_objective(name: str, names: Sequence[str]) -> int:
    """Index of objective ``name``; AmorError listing the objectives when unknown."""
    if name not in names:
        raise AmorError(f"unknown objective {name!r}; the run's objectives are {', '.join(names)}")
    return list(names).index(name)


def make_eval_env(
    config: TrainConfig,
    num_envs: int,
    *,
    motions: Sequence[str] | None = None,
    env_motion: np.ndarray | None = None,
    seed: int = 0,
) -> tuple[VectorEnv, list[str]]:
    """The run's env sized to ``num_envs``, optionally restricted to named motions.

    Args:
        config: the run's config.
        num_envs: N.
        motions: motion (clip) names as the user typed them; resolved against the run's dataset.
        env_motion: [N] index into ``motions`` per env: each env always tracks that motion.
            Without it, episodes draw among ``motions`` at random.
        seed: the env's seed.

    Returns:
        (env, resolved motion names; ``[ALL_MOTIONS]`` when ``motions`` is empty).

    Raises:
        AmorError: motions for a run without motions (toy, gym), or an unknown motion name.
    """
    if num_envs < 1:
        raise AmorError(f"need at least one environment, got {num_envs}")
    if motions and config.env.kind != "tracking":
        raise AmorError(f"--motion needs a motion-tracking run; this run's env is {config.env.kind!r}")
    cfg = dataclasses.replace(
        config,
        env=dataclasses.replace(config.env, num_envs=int(num_envs), **TRAINING_ONLY_ENV),
        run=dataclasses.replace(config.run, seed=int(seed)),
    )
    env = make_env(cfg)
    if not motions:
        return env, [ALL_MOTIONS]
    view = tracking_view(env)
    try:
        if view is None:
            raise AmorError("--motion: this run's env has no motion library")
        clip_names = list(view.clip_names)
        where = f"the run's {view.character.name} dataset"
        resolved = [resolve_name(q, clip_names, where) for q in motions]
        indices = np.array([clip_names.index(r) for r in resolved], dtype=np.int64)
        if env_motion is None:
            view.select_clips(clips=indices)
        else:
            view.select_clips(env_clips=indices[np.asarray(env_motion, dtype=np.int64)])
    except BaseException:
        close_env(env)
        raise
    return env, resolved


def sweep_weights(
    m: int, samples: int | None = None, *, grid: int | None = None, seed: int = 0
) -> tuple[np.ndarray, str]:
    """The K weight vectors of a sweep: Dirichlet(1) samples, or a uniform simplex grid.

    Returns:
        ([K, m] float64 rows on the simplex, a description such as ``"dirichlet(1)"``).

    Raises:
        AmorError: ``samples < 1`` or ``grid < 1``.
    """
    if grid is not None:
        if grid < 1:
            raise AmorError(f"--grid must be >= 1 divisions, got {grid}")
        return simplex_grid(m, grid), f"simplex grid ({grid} divisions)"
    k = 64 if samples is None else samples
    if k < 1:
        raise AmorError(f"--samples must be >= 1, got {k}")
    w = sample_dirichlet(np.random.default_rng(seed), k, m).astype(np.float64)
    return w / w.sum(axis=1, keepdims=True), "dirichlet(1)"


def episode_seeds(seed: int, keys: np.ndarray) -> np.ndarray:
    """One env seed per episode from ``seed`` and the episode's key alone (never its batch position).

    A sweep names each episode by a key (``(motion group, weight sample, episode)`` for a Pareto
    sweep, ``(level, episode)`` for a weight sweep) and resets its env with these seeds, so every
    env draws its start state and randomness from its own generator
    (:mod:`amorctl.core.env_random`): an episode is the same whether the batch holds all K
    samples or a block of them (``torchrun`` ranks, docs/distributed.md).

    Args:
        seed: the sweep's ``--seed`` (>= 0).
        keys: [N, k] non-negative ints, one row per env.

    Returns:
        [N] int64 seeds in [0, 2**63): ``SeedSequence(seed, spawn_key=key)``'s first 63 bits.
    """
    rows = np.asarray(keys, dtype=np.int64)
    if seed < 0:
        raise AmorError(f"--seed must be >= 0, got {seed}")
    if rows.ndim != 2 or (rows < 0).any():
        raise ValueError(f"episode keys must be [N, k] non-negative ints, got shape {rows.shape}")
    out = np.empty(len(rows), dtype=np.int64)
    for i, key in enumerate(rows.tolist()):
        state = np.random.SeedSequence(int(seed), spawn_key=tuple(key)).generate_state(1, np.uint64)
        out[i] = int(state[0] >> np.uint64(1))
    return out


def episode_limit(env: Any) -> int:
    """The env's time limit in control steps (0 when it has none)."""
    view = tracking_view(env)
    if view is not None:
        return int(view.max_episode_steps)
    return int(getattr(env, "max_episode_steps", 0) or getattr(env, "max_steps", 0) or 0)
