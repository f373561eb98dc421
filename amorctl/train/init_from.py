"""Start a new run from another run's networks (``[run] init_from``, docs/train.md, "Starting
from another run").

A new run takes the actor, the critic and the observation normalizer of one checkpoint of another
run (a run directory or ``pretrained:NAME``, the newest checkpoint or ``@ITERATION``) and trains
on from there with its own config: a fresh optimizer, its own envs, iteration and env-step
counters from 0. Uses: MOPPO after distillation (a student continued from rewards, docs/distill.md),
fine-tuning a shipped policy with other settings or clips.

Checked before anything is written: the run and checkpoint exist; the env kind and, for tracking,
the character, objective set and action mode are the new run's; the policy takes observations and
gives actions of the new run's sizes for the same objectives; and the new run's networks have
exactly the source's layer shapes (``[network]``, ``[ppo] survival_channel``). ``[run] init_from_std``
(> 0) starts the actions' std there instead of at the source's. The new run's config
stores the source as an absolute path (``pretrained:`` names as they are) with the iteration
taken, so the record says which weights it started from; a resumed run reads its own checkpoint.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from amorctl.core.config import TrainConfig
from amorctl.core.contracts import Trainer
from amorctl.core.errors import AmorError
from amorctl.train import pretrained
from amorctl.train.distill import SHARED_ENV
from amorctl.train.rundir import RunDir

#: Trainer checkpoint arrays a new run takes over: the networks and the observation normalizer.
NETWORK_PREFIXES = ("actor.", "critic.", "normalizer.", "survival_critic.")
WHERE = "[run] init_from"
#: The actor's state-independent log std [A] (``[run] init_from_std`` replaces it).
LOG_STD = "actor.log_std"


def split_reference(reference: str) -> tuple[str, int | None]:
    """``RUN@ITERATION`` -> (RUN, ITERATION); a reference without a numeric ``@`` suffix -> (it, None)."""
    run, sep, tail = reference.rpartition("@")
    if sep and run and tail.isdigit():
        return run, int(tail)
    return reference, None


def record_init_from(config: TrainConfig) -> TrainConfig:
    """A new run's config with ``run.init_from`` stored as ``/absolute/run@ITERATION`` (the
    checkpoint it starts from, checked to load); unchanged without one.

    Raises:
        AmorError: naming ``[run] init_from``: no such run, or no such (or a damaged) checkpoint.
    """
    reference = config.run.init_from
    if not reference:
        return config
    name, iteration = split_reference(reference)
    ckpt = _checkpoint(_open(name), iteration)
    stored = name if pretrained.is_reference(name) else str(Path(name).resolve())
    run = dataclasses.replace(config.run, init_from=f"{stored}@{ckpt.iteration}")
    return dataclasses.replace(config, run=run)


def source_networks(config: TrainConfig, env: Any) -> dict[str, np.ndarray]:
    """The network and normalizer arrays of ``config.run.init_from`` (recorded by
    :func:`record_init_from`), checked against the new run's config and ``env``.

    Raises:
        AmorError: naming ``[run] init_from`` and the mismatch (env kind, character, objective set,
            action mode, observation/action sizes or objectives).
    """
    name, iteration = split_reference(config.run.init_from)
    run = _open(name)
    where = f"{WHERE}: {run.label}"
    source = run.config
    _check_same_env(config, source, where)
    ckpt = _checkpoint(run, iteration)
    try:
        policy = run.policy_of(ckpt)
    except AmorError as err:
        raise AmorError(f"{where}: {err}") from None
    mine = (env.obs_dim, env.action_dim, tuple(env.reward_space.names))
    theirs = (policy.obs_dim, policy.action_dim, tuple(policy.objectives))
    if mine != theirs:
        raise AmorError(
            f"{where}: its observations, actions and objectives {theirs} differ from this run's {mine}"
        )
    arrays = {k: v for k, v in ckpt.trainer.arrays.items() if k.startswith(NETWORK_PREFIXES)}
    if config.run.init_from_std > 0:
        arrays[LOG_STD] = with_std(arrays.get(LOG_STD), config.run.init_from_std, where)
    return arrays


def with_std(log_std: np.ndarray | None, std: float, where: str = WHERE) -> np.ndarray:
    """The source's state-independent log std [A] replaced by ``log(std)`` in every dimension.

    Raises:
        AmorError: the source's actor has no state-independent std (``actor.log_std``).
    """
    if log_std is None:
        raise AmorError(f"{where}: [run] init_from_std needs an actor with a state-independent std")
    return np.full(np.shape(log_std), np.log(std), dtype=np.asarray(log_std).dtype)


def start_from(trainer: Trainer, arrays: dict[str, np.ndarray], where: str = WHERE) -> None:
    """Load ``arrays`` (:func:`source_networks`) into a new ``trainer``'s networks and normalizer;
    its optimizer, RNG, envs and counters stay as they are.

    Raises:
        AmorError: the trainer's networks have other arrays or shapes than the source's.
    """
    own = trainer.state_dict()
    mine = {k: _shape(v) for k, v in own.arrays.items() if k.startswith(NETWORK_PREFIXES)}
    theirs = {k: _shape(v) for k, v in arrays.items()}
    if mine != theirs:
        differ = sorted(k for k in mine.keys() | theirs.keys() if mine.get(k) != theirs.get(k))
        shown = ", ".join(f"{k} {theirs.get(k, 'absent')} vs {mine.get(k, 'absent')}" for k in differ[:4])
        raise AmorError(
            f"{where}: its networks differ from this run's ([network] sizes, [ppo] survival_channel): "
            f"{shown}{' ...' if len(differ) > 4 else ''} (source vs this run)"
        )
    for key, value in arrays.items():
        own.arrays[key] = np.reshape(value, np.shape(own.arrays[key]))
    trainer.load_state_dict(own)


def _shape(array: Any) -> tuple[int, ...]:
    """The array's shape, a scalar as (1,) (checkpoints store scalars with one element)."""
    return tuple(np.shape(array)) or (1,)


def _check_same_env(mine: TrainConfig, theirs: TrainConfig, where: str) -> None:
    if theirs.env.kind != mine.env.kind:
        raise AmorError(f"{where}: trained on env.kind = {theirs.env.kind!r}, this run has {mine.env.kind!r}")
    if mine.env.kind != "tracking":
        return
    for key in SHARED_ENV:  # what a distillation teacher must share too
        a, b = getattr(mine.env, key), getattr(theirs.env, key)
        if a != b:
            raise AmorError(f"{where}: trained with [env] {key} = {b!r}, this run has {a!r}")


def _open(name: str) -> RunDir:
    try:
        return RunDir.open(name)
    except AmorError as err:
        raise AmorError(f"{WHERE}: {err}") from None


def _checkpoint(run: RunDir, iteration: int | None) -> Any:
    try:
        return run.checkpoint(iteration)
    except AmorError as err:
        raise AmorError(f"{WHERE}: {err}") from None
