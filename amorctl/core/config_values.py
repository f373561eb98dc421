"""One config value checked against its field: type, bounds, choices and length, with a message
that names where the value came from (:mod:`amorctl.core.config` reads every TOML value through
:func:`coerce_value`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, get_args, get_origin

from amorctl.core.errors import AmorError

#: The longest string field (paths, ids, weight strings).
MAX_STRING = 4096


def range_text(meta: Mapping[str, Any]) -> str:
    """The bounds of a field for messages: ``1..100000``, ``> 0 and <= 3600``, ``>= 0``."""
    lo, hi, gt = meta.get("min"), meta.get("max"), meta.get("gt")
    if gt is not None:
        return f"> {gt:g}" + (f" and <= {hi:g}" if hi is not None else "")
    if lo is not None and hi is not None:
        return f"{lo:g}..{hi:g}"
    return f">= {lo:g}" if lo is not None else f"<= {hi:g}"


def in_range(value: float, meta: Mapping[str, Any]) -> bool:
    """Whether ``value`` lies within a field's bounds."""
    lo, hi, gt = meta.get("min"), meta.get("max"), meta.get("gt")
    return (lo is None or value >= lo) and (hi is None or value <= hi) and (gt is None or value > gt)


def coerce_value(value: Any, hint: Any, where: str, meta: Mapping[str, Any]) -> Any:
    """Check one TOML value against a field's type hint and bounds; ints are accepted for floats.

    ``where`` is ``"<source>: [section] key"``; every message starts with it.
    """
    if get_origin(hint) is tuple:
        (item,) = get_args(hint)[:1]
        if not isinstance(value, list | tuple):
            raise AmorError(f"{where}: expected a list of {item.__name__}, got {value!r}")
        longest, fewest = meta.get("max_len"), meta.get("min_len", 1)
        if len(value) < fewest or (longest is not None and len(value) > longest):
            raise AmorError(f"{where}: expected {fewest} to {longest} entries, got {len(value)}")
        items = tuple(coerce_value(v, item, where, {}) for v in value)
        bad = [v for v in items if not in_range(v, meta)]
        if bad:
            raise AmorError(
                f"{where} = {list(items)!r}: entry {bad[0]!r} is out of range ({range_text(meta)})"
            )
        return items
    if hint is bool:
        if not isinstance(value, bool):
            raise AmorError(f"{where}: expected true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise AmorError(f"{where}: expected an integer, got {value!r}")
    elif hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise AmorError(f"{where}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise AmorError(f"{where}: expected a finite number, got {value!r}")
        value = float(value)
    elif hint is str:
        if not isinstance(value, str):
            raise AmorError(f"{where}: expected a string, got {value!r}")
        choices = meta.get("choices")
        if choices is not None and value not in choices:
            raise AmorError(f"{where} must be one of {', '.join(choices)}, got {value!r}")
        if len(value) > MAX_STRING or "\x00" in value:
            raise AmorError(f"{where}: a string of at most {MAX_STRING} characters without NUL expected")
        return value
    else:  # pragma: no cover
        raise AssertionError(f"unsupported config type {hint}")
    if not in_range(value, meta):
        raise AmorError(f"{where} = {value!r} is out of range ({range_text(meta)})")
    return value
