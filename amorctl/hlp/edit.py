"""Editing what the HLP chose (paper Section 6: "a user could also edit the weights returned by
the HLP"): per-objective multipliers on w_t, renormalized onto the simplex."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.weights import parse_weight_pairs


def parse_scales(text: str | None, names: Sequence[str], source: str = "--scale") -> np.ndarray:
    """``"smooth=2,vel=0.5"`` -> multipliers [m] (objectives not named: 1). AmorError for an
    unknown name, a value that is not a finite number >= 0, or every multiplier zero."""
    names = list(names)
    scales = np.ones(len(names))
    if text is None or not text.strip():
        return scales
    for key, value in parse_weight_pairs(text, source=source):
        if key not in names:
            raise AmorError(f"{source}: unknown objective {key!r} (objectives: {', '.join(names)})")
        scales[names.index(key)] = value
    if not (scales > 0).any():
        raise AmorError(f"{source}: every multiplier is zero; at least one objective must keep weight")
    return scales


def edit_weights(w: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """w * scales renormalized per row: [N, m] -> [N, m] on the simplex. A row whose scaled
    weights vanish (the HLP put all weight on objectives scaled to 0) becomes uniform over the
    objectives with a positive multiplier."""
    w = np.asarray(w, dtype=np.float64)
    s = np.asarray(scales, dtype=np.float64)
    out = w * s
    total = out.sum(-1, keepdims=True)
    fallback = np.broadcast_to((s > 0) / (s > 0).sum(), out.shape)
    out = np.where(total > 1e-12, out / np.where(total > 1e-12, total, 1.0), fallback)
    return out.astype(np.float32)
