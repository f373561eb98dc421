"""Fuzz: mutated motion source files (DeepMimic JSON, BVH, robot .npz) through `amorctl preprocess`."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import BVH_MAP, bvh_text, deepmimic_doc, npz_arrays
from fuzzlib import (
    CI_EXAMPLES,
    NEST_DEPTHS,
    SLOW_EXAMPLES,
    bad_values,
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

from amorctl.motion.dataset import load_dataset

EXAMPLES = [
    pytest.param(CI_EXAMPLES, id="ci"),
    pytest.param(SLOW_EXAMPLES, id="many", marks=pytest.mark.slow),
]


def _preprocess(directory: Path, source: Path, character: str, *extra: str) -> None:
    """Run preprocess on ``source`` and check the contract; an accepted dataset must load."""
    out = directory / "out" / "d.mcap"
    result = run_cli(["preprocess", source, "-c", character, "--out", out, "--no-vae", "--json", *extra])

    def dataset_is_sane(summary: dict) -> None:
        lib = load_dataset(out)  # finite, shapes, >= 2 frames per clip: checked by the loader
        assert lib.num_frames == summary["num_frames"] >= 2

    check_outcome(result, (str(source),), left_out=(out,), what=source.name, on_success=dataset_is_sane)
    leftovers = list((directory / "out").glob("*")) if (directory / "out").exists() else []
    assert result[0] == 0 or not leftovers, leftovers


@pytest.mark.parametrize("examples", EXAMPLES)
def test_deepmimic_variants(examples: int) -> None:
    text = json.dumps(deepmimic_doc())

    @fuzz_settings(examples)
    @given(st.data())
    def variant(data: st.DataObject) -> None:
        if data.draw(st.booleans(), label="bytes"):
            body = data.draw(byte_mutation(text.encode()))
        else:
            doc, _ = data.draw(structured_mutation(deepmimic_doc()))
            body = dumps_json(doc, data.draw(st.sampled_from(NEST_DEPTHS))).encode()
        with scratch() as d:
            (d / "clip.txt").write_bytes(body)
            _preprocess(d, d / "clip.txt", "humanoid36")

    variant()


@pytest.mark.parametrize("examples", EXAMPLES)
def test_bvh_variants(examples: int) -> None:
    text = bvh_text()
    lines = text.splitlines()

    @fuzz_settings(examples)
    @given(st.data())
    def variant(data: st.DataObject) -> None:
        kind = data.draw(st.sampled_from(("bytes", "token", "lines", "nest")))
        if kind == "bytes":
            body = data.draw(byte_mutation(text.encode()))
        elif kind == "token":  # one number replaced by a bad one
            i = data.draw(st.integers(0, len(lines) - 1))
            tokens = lines[i].split() or [""]
            j = data.draw(st.integers(0, len(tokens) - 1))
            tokens[j] = repr(data.draw(st.sampled_from((1e308, -1e308, 1e300, 1e9, 0, -1, 2**63, "nan"))))
            body = "\n".join([*lines[:i], " ".join(tokens), *lines[i + 1 :]]).encode()
        elif kind == "lines":  # a line deleted or repeated (header/body disagreement)
            i = data.draw(st.integers(0, len(lines) - 1))
            repeat = data.draw(st.booleans())
            body = "\n".join(lines[: i + 1] + ([lines[i]] if repeat else []) + lines[i + 1 :]).encode()
            if not repeat:
                body = "\n".join(lines[:i] + lines[i + 1 :]).encode()
        else:  # a hierarchy nested thousands of joints deep
            depth = data.draw(st.sampled_from(NEST_DEPTHS))
            nest = "".join(f"JOINT j{k}\n{{\nOFFSET 0 0 0\nCHANNELS 0\n" for k in range(depth))
            body = text.replace("JOINT chest", nest + "}\n" * depth + "JOINT chest", 1).encode()
        with scratch() as d:
            (d / "clip.bvh").write_bytes(body)
            (d / "map.toml").write_text(BVH_MAP)
            _preprocess(d, d / "clip.bvh", "humanoid36", "--map", str(d / "map.toml"))

    variant()


def _npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


@pytest.mark.parametrize("examples", EXAMPLES)
def test_npz_variants(examples: int) -> None:
    seed = npz_arrays()
    good = _npz_bytes(seed)

    @fuzz_settings(examples)
    @given(st.data())
    def variant(data: st.DataObject) -> None:
        kind = data.draw(st.sampled_from(("bytes", "value", "delete", "shape", "dtype")))
        arrays = {k: v.copy() for k, v in seed.items()}
        key = data.draw(st.sampled_from(sorted(arrays)))
        if kind == "bytes":
            body = data.draw(byte_mutation(good))
        else:
            if kind == "delete":
                del arrays[key]
            elif kind == "shape":
                a = arrays[key]
                arrays[key] = a.reshape(-1) if a.ndim > 1 else np.concatenate([a.reshape(-1)] * 2)
            elif kind == "dtype":
                arrays[key] = np.array(["x"] * max(arrays[key].size, 1))
            else:
                value = data.draw(bad_values(allow_null=False).filter(lambda v: isinstance(v, int | float)))
                if arrays[key].dtype.kind == "f":
                    flat = arrays[key].reshape(-1)
                    flat[data.draw(st.integers(0, flat.size - 1))] = float(value)
                else:
                    arrays[key] = np.asarray(value, dtype=np.float64)
            body = _npz_bytes(arrays)
        with scratch() as d:
            (d / "robot.npz").write_bytes(body)
            _preprocess(d, d / "robot.npz", "biped20")

    variant()


def test_npz_seed_is_a_zip_of_the_arrays() -> None:
    """The seed itself is valid (so the variants above start from a file that preprocesses)."""
    with zipfile.ZipFile(io.BytesIO(_npz_bytes(npz_arrays()))) as z:
        assert sorted(z.namelist())[0] == "body_names.npy"
    with scratch() as d:
        (d / "robot.npz").write_bytes(_npz_bytes(npz_arrays()))
        code, out, err = run_cli(
            ["preprocess", d / "robot.npz", "-c", "biped20", "--out", d / "o.mcap", "--no-vae", "--json"]
        )
        assert code == 0, err
        assert json.loads(out)["num_frames"] >= 6
