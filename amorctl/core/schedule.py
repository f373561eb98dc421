"""Time-varying reward weights from a TOML schedule file (the paper's tuned weights over time).

A schedule is a list of keyframes, each a time ``t`` in seconds and weights by objective name,
with an interpolation rule between them; optional per-motion keyframe lists override it for one
motion. The format, defaults and validation rules are in ``docs/schedules.md``::

    interpolation = "linear"        # or "step"; optional, default "linear"
    default = 0.0                   # raw weight of objectives a keyframe leaves out; optional

    [[keyframe]]
    t = 0.0
    weights = { up = 1, lo = 1, smooth = 1 }

    [[keyframe]]
    t = 2.5
    weights = { up = 1, smooth = 3 }

    [motion.pirouette]              # optional: its own keyframes (and interpolation, default)
    interpolation = "step"
    [[motion.pirouette.keyframe]]
    t = 0.0
    weights = { smooth = 1 }

Keyframe weights are normalized onto the simplex when loaded; interpolation works on the
normalized weights, so ``weights_at`` is on the simplex at every time and equals a keyframe's
weights exactly at its time. Before the first keyframe the first is held, after the last the last.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import tomlkit

from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_write_text
from amorctl.core.weights import normalize_weights

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

Interpolation = Literal["linear", "step"]
INTERPOLATIONS: tuple[str, ...] = ("linear", "step")

_TOP_KEYS = {"interpolation", "default", "keyframe", "motion"}
_MOTION_KEYS = {"interpolation", "default", "keyframe"}
_KEYFRAME_KEYS = {"t", "weights"}
#: A schedule is a few keyframes; a file larger than this is refused before parsing.
MAX_SCHEDULE_BYTES = 1 << 20


@dataclass(frozen=True)
class Track:
    """One keyframe list, normalized and validated.

    Attributes:
        times: [K] float64 keyframe times in seconds, strictly increasing, K >= 1.
        weights: [K, m] float64 keyframe weights, each row on the simplex.
        interpolation: ``"linear"`` or ``"step"``.
    """

    times: np.ndarray
    weights: np.ndarray
    interpolation: Interpolation

    def at_times(self, ts: np.ndarray) -> np.ndarray:
        """Weights at the times ``ts`` [T] (seconds); returns [T, m], every row on the simplex.

        ``step`` holds a keyframe's weights from its time until the next keyframe's time;
        ``linear`` blends the two neighbouring keyframes' normalized weights. Times before the
        first keyframe hold the first, times after the last hold the last.
        """
        ts = np.asarray(ts, dtype=np.float64)
        if ts.ndim != 1 or not np.all(np.isfinite(ts)):
            raise AmorError(f"schedule times must be a 1-D array of finite seconds, got shape {ts.shape}")
        k = len(self.times)
        # idx: the last keyframe at or before t (-1 when t is before the first one)
        idx = np.searchsorted(self.times, ts, side="right") - 1
        lo = np.clip(idx, 0, k - 1)
        if self.interpolation == "step" or k == 1:
            return self.weights[lo].copy()
        hi = np.clip(idx + 1, 0, k - 1)
        span = self.times[hi] - self.times[lo]
        frac = np.where(span > 0, (ts - self.times[lo]) / np.where(span > 0, span, 1.0), 0.0)
        frac = np.clip(frac, 0.0, 1.0)[:, None]
        out = (1.0 - frac) * self.weights[lo] + frac * self.weights[hi]
        return out / out.sum(axis=1, keepdims=True)  # exact on the simplex despite rounding


@dataclass(frozen=True)
class Schedule:
    """Weights over time, for all motions or per motion.

    Attributes:
        objective_names: the m objective names, in reward order.
        track: the top-level keyframes, or None if the file only has per-motion keyframes.
        motions: per-motion tracks by motion name.
        source: the file it came from (for messages).
    """

    objective_names: tuple[str, ...]
    track: Track | None
    motions: dict[str, Track] = field(default_factory=dict)
    source: str = "<schedule>"

    def track_for(self, motion: str | None = None) -> Track:
        """The track that applies to ``motion``: its own if it has one, else the top-level one."""
        if motion is not None and motion in self.motions:
            return self.motions[motion]
        if self.track is None:
            which = f"motion {motion!r}" if motion is not None else "no motion"
            have = ", ".join(sorted(self.motions)) or "none"
            raise AmorError(
                f"schedule {self.source}: no top-level [[keyframe]] list, and {which} has no "
                f"[motion.NAME] keyframes (motions with keyframes: {have})"
            )
        return self.track

    def weights_at(self, t: float, motion: str | None = None) -> np.ndarray:
        """Weights at time ``t`` seconds; returns [m] float64 on the simplex."""
        return self.track_for(motion).at_times(np.array([t], dtype=np.float64))[0]

    def weights_at_times(self, ts: np.ndarray, motion: str | None = None) -> np.ndarray:
        """Weights at times ``ts`` [T] seconds; returns [T, m] float64, rows on the simplex."""
        return self.track_for(motion).at_times(ts)


# ---------------------------------------------------------------------------- loading


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _parse_track(
    table: Mapping[str, Any],
    where: str,
    names: Sequence[str],
    *,
    inherit_interpolation: str,
    inherit_default: float,
) -> Track:
    """Validate one table holding ``interpolation``/``default``/``keyframe`` into a :class:`Track`.

    ``where`` prefixes every message (``schedule FILE`` or ``schedule FILE: motion 'walk'``).
    """
    interpolation = table.get("interpolation", inherit_interpolation)
    if interpolation not in INTERPOLATIONS:
        raise AmorError(f'{where}: interpolation must be "linear" or "step", got {interpolation!r}')
    default = table.get("default", inherit_default)
    if not _is_number(default) or not math.isfinite(default) or default < 0:
        raise AmorError(f"{where}: default must be a finite number >= 0, got {default!r}")

    keyframes = table.get("keyframe")
    if keyframes is None:
        raise AmorError(f"{where}: missing [[keyframe]] tables (each with t and weights)")
    if not isinstance(keyframes, list) or not keyframes:
        raise AmorError(f"{where}: keyframe must be a non-empty array of [[keyframe]] tables")

    times = np.empty(len(keyframes))
    rows = np.empty((len(keyframes), len(names)))
    for i, kf in enumerate(keyframes):
        label = f"{where}: keyframe {i + 1}"
        if not isinstance(kf, dict):
            raise AmorError(f"{label}: expected a table with t and weights")
        unknown = sorted(set(kf) - _KEYFRAME_KEYS)
        if unknown:
            raise AmorError(f"{label}: unknown key(s) {', '.join(unknown)} (allowed: t, weights)")
        for key in ("t", "weights"):
            if key not in kf:
                raise AmorError(f"{label}: missing key {key!r}")
        t = kf["t"]
        if not _is_number(t) or not math.isfinite(t):
            raise AmorError(f"{label}: t must be a finite number of seconds, got {t!r}")
        label = f"{label} (t={t})"
        if i > 0 and t <= times[i - 1]:
            raise AmorError(
                f"{label}: keyframe times must be strictly increasing, but the previous keyframe "
                f"is at t={times[i - 1]:g}"
            )
        times[i] = t
        weights = kf["weights"]
        if not isinstance(weights, dict):
            raise AmorError(f"{label}: weights must be a table like {{ {names[0]} = 1 }}")
        raw = np.full(len(names), float(default))
        for name, value in weights.items():
            if name not in names:
                raise AmorError(f"{label}: unknown objective {name!r} (objectives: {', '.join(names)})")
            if not _is_number(value) or not math.isfinite(value):
                raise AmorError(f"{label}: weight {name} = {value!r} is not a finite number")
            if value < 0:
                raise AmorError(f"{label}: weight {name} = {value} is negative; weights must be >= 0")
            raw[names.index(name)] = float(value)
        if not (raw > 0).any():
            raise AmorError(
                f"{label}: all weights are zero (objectives left out take default = {default:g}); "
                "at least one objective needs a positive weight"
            )
        rows[i] = normalize_weights(raw, source=label)  # overflow-safe: 1e308 + 1e308 is fine
    times.flags.writeable = False
    rows.flags.writeable = False
    return Track(times=times, weights=rows, interpolation=interpolation)


def parse_schedule(
    data: Mapping[str, Any],
    objective_names: Sequence[str],
    motion_names: Sequence[str] | None = None,
    *,
    source: str = "<schedule>",
) -> Schedule:
    """Validate an already-parsed TOML document into a :class:`Schedule` (see :func:`load_schedule`)."""
    names = list(objective_names)
    if not names:
        raise AmorError("schedule: no objective names given")
    where = f"schedule {source}"
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise AmorError(
            f"{where}: unknown top-level key(s) {', '.join(unknown)} "
            "(allowed: interpolation, default, keyframe, motion)"
        )
    interpolation = data.get("interpolation", "linear")
    default = data.get("default", 0.0)
    # validate the top-level interpolation/default even when only motions have keyframes
    if interpolation not in INTERPOLATIONS:
        raise AmorError(f'{where}: interpolation must be "linear" or "step", got {interpolation!r}')
    if not _is_number(default) or not math.isfinite(default) or default < 0:
        raise AmorError(f"{where}: default must be a finite number >= 0, got {default!r}")

    motions_table = data.get("motion", {})
    if not isinstance(motions_table, dict):
        raise AmorError(f"{where}: motion must be tables like [motion.NAME]")
    if "keyframe" not in data and not motions_table:
        raise AmorError(f"{where}: missing [[keyframe]] tables (each with t and weights)")

    track = None
    if "keyframe" in data:
        track = _parse_track(
            data, where, names, inherit_interpolation=interpolation, inherit_default=float(default)
        )
    motions: dict[str, Track] = {}
    for motion, table in motions_table.items():
        mwhere = f"{where}: motion {motion!r}"
        if motion_names is not None and motion not in motion_names:
            raise AmorError(f"{mwhere}: unknown motion (motions: {', '.join(motion_names)})")
        if not isinstance(table, dict):
            raise AmorError(f"{mwhere}: expected a [motion.{motion}] table")
        bad = sorted(set(table) - _MOTION_KEYS)
        if bad:
            raise AmorError(
                f"{mwhere}: unknown key(s) {', '.join(bad)} (allowed: interpolation, default, keyframe)"
            )
        motions[motion] = _parse_track(
            table, mwhere, names, inherit_interpolation=interpolation, inherit_default=float(default)
        )
    return Schedule(objective_names=tuple(names), track=track, motions=motions, source=source)


def load_schedule(
    path: str | os.PathLike[str],
    objective_names: Sequence[str],
    motion_names: Sequence[str] | None = None,
) -> Schedule:
    """Read and validate a schedule file.

    Args:
        path: the TOML file.
        objective_names: the m objective names of the character, in reward order.
        motion_names: the known motions; when given, a ``[motion.NAME]`` not among them is an error.

    Returns:
        :class:`Schedule`.

    Raises:
        AmorError: naming the file (and the keyframe, 1-based, with its time) for a missing or
            unreadable file, malformed TOML, unknown or missing keys, an unknown objective or
            motion, a negative or non-finite weight, all-zero weights, or times not strictly
            increasing.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise AmorError(f"schedule {p}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise AmorError(f"schedule {p}: cannot read ({exc})") from None
    if len(text) > MAX_SCHEDULE_BYTES:
        raise AmorError(f"schedule {p}: larger than {MAX_SCHEDULE_BYTES} characters; not a schedule")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise AmorError(f"schedule {p}: malformed TOML: {exc}") from None
    except RecursionError:
        raise AmorError(f"schedule {p}: malformed TOML: nested too deeply") from None
    return parse_schedule(data, objective_names, motion_names, source=str(p))


# ---------------------------------------------------------------------------- saving

KeyframeLike = tuple[float, np.ndarray | Sequence[float] | Mapping[str, float]]
"""A keyframe to save: (t seconds, weights as [m] in objective order or name -> raw weight)."""


def _keyframe_rows(
    keyframes: Sequence[KeyframeLike], names: Sequence[str], where: str
) -> tuple[np.ndarray, np.ndarray]:
    """Turn (t, weights) pairs into validated [K] times and [K, m] normalized weights."""
    tables = []
    for i, (t, w) in enumerate(keyframes):
        if isinstance(w, Mapping):
            weights = dict(w)
        else:
            row = np.asarray(w, dtype=np.float64).ravel()
            if row.size != len(names):
                raise AmorError(
                    f"{where}: keyframe {i + 1} (t={t}) has {row.size} weights, expected {len(names)}"
                )
            weights = dict(zip(names, row.tolist(), strict=True))
        tables.append({"t": float(t), "weights": weights})
    track = _parse_track(
        {"keyframe": tables}, where, names, inherit_interpolation="linear", inherit_default=0.0
    )
    return track.times, track.weights


def _keyframe_tables(times: np.ndarray, weights: np.ndarray, names: Sequence[str]) -> tomlkit.items.AoT:
    """[[keyframe]] tables: t and every objective's normalized weight (an inline table)."""
    aot = tomlkit.aot()
    for t, row in zip(times, weights, strict=True):
        table = tomlkit.table()
        table.add("t", float(t))
        inline = tomlkit.inline_table()
        inline.update({n: float(v) for n, v in zip(names, row, strict=True)})
        table.add("weights", inline)
        aot.append(table)
    return aot


def dump_schedule(
    keyframes: Sequence[KeyframeLike],
    objective_names: Sequence[str],
    path: str | os.PathLike[str],
    *,
    interpolation: Interpolation = "linear",
    motion_keyframes: Mapping[str, Sequence[KeyframeLike]] | None = None,
) -> None:
    """Write keyframes as a schedule file that :func:`load_schedule` reads back (atomically).

    Weights are validated like a loaded file, normalized onto the simplex, and written for every
    objective (zeros included), so the file does not depend on a default.

    Args:
        keyframes: (t seconds, weights) pairs in increasing time; weights are [m] in the order of
            ``objective_names`` or a mapping name -> raw weight (left-out names are 0). May be empty
            only if ``motion_keyframes`` is given.
        objective_names: the m objective names.
        path: the file to write.
        interpolation: ``"linear"`` or ``"step"`` (written at the top level; motions inherit it).
        motion_keyframes: optional per-motion keyframes, written under ``[motion.NAME]``.

    Raises:
        AmorError: the same rules as :func:`load_schedule`; nothing is written then.
    """
    names = list(objective_names)
    where = f"schedule {Path(path)}"
    if interpolation not in INTERPOLATIONS:
        raise AmorError(f'{where}: interpolation must be "linear" or "step", got {interpolation!r}')
    if not keyframes and not motion_keyframes:
        raise AmorError(f"{where}: no keyframes to save")
    doc = tomlkit.document()
    doc.add(
        tomlkit.comment(
            "amorctl weight schedule (docs/schedules.md); weights are normalized onto the simplex"
        )
    )
    doc.add("interpolation", interpolation)
    if keyframes:
        times, weights = _keyframe_rows(keyframes, names, where)
        doc.add("keyframe", _keyframe_tables(times, weights, names))
    if motion_keyframes:
        motions = tomlkit.table(is_super_table=True)
        for motion, kfs in motion_keyframes.items():
            mwhere = f"{where}: motion {motion!r}"
            if not kfs:
                raise AmorError(f"{mwhere}: no keyframes to save")
            times, weights = _keyframe_rows(kfs, names, mwhere)
            table = tomlkit.table()
            table.add("keyframe", _keyframe_tables(times, weights, names))
            motions.add(motion, table)
        doc.add("motion", motions)
    atomic_write_text(path, tomlkit.dumps(doc))
