"""Fuzz: mutated checkpoints (JSON + safetensors), config TOML, schedule TOML and weight strings,
through `amorctl train --resume`, `train --config`, `tune --schedule` and `tune --weights`."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest
from conftest import TOY_TOML
from fuzzlib import (
    CI_EXAMPLES,
    NEST_DEPTHS,
    SLOW_EXAMPLES,
    byte_mutation,
    check_outcome,
    dumps_json,
    dumps_toml,
    files_under,
    fuzz_settings,
    run_cli,
    scratch,
    structured_mutation,
)
from hypothesis import given
from hypothesis import strategies as st

from amorctl.core.config import tomllib
from amorctl.train.checkpoint import record_sha256

EXAMPLES = [
    pytest.param(CI_EXAMPLES, id="ci"),
    pytest.param(SLOW_EXAMPLES, id="many", marks=pytest.mark.slow),
]
SCHEDULE = """interpolation = "linear"
[[keyframe]]
t = 0.0
weights = { right = 1, left = 0.5 }
[[keyframe]]
t = 0.1
weights = { left = 2 }
[motion.x]
interpolation = "step"
[[motion.x.keyframe]]
t = 0.0
weights = { right = 1 }
"""


@pytest.fixture(autouse=True)
def _one_thread():
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _toml_variant(data: st.DataObject, text: str) -> tuple[bytes, str]:
    """Bytes of a damaged TOML file: byte-level, or a key deleted / a value replaced."""
    if data.draw(st.booleans(), label="bytes"):
        return data.draw(byte_mutation(text.encode())), "bytes"
    for _ in range(20):
        doc, what = data.draw(structured_mutation(tomllib.loads(text), allow_null=False))
        body = dumps_toml(doc, data.draw(st.sampled_from(NEST_DEPTHS)))
        if body is not None:
            return body.encode(), what
    return text.encode(), "unchanged"


@pytest.mark.parametrize("examples", EXAMPLES)
def test_checkpoint_variants(examples: int, seed_run: Path) -> None:
    json_name = "iter_000002.json"
    record = json.loads((seed_run / "checkpoints" / json_name).read_text())

    @fuzz_settings(examples)
    @given(st.data())
    def variant(data: st.DataObject) -> None:
        with scratch() as d:
            run = d / "run"
            shutil.copytree(seed_run, run)
            ckpt = run / "checkpoints"
            kind = data.draw(st.sampled_from(("json-bytes", "json", "json", "tensors")))
            if kind == "json-bytes":
                target = ckpt / json_name
                target.write_bytes(data.draw(byte_mutation(target.read_bytes())))
                what = kind
            elif kind == "json":
                doc, what = data.draw(structured_mutation(record))
                if isinstance(doc, dict) and data.draw(st.booleans(), label="rehash"):
                    # a deliberate edit that also fixes the record's own hash: the type and meaning
                    # checks must catch it, not the hash
                    doc["meta_sha256"] = record_sha256(doc)
                    what += " (rehashed)"
                (ckpt / json_name).write_text(dumps_json(doc, data.draw(st.sampled_from(NEST_DEPTHS))))
            else:
                target = ckpt / "iter_000002.safetensors"
                target.write_bytes(data.draw(byte_mutation(target.read_bytes())))
                what = kind
            before = files_under(run)
            result = run_cli(["train", "--resume", "--out", run, "--iterations", "3", "--json"])
            names = (str(ckpt), str(run))

            def resumed(summary: dict[str, Any]) -> None:
                assert summary["start_iteration"] == 2 and summary["end_iteration"] == 3

            verdict = check_outcome(result, names, what=what, on_success=resumed)
            if verdict != "ok":
                assert files_under(run) == before, f"{what}: a refused resume changed the run"

    variant()


@pytest.mark.parametrize("examples", EXAMPLES)
def test_config_variants(examples: int) -> None:
    @fuzz_settings(examples)
    @given(st.data())
    def variant(data: st.DataObject) -> None:
        body, what = _toml_variant(data, TOY_TOML)
        with scratch() as d:
            (d / "c.toml").write_bytes(body)
            out = d / "run"
            # --env toy and --iterations 1 keep every variant to a second: a mutated `kind` would
            # otherwise build the default tracking dataset (minutes), a mutated `iterations` train long
            args = ["train", "--config", d / "c.toml", "--env", "toy", "--iterations", "1", "--out", out]
            check_outcome(run_cli([*args, "--json"]), (str(d / "c.toml"),), left_out=(out,), what=what)

    variant()


@pytest.mark.parametrize("examples", EXAMPLES)
def test_schedule_variants(examples: int, seed_run: Path) -> None:
    @fuzz_settings(examples)
    @given(st.data())
    def variant(data: st.DataObject) -> None:
        body, what = _toml_variant(data, SCHEDULE)
        with scratch() as d:
            (d / "s.toml").write_bytes(body)
            result = run_cli(["tune", seed_run, "--schedule", d / "s.toml", "--json"])

            def sane(rollout: dict[str, Any]) -> None:
                assert rollout["steps"] > 0 and set(rollout["returns"]) == {"right", "left"}

            check_outcome(result, (str(d / "s.toml"),), what=what, on_success=sane)

    variant()


WEIGHT_TEXT = st.text(alphabet="rightlef=,.0123456789e+-infa ", max_size=40)


@pytest.mark.parametrize("examples", EXAMPLES)
def test_weight_string_variants(examples: int, seed_run: Path) -> None:
    @fuzz_settings(examples)
    @given(
        st.one_of(
            WEIGHT_TEXT,
            st.sampled_from(
                ("", " ", ",", "right=1,,left=1", "right=1e308,left=1e308", "right=1e-320", "uniform")
            ),
            st.builds(lambda a, b: f"right={a!r},left={b!r}", st.floats(), st.floats()),
        )
    )
    def variant(text: str) -> None:
        result = run_cli(["tune", seed_run, "--weights", text, "--json"])

        def sane(rollout: dict[str, Any]) -> None:
            assert rollout["steps"] > 0

        check_outcome(result, ("--weights",), what=repr(text), on_success=sane)
        with scratch() as d:
            out = d / "run"
            args = ["train", "--env", "toy", "--fixed-weights", text, "--iterations", "0", "--out", out]
            result = run_cli([*args, "--json"])
            check_outcome(result, ("--fixed-weights",), left_out=(out,), what=repr(text))

    variant()
