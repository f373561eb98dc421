"""The motion dataset's format: names, the clip message's JSON Schema, the array codec and the
rules every dataset obeys (:func:`check_library`, run before writing and after reading).

The file layout is described in :mod:`amorctl.motion.dataset` and ``docs/dataset.md``.
"""

from __future__ import annotations

import base64
import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import STATE_ARRAYS
from amorctl.motion.clips import MotionLibrary
from amorctl.motion.source import MAX_ABS_VALUE, implausible

FORMAT = "amorctl.motion_dataset"
VERSION = 3
#: Oldest version still read: 1, the same layout without content hashes (unverified); 2, with the
#: arrays' hashes but none over the metadata.
OLDEST_VERSION = 1
HASHES_KEY = "sha256"
#: Key in the hashes of :func:`metadata_sha256` (required from :data:`METADATA_HASH_VERSION` on).
METADATA_HASH = "metadata"
METADATA_HASH_VERSION = 3
#: Keys of a clip message that :func:`metadata_sha256` leaves out (the arrays have hashes of their own).
UNHASHED_CLIP_KEYS = ("arrays",)
#: Plausible limits for metadata numbers (a corrupt value is refused, not allocated).
MAX_FPS = 10_000.0
MAX_CLIP_FRAMES = 10_000_000
CHANNEL = "/amorctl/motion_clip"
SCHEMA_NAME = "amorctl.MotionClip"
ENCODER_ATTACHMENT = "motion_vae_encoder.safetensors"
#: Per-frame arrays of :class:`MotionLibrary`, in the order they are stored.
ARRAYS: tuple[str, ...] = (*STATE_ARRAYS, "frames", "z")

_ARRAY_SCHEMA = {
    "type": "object",
    "properties": {
        "dtype": {"type": "string", "enum": ["float32"]},
        "shape": {"type": "array", "items": {"type": "integer"}},
        "data": {"type": "string", "contentEncoding": "base64", "description": "little-endian, C order"},
    },
    "required": ["dtype", "shape", "data"],
}
SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": SCHEMA_NAME,
    "description": "One motion clip on a character: info and per-frame arrays (docs/dataset.md).",
    "type": "object",
    "properties": {
        "name": {"type": "string"},
        "source": {"type": "string"},
        "sha256": {"type": "string"},
        "licence": {"type": "string"},
        "num_frames": {"type": "integer"},
        "source_fps": {"type": "number"},
        "retarget_error": {"type": "number", "description": "mean key-point error, m"},
        "stats": {"type": "object"},
        "arrays": {
            "type": "object",
            "properties": {k: _ARRAY_SCHEMA for k in ARRAYS},
            "required": list(ARRAYS),
        },
    },
    "required": ["name", "source", "sha256", "licence", "num_frames", "source_fps", "arrays"],
}


def encode_array(a: np.ndarray) -> dict[str, Any]:
    """An array as stored in a clip message: dtype, shape, base64 of little-endian float32 bytes."""
    a = np.ascontiguousarray(a, dtype="<f4")
    return {"dtype": "float32", "shape": list(a.shape), "data": base64.b64encode(a.tobytes()).decode("ascii")}


def decode_array(d: dict[str, Any]) -> np.ndarray:
    """The array of an :func:`encode_array` dict; ValueError if not float32 or not filling its shape."""
    if d.get("dtype") != "float32":
        raise ValueError(f"unsupported dtype {d.get('dtype')!r}")
    raw = base64.b64decode(d["data"], validate=True)
    if len(raw) % 4 or math.prod(d["shape"]) * 4 != len(raw):
        raise ValueError(f"{len(raw)} bytes do not fill shape {d['shape']}")
    return np.frombuffer(raw, dtype="<f4").reshape(d["shape"]).astype(np.float32)


def array_sha256(a: np.ndarray) -> str:
    """SHA-256 of an array as stored: little-endian float32, C order."""
    return hashlib.sha256(np.ascontiguousarray(a, dtype="<f4").tobytes()).hexdigest()


def metadata_sha256(meta: Mapping[str, str], clips: Sequence[Mapping[str, Any]]) -> str:
    """SHA-256 of what a dataset says about its arrays: every key of the dataset record but the
    hashes themselves (character, fps, joint names, sizes, VAE settings, ...) and every clip
    message but its arrays (name, frame count, source, licence, statistics), in order.

    Canonical JSON (sorted keys) of the values as stored, so the writer and the reader agree.
    """
    body = {
        "dataset": {k: v for k, v in meta.items() if k != HASHES_KEY},
        "clips": [{k: v for k, v in c.items() if k not in UNHASHED_CLIP_KEYS} for c in clips],
    }
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def expected_shapes(j: int, e: int, frame_dim: int, latent_dim: int) -> dict[str, tuple[int, ...]]:
    """Each array's shape after the frame axis, from the metadata: J joints, E end effectors,
    the frame width D and the latent size L."""
    return {
        "root_pos": (3,),
        "root_quat": (4,),
        "root_lin_vel": (3,),
        "root_ang_vel": (3,),
        "joint_pos": (j,),
        "joint_vel": (j,),
        "ee_pos": (e, 3),
        "ee_quat": (e, 4),
        "ee_lin_vel": (e, 3),
        "frames": (frame_dim,),
        "z": (latent_dim,),
    }


def check_library(library: MotionLibrary, where: str) -> None:
    """The rules every dataset obeys, checked before writing and after reading.

    Raises:
        AmorError: starting with ``where``: no clips, a clip name used twice, a clip shorter than
            two frames, clips that do not tile the frames, an array whose shape disagrees with the
            metadata, or an array holding NaN, inf or a value beyond the importers' plausibility
            bound (:data:`~amorctl.motion.source.MAX_ABS_VALUE`; the first bad array and frame are named).
    """
    if not library.clips:
        raise AmorError(f"{where}: the dataset holds no clips")
    if not (math.isfinite(library.fps) and 0 < library.fps <= MAX_FPS):
        raise AmorError(f"{where}: fps = {library.fps!r} must be a number in (0, {MAX_FPS:g}]")
    seen: set[str] = set()
    start = 0
    for clip in library.clips:
        if clip.name in seen:
            raise AmorError(f"{where}: clip name {clip.name!r} is used twice (clip names must be unique)")
        seen.add(clip.name)
        if clip.num_frames < 2:
            raise AmorError(f"{where}: clip {clip.name!r} has {clip.num_frames} frame(s); at least 2 needed")
        if clip.start != start:
            raise AmorError(f"{where}: clip {clip.name!r} starts at frame {clip.start}, expected {start}")
        if not (math.isfinite(clip.source_fps) and clip.source_fps >= 0):
            raise AmorError(f"{where}: clip {clip.name!r}: source_fps = {clip.source_fps!r} is not valid")
        if not (math.isfinite(clip.retarget_error) and clip.retarget_error >= 0):
            raise AmorError(
                f"{where}: clip {clip.name!r}: retarget_error = {clip.retarget_error!r} is not valid"
            )
        start += clip.num_frames
    shapes = expected_shapes(
        len(library.joint_names), len(library.end_effectors), library.frame_dim, library.latent_dim
    )
    for name in ARRAYS:
        a = np.asarray(getattr(library, name))
        if a.shape != (start, *shapes[name]):
            raise AmorError(
                f"{where}: array {name!r} has shape {list(a.shape)}, the metadata says "
                f"{[start, *shapes[name]]}"
            )
        bad = implausible(a)
        if bad.any():
            index = tuple(np.argwhere(bad)[0])
            frame = int(index[0])
            clip = next(c for c in library.clips if c.start <= frame < c.start + c.num_frames)
            what = "NaN or inf" if not np.isfinite(a[index]) else f"{a[index]:.4g} (|x| > {MAX_ABS_VALUE:g})"
            raise AmorError(
                f"{where}: array {name!r} holds {what} (clip {clip.name!r}, frame {frame - clip.start})"
            )
