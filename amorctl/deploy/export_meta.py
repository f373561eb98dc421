"""The metadata and motions of a deploy bundle, gathered at export (docs/deploy.md lists every key).

Split from :mod:`amorctl.deploy.export` (which builds and checks the ONNX graph): here the
JSON-ready ``deploy.json`` content (also stored in the ONNX ``metadata_props``), the character's
model copied into the bundle with the files it reads and its licence (:func:`copy_model`, so the
bundle runs wherever it is, whatever package held the model), the objective set's plugin (so the
torch-free runtime can compute rewards) and the run's reference motions as ``motions.npz`` arrays.
"""

from __future__ import annotations

import dataclasses
import hashlib
import shutil
from collections.abc import Mapping
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from amorctl import __version__
from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import STATE_ARRAYS
from amorctl.core.specs import CharacterSpec, describe_model_source
from amorctl.deploy.bundle import FORMAT, MODEL_DIR, MOTIONS_FILE, OPSET, compiled_model_hash
from amorctl.registry import get_registry
from amorctl.sim.model_files import model_files
from amorctl.train.rundir import RunDir


def copy_model(spec: CharacterSpec, folder: Path, model_sha256: str) -> dict[str, object]:
    """Copy the character's model into ``folder/model/``: the MJCF, its includes and assets, and
    its licence files (:func:`amorctl.sim.model_files.model_files`), keeping their layout; check
    that the copy compiles to ``model_sha256``. Returns the ``character_model`` entries naming
    them (paths relative to the bundle, POSIX style).

    Raises:
        AmorError: a referenced file is missing or absolute, or the copy compiles differently.
    """
    found = model_files(spec.mjcf_path)
    dest = folder / MODEL_DIR
    digests: dict[str, str] = {}
    for src in (*found.files, *found.licences):
        rel = found.relative(src)
        out = dest / rel
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, out)
        digests[(Path(MODEL_DIR) / rel).as_posix()] = hashlib.sha256(out.read_bytes()).hexdigest()
    mjcf = (Path(MODEL_DIR) / found.relative(found.mjcf)).as_posix()
    copied = compiled_model_hash(dataclasses.replace(spec, mjcf_path=folder / mjcf))
    if copied != model_sha256:
        raise AmorError(
            f"{found.mjcf}: copied into the bundle with the {len(found.files)} files it reads, the model "
            f"compiles differently ({copied[:12]}… vs {model_sha256[:12]}…): it reads a file amorctl did "
            "not find; keep every file the model uses beside it (in its directory or below)"
        )
    return {
        "mjcf": mjcf,
        "model_files": digests,
        "licence_files": [(Path(MODEL_DIR) / found.relative(p)).as_posix() for p in found.licences],
        "licence": spec.licence,
        "model_source": describe_model_source(spec.model_source),
    }


def objective_set_location(name: str | None) -> dict[str, Any] | None:
    """``{"name", "plugin"}``: the objective set and the entry point (plugin) that registered it,
    so the runtime loads only that plugin to compute rewards (None: the run has no objective set
    plugin, e.g. the toy envs)."""
    if not name:
        return None
    for row in get_registry().provided:
        if row.kind == "objective-set" and row.name == name:
            return {"name": name, "plugin": row.plugin}
    raise AmorError(f"objective set {name!r} of the run is not installed")


def motions_arrays(run: RunDir) -> dict[str, np.ndarray]:
    """The run's motion library as the bundle's ``motions.npz`` arrays (docs/deploy.md)."""
    from amorctl.motion.dataset import load_dataset

    lib = load_dataset(run.dataset_path())
    out = {
        "frames": np.asarray(lib.frames, dtype=np.float32),
        "z": np.asarray(lib.z, dtype=np.float32),
    }
    for key in STATE_ARRAYS:
        out[key] = np.asarray(getattr(lib, key), dtype=np.float64)
    out["clip_starts"] = lib.starts.astype(np.int64)
    out["clip_lengths"] = lib.lengths.astype(np.int64)
    out["clip_names"] = np.array([c.name for c in lib.clips], dtype=np.str_)
    return out


def write_motions(folder: Path, run: RunDir, layout: Mapping[str, Any]) -> dict[str, Any]:
    """Write the run's reference motions to ``folder/motions.npz``; return the metadata naming it.

    Raises:
        AmorError: the dataset's frames do not fit the policy's ``ref_frame`` input.
    """
    arrays = motions_arrays(run)
    if arrays["frames"].shape[1] != layout["ref_frame"][1] - layout["ref_frame"][0]:
        raise AmorError("the run's dataset frames do not fit the policy's ref_frame input")
    np.savez(folder / MOTIONS_FILE, **arrays)
    digest = hashlib.sha256((folder / MOTIONS_FILE).read_bytes()).hexdigest()
    return {"file": MOTIONS_FILE, "sha256": digest, "clips": arrays["clip_names"].tolist()}


def _action_meta(action_mode: str, out_name: str, ref: tuple[int, int, int] | None, clamp: bool, units: bool):
    return {
        "mode": action_mode,
        "output": out_name,
        "pd_target": (
            "q* = clamp(ref_frame[joint_pos] + action, joint_ranges)"
            if action_mode == "residual"
            else "q* = clamp(action, joint_ranges)"
            if action_mode == "absolute"
            else None
        ),
        "reference_columns": None if ref is None else {"input": "ref_frame", "start": ref[1], "stop": ref[2]},
        "clamp": "joint_ranges" if clamp else None,
        "units": "rad" if units else None,
    }


def bundle_metadata(
    *,
    run: RunDir,
    iteration: int,
    objectives: list[str],
    inputs: dict[str, Any],
    outputs: dict[str, Any],
    layout: dict[str, tuple[int, int]],
    action_mode: str,
    out_names: list[str],
    ref: tuple[int, int, int] | None,
    spec: CharacterSpec | None,
    fall_drop: float | None,
    context_inputs: list[str],
    future_offsets: list[int],
    parity: dict[str, Any],
) -> dict[str, Any]:
    """``deploy.json`` (without ``motions``, which the exporter fills once ``motions.npz`` is
    written); every key of :data:`amorctl.deploy.bundle.METADATA_KEYS`."""
    joints = list(spec.joint_names()) if spec else []
    objective_set = run.config.env.objective_set if spec is not None else None
    return {
        "format": FORMAT,
        "amorctl_version": __version__,
        "run": str(run.path),
        "iteration": int(iteration),
        "objectives": objectives,
        "objective_set": objective_set_location(objective_set),
        "inputs": inputs,
        "outputs": outputs,
        "observation_layout": {k: [int(a), int(b)] for k, (a, b) in layout.items()},
        "action": _action_meta(action_mode, out_names[0], ref, spec is not None, bool(joints)),
        "joint_names": joints,
        "joint_ranges": [[float(j.range[0]), float(j.range[1])] for j in spec.joints] if spec else [],
        "pd_gains": {"kp": [j.kp for j in spec.joints], "kd": [j.kd for j in spec.joints]} if spec else None,
        "torque_limits": [j.torque_limit for j in spec.joints] if spec else [],
        "actuator_model": asdict(spec.actuator) if spec else None,
        "default_pose": [float(spec.standing_pose.get(j, 0.0)) for j in joints] if spec else [],
        "control_hz": spec.control_hz if spec else None,
        "physics_hz": spec.physics_hz if spec else None,
        "character": spec.name if spec else None,
        "model_sha256": compiled_model_hash(spec) if spec else None,
        "character_model": (
            {  # copy_model adds where the model is in the bundle, once it is written
                "root_body": spec.root_body,
                "end_effectors": list(spec.end_effectors),
                "joint_groups": [j.group for j in spec.joints],
                "standing_height": spec.standing_height,
                "min_standing_height": spec.min_standing_height,
                "scale_profile": spec.scale_profile,
                "objective_scales": {k: dict(v) for k, v in spec.objective_scales.items()},
            }
            if spec
            else None
        ),
        "termination": {"fall_height_drop": fall_drop} if spec else None,
        "context": {
            "inputs": context_inputs,
            "future_frame_offsets": future_offsets,
            "next_frame": "context of the step from s_t is the reference frame t+1 and its latent",
            "clip_end": "the reference restarts its clip at the first frame after the last",
        },
        "motions": None,
        "opset": OPSET,
        "parity": parity,
    }
