"""The motion dataset file (MCAP) and its loader. Schema: ``docs/dataset.md``.

One MCAP file holds:

- metadata record ``amorctl.dataset``: character, fps, joint names, end effectors, frame layout,
  latent size, VAE settings and errors (JSON-encoded values, MCAP metadata values are strings);
- one metadata record ``amorctl.clip`` per clip: name, source, sha256, licence, frame count, ...;
- channel ``/amorctl/motion_clip`` (schema ``amorctl.MotionClip``, jsonschema; message encoding
  json): one message per clip, holding the clip's info and its per-frame arrays, each as
  ``{"dtype": "float32", "shape": [...], "data": base64 of little-endian bytes}``;
- attachment ``motion_vae_encoder.safetensors`` (when the VAE was trained).

Integrity (version 2): the dataset record holds ``sha256``, a JSON object with the SHA-256 of every
per-frame array (all clips concatenated, little-endian float32, C order) and of the attachment
(``attachment:<name>``). :func:`load_dataset` checks every hash, every shape against the metadata,
that arrays are finite, clip names unique and clips at least two frames long; a mismatch is one
``AmorError`` naming the file and the array. Version-1 files (written before hashes existed) load
with every check but the hashes; ``amorctl data show`` says they are unverified.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
import math
import struct
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
VERSION = 2
#: Oldest version still read: 1, the same layout without content hashes (unverified).
OLDEST_VERSION = 1
HASHES_KEY = "sha256"
#: Plausible limits for metadata numbers (a corrupt value is refused, not allocated).
MAX_FPS = 10_000.0
MAX_CLIP_FRAMES = 10_000_000
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
    raw = base64.b64decode(d["data"], validate=True)
    if len(raw) % 4 or math.prod(d["shape"]) * 4 != len(raw):
        raise ValueError(f"{len(raw)} bytes do not fill shape {d['shape']}")
    return np.frombuffer(raw, dtype="<f4").reshape(d["shape"]).astype(np.float32)


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
        meta[HASHES_KEY] = json.dumps(hashes)
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


def array_sha256(a: np.ndarray) -> str:
    """SHA-256 of an array as stored: little-endian float32, C order."""
    return hashlib.sha256(np.ascontiguousarray(a, dtype="<f4").tobytes()).hexdigest()


def expected_shapes(library: MotionLibrary) -> dict[str, tuple[int, ...]]:
    """Each array's shape after the frame axis, from the metadata (J joints, E effectors, D, L)."""
    j, e = len(library.joint_names), len(library.end_effectors)
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
        "frames": (library.frame_dim,),
        "z": (library.latent_dim,),
    }


def check_library(library: MotionLibrary, where: str) -> None:
    """The rules every dataset obeys, checked before writing and after reading.

    Raises:
        AmorError: starting with ``where``: no clips, a clip name used twice, a clip shorter than
            two frames, clips that do not tile the frames, an array whose shape disagrees with the
            metadata, or an array holding NaN or inf (the first bad array and frame are named).
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
    shapes = expected_shapes(library)
    for name in ARRAYS:
        a = np.asarray(getattr(library, name))
        if a.shape != (start, *shapes[name]):
            raise AmorError(
                f"{where}: array {name!r} has shape {list(a.shape)}, the metadata says "
                f"{[start, *shapes[name]]}"
            )
        bad = ~np.isfinite(a)
        if bad.any():
            frame = int(np.argwhere(bad)[0][0])
            clip = next(c for c in library.clips if c.start <= frame < c.start + c.num_frames)
            raise AmorError(
                f"{where}: array {name!r} holds NaN or inf (clip {clip.name!r}, frame {frame - clip.start})"
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
            arrays[a] = _decode_array(d)
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
    attachments: dict[str, bytes] = {}
    start = 0
    with f:
        try:
            for index, (_schema, _channel, message) in enumerate(reader.iter_messages(topics=[CHANNEL])):
                clip, arrays = _clip_of(path, json.loads(message.data), index, start)
                for a in ARRAYS:
                    if arrays[a].shape[:1] != (clip.num_frames,):
                        raise AmorError(
                            f"{path}: clip {clip.name!r}: array {a!r} has {arrays[a].shape[:1]} frames, "
                            f"num_frames says {clip.num_frames}"
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
    extra = {
        k: _maybe_json(v)
        for k, v in meta.items()
        if k not in ("character", "fps", "joint_names", "end_effectors", HASHES_KEY)
    }
    extra["integrity"] = (
        {"verified": True, "sha256": info["hashes"]}
        if info["hashes"] is not None
        else {"verified": False, "reason": f"version {info['version']} dataset without content hashes"}
    )
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
    return library


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
