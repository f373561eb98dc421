"""The motion dataset file (MCAP) and its loader. Schema: ``docs/dataset.md``.

One MCAP file holds:

- metadata record ``amorctl.dataset``: character, fps, joint names, end effectors, frame layout,
  latent size, VAE settings and errors (JSON-encoded values, MCAP metadata values are strings);
- one metadata record ``amorctl.clip`` per clip: name, source, sha256, licence, frame count, ...;
- channel ``/amorctl/motion_clip`` (schema ``amorctl.MotionClip``, jsonschema; message encoding
  json): one message per clip, holding the clip's info and its per-frame arrays, each as
  ``{"dtype": "float32", "shape": [...], "data": base64 of little-endian bytes}``;
- attachment ``motion_vae_encoder.safetensors`` (when the VAE was trained).

Integrity (version 3): the dataset record holds ``sha256``, a JSON object with the SHA-256 of every
per-frame array (all clips concatenated, little-endian float32, C order), of the attachment
(``attachment:<name>``) and of the metadata (``metadata``: every other key of the dataset record
and every clip message but its arrays, :func:`~amorctl.motion.dataset_schema.metadata_sha256`).
:func:`load_dataset` checks every hash, every shape against the metadata, that arrays are finite
and within the importers' plausibility bound, clip names unique and clips at least two frames
long; a mismatch is one ``AmorError`` naming the file and the array. Version-2 files (no metadata
hash) load with every check but that one; version-1 files (written before hashes existed) load
with every check but the hashes and an :class:`~amorctl.core.errors.AmorWarning`; ``amorctl data
show`` says what was not verified.

The format (names, schema, checks) is in :mod:`amorctl.motion.dataset_schema`, the reader in
:mod:`amorctl.motion.dataset_read`; this module writes datasets and is where callers import from.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import CompressionType, Writer

from amorctl import __version__
from amorctl.core.files import atomic_path
from amorctl.motion.clips import ClipInfo, MotionLibrary
from amorctl.motion.dataset_read import (
    load_clip_stats,
    load_dataset,
    load_encoder_bytes,
    read_dataset_metadata,
)
from amorctl.motion.dataset_schema import (
    ARRAYS,
    CHANNEL,
    ENCODER_ATTACHMENT,
    FORMAT,
    HASHES_KEY,
    METADATA_HASH,
    SCHEMA,
    SCHEMA_NAME,
    VERSION,
    array_sha256,
    check_library,
    metadata_sha256,
)

# write_dataset looks the codec up here, so a test can swap it to write a corrupt file
from amorctl.motion.dataset_schema import encode_array as _encode_array

__all__ = [
    "ARRAYS",
    "CHANNEL",
    "ENCODER_ATTACHMENT",
    "FORMAT",
    "HASHES_KEY",
    "SCHEMA",
    "SCHEMA_NAME",
    "VERSION",
    "array_sha256",
    "check_library",
    "clip_of_frame",
    "frame_windows",
    "load_clip_stats",
    "load_dataset",
    "load_encoder_bytes",
    "read_dataset_metadata",
    "write_dataset",
]


def write_dataset(
    path: str | Path,
    library: MotionLibrary,
    clip_stats: dict[str, dict[str, Any]] | None = None,
    encoder: bytes | None = None,
) -> None:
    """Write ``library`` as an MCAP dataset, atomically (temp file + rename), with the SHA-256 of
    every array and of the encoder attachment.

    Raises:
        AmorError: the library fails :func:`check_library` (nothing is written then).
    """
    clip_stats = clip_stats or {}
    check_library(library, str(path))
    hashes = {a: array_sha256(getattr(library, a)) for a in ARRAYS}
    if encoder is not None:
        hashes[f"attachment:{ENCODER_ATTACHMENT}"] = hashlib.sha256(encoder).hexdigest()
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile="", library=f"amorctl {__version__}")
        meta = {
            "format": FORMAT,
            "version": str(VERSION),
            "character": library.character,
            "fps": repr(float(library.fps)),
            "joint_names": json.dumps(list(library.joint_names)),
            "end_effectors": json.dumps(list(library.end_effectors)),
            "num_clips": str(len(library.clips)),
            "num_frames": str(library.num_frames),
            "frame_dim": str(library.frame_dim),
            "latent_dim": str(library.latent_dim),
        }
        own = (HASHES_KEY, "version", "format", "integrity")  # written here, never copied
        # computed keys win over stale copies carried in library.metadata (e.g. a clip subset)
        extra = {k: v for k, v in library.metadata.items() if k not in own and k not in meta}
        meta.update({k: v if isinstance(v, str) else json.dumps(v) for k, v in extra.items()})
        # each clip message but its arrays, as a reader will parse it back from the JSON
        infos = [
            json.loads(json.dumps({**_clip_info(clip), "stats": clip_stats.get(clip.name, {})}))
            for clip in library.clips
        ]
        hashes[METADATA_HASH] = metadata_sha256(meta, infos)
        meta[HASHES_KEY] = json.dumps(hashes)
        writer.add_metadata("amorctl.dataset", meta)
        schema = writer.register_schema(SCHEMA_NAME, "jsonschema", json.dumps(SCHEMA).encode())
        channel = writer.register_channel(CHANNEL, "json", schema)
        for k, (clip, info) in enumerate(zip(library.clips, infos, strict=True)):
            writer.add_metadata("amorctl.clip", {key: str(v) for key, v in _clip_info(clip).items()})
            sl = slice(clip.start, clip.start + clip.num_frames)
            msg = {**info, "arrays": {a: _encode_array(getattr(library, a)[sl]) for a in ARRAYS}}
            writer.add_message(channel, log_time=k, data=json.dumps(msg).encode(), publish_time=k, sequence=k)
        if encoder is not None:
            writer.add_attachment(0, 0, ENCODER_ATTACHMENT, "application/octet-stream", encoder)
        writer.finish()


def _clip_info(clip: ClipInfo) -> dict[str, Any]:
    """A clip's info as its message and ``amorctl.clip`` record store it (``start`` is implied)."""
    info = asdict(clip)
    info.pop("start")
    return info


def clip_of_frame(library: MotionLibrary, index: np.ndarray) -> np.ndarray:
    """Clip number [N] of each flat frame index [N]."""
    return np.searchsorted(library.starts, np.asarray(index), side="right") - 1


def frame_windows(library: MotionLibrary, index: np.ndarray, window: int) -> np.ndarray:
    """Frames m_{t-W..t+W} around flat frame indices [N] -> [N, 2W+1, D], no copy of the library.

    Windows stay inside their clip; at clip edges the first or last frame repeats (the VAE's
    padding rule).
    """
    index = np.asarray(index, dtype=np.int64)
    k = clip_of_frame(library, index)
    start, end = library.starts[k], library.starts[k] + library.lengths[k] - 1
    offsets = np.arange(-window, window + 1)
    rows = np.clip(index[:, None] + offsets[None], start[:, None], end[:, None])
    return library.frames[rows]
