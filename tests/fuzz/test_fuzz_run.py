"""Fuzz: mutated checkpoints (JSON + safetensors, also re-hashed), config TOML, schedule TOML and
weight strings, through `amorctl train --resume`, `train --config`, `tune --schedule` and
`tune --weights`."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import TOY_TOML
from fuzzlib import (
    CI_EXAMPLES,
    NEST_DEPTHS,
    SLOW_EXAMPLES,
    array_mutation,
    byte_mutation,
    check_outcome,
    dumps_json,
    dumps_toml,
    files_under,
    fuzz_settings,
    run_cli,
    scratch,
    structured_mutation,
    write_rehashed_checkpoint,
)
from hypothesis import given
from hypothesis import strategies as st
from safetensors.numpy import load_file

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


CKPT = "checkpoints/iter_000002"


def _resume_edited(run: Path, what: str) -> str:
    """Resume ``run`` one iteration and check the contract; a refused resume changes nothing but,
    after a divergence, the metrics of the diverged iteration. Returns "ok" or the error line."""
    before = files_under(run)
    result = run_cli(["train", "--resume", "--out", run, "--iterations", "3", "--json"])

    def resumed(summary: dict[str, Any]) -> None:
        assert summary["start_iteration"] == 2 and summary["end_iteration"] == 3

    verdict = check_outcome(result, (str(run / CKPT),), what=what, on_success=resumed)
    if verdict != "ok":
        after = files_under(run)
        if "training diverged" in verdict:  # the checkpoint stays, the diverged row is in metrics.csv
            before.pop("metrics.csv"), after.pop("metrics.csv")
        assert after == before, f"{what}: a refused resume changed the run"
    return verdict


@pytest.mark.parametrize("examples", EXAMPLES)
def test_rehashed_checkpoint_variants(examples: int, seed_run: Path) -> None:
    """Arrays (and sometimes the record) edited, then every hash recomputed: the checks behind the
    hashes (types, shapes, finiteness, the optimizer against a fresh one, weights on the simplex)
    must refuse the edit with one line, or the resume must work."""
    record = json.loads((seed_run / f"{CKPT}.json").read_text())
    arrays = load_file(str(seed_run / f"{CKPT}.safetensors"))

    @fuzz_settings(examples)
    @given(st.data())
    def variant(data: st.DataObject) -> None:
        with scratch() as d:
            run = d / "run"
            shutil.copytree(seed_run, run)
            edited, what = data.draw(array_mutation(arrays))
            doc = record
            if data.draw(st.booleans(), label="record too"):
                doc, change = data.draw(structured_mutation(record))
                what += f", {change}"
            write_rehashed_checkpoint(run / f"{CKPT}.json", json.loads(json.dumps(doc)), edited)
            _resume_edited(run, what + " (rehashed)")

    variant()


def _drop(keys: str, index: str, key: str):
    def change(record: dict, arrays: dict) -> None:
        record["trainer"][keys][index].remove(key)
        del arrays[f"trainer/optimizer.{index}.{key}"]

    return change


def _swap_state(record: dict, arrays: dict) -> None:
    for key in ("exp_avg", "exp_avg_sq", "step"):
        a, b = f"trainer/optimizer.1.{key}", f"trainer/optimizer.2.{key}"
        arrays[a], arrays[b] = arrays[b], arrays[a]


def _set(name: str, index: tuple, value: float):
    def change(record: dict, arrays: dict) -> None:
        arrays[name][index] = value

    return change


def _params(params: list[int]):
    def change(record: dict, arrays: dict) -> None:
        record["trainer"]["optimizer_param_groups"][0]["params"] = params

    return change


def _alias_index(record: dict, arrays: dict) -> None:  # "01" and "1": one parameter twice
    record["trainer"]["optimizer_state_keys"]["01"] = record["trainer"]["optimizer_state_keys"]["1"]
    for key in ("exp_avg", "exp_avg_sq", "step"):
        arrays[f"trainer/optimizer.01.{key}"] = arrays[f"trainer/optimizer.1.{key}"]


def _before_meta_hash(change):
    """``change``, in a checkpoint written before ``meta_sha256`` existed."""

    def old(record: dict, arrays: dict) -> None:
        change(record, arrays)
        record["written_before_meta_sha256"] = True  # popped with the hash below

    return old


#: One re-hashed edit per class of deep check, each with the error it must give.
REHASHED_EDITS = {
    "exp_avg deleted": (
        _drop("optimizer_state_keys", "3", "exp_avg"),
        r"optimizer state of parameter 3 has keys \['exp_avg_sq', 'step'\]; Adam keeps \['exp_avg', "
        r"'exp_avg_sq', 'step'\]: the optimizer state is damaged",
    ),
    "exp_avg deleted, before meta_sha256": (
        _before_meta_hash(_drop("optimizer_state_keys", "3", "exp_avg")),
        r"optimizer state of parameter 3 has keys \['exp_avg_sq', 'step'\]",
    ),
    "a duplicate parameter index": (
        _params([0, 0, 2, 3, 4, 5, 6, 7, 8]),
        r"optimizer_param_groups\[0\]\.params = \[0, 0, 2, 3, 4, 5, 6, 7, 8\]; this trainer's optimizer "
        r"has parameters \[0, 1, 2, 3, 4, 5, 6, 7, 8\] \(an index duplicated, missing or permuted\)",
    ),
    "a permuted parameter index": (_params([0, 2, 1, 3, 4, 5, 6, 7, 8]), r"params = \[0, 2, 1, 3"),
    "a generator name that is a list": (  # found by the slow fuzz run: a raw TypeError before
        lambda r, a: r["env"]["rng"].update(bit_generator=[]),
        r"unknown random generator \[\]",
    ),
    "a parameter index spelled twice": (
        _alias_index,
        r"optimizer state has parameter index '01'; this optimizer has parameters 0\.\.8",
    ),
    "state swapped between parameters": (
        _swap_state,
        r"array 'optimizer\.1\.exp_avg' is float32\[8\]; parameter 1 needs float32\[8, 5\]",
    ),
    "a negative second moment": (
        _set("trainer/optimizer.5.exp_avg_sq", (0, 0), -1.0),
        r"array 'optimizer\.5\.exp_avg_sq' holds a non-finite or negative value",
    ),
    "NaN in the env's weights": (
        _set("env/w", (3, 0), np.nan),
        r"env snapshot array 'w': row 3 holds NaN or inf \(nan, [0-9.]+\); weights must be finite, >= 0 "
        r"and sum to 1",
    ),
    "weights off the simplex": (
        _set("env/w", (5, 1), 7.0),
        r"env snapshot array 'w': row 5 holds weights summing to 7\.\d+",
    ),
    "NaN in the actor": (
        _set("trainer/actor.net.0.weight", (1, 2), np.nan),
        r"trainer array 'actor\.net\.0\.weight' holds NaN or inf: the checkpoint is damaged",
    ),
}


@pytest.mark.parametrize("edit", sorted(REHASHED_EDITS))
def test_rehashed_checkpoint_edits_are_refused_by_the_checks_behind_the_hash(
    edit: str, seed_run: Path
) -> None:
    change, message = REHASHED_EDITS[edit]
    with scratch() as d:
        run = d / "run"
        shutil.copytree(seed_run, run)
        record = json.loads((run / f"{CKPT}.json").read_text())
        arrays = load_file(str(run / f"{CKPT}.safetensors"))
        change(record, arrays)
        old = record.pop("written_before_meta_sha256", False)
        write_rehashed_checkpoint(run / f"{CKPT}.json", record, arrays)
        if old:
            record.pop("meta_sha256")
            (run / f"{CKPT}.json").write_text(json.dumps(record))
        verdict = _resume_edited(run, edit)
        assert verdict.startswith(f"error: {run / CKPT}.json: ") and re.search(message, verdict), verdict


HLP_EDITS = {
    "Adam's exp_avg deleted": (
        lambda a: a.pop("trainer/hlp_opt/0/exp_avg"),
        r"optimizer state of parameter 0 has keys \['exp_avg_sq', 'step'\]; Adam keeps",
    ),
    "a parameter index spelled twice": (
        lambda a: a.update(
            {
                f"trainer/hlp_opt/00/{k}": a[f"trainer/hlp_opt/0/{k}"]
                for k in ("exp_avg", "exp_avg_sq", "step")
            }
        ),
        r"optimizer state has parameter index '00'",
    ),
    "a moment of another shape": (
        lambda a: a.update({"trainer/hlp_opt/1/exp_avg": a["trainer/hlp_opt/1/exp_avg"][:1]}),
        r"array 'hlp_opt/1/exp_avg' is float32\[1, 3\]; parameter 1 needs float32\[8, 3\]",
    ),
    "a negative second moment": (
        lambda a: a["trainer/hlp_opt/1/exp_avg_sq"].__setitem__((0, 0), -1.0),
        r"array 'hlp_opt/1/exp_avg_sq' holds a non-finite or negative value",
    ),
}


@pytest.mark.parametrize("edit", sorted(HLP_EDITS))
def test_rehashed_hlp_optimizer_edits_are_refused_before_resume(
    edit: str, toy_run: Path, toy_hlp_config: Any, tmp_path: Path
) -> None:
    """The HLP's Adam states (policy and discriminator) are checked against fresh optimizers on
    resume, like MOPPO's: one line, exit 2, nothing changed."""
    from amorctl.hlp.run import train_hlp
    from amorctl.train.checkpoint import list_checkpoints

    hd = tmp_path / "hlp"
    train_hlp(toy_run, hd, toy_hlp_config)
    ((_, path),) = list_checkpoints(hd / "checkpoints")
    change, message = HLP_EDITS[edit]
    arrays = {k: v.copy() for k, v in load_file(str(path.with_suffix(".safetensors"))).items()}
    change(arrays)
    write_rehashed_checkpoint(path, json.loads(path.read_text()), arrays)
    before = files_under(hd)
    code, _, err = run_cli(["hlp", "train", str(toy_run), "--out", str(hd), "--resume", "--iterations", "2"])
    assert code == 2 and err.count("\n") == 1 and re.search(message, err), err
    assert "the optimizer state is damaged; resume from another checkpoint or start anew" in err
    assert files_under(hd) == before


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


#: The jax-mjx backend keeps its optax state as numbered leaves; a fresh trainer has all of them,
#: so keys and shapes are checked against it, and finiteness like torch-cpu's networks.
JAX_EDITS = {
    "a leaf deleted": (
        lambda r, a: a.pop("trainer/optimizer.13"),
        r"trainer array 'optimizer\.13' is missing",
    ),
    "leaves swapped": (
        lambda r, a: a.update({"trainer/optimizer.13": a["trainer/optimizer.15"]}),
        r"trainer array 'optimizer\.13' is float32\[8, 2\], this run needs float32\[5, 8\]",
    ),
    "NaN in a moment": (
        _set("trainer/optimizer.13", (0, 0), np.nan),
        r"trainer array 'optimizer\.13' holds NaN or inf: the checkpoint is damaged",
    ),
}


@pytest.mark.slow
def test_rehashed_jax_mjx_checkpoint_edits_are_refused(tmp_path: Path) -> None:
    pytest.importorskip("optax")
    (tmp_path / "toy.toml").write_text(TOY_TOML.replace("threads = 1", 'threads = 1\nbackend = "jax-mjx"'))
    seed = tmp_path / "seed"
    assert run_cli(["train", "--config", tmp_path / "toy.toml", "--out", seed, "--json"])[0] == 0
    for edit, (change, message) in JAX_EDITS.items():
        run = tmp_path / edit.replace(" ", "-")
        shutil.copytree(seed, run)
        record = json.loads((run / f"{CKPT}.json").read_text())
        arrays = load_file(str(run / f"{CKPT}.safetensors"))
        change(record, arrays)
        write_rehashed_checkpoint(run / f"{CKPT}.json", record, arrays)
        verdict = _resume_edited(run, edit)
        assert verdict.startswith(f"error: {run / CKPT}.json: ") and re.search(message, verdict), verdict
