"""torch modules, optimizers and generators to and from :class:`~amorctl.core.contracts.Snapshot`
arrays (safetensors-ready numpy, no pickles)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from amorctl.core.errors import AmorError
from amorctl.core.optimizer_state import check_param_groups, check_state


def module_arrays(prefix: str, module: nn.Module) -> dict[str, np.ndarray]:
    """Parameters and buffers of ``module`` as ``{prefix/name: array}``."""
    return {f"{prefix}/{k}": v.detach().cpu().numpy().copy() for k, v in module.state_dict().items()}


def load_module(prefix: str, module: nn.Module, arrays: dict[str, np.ndarray]) -> None:
    """Inverse of :func:`module_arrays`; AmorError when a tensor is missing or of another shape."""
    own = module.state_dict()
    new = {}
    for key, cur in own.items():
        name = f"{prefix}/{key}"
        if name not in arrays:
            raise AmorError(f"HLP checkpoint has no array {name!r}")
        value = torch.as_tensor(np.asarray(arrays[name]))
        if value.numel() == cur.numel() == 1:  # safetensors may store a scalar as [1]
            value = value.reshape(cur.shape)
        if tuple(value.shape) != tuple(cur.shape):
            raise AmorError(
                f"HLP checkpoint array {name!r} has shape {tuple(value.shape)}, expected {tuple(cur.shape)}"
            )
        new[key] = value.to(cur.dtype)
    module.load_state_dict(new)


def optimizer_arrays(prefix: str, opt: torch.optim.Optimizer) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """An optimizer's per-parameter state as arrays plus its hyperparameters as JSON meta."""
    sd = opt.state_dict()
    arrays = {}
    for idx, st in sd["state"].items():
        for key, value in st.items():
            arrays[f"{prefix}/{idx}/{key}"] = torch.as_tensor(value).detach().cpu().numpy().copy()
    groups = [{k: v for k, v in g.items() if k != "params"} for g in sd["param_groups"]]
    return arrays, {"param_groups": groups}


def load_optimizer(
    prefix: str, opt: torch.optim.Optimizer, arrays: dict[str, np.ndarray], meta: dict[str, Any]
) -> None:
    """Inverse of :func:`optimizer_arrays`, after checking the saved hyperparameters and state
    against a fresh optimizer (:mod:`amorctl.core.optimizer_state`).

    Raises:
        AmorError: an array name that is not ``prefix/<parameter>/<key>``, or state or
            hyperparameters a fresh optimizer would not have (the checkpoint was edited).
    """
    check_param_groups(meta.get("param_groups"), opt, f"HLP checkpoint's {prefix} param_groups")
    saved: dict[str, dict[str, np.ndarray | None]] = {}
    for name, value in arrays.items():
        if not name.startswith(prefix + "/"):
            continue
        parts = name[len(prefix) + 1 :].split("/", 1)
        if len(parts) != 2:
            raise AmorError(f"HLP checkpoint array {name!r}: expected {prefix}/<parameter index>/<state key>")
        saved.setdefault(parts[0], {})[parts[1]] = np.asarray(value)
    check_state(saved, opt, lambda index, key: f"{prefix}/{index}/{key}")
    state = {
        int(index): {key: torch.as_tensor(value).clone() for key, value in slot.items()}
        for index, slot in saved.items()
    }
    fresh_groups = opt.state_dict()["param_groups"]
    groups = [{**g, "params": f["params"]} for f, g in zip(fresh_groups, meta["param_groups"], strict=True)]
    opt.load_state_dict({"state": state, "param_groups": groups})


def generator_array(gen: torch.Generator) -> np.ndarray:
    """A torch generator's state as uint8 [S]."""
    return gen.get_state().numpy().copy()


def load_generator(gen: torch.Generator, state: np.ndarray) -> None:
    gen.set_state(torch.as_tensor(np.asarray(state, dtype=np.uint8)))
