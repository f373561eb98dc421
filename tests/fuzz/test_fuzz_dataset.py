"""Fuzz: mutated MCAP motion datasets through `amorctl data show` (bytes, metadata, clip messages)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from fuzzlib import (
    BAD_STRINGS,
    CI_EXAMPLES,
    NEST_DEPTHS,
    SLOW_EXAMPLES,
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

EXAMPLES = [
    pytest.param(CI_EXAMPLES, id="ci"),
    pytest.param(SLOW_EXAMPLES, id="many", marks=pytest.mark.slow),
]
META_KEYS = (
    "version", "fps", "character", "joint_names", "end_effectors", "num_clips", "num_frames",
    "frame_dim", "latent_dim", "sha256",
)  # fmt: skip


def rewrite_mcap(
    src: Path,
    dst: Path,
    meta: Callable[[dict[str, str]], dict[str, str]] = lambda m: m,
    message: Callable[[int, bytes], bytes] = lambda i, b: b,
) -> None:
    """Copy an MCAP dataset record by record, letting ``meta`` change the dataset record and
    ``message`` change clip messages (by index); what a hand-editing user could produce."""
    with open(src, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        records = [(r.name, dict(r.metadata)) for r in reader.iter_metadata()]
        messages = [(ch.topic, s, m) for s, ch, m in reader.iter_messages()]
        attachments = [(a.name, a.media_type, bytes(a.data)) for a in reader.iter_attachments()]
    assert summary is not None
    with open(dst, "wb") as f:
        writer = Writer(f, compression=CompressionType.NONE)
        writer.start(profile="", library="fuzz")
        for name, values in records:
            writer.add_metadata(name, meta(values) if name == "amorctl.dataset" else values)
        schema = next(iter(summary.schemas.values()))
        schema_id = writer.register_schema(schema.name, schema.encoding, schema.data)
        channel_id = writer.register_channel(next(iter(summary.channels.values())).topic, "json", schema_id)
        for k, (_topic, _s, m) in enumerate(messages):
            writer.add_message(channel_id, m.log_time, message(k, m.data), m.publish_time, m.sequence)
        for name, media, data in attachments:
            writer.add_attachment(0, 0, name, media, data)
        writer.finish()


@st.composite
def dataset_variant(draw: st.DrawFn, seed: Path, directory: Path) -> tuple[Path, str]:
    """A damaged copy of ``seed`` in ``directory`` and what was done to it."""
    path = directory / "d.mcap"
    kind = draw(st.sampled_from(("bytes", "bytes", "meta", "message", "message")))
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

        rewrite_mcap(seed, path, meta=meta)
        return path, f"meta {key} {'deleted' if delete else value[:20]}"
    with open(seed, "rb") as f:
        first = json.loads(next(iter(make_reader(f).iter_messages()))[2].data)
    doc, what = draw(structured_mutation(first))
    body = dumps_json(doc, draw(st.sampled_from(NEST_DEPTHS))).encode()
    which = draw(st.integers(0, 1))
    rewrite_mcap(seed, path, message=lambda k, b: body if k == which else b)
    return path, f"message {which}: {what}"


@pytest.mark.parametrize("examples", EXAMPLES)
def test_dataset_variants(examples: int, seed_dataset: Path) -> None:
    @fuzz_settings(examples)
    @given(st.data())
    def variant(data: st.DataObject) -> None:
        with scratch() as d:
            path, what = data.draw(dataset_variant(seed_dataset, d))

            def sane(shown: dict[str, Any]) -> None:
                assert shown["num_frames"] >= 4 and shown["fps"] > 0
                assert len({c["name"] for c in shown["clips"]}) == len(shown["clips"])

            check_outcome(run_cli(["data", "show", path, "--json"]), (str(path),), what=what, on_success=sane)

    variant()


def test_rewrite_keeps_a_dataset_valid(seed_dataset: Path, tmp_path: Path) -> None:
    """The rewriting helper itself changes nothing: the copy loads, with every hash verified."""
    rewrite_mcap(seed_dataset, tmp_path / "copy.mcap")
    code, out, err = run_cli(["data", "show", tmp_path / "copy.mcap", "--json"])
    assert code == 0, err
    assert json.loads(out)["integrity"]["verified"] is True
