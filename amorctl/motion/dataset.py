"""The motion dataset file (MCAP) and its loader. Schema: ``docs/dataset.md``.

One MCAP file holds:

- metadata record ``amorctl.dataset``: character, fps, joint names, end effectors, frame layout,
  latent size, VAE settings and errors (JSON-encoded values, MCAP metadata values are strings);
- one metadata record ``amorctl.clip`` per clip: name, source, sha256, licence, frame count, ...;
- channel ``/amorctl/motion_clip`` (schema ``amorctl.MotionClip``, jsonschema; message encoding
  json): one message per clip, holding the clip's info and its per-frame arrays, each as
  ``{"dtype": "float32", "shape": [...], "data": base64 of little-endian bytes}``;
- attachment ``motion_vae_encoder.safetensors`` (when the VAE was trained).
"""

from __future__ import annotations

import base64
import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from amorctl import __version__
from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_path
from amorctl.motion.clips import ClipInfo, MotionLibrary

FORMAT = "amorctl.motion_dataset"
VERSION = 1
CHANNEL = "/amorctl/motion_clip"
SCHEMA_NAME = "amorctl.MotionClip"
ENCODER_ATTACHMENT = "motion_vae_encoder.safetensors"
#: Per-frame arrays of :class:`MotionLibrary`, in the order they are stored.
ARRAYS: tuple[str, ...] = (
    "root_pos",
    "root_quat",
    "root_lin_vel",
    "root_ang_vel",
    "joint_pos",
    "joint_vel",
    "ee_pos",
    "ee_quat",
    "ee_lin_vel",
    "frames",
    "z",
)

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


def _encode_array(a: np.ndarray) -> dict[str, Any]:
    a = np.ascontiguousarray(a, dtype="<f4")
    return {"dtype": "float32", "shape": list(a.shape), "data": base64.b64encode(a.tobytes()).decode("ascii")}


def _decode_array(d: dict[str, Any]) -> np.ndarray:
    if d.get("dtype") != "float32":
        raise ValueError(f"unsupported dtype {d.get('dtype')!r}")
    raw = base64.b64decode(d["data"])
    return np.frombuffer(raw, dtype="<f4").reshape(d["shape"]).astype(np.float32)


def write_dataset(
    path: str | Path,
    library: MotionLibrary,
    clip_stats: dict[str, dict[str, Any]] | None = None,
    encoder: bytes | None = None,
) -> None:
    """Write ``library`` as an MCAP dataset, atomically (temp file + rename)."""
    clip_stats = clip_stats or {}
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
        meta.update({k: v if isinstance(v, str) else json.dumps(v) for k, v in library.metadata.items()})
        writer.add_metadata("amorctl.dataset", meta)
        schema = writer.register_schema(SCHEMA_NAME, "jsonschema", json.dumps(SCHEMA).encode())
        channel = writer.register_channel(CHANNEL, "json", schema)
        for k, clip in enumerate(library.clips):
            info = asdict(clip)
            info.pop("start")
            writer.add_metadata("amorctl.clip", {key: str(v) for key, v in info.items()})
            sl = slice(clip.start, clip.start + clip.num_frames)
            msg = {
                **info,
                "stats": clip_stats.get(clip.name, {}),
                "arrays": {a: _encode_array(getattr(library, a)[sl]) for a in ARRAYS},
            }
            writer.add_message(channel, log_time=k, data=json.dumps(msg).encode(), publish_time=k, sequence=k)
        if encoder is not None:
            writer.add_attachment(0, 0, ENCODER_ATTACHMENT, "application/octet-stream", encoder)
        writer.finish()


def _open_reader(path: Path):  # type: ignore[no-untyped-def]
    if not path.is_file():
        raise AmorError(f"{path}: dataset not found")
    f = open(path, "rb")  # noqa: SIM115 - closed by the caller
    try:
        return f, make_reader(f)
    except (McapError, ValueError, EOFError, OSError) as exc:
        f.close()
        raise AmorError(f"{path}: not a readable MCAP file: {exc}") from None


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
        except (McapError, ValueError, EOFError, OSError) as exc:
            raise AmorError(f"{path}: not a readable MCAP file: {exc}") from None
    raise AmorError(f"{path}: not an amorctl motion dataset (no {FORMAT} metadata)")


def load_dataset(path: str | Path) -> MotionLibrary:
    """Read a dataset into a :class:`MotionLibrary`; every array is decoded once, here."""
    path = Path(path)
    meta = read_dataset_metadata(path)
    if int(meta.get("version", "0")) > VERSION:
        raise AmorError(f"{path}: dataset version {meta['version']} is newer than this amorctl supports")
    f, reader = _open_reader(path)
    parts: dict[str, list[np.ndarray]] = {a: [] for a in ARRAYS}
    clips: list[ClipInfo] = []
    start = 0
    with f:
        try:
            for _schema, channel, message in reader.iter_messages(topics=[CHANNEL]):
                del channel
                msg = json.loads(message.data)
                arrays = {a: _decode_array(msg["arrays"][a]) for a in ARRAYS}
                n = int(msg["num_frames"])
                if any(v.shape[0] != n for v in arrays.values()):
                    raise ValueError(f"clip {msg['name']!r}: arrays disagree with num_frames={n}")
                for a in ARRAYS:
                    parts[a].append(arrays[a])
                clips.append(
                    ClipInfo(
                        name=msg["name"],
                        source=msg["source"],
                        sha256=msg["sha256"],
                        licence=msg["licence"],
                        start=start,
                        num_frames=n,
                        source_fps=float(msg["source_fps"]),
                        retarget_error=float(msg.get("retarget_error", 0.0)),
                    )
                )
                start += n
        except (McapError, ValueError, KeyError, TypeError, EOFError, OSError) as exc:
            raise AmorError(f"{path}: corrupt motion dataset: {exc}") from None
    if not clips:
        raise AmorError(f"{path}: the dataset holds no clips")
    extra = {
        k: _maybe_json(v)
        for k, v in meta.items()
        if k not in ("character", "fps", "joint_names", "end_effectors")
    }
    return MotionLibrary(
        character=meta["character"],
        fps=float(meta["fps"]),
        joint_names=tuple(json.loads(meta["joint_names"])),
        end_effectors=tuple(json.loads(meta["end_effectors"])),
        clips=tuple(clips),
        metadata=extra,
        **{a: np.concatenate(parts[a], axis=0) for a in ARRAYS},
    )


def load_clip_stats(path: str | Path) -> dict[str, dict[str, Any]]:
    """Per-clip retargeting statistics stored with each clip message (name -> stats)."""
    path = Path(path)
    f, reader = _open_reader(path)
    out = {}
    with f:
        for _s, _c, message in reader.iter_messages(topics=[CHANNEL]):
            msg = json.loads(message.data)
            out[msg["name"]] = msg.get("stats", {})
    return out


def load_encoder_bytes(path: str | Path) -> bytes | None:
    """The stored motion-VAE encoder (safetensors bytes), or None if the VAE was not trained."""
    path = Path(path)
    f, reader = _open_reader(path)
    with f:
        for att in reader.iter_attachments():
            if att.name == ENCODER_ATTACHMENT:
                return bytes(att.data)
    return None


def _maybe_json(v: str) -> Any:
    try:
        return json.loads(v)
    except (json.JSONDecodeError, TypeError):
        return v


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
