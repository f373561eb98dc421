"""MOPPO's checkpoint state: :func:`trainer_state` and its inverse :func:`load_trainer_state`
(``trainer`` is a :class:`~amorctl.plugins.backends.torch_cpu.moppo.MOPPOTrainer`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.plugins.backends.torch_cpu.networks import load_modules, modules_to_arrays
from amorctl.plugins.backends.torch_cpu.weight_feedback import ARRAYS as FEEDBACK_ARRAYS

#: Per-env episode accumulators and recent-episode windows, saved in checkpoints for exact resume.
EPISODE_STATS = (
    "ep_return",
    "ep_scalar",
    "ep_length",
    "recent_return",
    "recent_scalar",
    "recent_length",
    "recent_survived",
)


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
    for key in EPISODE_STATS:
        arrays[f"episodes.{key}"] = getattr(trainer, key).numpy().copy()
    _lever_arrays(trainer, arrays)
    meta = {
        "iteration": trainer.iteration_count,
        "env_steps": trainer.env_steps,
        "learning_rate": trainer.learning_rate,
        "optimizer_param_groups": optim["param_groups"],
        "optimizer_state_keys": {str(i): sorted(s) for i, s in optim["state"].items()},
        "recent_ptr": trainer.recent_ptr,
        "episodes": trainer.episodes,
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


#: Adam's hyperparameters in a checkpoint: the range each must lie in (``betas``: each entry).
_ADAM_RANGES = {"lr": (0.0, 1.0), "betas": (0.0, 1.0), "eps": (0.0, 1.0), "weight_decay": (0.0, 1e6)}


def _check_optimizer_meta(meta: dict[str, Any], fresh_groups: list[dict[str, Any]]) -> None:
    """Refuse a checkpoint whose learning rate or Adam hyperparameters are out of range (types
    and structure are :func:`amorctl.train.checkpoint.check_like`'s job; Adam would accept, say,
    betas of 1e308 and fail only mid-iteration, with torch's own message)."""
    rate = meta.get("learning_rate")
    if not _number_in(rate, 0.0, 1.0):
        raise AmorError(f"checkpoint has learning_rate = {rate!r}; expected a finite number in [0, 1]")
    groups = meta.get("optimizer_param_groups")
    if not isinstance(groups, list) or len(groups) != len(fresh_groups):
        raise AmorError(
            f"checkpoint's optimizer_param_groups do not match this trainer's ({len(fresh_groups)} group(s))"
        )
    for i, (saved, fresh) in enumerate(zip(groups, fresh_groups, strict=True)):
        if not isinstance(saved, dict) or set(saved) != set(fresh):
            raise AmorError(f"checkpoint's optimizer_param_groups[{i}] has other keys than this trainer's")
        for key, (low, high) in _ADAM_RANGES.items():
            values = saved[key] if key == "betas" and isinstance(saved[key], list | tuple) else [saved[key]]
            if key == "betas" and len(values) != 2:
                raise AmorError(
                    f"checkpoint's optimizer_param_groups[{i}].betas = {saved[key]!r}; expected 2 numbers"
                )
            if not all(_number_in(v, low, high, strict_high=key != "weight_decay") for v in values):
                raise AmorError(
                    f"checkpoint's optimizer_param_groups[{i}].{key} = {saved[key]!r}; expected finite "
                    f"number(s) in [{low:g}, {high:g})"
                )


#: Optimizer state that is never negative (Adam's step count and second moments).
_NON_NEGATIVE_STATE = ("step", "exp_avg_sq", "max_exp_avg_sq")


def _fresh_state_layout(
    optimizer: torch.optim.Optimizer,
) -> dict[int, dict[str, tuple[tuple[int, ...], Any]]]:
    """What a fresh optimizer of ``optimizer``'s kind and settings keeps per parameter once it has
    stepped: parameter index -> state key -> (shape, dtype). Built on zero copies of the
    parameters, so ``optimizer`` and its parameters are untouched."""
    groups = []
    for group in optimizer.param_groups:
        copies = [torch.zeros_like(p, requires_grad=True) for p in group["params"]]
        for copy in copies:
            copy.grad = torch.zeros_like(copy)
        groups.append({**{k: v for k, v in group.items() if k != "params"}, "params": copies})
    fresh = type(optimizer)(groups)
    fresh.step()
    state = fresh.state_dict()["state"]
    return {i: {k: (tuple(v.shape), v.dtype) for k, v in slot.items()} for i, slot in state.items()}


def _check_optimizer_state(
    meta: dict[str, Any], arrays: dict[str, Any], optimizer: torch.optim.Optimizer
) -> None:
    """Refuse optimizer state that a fresh optimizer of this trainer would not have: parameter
    indices other than the fresh optimizer's (a duplicate, missing or permuted index), a state
    key missing or extra (Adam's ``exp_avg`` deleted), an array of another shape or dtype, or a
    moment that is not finite (or a negative second moment or step). Without this check such a
    checkpoint resumes and fails at the first optimizer step with torch's KeyError/RuntimeError."""

    def fail(problem: str) -> AmorError:
        return AmorError(
            f"{problem}: the optimizer state is damaged; resume from another checkpoint or start anew"
        )

    fresh_groups = optimizer.state_dict()["param_groups"]
    for i, (saved, fresh) in enumerate(zip(meta["optimizer_param_groups"], fresh_groups, strict=True)):
        if saved.get("params") != fresh["params"]:
            raise fail(
                f"checkpoint's optimizer_param_groups[{i}].params = {saved.get('params')!r}; this trainer's "
                f"optimizer has parameters {fresh['params']!r} (an index duplicated, missing or permuted)"
            )
    layout = _fresh_state_layout(optimizer)
    saved_keys = meta.get("optimizer_state_keys")
    if not isinstance(saved_keys, dict):
        raise fail("checkpoint's optimizer_state_keys must be a table: parameter index -> state keys")
    for index, keys in saved_keys.items():
        canonical = (
            isinstance(index, str) and index.isascii() and index.isdigit() and str(int(index)) == index
        )
        if not (canonical and int(index) in layout):
            raise fail(
                f"checkpoint's optimizer_state_keys has parameter index {index!r}; this trainer's optimizer "
                f"has parameters 0..{len(layout) - 1}"
            )
        want = layout[int(index)]
        if (
            not isinstance(keys, list)
            or not all(isinstance(k, str) for k in keys)
            or sorted(keys) != sorted(want)
        ):
            raise fail(
                f"checkpoint's optimizer state of parameter {index} has keys {keys!r}; "
                f"{type(optimizer).__name__} keeps {sorted(want)}"
            )
        for key, (shape, dtype) in want.items():
            name = f"optimizer.{index}.{key}"
            value = arrays.get(name)
            need = torch.empty(shape, dtype=dtype).numpy()
            if value is None:
                raise fail(f"checkpoint lacks the array {name!r} its optimizer_state_keys list")
            same_shape = value.shape == need.shape or value.size == need.size == 1  # () stored as [1]
            if not same_shape or value.dtype != need.dtype:
                raise fail(
                    f"checkpoint array {name!r} is {value.dtype}{list(value.shape)}; parameter {index} "
                    f"needs {need.dtype}{list(need.shape)}"
                )
            if not np.isfinite(value).all() or (key in _NON_NEGATIVE_STATE and (value < 0).any()):
                raise fail(f"checkpoint array {name!r} holds a non-finite or negative value")


def _number_in(value: Any, low: float, high: float, strict_high: bool = False) -> bool:
    """``value`` is an int or float (not a bool), finite, in [low, high] (or [low, high))."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return False
    return low <= value < high if strict_high else low <= value <= high


def load_trainer_state(trainer: Any, state: Snapshot) -> None:
    """Restore :meth:`state_dict`. Raises AmorError on a checkpoint of another shape or objective set."""
    meta, arrays = state.meta, state.arrays
    expect = {
        "obs_dim": trainer.env.obs_dim,
        "action_dim": trainer.env.action_dim,
        "objectives": list(trainer.names),
    }
    for key, value in expect.items():
        if meta.get(key) != value:
            raise AmorError(f"checkpoint has {key} = {meta.get(key)!r}, this environment has {value!r}")
    _check_optimizer_meta(meta, trainer.optimizer.param_groups)
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
        for key in EPISODE_STATS:
            setattr(trainer, key, torch.from_numpy(arrays[f"episodes.{key}"].copy()))
        if trainer.return_scale is not None:
            keys = trainer.return_scale.state()
            saved = {k: torch.from_numpy(arrays[f"return_scale.{k}"].copy()) for k in keys}
            trainer.return_scale.load_state(saved, int(meta["return_scale_updates"]))
        if trainer.feedback is not None:
            for key in FEEDBACK_ARRAYS:
                setattr(trainer.feedback, key, torch.from_numpy(arrays[f"feedback.{key}"].copy()))
    except (KeyError, RuntimeError, ValueError) as exc:
        raise AmorError(f"checkpoint does not fit this network configuration: {exc}") from None
    trainer.iteration_count = int(meta["iteration"])
    trainer.env_steps = int(meta["env_steps"])
    trainer.learning_rate = float(meta["learning_rate"])
    trainer.recent_ptr = int(meta["recent_ptr"])
    trainer.episodes = int(meta["episodes"])
