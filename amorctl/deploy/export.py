"""``amorctl deploy export``: a run's policy as an ONNX bundle whose weights are an input.

The torch module that is exported is rebuilt from :meth:`Policy.export_arrays` (backend-neutral
names), so any backend's policy exports: normalizer ``clip((x - mean) / scale, -c, c)``, the
actor MLP's deterministic mean, then the PD targets (``ref_frame``'s next-frame joint angles +
action in residual mode, the action itself in absolute mode), clamped to the joint ranges. The
observation is fed as separate named inputs: ``obs`` (every part that is neither context nor
weights, in observation order), one input per context part (``ref_frame``, ``latent``,
``future_frames``) and ``w``. Exported with the TorchScript exporter (``dynamo=False``) at
opset :data:`~amorctl.deploy.bundle.OPSET` with a dynamic batch axis; the bundle is built in a
temporary directory and renamed into place only after onnxruntime reproduces the torch policy
(parity check), so a failed export writes nothing.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from amorctl import __version__
from amorctl.core.contracts import Policy, Snapshot, tracking_view
from amorctl.core.errors import AmorError
from amorctl.core.specs import CharacterSpec
from amorctl.core.vecenv import close_env
from amorctl.core.weights import sample_dirichlet
from amorctl.deploy.bundle import (
    CONTEXT_PARTS,
    META_FILE,
    ONNX_FILE,
    OPSET,
    open_session,
    part_element_names,
)
from amorctl.deploy.export_meta import bundle_metadata, copy_model, write_motions
from amorctl.train.rundir import RunDir

#: largest |onnxruntime - torch| the export accepts (PD targets and raw actions, rad).
PARITY_TOLERANCE = 1e-5
#: random observations of the parity check (plus the m simplex corners and the uniform weights).
PARITY_SAMPLES = 1024
#: offset of the joint angles inside a frame vector (h [1], root_rot6d [6], root_vel [6]).
FRAME_JOINT_OFFSET = 13


@dataclasses.dataclass
class ExportResult:
    """What an export wrote and measured."""

    out: Path
    iteration: int
    inputs: dict[str, list[Any]]
    outputs: dict[str, list[Any]]
    parity_max_abs: float
    parity_samples: int
    onnx_bytes: int
    model_files: int = 0  # files of the character's model copied into the bundle (licence included)


# ---------------------------------------------------------------------------- env facts


@dataclasses.dataclass
class EnvFacts:
    """What export needs to know about a run's env beyond the policy."""

    layout: dict[str, tuple[int, int]]
    character: CharacterSpec | None
    fall_drop: float | None
    future_offsets: list[int]


def _env_facts(env: Any) -> EnvFacts:
    """The observation layout, character, fall drop (m) and future-frame offsets of a run's env,
    read through its :class:`~amorctl.core.contracts.TrackingView` (empty for envs without one)."""
    view = tracking_view(env)
    if view is None:
        return EnvFacts({}, None, None, [])
    layout = {k: (int(a), int(b)) for k, (a, b) in view.observation_layout.items()}
    return EnvFacts(layout, view.character, float(view.fall_drop), [int(o) for o in view.future_frames])


# ---------------------------------------------------------------------------- policy arrays


def policy_arrays(snap: Snapshot) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """A policy's ``export_arrays()`` as (arrays, meta), checked for the backend-neutral names
    (``normalizer/mean``, ``normalizer/scale``, ``actor/<i>/weight``..., documented in
    :mod:`amorctl.plugins.backends.torch_cpu.policy`) that every backend hands out."""
    arrays, meta = dict(snap.arrays), dict(snap.meta)
    missing = [k for k in ("normalizer/mean", "normalizer/scale", "actor/0/weight") if k not in arrays]
    if missing:
        raise AmorError(f"the policy's export_arrays() has no {', '.join(missing)} (backend-neutral names)")
    return arrays, meta


# ---------------------------------------------------------------------------- the torch module


class ExportModule(nn.Module):
    """The deterministic policy as a function of named inputs (module docstring).

    Args:
        arrays, meta: :meth:`Policy.export_arrays`.
        pieces: for each observation part, in observation order, (input index, start, stop) of
            its columns inside that input.
        action_mode: ``"residual"``, ``"absolute"`` or ``"raw"`` (no character: the action only).
        ref: (input index, start, stop) of the next-frame joint angles (residual mode).
        low, high: [A] joint ranges (rad) the PD targets are clamped to.
    """

    def __init__(
        self,
        arrays: Mapping[str, np.ndarray],
        meta: Mapping[str, Any],
        pieces: list[tuple[int, int, int]],
        action_mode: str,
        ref: tuple[int, int, int] | None,
        low: np.ndarray | None,
        high: np.ndarray | None,
    ) -> None:
        super().__init__()
        if meta.get("activation") != "elu":
            raise AmorError(f"policy activation {meta.get('activation')!r} is not supported by the exporter")
        self.pieces, self.action_mode, self.ref = pieces, action_mode, ref
        t = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float32))  # noqa: E731
        self.register_buffer("mean", t(arrays["normalizer/mean"]))
        self.register_buffer("scale", t(arrays["normalizer/scale"]))
        self.clip = float(meta["obs_clip"])
        layers: list[nn.Module] = []
        n = int(meta["actor_layers"])
        for i in range(n):
            w, b = t(arrays[f"actor/{i}/weight"]), t(arrays[f"actor/{i}/bias"])
            lin = nn.Linear(w.shape[1], w.shape[0])
            lin.weight.data.copy_(w)
            lin.bias.data.copy_(b)
            layers.append(lin)
            if i < n - 1:
                layers.append(nn.ELU())
        self.net = nn.Sequential(*layers)
        self.has_limits = low is not None and high is not None
        self.register_buffer("low", t(low if low is not None else np.zeros(0)))
        self.register_buffer("high", t(high if high is not None else np.zeros(0)))

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        obs = torch.cat([inputs[k][:, a:b] for k, a, b in self.pieces], dim=1)
        x = torch.clamp((obs - self.mean) / self.scale, -self.clip, self.clip)
        action = self.net(x)
        if self.action_mode == "raw":
            return (action,)
        target = action
        if self.action_mode == "residual" and self.ref is not None:
            k, a, b = self.ref
            target = inputs[k][:, a:b] + action
        if self.has_limits:
            target = torch.minimum(torch.maximum(target, self.low), self.high)
        return target, action


# ---------------------------------------------------------------------------- signature


def plan_inputs(
    layout: Mapping[str, tuple[int, int]], obs_dim: int, m: int
) -> tuple[dict[str, list[tuple[str, int, int]]], list[tuple[int, int, int]]]:
    """The ONNX inputs for an observation layout.

    Returns ({input name: [(part, start, stop) in the observation]}, pieces for
    :class:`ExportModule`). Input order: ``obs``, the context parts present, ``w``.
    """
    parts = sorted(((a, b, name) for name, (a, b) in layout.items() if b > a), key=lambda p: p[0])
    covered = sum(b - a for a, b, _ in parts)
    if covered != obs_dim or parts[-1][1] != obs_dim or parts[-1][1] - parts[-1][0] != m:
        raise AmorError(f"observation layout {dict(layout)} does not tile the {obs_dim} observation entries")
    groups: dict[str, list[tuple[str, int, int]]] = {"obs": []}
    for a, b, name in parts[:-1]:
        groups.setdefault(name if name in CONTEXT_PARTS else "obs", []).append((name, a, b))
    groups["w"] = [(parts[-1][2], parts[-1][0], parts[-1][1])]
    if not groups["obs"]:
        del groups["obs"]
    order = list(groups)
    located: dict[str, tuple[int, int, int]] = {}
    for name in order:
        col = 0
        for part, a, b in groups[name]:
            located[part] = (order.index(name), col, col + b - a)
            col += b - a
    pieces = [located[name] for _, _, name in parts]
    return groups, pieces


def split_observation(
    obs: np.ndarray, groups: Mapping[str, list[tuple[str, int, int]]]
) -> dict[str, np.ndarray]:
    """Cut full observations [B, D] into the ONNX inputs {name: [B, n]} float32."""
    return {
        name: np.concatenate([obs[:, a:b] for _, a, b in parts], axis=1).astype(np.float32)
        for name, parts in groups.items()
    }


# ---------------------------------------------------------------------------- parity


def parity_observations(
    mean: np.ndarray, scale: np.ndarray, m: int, samples: int, seed: int = 0
) -> np.ndarray:
    """[samples + m + 1, D] float32 random observations around the normalizer's statistics
    (±3 standard deviations, some beyond the clip) whose weights are the m simplex corners, the
    uniform vector and Dirichlet(1) draws."""
    rng = np.random.default_rng(seed)
    n = samples + m + 1
    obs = mean + scale * rng.normal(0.0, 3.0, size=(n, mean.shape[0]))
    draws = sample_dirichlet(rng, samples, m, dtype=np.float64)  # [samples, m]
    w = np.concatenate([np.eye(m), np.full((1, m), 1.0 / m), draws])
    obs[:, -m:] = w
    return obs.astype(np.float32)


def reference_outputs(
    policy: Callable[[np.ndarray], np.ndarray],
    obs: np.ndarray,
    action_mode: str,
    ref_cols: tuple[int, int] | None,
    low: np.ndarray | None,
    high: np.ndarray | None,
) -> dict[str, np.ndarray]:
    """What the exported graph must output, computed from the torch policy in float64."""
    action = np.asarray(policy(obs), dtype=np.float64)
    if action_mode == "raw":
        return {"action": action}
    target = action.copy()
    if action_mode == "residual" and ref_cols is not None:
        target = obs[:, ref_cols[0] : ref_cols[1]].astype(np.float64) + action
    if low is not None and high is not None:
        target = np.clip(target, low, high)
    return {"pd_target": target, "action": action}


# ---------------------------------------------------------------------------- export


def _check_out(out: Path) -> None:
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise AmorError(f"{out}: already exists; choose a new --out directory or remove it")
    if not out.parent.is_dir():
        raise AmorError(f"{out}: directory {out.parent} does not exist")


@dataclasses.dataclass(frozen=True)
class ActionPlan:
    """How the exported graph turns the policy's action into its outputs.

    mode: ``"raw"`` (the action as is; no character) or the run's ``env.action_mode``; low/high:
    [J] joint ranges (clip of the PD target); ref: (index of the ``ref_frame`` input, first and
    last column of its joint angles) for residual actions; ref_cols: those columns in the whole
    observation; joints/ees: the character's joint and end-effector names (empty without one).
    """

    mode: str = "raw"
    low: np.ndarray | None = None
    high: np.ndarray | None = None
    ref: tuple[int, int, int] | None = None
    ref_cols: tuple[int, int] | None = None
    joints: list[str] = dataclasses.field(default_factory=list)
    ees: list[str] = dataclasses.field(default_factory=list)


def _action_plan(
    spec: CharacterSpec | None, action_mode: str, layout: Mapping[str, Any], groups: Mapping[str, Any]
) -> ActionPlan:
    """The :class:`ActionPlan` of a policy for ``spec`` (None: an env without a character).

    Raises:
        AmorError: a residual-action policy without a ``ref_frame`` in its observation.
    """
    if spec is None:
        return ActionPlan()
    joints, ees = list(spec.joint_names()), list(spec.end_effectors)
    low = np.array([j.range[0] for j in spec.joints])
    high = np.array([j.range[1] for j in spec.joints])
    ref, ref_cols = None, None
    if action_mode == "residual":
        if "ref_frame" not in layout:
            raise AmorError(
                "residual-action policy without a ref_frame in its observation cannot be exported"
            )
        a = layout["ref_frame"][0] + FRAME_JOINT_OFFSET
        ref_cols = (a, a + len(joints))
        k = list(groups).index("ref_frame")
        ref = (k, FRAME_JOINT_OFFSET, FRAME_JOINT_OFFSET + len(joints))
    return ActionPlan(action_mode, low, high, ref, ref_cols, joints, ees)


def _io_tables(
    groups: Mapping[str, Any],
    out_names: list[str],
    joints: list[str],
    ees: list[str],
    names: list[str],
    action_dim: int,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The bundle's ``inputs`` and ``outputs`` tables: per ONNX input its shape, the observation
    parts it holds (``[start, stop)``) and element names; per output its shape and element names."""
    inputs = {
        name: {
            "shape": ["batch", sum(b - a for _, a, b in parts)],
            "parts": {p: [a, b] for p, a, b in parts},
            "elements": [e for p, a, b in parts for e in part_element_names(p, b - a, joints, ees, names)],
        }
        for name, parts in groups.items()
    }
    outputs = {
        n: {"shape": ["batch", action_dim], "elements": joints or [f"action/{i}" for i in range(action_dim)]}
        for n in out_names
    }
    return inputs, outputs


def _store_metadata(onnx_path: Path, meta: Mapping[str, Any]) -> None:
    """Write ``meta`` into the ONNX file's metadata (each value as JSON), checked, in place."""
    import onnx

    model = onnx.load(str(onnx_path))
    del model.metadata_props[:]
    for key, value in meta.items():
        prop = model.metadata_props.add()
        prop.key, prop.value = key, json.dumps(value)
    model.producer_name, model.producer_version = "amorctl", __version__
    onnx.checker.check_model(model)
    onnx.save(model, str(onnx_path))


def _export_checked(
    module: nn.Module,
    onnx_path: Path,
    input_names: list[str],
    out_names: list[str],
    feeds: Mapping[str, np.ndarray],
    want: Mapping[str, np.ndarray],
    tolerance: float,
) -> float:
    """Export ``module`` to ``onnx_path`` and run it in onnxruntime on ``feeds`` (per input [K, d]).

    Returns:
        The largest absolute difference from the torch policy's outputs ``want``.

    Raises:
        AmorError: that difference is over ``tolerance`` (or not finite).
    """
    example = tuple(torch.from_numpy(feeds[n][:2]) for n in input_names)
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            module,
            example,
            str(onnx_path),
            dynamo=False,
            opset_version=OPSET,
            input_names=input_names,
            output_names=out_names,
            dynamic_axes={n: {0: "batch"} for n in [*input_names, *out_names]},
        )
    got = dict(zip(out_names, open_session(onnx_path).run(out_names, dict(feeds)), strict=True))
    delta = max(float(np.max(np.abs(got[n].astype(np.float64) - want[n]))) for n in out_names)
    if not np.isfinite(delta) or delta > tolerance:
        samples = len(next(iter(feeds.values())))
        raise AmorError(
            f"export parity check failed: onnxruntime differs from the torch policy by {delta:.3g} "
            f"(tolerance {tolerance:g}) on {samples} observations; nothing written"
        )
    return delta


def export_bundle(
    run_path: str | Path,
    out: str | Path,
    iteration: int | None = None,
    *,
    samples: int = PARITY_SAMPLES,
    tolerance: float = PARITY_TOLERANCE,
    data: str | Path | None = None,
) -> ExportResult:
    """Export the policy of ``run_path`` (checkpoint ``iteration``, default the newest) to ``out``.
    ``data``: where the run's dataset is now, if it moved (the same file: its SHA-256 is checked).

    Raises:
        AmorError: no run or checkpoint, ``out`` exists, ``data`` is not the run's dataset, the
            policy cannot be exported, or the onnxruntime/torch parity check fails (nothing is
            written then).
    """
    out = Path(out)
    _check_out(out)
    run = RunDir.open(run_path)
    if data is not None:
        run.relocate_dataset(data, required="a bundle carries the clips the run trained on")
    ckpt = run.checkpoint(iteration)
    policy: Policy = run.policy_of(ckpt)
    arrays, snap_meta = policy_arrays(policy.export_arrays())
    names = list(policy.objectives)
    m, obs_dim = len(names), int(policy.obs_dim)

    env = run.env(num_envs=1)
    try:
        facts = _env_facts(env)
    finally:
        close_env(env)
    layout, spec, fall_drop = facts.layout, facts.character, facts.fall_drop
    if not layout:
        layout = dict(policy.observation_layout)
    groups, pieces = plan_inputs(layout, obs_dim, m)

    plan = _action_plan(spec, run.config.env.action_mode, layout, groups)
    action_mode, low, high, ref, ref_cols = plan.mode, plan.low, plan.high, plan.ref, plan.ref_cols
    module = ExportModule(arrays, snap_meta, pieces, action_mode, ref, low, high).eval()
    out_names = ["action"] if action_mode == "raw" else ["pd_target", "action"]
    inputs, outputs = _io_tables(groups, out_names, plan.joints, plan.ees, names, policy.action_dim)

    obs = parity_observations(arrays["normalizer/mean"], arrays["normalizer/scale"], m, samples)
    want = reference_outputs(policy, obs, action_mode, ref_cols, low, high)
    feeds = split_observation(obs, groups)

    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        onnx_path = tmp / ONNX_FILE
        delta = _export_checked(module, onnx_path, list(groups), out_names, feeds, want, tolerance)
        meta = bundle_metadata(
            run=run,
            iteration=int(ckpt.iteration),
            objectives=names,
            inputs=inputs,
            outputs=outputs,
            layout=layout,
            action_mode=action_mode,
            out_names=out_names,
            ref=ref,
            spec=spec,
            fall_drop=fall_drop,
            context_inputs=[n for n in groups if n in CONTEXT_PARTS],
            future_offsets=facts.future_offsets,
            parity={"max_abs": delta, "samples": len(obs), "tolerance": tolerance},
        )
        if spec is not None:
            meta["motions"] = write_motions(tmp, run, layout)
            meta["character_model"].update(copy_model(spec, tmp, meta["model_sha256"]))
        _store_metadata(onnx_path, meta)
        (tmp / META_FILE).write_text(json.dumps(meta, indent=1) + "\n")
        umask = os.umask(0)
        os.umask(umask)
        tmp.chmod(0o777 & ~umask)  # mkdtemp makes it private; the bundle is an ordinary directory
        if out.exists():
            out.rmdir()  # checked empty above
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return ExportResult(
        out=out,
        iteration=int(ckpt.iteration),
        inputs={k: v["shape"] for k, v in inputs.items()},
        outputs={k: v["shape"] for k, v in outputs.items()},
        parity_max_abs=delta,
        parity_samples=len(obs),
        onnx_bytes=(out / ONNX_FILE).stat().st_size,
        model_files=len((meta.get("character_model") or {}).get("model_files", {})),
    )
