"""MOPPO's checkpoint state: :func:`trainer_state` and its inverse :func:`load_trainer_state`
(``trainer`` is a :class:`~amorctl.plugins.backends.torch_cpu.moppo.MOPPOTrainer`)."""

from __future__ import annotations

from typing import Any

import torch

from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.core.optimizer_state import DAMAGED, check_param_groups, check_state, number_in
from amorctl.plugins.backends.host import check_env_meta, load_counters
from amorctl.plugins.backends.torch_cpu.networks import load_modules, modules_to_arrays
from amorctl.plugins.backends.torch_cpu.weight_feedback import ARRAYS as FEEDBACK_ARRAYS


def trainer_state(trainer: Any) -> Snapshot:
    """Weights, normalizer, Adam state, RNG, current observations and episode statistics
    (this rank's; the training loop merges the ranks' snapshots into one checkpoint)."""
    if trainer.replicas is not None:
        trainer.replicas.check_identical(trainer._modules(), trainer.iteration_count)
    arrays = modules_to_arrays(trainer._modules())
    optim = trainer.optimizer.state_dict()
    for index, slot in optim["state"].items():
        for key, tensor in slot.items():
            arrays[f"optimizer.{index}.{key}"] = torch.as_tensor(tensor).numpy().copy()
    arrays["rng.torch"] = trainer.generator.get_state().numpy().copy()
    arrays["obs"] = trainer.obs.numpy().copy()
    window_arrays, window_meta = trainer.window.state()
    arrays.update(window_arrays)
    _lever_arrays(trainer, arrays)
    meta = {
        "iteration": trainer.iteration_count,
        "env_steps": trainer.env_steps,
        "learning_rate": trainer.learning_rate,
        "optimizer_param_groups": optim["param_groups"],
        "optimizer_state_keys": {str(i): sorted(s) for i, s in optim["state"].items()},
        **window_meta,
        "obs_dim": trainer.env.obs_dim,
        "action_dim": trainer.env.action_dim,
        "objectives": list(trainer.names),
    }
    if trainer.return_scale is not None:
        meta["return_scale_updates"] = trainer.return_scale.updates
    return Snapshot(arrays, meta)


def _lever_arrays(trainer: Any, arrays: dict[str, Any]) -> None:
    """The levers' state (only when on, so checkpoints without levers keep their keys)."""
    if trainer.return_scale is not None:
        for key, value in trainer.return_scale.state().items():
            arrays[f"return_scale.{key}"] = value.numpy().copy()
    if trainer.feedback is not None:
        for key in FEEDBACK_ARRAYS:
            arrays[f"feedback.{key}"] = getattr(trainer.feedback, key).numpy().copy()


def _check_optimizer_meta(meta: dict[str, Any], optimizer: torch.optim.Optimizer) -> None:
    """Refuse a checkpoint whose learning rate or Adam hyperparameters are out of range (types
    and structure are :func:`amorctl.train.checkpoint.check_like`'s job)."""
    rate = meta.get("learning_rate")
    if not number_in(rate, 0.0, 1.0):
        raise AmorError(f"checkpoint has learning_rate = {rate!r}; expected a finite number in [0, 1]")
    check_param_groups(meta.get("optimizer_param_groups"), optimizer, "checkpoint's optimizer_param_groups")


def _check_optimizer_state(
    meta: dict[str, Any], arrays: dict[str, Any], optimizer: torch.optim.Optimizer
) -> None:
    """Refuse optimizer state that a fresh optimizer of this trainer would not have: parameter
    indices other than the fresh optimizer's (a duplicate, missing or permuted index), and what
    :func:`amorctl.core.optimizer_state.check_state` refuses."""
    fresh_groups = optimizer.state_dict()["param_groups"]
    for i, (saved, fresh) in enumerate(zip(meta["optimizer_param_groups"], fresh_groups, strict=True)):
        if saved.get("params") != fresh["params"]:
            raise AmorError(
                f"checkpoint's optimizer_param_groups[{i}].params = {saved.get('params')!r}; this trainer's "
                f"optimizer has parameters {fresh['params']!r} (an index duplicated, missing or permuted): "
                f"{DAMAGED}"
            )
    saved_keys = meta.get("optimizer_state_keys")
    if not isinstance(saved_keys, dict) or not all(
        isinstance(keys, list) and all(isinstance(k, str) for k in keys) for keys in saved_keys.values()
    ):
        raise AmorError(
            f"checkpoint's optimizer_state_keys must be a table: parameter index -> state keys: {DAMAGED}"
        )
    state = {i: {k: arrays.get(f"optimizer.{i}.{k}") for k in keys} for i, keys in saved_keys.items()}
    check_state(state, optimizer, lambda index, key: f"optimizer.{index}.{key}")


def load_trainer_state(trainer: Any, state: Snapshot) -> None:
    """Restore :meth:`state_dict`. Raises AmorError on a checkpoint of another shape or objective set."""
    meta, arrays = state.meta, state.arrays
    check_env_meta(meta, trainer.env, trainer.names)
    _check_optimizer_meta(meta, trainer.optimizer)
    _check_optimizer_state(meta, arrays, trainer.optimizer)
    try:
        load_modules(trainer._modules(), arrays)
        optim_state: dict[int, dict[str, torch.Tensor]] = {}
        for index, keys in meta["optimizer_state_keys"].items():
            optim_state[int(index)] = {
                k: torch.from_numpy(arrays[f"optimizer.{index}.{k}"].copy()) for k in keys
            }
        trainer.optimizer.load_state_dict(
            {"state": optim_state, "param_groups": meta["optimizer_param_groups"]}
        )
        trainer.generator.set_state(torch.from_numpy(arrays["rng.torch"].copy()))
        trainer.obs = torch.from_numpy(arrays["obs"].copy())
        trainer.window.load_state(arrays, meta)
        if trainer.return_scale is not None:
            keys = trainer.return_scale.state()
            saved = {k: torch.from_numpy(arrays[f"return_scale.{k}"].copy()) for k in keys}
            trainer.return_scale.load_state(saved, int(meta["return_scale_updates"]))
        if trainer.feedback is not None:
            for key in FEEDBACK_ARRAYS:
                setattr(trainer.feedback, key, torch.from_numpy(arrays[f"feedback.{key}"].copy()))
    except (KeyError, RuntimeError, ValueError) as exc:
        raise AmorError(f"checkpoint does not fit this network configuration: {exc}") from None
    load_counters(trainer, meta)
    trainer.learning_rate = float(meta["learning_rate"])
