"""Checks on an optimizer's state read back from a checkpoint, against a fresh optimizer of the
same kind: what MOPPO's and the HLP's resume both run before ``load_state_dict``. Without them an
edited (and re-hashed) checkpoint resumes and fails at the first optimizer step with torch's own
``KeyError`` / ``RuntimeError``.

The messages name ``where`` (e.g. ``"checkpoint's optimizer_param_groups"``) and end in what to do.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from amorctl.core.errors import AmorError

#: Adam's hyperparameters: the range each must lie in (``betas``: each entry).
ADAM_RANGES = {"lr": (0.0, 1.0), "betas": (0.0, 1.0), "eps": (0.0, 1.0), "weight_decay": (0.0, 1e6)}
#: Optimizer state that is never negative (Adam's step count and second moments).
NON_NEGATIVE_STATE = ("step", "exp_avg_sq", "max_exp_avg_sq")
DAMAGED = "the optimizer state is damaged; resume from another checkpoint or start anew"


def number_in(value: Any, low: float, high: float, strict_high: bool = False) -> bool:
    """``value`` is an int or float (not a bool), finite, in [low, high] (or [low, high))."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return False
    return low <= value < high if strict_high else low <= value <= high


def check_param_groups(saved: Any, optimizer: torch.optim.Optimizer, where: str) -> None:
    """Refuse saved parameter groups (hyperparameters, without ``params``) that differ in number or
    keys from ``optimizer``'s, or hold an Adam hyperparameter out of range (Adam accepts betas of
    1e308 and fails only mid-iteration)."""
    fresh_groups = optimizer.param_groups
    if not isinstance(saved, list) or len(saved) != len(fresh_groups):
        raise AmorError(f"{where} do not match this optimizer's ({len(fresh_groups)} group(s))")
    for i, (group, fresh) in enumerate(zip(saved, fresh_groups, strict=True)):
        if not isinstance(group, dict) or set(group) - {"params"} != set(fresh) - {"params"}:
            raise AmorError(f"{where}[{i}] has other keys than this optimizer's")
        for key, (low, high) in ADAM_RANGES.items():
            if key not in group:
                continue
            values = group[key] if key == "betas" and isinstance(group[key], list | tuple) else [group[key]]
            if key == "betas" and len(values) != 2:
                raise AmorError(f"{where}[{i}].betas = {group[key]!r}; expected 2 numbers")
            if not all(number_in(v, low, high, strict_high=key != "weight_decay") for v in values):
                raise AmorError(
                    f"{where}[{i}].{key} = {group[key]!r}; expected finite number(s) in [{low:g}, {high:g})"
                )


def fresh_state_layout(optimizer: torch.optim.Optimizer) -> dict[int, dict[str, tuple[tuple[int, ...], Any]]]:
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


def check_state(
    state: Mapping[str, Mapping[str, np.ndarray | None]],
    optimizer: torch.optim.Optimizer,
    array_name: Any,
) -> None:
    """Refuse per-parameter state a fresh ``optimizer`` would not have. ``state``: parameter index
    as written in the checkpoint (a string) -> state key -> array (None where the checkpoint lacks
    it). Refused: an index that is not a canonical integer of this optimizer's parameters (``"01"``,
    ``"9"`` of 9), a key set other than the optimizer's (Adam's ``exp_avg`` deleted), an array of
    another shape or dtype, a non-finite value, a negative step or second moment.
    ``array_name(index, key)``: how the checkpoint names that array, for the message."""
    layout = fresh_state_layout(optimizer)
    for index, slot in state.items():
        canonical = isinstance(index, str) and index.isascii() and index.isdigit()
        canonical = canonical and str(int(index)) == index
        if not (canonical and int(index) in layout):
            raise AmorError(
                f"optimizer state has parameter index {index!r}; this optimizer has parameters "
                f"0..{len(layout) - 1}: {DAMAGED}"
            )
        want = layout[int(index)]
        if sorted(slot) != sorted(want):
            raise AmorError(
                f"optimizer state of parameter {index} has keys {sorted(slot)!r}; "
                f"{type(optimizer).__name__} keeps {sorted(want)}: {DAMAGED}"
            )
        for key, (shape, dtype) in want.items():
            name, value = array_name(index, key), slot[key]
            need = torch.empty(shape, dtype=dtype).numpy()
            if value is None:
                raise AmorError(f"checkpoint lacks the optimizer array {name!r}: {DAMAGED}")
            same_shape = value.shape == need.shape or value.size == need.size == 1  # () stored as [1]
            if not same_shape or value.dtype != need.dtype:
                raise AmorError(
                    f"checkpoint array {name!r} is {value.dtype}{list(value.shape)}; parameter {index} "
                    f"needs {need.dtype}{list(need.shape)}: {DAMAGED}"
                )
            if not np.isfinite(value).all() or (key in NON_NEGATIVE_STATE and (value < 0).any()):
                raise AmorError(f"checkpoint array {name!r} holds a non-finite or negative value: {DAMAGED}")
