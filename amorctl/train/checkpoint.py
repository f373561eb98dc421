"""Checkpoints: one safetensors file of arrays plus one JSON file of metadata, never pickles.

``checkpoints/iter_000050.safetensors`` holds the trainer's arrays under ``trainer/...`` and the
env's under ``env/...``; ``iter_000050.json`` holds the metadata (iteration, character, backend,
objectives, the trainer's and env's JSON state) and the size and SHA-256 of the safetensors file.
Both are written atomically, the JSON last, so a checkpoint exists only once both are complete;
loading checks size and hash, so a truncated or altered file is reported, not half-loaded.
Loading reads tensors with ``safetensors`` and metadata with ``json``: no code is executed.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from safetensors import SafetensorError
from safetensors.numpy import load_file, save_file

from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_path, atomic_write_text

FORMAT = "amorctl-checkpoint/1"
_NAME = re.compile(r"^iter_(\d+)\.json$")


@dataclass
class Checkpoint:
    """A loaded checkpoint."""

    path: Path  # the JSON file
    iteration: int
    meta: dict[str, Any]  # run metadata: character, backend, objectives, config kind, ...
    trainer: Snapshot
    env: Snapshot | None  # None when the env could not snapshot itself


def checkpoint_paths(directory: Path, iteration: int) -> tuple[Path, Path]:
    """(safetensors path, JSON path) of the checkpoint of ``iteration``."""
    stem = directory / f"iter_{iteration:06d}"
    return stem.with_suffix(".safetensors"), stem.with_suffix(".json")


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def save_checkpoint(
    directory: Path, iteration: int, meta: dict[str, Any], trainer: Snapshot, env: Snapshot | None
) -> Path:
    """Write a checkpoint atomically; returns the JSON path."""
    tensors_path, json_path = checkpoint_paths(directory, iteration)
    arrays = {f"trainer/{k}": np.ascontiguousarray(v) for k, v in trainer.arrays.items()}
    if env is not None:
        arrays.update({f"env/{k}": np.ascontiguousarray(v) for k, v in env.arrays.items()})
    with atomic_path(tensors_path) as tmp:
        save_file(arrays, str(tmp), metadata={"format": FORMAT})
    record = {
        "format": FORMAT,
        "iteration": iteration,
        **meta,
        "trainer": trainer.meta,
        "env": None if env is None else env.meta,
        "tensors": {
            "file": tensors_path.name,
            "bytes": tensors_path.stat().st_size,
            "sha256": _sha256(tensors_path),
        },
    }
    atomic_write_text(json_path, json.dumps(record, indent=1, sort_keys=True) + "\n")
    return json_path


def list_checkpoints(directory: Path) -> list[tuple[int, Path]]:
    """(iteration, JSON path) of every checkpoint in ``directory``, oldest first."""
    if not directory.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in directory.iterdir() if (m := _NAME.match(p.name))]
    return sorted(found)


def load_checkpoint(json_path: Path) -> Checkpoint:
    """Read and verify a checkpoint.

    Raises:
        AmorError: the JSON or tensor file is missing, not JSON, of another format, truncated or
            altered (size or hash mismatch), or not a valid safetensors file.
    """
    if not json_path.is_file():
        raise AmorError(f"{json_path}: checkpoint not found")
    try:
        record = json.loads(json_path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise AmorError(f"{json_path}: checkpoint metadata is not valid JSON (truncated?): {exc}") from None
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        raise AmorError(f"{json_path}: not an amorctl checkpoint (format {FORMAT!r} expected)")
    info = record.get("tensors", {})
    tensors_path = json_path.parent / str(info.get("file", ""))
    if not tensors_path.is_file():
        raise AmorError(f"{tensors_path}: checkpoint tensors file missing")
    size = tensors_path.stat().st_size
    if size != info.get("bytes"):
        raise AmorError(
            f"{tensors_path}: checkpoint is truncated or altered ({size} bytes, {info.get('bytes')} expected)"
        )
    if _sha256(tensors_path) != info.get("sha256"):
        raise AmorError(f"{tensors_path}: checkpoint content does not match its recorded SHA-256")
    try:
        arrays = load_file(str(tensors_path))
    except (SafetensorError, OSError, ValueError) as exc:
        raise AmorError(f"{tensors_path}: not a valid safetensors file: {exc}") from None
    trainer = Snapshot(
        {k[8:]: v for k, v in arrays.items() if k.startswith("trainer/")}, record.get("trainer") or {}
    )
    env = None
    if record.get("env") is not None:
        env = Snapshot({k[4:]: v for k, v in arrays.items() if k.startswith("env/")}, record["env"])
    meta = {k: v for k, v in record.items() if k not in ("trainer", "env", "tensors", "format")}
    return Checkpoint(json_path, int(record["iteration"]), meta, trainer, env)


def prune_checkpoints(directory: Path, keep: int) -> None:
    """Delete all but the ``keep`` newest checkpoints (``keep=0`` keeps all)."""
    if keep <= 0:
        return
    for iteration, json_path in list_checkpoints(directory)[:-keep]:
        tensors_path, _ = checkpoint_paths(directory, iteration)
        json_path.unlink(missing_ok=True)  # JSON first: a half-pruned checkpoint is never "found"
        tensors_path.unlink(missing_ok=True)
