"""Reward weights on the simplex: parsing user strings, Dirichlet sampling, checks.

A weight vector ``w`` has one entry per objective (m entries), every entry >= 0, summing to 1.
The paper samples ``w ~ Dirichlet(1)``, the uniform distribution on the simplex.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from amorctl.core.errors import AmorError


def parse_weight_pairs(text: str, *, source: str = "weights") -> list[tuple[str, float]]:
    """Parse the syntax of ``"up=2,smooth=1"`` into (name, value) pairs, without knowing the names.

    Raises:
        AmorError: starting with ``source``: empty text, an empty item (``up=1,,lo=1``), a pair
            without ``=``, a repeated name, or a value that is not a finite number >= 0.
    """
    stripped = text.strip()
    if not stripped:
        raise AmorError(f"{source}: empty weights; give name=value pairs (or 'uniform')")
    pairs: list[tuple[str, float]] = []
    for part in stripped.split(","):
        part = part.strip()
        if not part:
            raise AmorError(f"{source}: empty item in {text!r} (two commas in a row or a trailing comma)")
        if "=" not in part:
            raise AmorError(f"{source}: {part!r} is not name=value")
        key, _, value = (s.strip() for s in part.partition("="))
        if not key:
            raise AmorError(f"{source}: {part!r} has no objective name before '='")
        if any(key == k for k, _ in pairs):
            raise AmorError(f"{source}: objective {key!r} given twice")
        try:
            number = float(value)
        except ValueError:
            raise AmorError(f"{source}: {key}={value!r} is not a number") from None
        if not math.isfinite(number):
            raise AmorError(f"{source}: {key}={value} is not finite")
        if number < 0:
            raise AmorError(f"{source}: {key}={value} is negative; weights must be >= 0")
        pairs.append((key, number))
    return pairs


def parse_weights(
    text: str, names: Sequence[str], *, default: float = 0.0, source: str = "weights"
) -> np.ndarray:
    """Parse ``"up=2,smooth=1"`` into a weight vector on the simplex, ordered as ``names``.

    Objectives not named get ``default`` before normalization. ``"uniform"`` gives 1/m each.
    Values are normalized to sum to 1, so ``up=2,smooth=1`` and ``up=0.66,smooth=0.33`` agree;
    the normalization cannot overflow (``up=1e308,lo=1e308`` is ``up=0.5,lo=0.5``).

    Args:
        text: comma-separated ``name=value`` pairs (spaces allowed) or ``"uniform"``.
        names: the objective names, in reward order (m of them).
        default: the raw value of objectives the text leaves out.
        source: where the text came from (``--weights``, ``[env] fixed_weights``), starts messages.

    Returns:
        [m] float64 weights, non-negative, summing to 1.

    Raises:
        AmorError: naming ``source``: empty text, an empty item, a pair without ``=``, an unknown
            or repeated name, a value that is not a finite non-negative number, or all values zero.
    """
    names = list(names)
    if text.strip().lower() == "uniform":
        return np.full(len(names), 1.0 / len(names))
    raw = np.full(len(names), float(default))
    for key, number in parse_weight_pairs(text, source=source):
        if key not in names:
            raise AmorError(f"{source}: unknown objective {key!r} (objectives: {', '.join(names)})")
        raw[names.index(key)] = number
    return normalize_weights(raw, source=source)


def normalize_weights(raw: np.ndarray, *, source: str = "weights") -> np.ndarray:
    """Project non-negative raw weights [..., m] onto the simplex by dividing by their sum.

    Each row is first divided by its largest entry, so the sum is at most m and cannot overflow
    even for entries near the float maximum.

    Raises:
        AmorError: naming ``source``: a negative or non-finite entry, or a row that sums to zero.
    """
    raw = np.asarray(raw, dtype=np.float64)
    if not np.all(np.isfinite(raw)):
        raise AmorError(f"{source}: weights must be finite")
    if np.any(raw < 0):
        raise AmorError(f"{source}: weights must be >= 0")
    peak = raw.max(axis=-1, keepdims=True) if raw.size else raw
    if raw.shape[-1] == 0 or np.any(peak <= 0):
        raise AmorError(f"{source}: weights are all zero; at least one objective needs a positive weight")
    scaled = raw / peak
    return scaled / scaled.sum(axis=-1, keepdims=True)


#: How far a row of weights may sum from 1 (float32 rounding of a Dirichlet draw is ~1e-7).
SIMPLEX_ATOL = 1e-4


def check_simplex_rows(w: np.ndarray, source: str = "weights") -> None:
    """Raise unless every row of ``w`` [..., m] lies on the simplex (finite, >= 0, sum 1).

    Raises:
        AmorError: ``"<source>: row i holds <what was found> (<the row>); weights must be finite,
            >= 0 and sum to 1"`` (without ``row i`` for one vector [m]).
    """
    w = np.asarray(w, dtype=np.float64)
    rows = w.reshape(-1, w.shape[-1]) if w.ndim else w.reshape(1, 1)
    finite = np.isfinite(rows).all(axis=1)
    negative = (rows < 0).any(axis=1)
    with np.errstate(invalid="ignore", over="ignore"):
        off = ~(np.abs(rows.sum(axis=1) - 1.0) <= SIMPLEX_ATOL)
    bad = ~finite | negative | off
    if not bad.any():
        return
    i = int(np.argmax(bad))
    what = (
        "NaN or inf"
        if not finite[i]
        else ("a negative weight" if negative[i] else f"weights summing to {rows[i].sum():.6g}")
    )
    shown = ", ".join(f"{x:.4g}" for x in rows[i][:8]) + (", ..." if rows.shape[1] > 8 else "")
    row = f"row {i} " if w.ndim > 1 else ""
    raise AmorError(f"{source}: {row}holds {what} ({shown}); weights must be finite, >= 0 and sum to 1")


def sample_dirichlet(
    rng: np.random.Generator, n: int, m: int, alpha: float = 1.0, dtype: type = np.float32
) -> np.ndarray:
    """Draw n weight vectors from Dirichlet(alpha) over m objectives (alpha=1: uniform on the simplex).

    amorctl's one numpy Dirichlet sampler: env episodes, sweeps, the weight-sampling levers,
    coverage designs and export checks all draw through it (the jax-mjx backend draws on device
    with ``jax.random.dirichlet``). With m = 1 every row is ``[1]`` and ``rng`` is not advanced.

    Args:
        dtype: of the result; float32 (what envs hand the policy) or float64 (numpy's own draw).

    Returns:
        [n, m] ``dtype``, each row on the simplex.
    """
    if m == 1:
        return np.ones((n, 1), dtype=dtype)
    w = rng.dirichlet(np.full(m, alpha), size=n)
    return w.astype(dtype)


def format_weights(w: np.ndarray, names: Sequence[str]) -> str:
    """The inverse of :func:`parse_weights`: ``"up=0.5,lo=0.5,..."`` with 4 significant digits."""
    return ",".join(f"{n}={float(v):.4g}" for n, v in zip(names, np.asarray(w).ravel(), strict=True))


def simplex_grid(m: int, divisions: int) -> np.ndarray:
    """All weight vectors on the simplex whose entries are multiples of ``1 / divisions``.

    The uniform grid alternative to Dirichlet sampling: ``C(divisions + m - 1, m - 1)`` vectors,
    including the corners (one objective only) and, when ``divisions`` is a multiple of m, the
    equal-weights vector. Rows are in lexicographic order of their integer counts, largest first.

    Args:
        m: number of objectives, >= 1.
        divisions: grid resolution, >= 1 (``divisions=1`` gives the m corners).

    Returns:
        [C(divisions + m - 1, m - 1), m] float64, each row summing to 1.
    """
    if m < 1:
        raise AmorError(f"simplex grid: need at least one objective, got m={m}")
    if divisions < 1:
        raise AmorError(f"simplex grid: divisions must be >= 1, got {divisions}")
    rows: list[tuple[int, ...]] = []

    def fill(prefix: tuple[int, ...], left: int) -> None:
        if len(prefix) == m - 1:
            rows.append((*prefix, left))
            return
        for k in range(left, -1, -1):
            fill((*prefix, k), left - k)

    fill((), divisions)
    return np.asarray(rows, dtype=np.float64) / divisions
