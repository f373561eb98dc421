"""The fuzz suite's machinery: mutations of a valid seed file, the CLI run in-process, the verdict.

Every variant of a seed file goes through the real entry point (:func:`amorctl.cli.main.main`)
and must end in one of two ways:

- exit 0, nothing on stderr, and finite JSON on stdout (no NaN/inf anywhere), or
- exit 2 with exactly one ``error: ...`` line on stderr that names the file (or the flag),
  and no output file left behind.

Never exit 1 (an unexpected exception), never a traceback, never a warning line.

Mutations are drawn by hypothesis: byte-level (truncate, flip a byte, delete / insert /
duplicate a span) on any file, and structured ones on parsed JSON / TOML documents (delete a key,
replace a value with NaN, inf, a huge number, a wrong type, or a deeply nested list) and on
arrays (deleted, a bad value, another dtype or shape, swapped with another). Files that carry
hashes (checkpoints, datasets) are also mutated and then re-hashed, as a user who edits a file and
fixes its hashes would: then only the checks behind the hashes stand between the edit and a run.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import HealthCheck, Phase, settings
from hypothesis import strategies as st

from amorctl.cli.main import main
from amorctl.train.checkpoint import FORMAT as CHECKPOINT_FORMAT
from amorctl.train.checkpoint import record_sha256

#: Variants per file class: the default (CI) run and the ``-m slow`` run.
CI_EXAMPLES = int(os.environ.get("AMORCTL_FUZZ_EXAMPLES", "30"))
SLOW_EXAMPLES = int(os.environ.get("AMORCTL_FUZZ_SLOW_EXAMPLES", "400"))
#: Placeholder replaced by a deeply nested list after serialization (serializers recurse).
NEST = "__amorctl_fuzz_nest__"
NEST_DEPTHS = (50, 3000, 100_000)


#: ``AMORCTL_FUZZ_RANDOM=1``: the slow run draws new variants every time (to hunt); by default it
#: draws the same ones, so CI's verdict does not depend on the draw.
RANDOM_SLOW = os.environ.get("AMORCTL_FUZZ_RANDOM", "") not in ("", "0")


def fuzz_settings(examples: int) -> settings:
    """Deterministic (the same variants every run) unless the slow run is asked to be random."""
    return settings(
        max_examples=examples,
        deadline=None,
        database=None,
        derandomize=examples <= CI_EXAMPLES or not RANDOM_SLOW,
        phases=(Phase.explicit, Phase.generate, Phase.shrink),
        suppress_health_check=list(HealthCheck),
    )


# --- values a corrupt file may hold -------------------------------------------------------------
BAD_NUMBERS: tuple[Any, ...] = (
    math.nan,
    math.inf,
    -math.inf,
    1e308,
    -1e308,
    1e300,
    2**63 - 1,
    -(2**63),
    10**9,
    -1,
    0,
    0.0,
    -0.0,
    5e-324,
    0.5,
)
BAD_OTHERS: tuple[Any, ...] = ("", "x", "1", "nan", True, False, [], {}, [1, 2, 3], {"a": 1}, NEST)
BAD_STRINGS: tuple[str, ...] = (
    "",
    "0",
    "-1",
    "nan",
    "inf",
    "1e308",
    "x",
    "[",
    "{}",
    "[]",
    '["a", "a"]',
    '"a"',
    "99",
    "1.5",
    "[" * 5000 + "]" * 5000,
)


def bad_values(allow_null: bool) -> st.SearchStrategy[Any]:
    values = BAD_NUMBERS + BAD_OTHERS + ((None,) if allow_null else ())
    return st.sampled_from(values)


# --- byte-level mutations -----------------------------------------------------------------------
@st.composite
def byte_mutation(draw: st.DrawFn, data: bytes) -> bytes:
    """One of: truncate, flip a byte, delete a span, insert random bytes, duplicate a span."""
    n = len(data)
    kind = draw(st.sampled_from(("truncate", "flip", "flip", "delete", "insert", "duplicate")))
    i = draw(st.integers(0, max(n - 1, 0)))
    if kind == "truncate":
        return data[:i]
    if kind == "flip":
        mask = draw(st.integers(1, 255))
        return data[:i] + bytes([data[i] ^ mask]) + data[i + 1 :] if n else data
    j = min(n, i + draw(st.integers(1, 64)))
    if kind == "delete":
        return data[:i] + data[j:]
    if kind == "insert":
        return data[:i] + draw(st.binary(min_size=1, max_size=32)) + data[i:]
    return data[:j] + data[i:j] + data[j:]


# --- structured mutations -----------------------------------------------------------------------
Path_ = tuple[Any, ...]


def node_paths(doc: Any, prefix: Path_ = (), limit: int = 4000) -> list[Path_]:
    """Paths (tuples of keys / indices) to every node below the root (long lists sampled)."""
    out: list[Path_] = []
    if isinstance(doc, dict):
        items: list[tuple[Any, Any]] = list(doc.items())
    elif isinstance(doc, list):
        idx = sorted({0, 1, len(doc) // 2, len(doc) - 2, len(doc) - 1} & set(range(len(doc))))
        items = [(i, doc[i]) for i in idx]
    else:
        return out
    for key, value in items:
        out.append((*prefix, key))
        if len(out) < limit:
            out.extend(node_paths(value, (*prefix, key), limit - len(out)))
    return out


@st.composite
def structured_mutation(draw: st.DrawFn, doc: Any, allow_null: bool = True) -> tuple[Any, str]:
    """(a mutated deep copy of ``doc``, a description): a key deleted or a value replaced."""
    doc = json.loads(json.dumps(doc))
    paths = node_paths(doc)
    path = draw(st.sampled_from(paths))
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    last = path[-1]
    if draw(st.booleans()) and isinstance(parent, dict):
        del parent[last]
        return doc, f"delete {path}"
    value = draw(bad_values(allow_null))
    parent[last] = value
    return doc, f"{path} = {value!r}"[:200]


@st.composite
def array_mutation(draw: st.DrawFn, arrays: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], str]:
    """(a mutated copy of ``arrays``, a description): one array deleted, given a bad value, cast to
    another dtype, reshaped (flattened, a row dropped or repeated) or swapped with another."""
    arrays = {k: v.copy() for k, v in arrays.items()}
    key = draw(st.sampled_from(sorted(arrays)))
    a = arrays[key]
    kind = draw(st.sampled_from(("delete", "value", "value", "dtype", "shape", "swap")))
    if kind == "delete":
        del arrays[key]
        return arrays, f"delete {key}"
    if kind == "value" and a.size:
        flat = a.reshape(-1)
        i = draw(st.integers(0, flat.size - 1))
        if a.dtype.kind == "f":
            value: Any = draw(st.sampled_from(BAD_NUMBERS))
            with np.errstate(over="ignore"):  # 1e308 in a float32 array: inf
                flat[i] = value
        else:
            value = draw(st.sampled_from((-1, 0, 1, 255, 2**31)))
            flat[i] = np.array(value).astype(a.dtype)
        arrays[key] = flat.reshape(a.shape)
        return arrays, f"{key}.flat[{i}] = {value!r}"
    if kind == "dtype":
        dtype = draw(st.sampled_from((np.float64, np.float32, np.float16, np.int64, np.uint8, np.bool_)))
        with np.errstate(invalid="ignore", over="ignore"):  # NaN or 1e300 as an integer
            arrays[key] = a.astype(dtype)
        return arrays, f"{key} as {np.dtype(dtype)}"
    if kind == "shape":
        how = draw(st.sampled_from(("flatten", "drop", "repeat")))
        rows = a.reshape(1, -1) if a.ndim == 0 else a
        reshaped = {"flatten": a.reshape(-1), "drop": rows[:-1], "repeat": np.concatenate([rows, rows[-1:]])}
        arrays[key] = np.ascontiguousarray(reshaped[how])
        return arrays, f"{how} a row of {key}"
    other = draw(st.sampled_from(sorted(arrays)))
    arrays[key], arrays[other] = arrays[other], a
    return arrays, f"swap {key} and {other}"


def write_rehashed_checkpoint(json_path: Path, record: Any, arrays: dict[str, np.ndarray]) -> None:
    """Write a checkpoint (``json_path`` and the tensors file beside it) from ``record`` and
    ``arrays`` with every hash recomputed: the tensors' size and SHA-256 and the record's own
    ``meta_sha256`` (where the record is still a table with a ``tensors`` table)."""
    from safetensors.numpy import save

    data = save(
        {k: np.ascontiguousarray(v) for k, v in arrays.items()}, metadata={"format": CHECKPOINT_FORMAT}
    )
    json_path.with_suffix(".safetensors").write_bytes(data)
    if isinstance(record, dict):
        if isinstance(record.get("tensors"), dict):
            record["tensors"].update(bytes=len(data), sha256=hashlib.sha256(data).hexdigest())
        record["meta_sha256"] = record_sha256(record)
    json_path.write_text(json.dumps(record, allow_nan=True))


def dumps_json(doc: Any, depth: int) -> str:
    text = json.dumps(doc, allow_nan=True)
    return text.replace(json.dumps(NEST), "[" * depth + "]" * depth)


def dumps_toml(doc: Any, depth: int) -> str | None:
    """TOML text of ``doc`` (None when TOML cannot hold it: a null)."""
    import tomlkit

    try:
        text = tomlkit.dumps(doc)
    except (TypeError, ValueError, tomlkit.exceptions.TOMLKitError):
        return None
    return text.replace(f'"{NEST}"', "[" * depth + "]" * depth)


# --- running the CLI ----------------------------------------------------------------------------
def run_cli(args: list[str]) -> tuple[int, str, str]:
    """``amorctl ARGS`` in-process: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


@contextlib.contextmanager
def scratch() -> Iterator[Path]:
    """A fresh directory per variant (hypothesis reuses one test call for many variants)."""
    path = Path(tempfile.mkdtemp(prefix="amorctl-fuzz-"))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


def _reject_constant(name: str) -> float:
    raise AssertionError(f"non-finite number {name} in JSON output")


def _check_finite(value: Any, where: str = "$") -> None:
    if isinstance(value, float):
        assert math.isfinite(value), f"{where} = {value}"
    elif isinstance(value, dict):
        for k, v in value.items():
            _check_finite(v, f"{where}.{k}")
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _check_finite(v, f"{where}[{i}]")


def files_under(directory: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()
    }


def check_outcome(
    result: tuple[int, str, str],
    names: tuple[str, ...],
    *,
    left_out: tuple[Path, ...] = (),
    what: str = "",
    on_success: Callable[[Any], None] | None = None,
) -> str:
    """Assert the contract on one variant; returns "ok" or the error line.

    Args:
        result: (exit code, stdout, stderr) of :func:`run_cli` (with ``--json``).
        names: the error line must contain one of these (the file's path, or the flag).
        left_out: paths that must not exist after a refusal (output files, run directories).
        what: the mutation, for assertion messages.
        on_success: further checks of the parsed JSON output of an accepted variant.
    """
    code, out, err = result
    assert "Traceback" not in err, f"{what}: traceback\n{err}"
    assert code in (0, 2), f"{what}: exit {code}\n{err}"
    if code == 2:
        lines = err.splitlines()
        one_line = len(lines) == 1 and lines[0].startswith("error: ")
        assert one_line, f"{what}: stderr is not one error line:\n{err}"
        assert any(n in lines[0] for n in names), f"{what}: error does not name {names}: {lines[0]}"
        for path in left_out:
            assert not path.exists(), f"{what}: refused, but {path} was left behind"
        return lines[0]
    assert err == "", f"{what}: accepted but wrote to stderr:\n{err}"
    data = json.loads(out, parse_constant=_reject_constant)
    _check_finite(data)
    if on_success is not None:
        on_success(data)
    return "ok"
