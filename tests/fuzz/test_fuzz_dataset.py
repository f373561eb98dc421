"""Fuzz: mutated MCAP motion datasets through `amorctl data show` (bytes, metadata, clip messages,
arrays; also re-hashed, so the checks behind the hashes are what refuses them)."""

from __future__ import annotations

import base64
import binascii
import contextlib
import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fuzzlib import (
    BAD_STRINGS,
    CI_EXAMPLES,
    NEST_DEPTHS,
    SLOW_EXAMPLES,
    array_mutation,
    byte_mutation,
    check_outcome,
    dumps_json,
    fuzz_settings,
    run_cli,
    scratch,
    structured_mutation,
)
from hypothesis import given
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from amorctl.motion.dataset_schema import (
    ARRAYS,
    HASHES_KEY,
    METADATA_HASH,
    array_sha256,
    decode_array,
    metadata_sha256,
)

EXAMPLES = [
    pytest.param(CI_EXAMPLES, id="ci"),
    pytest.param(SLOW_EXAMPLES, id="many", marks=pytest.mark.slow),
]
META_KEYS = (
    "version", "fps", "character", "joint_names", "end_effectors", "num_clips", "num_frames",
    "frame_dim", "latent_dim", "sha256",
)  # fmt: skip


def rehashed(meta: dict[str, str], bodies: list[bytes]) -> dict[str, str]:
    """``meta`` with its hashes recomputed from the clip messages ``bodies``: every array's (where
    every clip's array still decodes and the clips concatenate) and the metadata's. What a user
    who edits a dataset and fixes its hashes produces."""
    try:
        hashes = json.loads(meta[HASHES_KEY])
        messages = [json.loads(b) for b in bodies]
    except (KeyError, ValueError, RecursionError):
        return meta  # nothing to recompute: the reader refuses the file anyway
    if not isinstance(hashes, dict) or not all(isinstance(m, dict) for m in messages):
        return meta
    for name in ARRAYS:
        with contextlib.suppress(KeyError, TypeError, ValueError, AttributeError, binascii.Error):
            hashes[name] = array_sha256(np.concatenate([decode_array(m["arrays"][name]) for m in messages]))
    hashes[METADATA_HASH] = metadata_sha256(meta, messages)
    return {**meta, HASHES_KEY: json.dumps(hashes)}


def rewrite_mcap(
    src: Path,
    dst: Path,
    meta: Callable[[dict[str, str]], dict[str, str]] = lambda m: m,
    message: Callable[[int, bytes], bytes] = lambda i, b: b,
    rehash: bool = False,
) -> None:
    """Copy an MCAP dataset record by record, letting ``meta`` change the dataset record and
    ``message`` change clip messages (by index); what a hand-editing user could produce.
    ``rehash``: then recompute the hashes (:func:`rehashed`)."""
    with open(src, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        records = [(r.name, dict(r.metadata)) for r in reader.iter_metadata()]
        messages = [(ch.topic, s, m) for s, ch, m in reader.iter_messages()]
        attachments = [(a.name, a.media_type, bytes(a.data)) for a in reader.iter_attachments()]
    assert summary is not None
    bodies = [message(k, m.data) for k, (_topic, _s, m) in enumerate(messages)]
    with open(dst, "wb") as f:
        writer = Writer(f, compression=CompressionType.NONE)
        writer.start(profile="", library="fuzz")
        for name, values in records:
            if name == "amorctl.dataset":
                values = rehashed(meta(values), bodies) if rehash else meta(values)
            writer.add_metadata(name, values)
        schema = next(iter(summary.schemas.values()))
        schema_id = writer.register_schema(schema.name, schema.encoding, schema.data)
        channel_id = writer.register_channel(next(iter(summary.channels.values())).topic, "json", schema_id)
        for (_topic, _s, m), body in zip(messages, bodies, strict=True):
            writer.add_message(channel_id, m.log_time, body, m.publish_time, m.sequence)
        for name, media, data in attachments:
            writer.add_attachment(0, 0, name, media, data)
        writer.finish()


def _messages(seed: Path) -> list[dict[str, Any]]:
    with open(seed, "rb") as f:
        return [json.loads(m.data) for _s, _c, m in make_reader(f).iter_messages()]


@st.composite
def dataset_variant(draw: st.DrawFn, seed: Path, directory: Path, rehash: bool = False) -> tuple[Path, str]:
    """A damaged copy of ``seed`` in ``directory`` and what was done to it; ``rehash``: edits of
    the metadata, a clip message or an array, with every hash recomputed afterwards."""
    path = directory / "d.mcap"
    plain = ("bytes", "bytes", "meta", "message", "message")
    kinds = ("meta", "message", "array", "array") if rehash else plain
    kind = draw(st.sampled_from(kinds))
    if kind == "array":
        which = draw(st.integers(0, 1))
        msg = _messages(seed)[which]
        arrays = {a: decode_array(d) for a, d in msg["arrays"].items()}
        edited, what = draw(array_mutation(arrays))
        msg["arrays"] = {a: _encode_any(v) for a, v in edited.items()}
        body = json.dumps(msg, allow_nan=True).encode()
        rewrite_mcap(seed, path, message=lambda k, b: body if k == which else b, rehash=True)
        return path, f"clip {which}: {what} (rehashed)"
    if kind == "bytes":
        path.write_bytes(draw(byte_mutation(seed.read_bytes())))
        return path, "bytes"
    if kind == "meta":
        key = draw(st.sampled_from(META_KEYS))
        value = draw(st.sampled_from(BAD_STRINGS))
        delete = draw(st.booleans())

        def meta(m: dict[str, str]) -> dict[str, str]:
            if delete:
                m.pop(key, None)
            else:
                m[key] = value
            return m

        rewrite_mcap(seed, path, meta=meta, rehash=rehash)
        return path, f"meta {key} {'deleted' if delete else value[:20]}{' (rehashed)' * rehash}"
    doc, what = draw(structured_mutation(_messages(seed)[0]))
    body = dumps_json(doc, draw(st.sampled_from(NEST_DEPTHS))).encode()
    which = draw(st.integers(0, 1))
    rewrite_mcap(seed, path, message=lambda k, b: body if k == which else b, rehash=rehash)
    return path, f"message {which}: {what}{' (rehashed)' * rehash}"


def _encode_any(a: np.ndarray) -> dict[str, Any]:
    """An array as a clip message stores it, whatever its dtype (the reader accepts only float32)."""
    data = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<")).tobytes()
    return {"dtype": str(a.dtype), "shape": list(a.shape), "data": base64.b64encode(data).decode("ascii")}


def _sane(shown: dict[str, Any]) -> None:
    assert shown["num_frames"] >= 4 and shown["fps"] > 0
    assert len({c["name"] for c in shown["clips"]}) == len(shown["clips"])
    assert shown["integrity"]["verified"] is True and shown["integrity"]["metadata_verified"] is True


@pytest.mark.parametrize("rehash", [False, True], ids=["plain", "rehashed"])
@pytest.mark.parametrize("examples", EXAMPLES)
def test_dataset_variants(examples: int, rehash: bool, seed_dataset: Path) -> None:
    @fuzz_settings(examples)
    @given(st.data())
    def variant(data: st.DataObject) -> None:
        with scratch() as d:
            path, what = data.draw(dataset_variant(seed_dataset, d, rehash))
            result = run_cli(["data", "show", path, "--json"])
            check_outcome(result, (str(path),), what=what, on_success=_sane)

    variant()


def _edit_array(name: str, clip: int, index: tuple, value: float):
    def change(msg: dict[str, Any], k: int) -> dict[str, Any]:
        if k == clip:
            a = decode_array(msg["arrays"][name]).copy()
            a[index] = value
            msg["arrays"][name] = _encode_any(a)
        return msg

    return change


def _drop_frame(msg: dict[str, Any], k: int) -> dict[str, Any]:
    if k == 0:
        msg["arrays"]["frames"] = _encode_any(decode_array(msg["arrays"]["frames"])[:-1])
    return msg


#: One edit per class of deep check, each then re-hashed (or not, ``rehash=False``), and the
#: error it must give: (change a clip message (msg, k), change the dataset record, rehash, error).
REHASHED_EDITS: dict[str, tuple[Any, Any, bool, str]] = {
    "character edited, not rehashed": (
        None,
        lambda m: {**m, "character": "humanoid36"},
        False,
        r"the dataset's metadata \(character, fps, joint names, clip info, \.\.\.\) does not match its "
        r"recorded SHA-256 \(edited or corrupt; re-run preprocess\)",
    ),
    "a clip renamed, not rehashed": (
        lambda msg, k: {**msg, "name": "c"} if k == 1 else msg,
        None,
        False,
        r"the dataset's metadata .* does not match its recorded SHA-256",
    ),
    "NaN in frames": (
        _edit_array("frames", 1, (2, 0), np.nan),
        None,
        True,
        r"array 'frames' holds NaN or inf \(clip 'b', frame 2\)",
    ),
    "a root position beyond the bound": (
        _edit_array("root_pos", 0, (1, 2), 1e30),
        None,
        True,
        r"array 'root_pos' holds 1e\+30 \(\|x\| > 1e\+06\) \(clip 'a', frame 1\)",
    ),
    "a frame dropped": (
        _drop_frame,
        None,
        True,
        r"clip 'a': array 'frames' has \(\d+,\) frames, num_frames says \d+",
    ),
    "a clip name used twice": (
        lambda msg, k: {**msg, "name": "a"},
        None,
        True,
        "clip name 'a' is used twice",
    ),
    "a joint name removed": (
        None,
        lambda m: {**m, "joint_names": json.dumps(json.loads(m["joint_names"])[1:])},
        True,
        r"array 'joint_pos' has shape \[\d+, 20\], the metadata says \[\d+, 19\]",
    ),
}


@pytest.mark.parametrize("edit", sorted(REHASHED_EDITS))
def test_dataset_edits_are_refused_by_the_checks_behind_the_hash(edit: str, seed_dataset: Path) -> None:
    change_message, change_meta, rehash, message = REHASHED_EDITS[edit]
    with scratch() as d:
        path = d / "d.mcap"

        def body(k: int, data: bytes) -> bytes:
            return json.dumps(change_message(json.loads(data), k)).encode() if change_message else data

        rewrite_mcap(seed_dataset, path, meta=change_meta or (lambda m: m), message=body, rehash=rehash)
        verdict = check_outcome(run_cli(["data", "show", path, "--json"]), (str(path),), what=edit)
        assert verdict.startswith(f"error: {path}: ") and re.search(message, verdict), verdict


@pytest.mark.parametrize("rehash", [False, True])
def test_rewrite_keeps_a_dataset_valid(seed_dataset: Path, tmp_path: Path, rehash: bool) -> None:
    """The rewriting helper itself changes nothing (and re-hashing an unchanged file recomputes the
    same hashes): the copy loads, with every hash verified."""
    rewrite_mcap(seed_dataset, tmp_path / "copy.mcap", rehash=rehash)
    code, out, err = run_cli(["data", "show", tmp_path / "copy.mcap", "--json"])
    assert code == 0, err
    _sane(json.loads(out))
    with open(seed_dataset, "rb") as f, open(tmp_path / "copy.mcap", "rb") as g:
        records = [{r.name: dict(r.metadata) for r in make_reader(h).iter_metadata()} for h in (f, g)]
    assert records[0]["amorctl.dataset"] == records[1]["amorctl.dataset"]
