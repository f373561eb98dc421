"""The tracking observation's layout, defined once: its named terms, their sizes and order.

Every tracking env (torch-cpu's, jax-mjx's) builds its ``obs_layout`` with
:func:`observation_layout`, the deploy runtime assembles the same terms by these names, and
docs/observations.md lists them in this order (tests/test_docs.py checks it). Shapes: J actuated
joints, E end effectors, D = :func:`~amorctl.core.frame_layout.frame_dim` (J, E), L latent size,
K future frames, m objectives.
"""

from __future__ import annotations

from collections.abc import Sequence

#: (name, size in terms of D, J, L, K, m), in observation order. ``weights`` is always last: the
#: VectorEnv contract puts w in the last m entries.
OBSERVATION_TERMS: tuple[tuple[str, str], ...] = (
    ("proprio", "D"),
    ("prev_targets", "2J"),
    ("ref_frame", "D"),
    ("latent", "L"),
    ("future_frames", "K·D"),
    ("weights", "m"),
)
TERM_NAMES: tuple[str, ...] = tuple(name for name, _ in OBSERVATION_TERMS)


def observation_layout(
    frame_dim: int, num_joints: int, latent_dim: int, future_frames: Sequence[int], m: int
) -> dict[str, slice]:
    """{term: slice of the observation} for a frame of ``frame_dim`` (D) entries, J joints, a
    latent of L, the future-frame offsets (K of them) and m objectives, in
    :data:`OBSERVATION_TERMS` order."""
    sizes = {
        "proprio": frame_dim,
        "prev_targets": 2 * num_joints,
        "ref_frame": frame_dim,
        "latent": latent_dim,
        "future_frames": frame_dim * len(future_frames),
        "weights": m,
    }
    layout: dict[str, slice] = {}
    start = 0
    for name in TERM_NAMES:
        layout[name] = slice(start, start + sizes[name])
        start += sizes[name]
    return layout
