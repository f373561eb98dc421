"""Validation of what the tracking env is built from: fixed weights, clip selections, and a motion
library's fit to the character (each failure one :class:`AmorError` naming the problem)."""

from __future__ import annotations

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.specs import CharacterSpec
from amorctl.core.weights import check_simplex_rows
from amorctl.motion.clips import MotionLibrary


def check_weights(w: np.ndarray, m: int) -> np.ndarray:
    w = np.asarray(w, dtype=np.float64).reshape(-1)
    if w.shape != (m,):
        raise AmorError(f"fixed weights must be {m} non-negative numbers summing to 1, got {w.tolist()}")
    check_simplex_rows(w, "fixed weights")
    return w.astype(np.float32)


def check_clips(clips: np.ndarray, lib: MotionLibrary) -> np.ndarray:
    """Clip indices [k] that exist and have at least 2 frames; AmorError naming the bad one."""
    if clips.size == 0:
        raise AmorError("no clips to track: the clip selection is empty")
    for c in np.unique(clips):
        if not 0 <= c < len(lib.clips):
            raise AmorError(f"clip index {int(c)} out of range (the library has {len(lib.clips)} clips)")
        if lib.lengths[c] < 2:
            raise AmorError(f"clip {lib.clips[c].name!r} has fewer than 2 frames; it cannot be tracked")
    return clips


def _first_difference(have: tuple[str, ...], want: tuple[str, ...]) -> str:
    """Where two name lists first differ, e.g. ``"#3 is 'knee_l', the character's is 'hip_l'"``."""
    for i, (a, b) in enumerate(zip(have, want, strict=False)):
        if a != b:
            return f"#{i} is {a!r}, the character's is {b!r}"
    return f"the library has {len(have)}, the character {len(want)}"


def check_library(ch: CharacterSpec, lib: MotionLibrary) -> None:
    if lib.character != ch.name:
        raise AmorError(f"motion library is for character {lib.character!r}, not {ch.name!r}")
    for what, have, want in (
        ("joints", tuple(lib.joint_names), ch.joint_names()),
        ("end effectors", tuple(lib.end_effectors), tuple(ch.end_effectors)),
    ):
        if have != want:
            raise AmorError(
                f"motion library {what} do not match the {what} of character {ch.name}: "
                f"{_first_difference(have, want)}"
            )
    if lib.fps != ch.control_hz:
        raise AmorError(
            f"motion library is at {lib.fps} fps; character {ch.name!r} runs at {ch.control_hz} Hz"
        )
