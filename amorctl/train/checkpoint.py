"""Checkpoints: one safetensors file of arrays plus one JSON file of metadata, never pickles.

``checkpoints/iter_000050.safetensors`` holds the trainer's arrays under ``trainer/...`` and the
env's under ``env/...``; ``iter_000050.json`` holds the metadata (iteration, character, backend,
objectives, the trainer's and env's JSON state) and the size and SHA-256 of the safetensors file.
Both are written atomically, the JSON last, so a checkpoint exists only once both are complete;
loading checks size and hash, so a truncated or altered file is reported, not half-loaded.
Loading reads tensors with ``safetensors`` and metadata with ``json``: no code is executed.
Before anything is used, :func:`check_record` checks the metadata's types and meaning (the
iteration is the file name's, a non-negative integer; the tensor file is a plain name inside the
checkpoint directory; sizes are positive integers; RNG states are valid numpy states; clip indices
are integers) and :func:`check_against_config` checks it against the run's config.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.random import MT19937, PCG64, PCG64DXSM, SFC64, Philox
from safetensors import SafetensorError
from safetensors.numpy import load_file, save

from amorctl.core.config import TrainConfig
from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_write_bytes, atomic_write_text, file_sha256

FORMAT = "amorctl-checkpoint/1"
_NAME = re.compile(r"^iter_(\d+)\.json$")
_TENSOR_NAME = re.compile(r"^[A-Za-z0-9_.-]+\.safetensors$")
_SHA256 = re.compile(r"^[0-9a-f]{64}$")
#: Key of the record's own SHA-256 (checkpoints written before it existed load without the check).
META_HASH = "meta_sha256"
_BIT_GENERATORS = {g.__name__: g for g in (PCG64, PCG64DXSM, Philox, SFC64, MT19937)}
#: Keys of env / trainer state that hold clip indices: lists of ints (or None).
_INDEX_LISTS = ("valid_clips", "env_clips", "clip_index", "clips")
#: Keys of env / trainer state that hold counts: non-negative ints.
_COUNTS = ("iteration", "env_steps", "episodes", "diverged_total", "obs_dim", "action_dim", "recent_ptr")


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


def record_sha256(record: dict[str, Any]) -> str:
    """SHA-256 of a checkpoint's JSON record without its own hash (canonical JSON: sorted keys)."""
    body = {k: v for k, v in record.items() if k != META_HASH}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def save_checkpoint(
    directory: Path, iteration: int, meta: dict[str, Any], trainer: Snapshot, env: Snapshot | None
) -> Path:
    """Write a checkpoint atomically; returns the JSON path.

    Raises:
        StorageError: the storage refused the write (disk full, ...): neither file is left behind
            and the older checkpoints are untouched.
    """
    tensors_path, json_path = checkpoint_paths(directory, iteration)
    arrays = {f"trainer/{k}": np.ascontiguousarray(v) for k, v in trainer.arrays.items()}
    if env is not None:
        arrays.update({f"env/{k}": np.ascontiguousarray(v) for k, v in env.arrays.items()})
    data = save(arrays, metadata={"format": FORMAT})
    atomic_write_bytes(tensors_path, data)  # a refused write (disk full) leaves no partial file
    record = {
        "format": FORMAT,
        "iteration": iteration,
        **meta,
        "trainer": trainer.meta,
        "env": None if env is None else env.meta,
        "tensors": {
            "file": tensors_path.name,
            "bytes": len(data),
            "sha256": hashlib.sha256(data).hexdigest(),
        },
    }
    record[META_HASH] = record_sha256(record)
    try:
        atomic_write_text(json_path, json.dumps(record, indent=1, sort_keys=True) + "\n")
    except BaseException:  # no JSON, no checkpoint: leave no orphan tensors file either
        tensors_path.unlink(missing_ok=True)
        raise
    return json_path


def list_checkpoints(directory: Path) -> list[tuple[int, Path]]:
    """(iteration, JSON path) of every checkpoint in ``directory``, oldest first."""
    if not directory.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in directory.iterdir() if (m := _NAME.match(p.name))]
    return sorted(found)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _check_state(path: Path, where: str, value: Any) -> None:
    """Walk a JSON state (trainer or env): RNG states, clip indices and counts must be well typed."""
    if isinstance(value, dict):
        if "bit_generator" in value:
            name = value.get("bit_generator")
            generator = _BIT_GENERATORS.get(name) if isinstance(name, str) else None
            if generator is None:
                raise AmorError(f"{path}: {where}: unknown random generator {value.get('bit_generator')!r}")
            try:
                generator().state = value
            except (TypeError, ValueError, KeyError, OverflowError) as exc:
                raise AmorError(f"{path}: {where}: not a valid random-generator state ({exc})") from None
            return
        for key, item in value.items():
            sub = f"{where}.{key}"
            if key in _COUNTS and not (_is_int(item) and item >= 0):
                raise AmorError(f"{path}: {sub} = {item!r} must be an integer >= 0")
            if (
                key in _INDEX_LISTS
                and item is not None
                and not (isinstance(item, list) and all(_is_int(i) and i >= 0 for i in item))
            ):
                raise AmorError(f"{path}: {sub} must be a list of clip indices (integers >= 0)")
            _check_state(path, sub, item)
    elif isinstance(value, list):
        for i, item in enumerate(value):
            _check_state(path, f"{where}[{i}]", item)
    elif isinstance(value, float) and not np.isfinite(value):
        raise AmorError(f"{path}: {where} = {value!r} is not finite")


def check_record(json_path: Path, record: Any) -> int:
    """Check a checkpoint's JSON record (types and meaning) before any of it is used.

    Returns:
        the iteration.

    Raises:
        AmorError: naming the file and the key: another format, an iteration that is not an
            integer >= 0 or not the file name's, a tensor file name with a directory part (``/abs``,
            ``..``), bad size/hash fields, run metadata of the wrong type, an invalid RNG state, or
            clip indices that are not integers.
    """
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        raise AmorError(f"{json_path}: not an amorctl checkpoint (format {FORMAT!r} expected)")
    iteration = record.get("iteration")
    if not _is_int(iteration) or iteration < 0:
        raise AmorError(f"{json_path}: 'iteration' = {iteration!r} must be an integer >= 0")
    named = _NAME.match(json_path.name)
    if named and int(named.group(1)) != iteration:
        raise AmorError(f"{json_path}: 'iteration' = {iteration} disagrees with the file name")
    info = record.get("tensors")
    if not isinstance(info, dict):
        raise AmorError(f"{json_path}: 'tensors' must be a table with file, bytes and sha256")
    name = info.get("file")
    if not isinstance(name, str) or not _TENSOR_NAME.match(name) or name.startswith("."):
        raise AmorError(
            f"{json_path}: tensors.file = {name!r} must be a plain *.safetensors name in the checkpoint "
            "directory (no directory part, no '..')"
        )
    if not _is_int(info.get("bytes")) or info["bytes"] <= 0:
        raise AmorError(f"{json_path}: tensors.bytes = {info.get('bytes')!r} must be a positive integer")
    if not isinstance(info.get("sha256"), str) or not _SHA256.match(info["sha256"]):
        raise AmorError(f"{json_path}: tensors.sha256 must be 64 lowercase hex digits")
    for key in ("backend", "env_kind"):
        if not isinstance(record.get(key), str):
            raise AmorError(f"{json_path}: {key!r} = {record.get(key)!r} must be a string")
    for key in ("character", "gym_id", "objective_set"):
        if record.get(key) is not None and not isinstance(record[key], str):
            raise AmorError(f"{json_path}: {key!r} = {record[key]!r} must be a string or null")
    objectives = record.get("objectives")
    if not isinstance(objectives, list) or not objectives or not all(isinstance(o, str) for o in objectives):
        raise AmorError(f"{json_path}: 'objectives' must be a non-empty list of names")
    for key in ("obs_dim", "action_dim"):
        if not _is_int(record.get(key)) or record[key] <= 0:
            raise AmorError(f"{json_path}: {key!r} = {record.get(key)!r} must be a positive integer")
    for key in ("trainer", "env"):
        if record.get(key) is not None and not isinstance(record[key], dict):
            raise AmorError(f"{json_path}: {key!r} must be a table (the {key}'s state)")
        _check_state(json_path, key, record.get(key))
    trainer_iteration = (record.get("trainer") or {}).get("iteration", iteration)
    if trainer_iteration != iteration:
        raise AmorError(
            f"{json_path}: trainer.iteration = {trainer_iteration!r} disagrees with 'iteration' = {iteration}"
        )
    return iteration


def load_checkpoint(json_path: Path) -> Checkpoint:
    """Read and verify a checkpoint.

    Raises:
        AmorError: the JSON or tensor file is missing, not JSON, of another format, fails
            :func:`check_record`, is truncated or altered (size or hash mismatch), or is not a
            valid safetensors file.
    """
    if not json_path.is_file():
        raise AmorError(f"{json_path}: checkpoint not found")
    try:
        record = json.loads(json_path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise AmorError(f"{json_path}: checkpoint metadata is not valid JSON (truncated?): {exc}") from None
    except RecursionError:
        raise AmorError(f"{json_path}: checkpoint metadata is nested too deeply") from None
    iteration = check_record(json_path, record)
    if META_HASH in record and record[META_HASH] != record_sha256(record):
        raise AmorError(
            f"{json_path}: checkpoint metadata was altered (it does not match its recorded SHA-256)"
        )
    info = record["tensors"]
    tensors_path = json_path.parent / info["file"]
    if not tensors_path.is_file():
        raise AmorError(f"{tensors_path}: checkpoint tensors file missing")
    size = tensors_path.stat().st_size
    if size != info["bytes"]:
        raise AmorError(
            f"{tensors_path}: checkpoint is truncated or altered ({size} bytes, {info['bytes']} expected)"
        )
    if file_sha256(tensors_path) != info["sha256"]:
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
    meta = {k: v for k, v in record.items() if k not in ("trainer", "env", "tensors", "format", META_HASH)}
    return Checkpoint(json_path, iteration, meta, trainer, env)


def _like(path: Path, where: str, want: Any, got: Any) -> None:
    """``got`` has the JSON structure of ``want``: the same keys, element and leaf types."""
    if isinstance(want, dict):
        if not isinstance(got, dict):
            raise AmorError(f"{path}: {where} must be a table, got {type(got).__name__}")
        if want and set(want) != set(got):
            diff = sorted(set(want) ^ set(got), key=str)[0]
            raise AmorError(f"{path}: {where}.{diff} is {'missing' if diff in want else 'unexpected'}")
        for key in want:
            _like(path, f"{where}.{key}", want[key], got[key])
    elif isinstance(want, list | tuple):  # torch keeps some lists (Adam's betas) as tuples
        if not isinstance(got, list):
            raise AmorError(f"{path}: {where} must be a list, got {type(got).__name__}")
        for i, item in enumerate(got):
            if want:
                _like(path, f"{where}[{i}]", want[min(i, len(want) - 1)], item)
    elif want is None:
        return
    elif isinstance(want, bool | str):
        if type(got) is not type(want):
            raise AmorError(f"{path}: {where} = {got!r} must be a {type(want).__name__}")
    elif isinstance(want, int):
        if not _is_int(got):
            raise AmorError(f"{path}: {where} = {got!r} must be an integer")
    elif isinstance(want, float):  # noqa: SIM102 - one branch per JSON type
        if isinstance(got, bool) or not isinstance(got, int | float) or not np.isfinite(got):
            raise AmorError(f"{path}: {where} = {got!r} must be a finite number")


def check_like(path: Path, where: str, expected: Snapshot, got: Snapshot, finite: bool = False) -> None:
    """Check a loaded state against the state a fresh trainer or env of this run has: the same
    JSON structure and types, and every expected array present with its shape and dtype (extra
    arrays, such as optimizer moments a fresh trainer lacks, are allowed). ``finite``: an array
    that is finite in the fresh state (networks, normalizer, optimizer) must be finite here too
    (arrays a fresh state fills with NaN, such as empty episode windows, are exempt).

    Raises:
        AmorError: naming ``path`` and the first key that differs.
    """
    _like(path, where, expected.meta, got.meta)
    for key, want in expected.arrays.items():
        have = got.arrays.get(key)
        if have is None:
            raise AmorError(f"{path}: {where} array {key!r} is missing")
        same_shape = have.shape == want.shape or have.size == want.size == 1  # () and [1]: one value
        if not same_shape or have.dtype != want.dtype:
            raise AmorError(
                f"{path}: {where} array {key!r} is {have.dtype}{list(have.shape)}, "
                f"this run needs {want.dtype}{list(want.shape)}"
            )
        numeric = want.dtype.kind in "fc"
        if finite and numeric and np.isfinite(want).all() and not np.isfinite(have).all():
            raise AmorError(
                f"{path}: {where} array {key!r} holds NaN or inf: the checkpoint is damaged; resume "
                "from another checkpoint or start anew"
            )


def check_against_config(ckpt: Checkpoint, config: TrainConfig, config_path: Path | str) -> None:
    """Raise AmorError if a checkpoint was made for another backend, env kind, character, gym id
    or objective set than the run's config (``config_path``, named in the message) says."""
    e = config.env
    expected: dict[str, Any] = {
        "backend": config.run.backend,
        "env_kind": e.kind,
        "character": e.character if e.kind == "tracking" else None,
        "gym_id": e.gym_id if e.kind == "gym" else None,
    }
    if "objective_set" in ckpt.meta:  # checkpoints written before it was recorded lack it
        expected["objective_set"] = e.objective_set if e.kind == "tracking" else None
    for key, want in expected.items():
        if ckpt.meta.get(key) != want:
            raise AmorError(
                f"{ckpt.path}: checkpoint was made for {key.replace('_', ' ')} {ckpt.meta.get(key)!r}, "
                f"the run's config ({config_path}) has {want!r}"
            )


def check_policy_sizes(ckpt: Checkpoint, obs_dim: int, action_dim: int, objectives: Any) -> None:
    """Raise AmorError if the networks stored in a checkpoint disagree with its metadata."""
    for key, got in (("obs_dim", obs_dim), ("action_dim", action_dim), ("objectives", list(objectives))):
        if ckpt.meta.get(key) != got:
            raise AmorError(
                f"{ckpt.path}: metadata says {key} = {ckpt.meta.get(key)!r}, its networks have {got!r}"
            )


def prune_checkpoints(directory: Path, keep: int) -> None:
    """Delete all but the ``keep`` newest checkpoints (``keep=0`` keeps all)."""
    if keep <= 0:
        return
    for iteration, json_path in list_checkpoints(directory)[:-keep]:
        tensors_path, _ = checkpoint_paths(directory, iteration)
        json_path.unlink(missing_ok=True)  # JSON first: a half-pruned checkpoint is never "found"
        tensors_path.unlink(missing_ok=True)
