"""Reading a motion dataset file: every record parsed, every array decoded, shaped, checked
against the metadata and its recorded SHA-256, once, in :func:`load_dataset`.

Any damage a file can carry ends as one ``AmorError`` naming the file (and the key, clip or array).
The file layout is described in :mod:`amorctl.motion.dataset` and ``docs/dataset.md``.
"""

from __future__ import annotations

import binascii
import hashlib
import json
import math
import struct
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader

from amorctl.core.errors import AmorError, AmorWarning
from amorctl.motion.clips import ClipInfo, MotionLibrary
from amorctl.motion.dataset_schema import (
    ARRAYS,
    CHANNEL,
    ENCODER_ATTACHMENT,
    FORMAT,
    HASHES_KEY,
    MAX_CLIP_FRAMES,
    MAX_FPS,
    METADATA_HASH,
    METADATA_HASH_VERSION,
    OLDEST_VERSION,
    VERSION,
    array_sha256,
    check_library,
    decode_array,
    expected_shapes,
    metadata_sha256,
)

try:
    from zstandard import ZstdError

    _ZSTD_ERRORS: tuple[type[Exception], ...] = (ZstdError,)
except ImportError:  # pragma: no cover - mcap's zstd chunks need it, but a reader may lack it
    _ZSTD_ERRORS = ()


def _open_reader(path: Path):  # type: ignore[no-untyped-def]
    if not path.is_file():
        raise AmorError(f"{path}: dataset not found")
    f = open(path, "rb")  # noqa: SIM115 - closed by the caller
    try:
        return f, make_reader(f, validate_crcs=True)
    except _READ_ERRORS as exc:
        f.close()
        raise AmorError(f"{path}: not a readable MCAP file: {exc}") from None


#: What a damaged file can raise while being read (MCAP records, zstd, JSON, base64, numpy).
_READ_ERRORS = (
    McapError,
    ValueError,
    KeyError,
    TypeError,
    IndexError,
    AttributeError,
    EOFError,
    OSError,
    OverflowError,
    MemoryError,
    RecursionError,
    binascii.Error,
    struct.error,
    *_ZSTD_ERRORS,
)


def read_dataset_metadata(path: str | Path) -> dict[str, str]:
    """The ``amorctl.dataset`` metadata record of a dataset file."""
    path = Path(path)
    f, reader = _open_reader(path)
    with f:
        try:
            for rec in reader.iter_metadata():
                if rec.name == "amorctl.dataset":
                    meta = dict(rec.metadata)
                    if meta.get("format") != FORMAT:
                        break
                    return meta
        except _READ_ERRORS as exc:
            raise AmorError(f"{path}: not a readable MCAP file: {type(exc).__name__}: {exc}") from None
    raise AmorError(f"{path}: not an amorctl motion dataset (no {FORMAT} metadata)")


def _parse_meta(path: Path, meta: dict[str, str]) -> dict[str, Any]:
    """The dataset record's values, parsed and checked; AmorError naming the file and the key."""

    def fail(key: str, what: str) -> AmorError:
        return AmorError(f"{path}: dataset metadata {key!r} = {meta.get(key)!r} {what}")

    try:
        version = int(meta.get("version", ""))
    except ValueError:
        raise fail("version", "is not an integer") from None
    if version > VERSION:
        raise AmorError(f"{path}: dataset version {version} is newer than this amorctl supports ({VERSION})")
    if version < OLDEST_VERSION:
        raise fail("version", f"is not a version this amorctl reads ({OLDEST_VERSION}..{VERSION})")
    try:
        fps = float(meta.get("fps", ""))
    except ValueError:
        raise fail("fps", "is not a number") from None
    if not (math.isfinite(fps) and 0 < fps <= MAX_FPS):
        raise fail("fps", f"must be a number in (0, {MAX_FPS:g}]")
    out: dict[str, Any] = {"version": version, "fps": fps, "character": meta.get("character")}
    if not isinstance(out["character"], str) or not out["character"]:
        raise fail("character", "must be a character name")
    for key in ("joint_names", "end_effectors"):
        try:
            names = json.loads(meta.get(key, ""))
        except (json.JSONDecodeError, RecursionError):
            raise fail(key, "is not a JSON list") from None
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise fail(key, "must be a JSON list of names")
        if len(set(names)) != len(names):
            raise fail(key, "names a joint or body twice")
        out[key] = tuple(names)
    for key in ("num_clips", "num_frames", "frame_dim", "latent_dim"):
        try:
            out[key] = int(meta.get(key, ""))
        except ValueError:
            raise fail(key, "is not an integer") from None
        if not 0 <= out[key] <= MAX_CLIP_FRAMES:
            raise fail(key, "is out of range")
    hashes = None
    if HASHES_KEY in meta:
        try:
            hashes = json.loads(meta[HASHES_KEY])
        except (json.JSONDecodeError, RecursionError):
            raise fail(HASHES_KEY, "is not JSON") from None
        if not isinstance(hashes, dict) or set(ARRAYS) - set(hashes):
            raise fail(HASHES_KEY, "must hold the SHA-256 of every array")
        if version >= METADATA_HASH_VERSION and METADATA_HASH not in hashes:
            raise fail(
                HASHES_KEY, f"lacks the SHA-256 of the metadata ({METADATA_HASH!r}) of version {version}"
            )
    elif version >= 2:
        raise AmorError(
            f"{path}: dataset metadata lacks the content hashes ('{HASHES_KEY}') of version {version}"
        )
    out["hashes"] = hashes
    return out


def _clip_of(path: Path, msg: Any, index: int, start: int) -> tuple[ClipInfo, dict[str, np.ndarray]]:
    """One clip message into its ClipInfo and arrays, shapes checked against the metadata."""
    if not isinstance(msg, dict):
        raise AmorError(f"{path}: clip message {index} is not a JSON object")
    name = msg.get("name")
    if not isinstance(name, str) or not name:
        raise AmorError(f"{path}: clip message {index} has no name")
    n = msg.get("num_frames")
    if not isinstance(n, int) or isinstance(n, bool) or not 0 <= n <= MAX_CLIP_FRAMES:
        raise AmorError(f"{path}: clip {name!r}: num_frames = {n!r} is not a frame count")
    raw = msg.get("arrays")
    if not isinstance(raw, dict):
        raise AmorError(f"{path}: clip {name!r} has no arrays")
    arrays = {}
    for a in ARRAYS:
        d = raw.get(a)
        if (
            not isinstance(d, dict)
            or not isinstance(d.get("data"), str)
            or not isinstance(d.get("shape"), list)
        ):
            raise AmorError(f"{path}: clip {name!r}: array {a!r} is missing or malformed")
        shape = d["shape"]
        if not all(isinstance(k, int) and not isinstance(k, bool) and k >= 0 for k in shape):
            raise AmorError(f"{path}: clip {name!r}: array {a!r} has a bad shape {shape!r}")
        try:
            arrays[a] = decode_array(d)
        except (ValueError, binascii.Error) as exc:
            raise AmorError(f"{path}: clip {name!r}: array {a!r} cannot be decoded: {exc}") from None
    fields_ = {}
    for key, kind in (("source", str), ("sha256", str), ("licence", str)):
        if not isinstance(msg.get(key), kind):
            raise AmorError(f"{path}: clip {name!r}: {key!r} must be a string")
        fields_[key] = msg[key]
    for key in ("source_fps", "retarget_error"):
        value = msg.get(key, 0.0)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise AmorError(f"{path}: clip {name!r}: {key!r} = {value!r} must be a number")
        fields_[key] = float(value)
    clip = ClipInfo(name=name, start=start, num_frames=n, **fields_)
    return clip, arrays


def load_dataset(path: str | Path) -> MotionLibrary:
    """Read a dataset into a :class:`MotionLibrary`; every array is decoded and checked once, here.

    Raises:
        AmorError: one line naming the file (and the key, clip or array): not an MCAP dataset,
            bad metadata (version, fps, joint names, sizes), a damaged message, shapes that
            disagree with the metadata, non-finite values, duplicate or one-frame clips, or an
            array or attachment whose SHA-256 differs from the recorded one.
    """
    path = Path(path)
    meta = read_dataset_metadata(path)
    info = _parse_meta(path, meta)
    f, reader = _open_reader(path)
    parts: dict[str, list[np.ndarray]] = {a: [] for a in ARRAYS}
    clips: list[ClipInfo] = []
    messages: list[dict[str, Any]] = []  # each clip message but its arrays, for the metadata hash
    attachments: dict[str, bytes] = {}
    start = 0
    shapes = expected_shapes(
        len(info["joint_names"]), len(info["end_effectors"]), info["frame_dim"], info["latent_dim"]
    )
    with f:
        try:
            for index, (_schema, _channel, message) in enumerate(reader.iter_messages(topics=[CHANNEL])):
                msg = json.loads(message.data)
                clip, arrays = _clip_of(path, msg, index, start)
                messages.append({k: v for k, v in msg.items() if k != "arrays"})
                for a in ARRAYS:
                    if arrays[a].shape[:1] != (clip.num_frames,):
                        raise AmorError(
                            f"{path}: clip {clip.name!r}: array {a!r} has {arrays[a].shape[:1]} frames, "
                            f"num_frames says {clip.num_frames}"
                        )
                    if arrays[a].shape[1:] != shapes[a]:
                        raise AmorError(
                            f"{path}: clip {clip.name!r}: array {a!r} has shape {list(arrays[a].shape)}, "
                            f"the metadata says {[clip.num_frames, *shapes[a]]}"
                        )
                    parts[a].append(arrays[a])
                clips.append(clip)
                start += clip.num_frames
                if start > MAX_CLIP_FRAMES:
                    raise AmorError(f"{path}: more than {MAX_CLIP_FRAMES} frames")
            if info["hashes"] is not None:
                for att in reader.iter_attachments():
                    attachments[att.name] = bytes(att.data)
        except AmorError:
            raise
        except _READ_ERRORS as exc:
            raise AmorError(f"{path}: corrupt motion dataset: {type(exc).__name__}: {exc}") from None
    if not clips:
        raise AmorError(f"{path}: the dataset holds no clips")
    if len(clips) != info["num_clips"] or start != info["num_frames"]:
        raise AmorError(
            f"{path}: holds {len(clips)} clips / {start} frames, its metadata says "
            f"{info['num_clips']} / {info['num_frames']}"
        )
    flat = {a: np.concatenate(parts[a], axis=0) for a in ARRAYS}
    if info["hashes"] is not None:
        _check_hashes(path, info["hashes"], flat, attachments)
        recorded = info["hashes"].get(METADATA_HASH)
        if recorded is not None and recorded != metadata_sha256(meta, messages):
            raise AmorError(
                f"{path}: the dataset's metadata (character, fps, joint names, clip info, ...) does not "
                "match its recorded SHA-256 (edited or corrupt; re-run preprocess)"
            )
    extra = {
        k: _maybe_json(v)
        for k, v in meta.items()
        if k not in ("character", "fps", "joint_names", "end_effectors", HASHES_KEY)
    }
    extra["integrity"] = _integrity(info["version"], info["hashes"])
    library = MotionLibrary(
        character=info["character"],
        fps=info["fps"],
        joint_names=info["joint_names"],
        end_effectors=info["end_effectors"],
        clips=tuple(clips),
        metadata=extra,
        **flat,
    )
    if library.frame_dim != info["frame_dim"] or library.latent_dim != info["latent_dim"]:
        raise AmorError(
            f"{path}: frames are {library.frame_dim} wide and latents {library.latent_dim}, its metadata "
            f"says frame_dim {info['frame_dim']}, latent_dim {info['latent_dim']}"
        )
    check_library(library, str(path))
    if info["hashes"] is None:  # every other check passed: the command goes on, but says so
        warnings.warn(
            f"{path}: version {info['version']} dataset without content hashes: its arrays and metadata "
            "cannot be verified; re-run `amorctl preprocess` (or delete a cached copy) to add them",
            AmorWarning,
            stacklevel=2,
        )
    return library


def _integrity(version: int, hashes: dict[str, Any] | None) -> dict[str, Any]:
    """What loading verified: ``verified`` (the arrays' hashes), ``metadata_verified`` (the
    metadata's hash, from version 3 on), ``sha256`` (the recorded hashes) and a ``reason`` for
    what was not verified."""
    if hashes is None:
        return {
            "verified": False,
            "metadata_verified": False,
            "reason": f"version {version} dataset without content hashes",
        }
    out: dict[str, Any] = {"verified": True, "metadata_verified": METADATA_HASH in hashes, "sha256": hashes}
    if not out["metadata_verified"]:
        out["reason"] = (
            f"version {version} dataset: its metadata (character, fps, clip info, ...) has no hash"
        )
    return out


def _check_hashes(
    path: Path, hashes: dict[str, Any], flat: dict[str, np.ndarray], attachments: dict[str, bytes]
) -> None:
    for a in ARRAYS:
        if array_sha256(flat[a]) != hashes[a]:
            raise AmorError(
                f"{path}: array {a!r} does not match its recorded SHA-256 (the file is corrupt; "
                "re-run preprocess)"
            )
    for key, digest in hashes.items():
        if not key.startswith("attachment:"):
            continue
        name = key.removeprefix("attachment:")
        data = attachments.get(name)
        if data is None:
            raise AmorError(f"{path}: attachment {name!r} is missing (its SHA-256 is recorded)")
        if hashlib.sha256(data).hexdigest() != digest:
            raise AmorError(
                f"{path}: attachment {name!r} does not match its recorded SHA-256 (the file is corrupt)"
            )


def load_clip_stats(path: str | Path) -> dict[str, dict[str, Any]]:
    """Per-clip retargeting statistics stored with each clip message (name -> stats)."""
    path = Path(path)
    f, reader = _open_reader(path)
    out = {}
    with f:
        try:
            for _s, _c, message in reader.iter_messages(topics=[CHANNEL]):
                msg = json.loads(message.data)
                out[msg["name"]] = msg.get("stats", {})
        except _READ_ERRORS as exc:
            raise AmorError(f"{path}: corrupt motion dataset: {type(exc).__name__}: {exc}") from None
    return out


def load_encoder_bytes(path: str | Path) -> bytes | None:
    """The stored motion-VAE encoder (safetensors bytes), or None if the VAE was not trained.

    Raises:
        AmorError: the file is damaged, or the attachment differs from its recorded SHA-256.
    """
    path = Path(path)
    info = _parse_meta(path, read_dataset_metadata(path))
    f, reader = _open_reader(path)
    with f:
        try:
            for att in reader.iter_attachments():
                if att.name == ENCODER_ATTACHMENT:
                    data = bytes(att.data)
                    digest = (info["hashes"] or {}).get(f"attachment:{ENCODER_ATTACHMENT}")
                    if digest is not None and hashlib.sha256(data).hexdigest() != digest:
                        raise AmorError(
                            f"{path}: attachment {ENCODER_ATTACHMENT!r} does not match its recorded SHA-256"
                        )
                    return data
        except AmorError:
            raise
        except _READ_ERRORS as exc:
            raise AmorError(f"{path}: corrupt motion dataset: {type(exc).__name__}: {exc}") from None
    return None


def _maybe_json(v: str) -> Any:
    try:
        return json.loads(v)
    except (json.JSONDecodeError, TypeError):
        return v
