"""Observation windows O_t = (o_{t-V+1}, ..., o_t) of o = (theta 6D, v lin + ang, q), heading frame.

Both sides of the discriminator use the same frame vector (:mod:`amorctl.core.frame_layout`):
the policy's from the ``proprio`` slice of the AMOR observation (the simulated state s_{t+1} after
each step), the dataset's from the motion library's ``frames``. Each window is paired with the
motion latent the observation carries beside that state (the ``latent`` slice, z of the next
reference frame); dataset windows ending at frame f take ``z[f + 1]`` of the dataset itself (never
recomputed), so both sides pair a window with the same latent.

Only **full** windows are compared: dataset windows end at least V - 1 frames into their clip,
and a policy window counts once its env has run V - 1 steps since its episode began (before
that its first frame repeats; such windows get no reward and never reach the discriminator).
Why: an episode starts in the reference state (RSI), so a padded policy window right after a
reset is a copy of a padded dataset window, and a D trained on both hands out large rewards for
being reset rather than for moving well. Clips shorter than V frames contribute padded windows
only when no clip is long enough.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import frame_dim, split_frame
from amorctl.motion.clips import MotionLibrary


@dataclass(frozen=True)
class WindowSpec:
    """V frames of o = (root_rot6d [6], root_lin_vel [3], root_ang_vel [3], joint_pos [J])."""

    window: int  # V
    num_joints: int  # J
    num_ee: int  # E

    @property
    def frame_features(self) -> int:
        """F = 12 + J, features per frame."""
        return 12 + self.num_joints

    @property
    def size(self) -> int:
        """V * F, the flat window size."""
        return self.window * self.frame_features

    def features(self, frames: np.ndarray) -> np.ndarray:
        """o [N, F] float32 of frame vectors [N, 13 + 2J + 12E]."""
        if frames.shape[-1] != frame_dim(self.num_joints, self.num_ee):
            raise AmorError(
                f"frame vectors have {frames.shape[-1]} entries; J={self.num_joints}, "
                f"E={self.num_ee} needs {frame_dim(self.num_joints, self.num_ee)}"
            )
        p = split_frame(frames, self.num_joints, self.num_ee)
        return np.concatenate(
            [p.root_rot6d, p.root_lin_vel, p.root_ang_vel, p.joint_pos], axis=-1, dtype=np.float32
        )


def observation_slices(layout: Mapping[str, object], latent_dim: int) -> tuple[slice, slice]:
    """(proprio slice, latent slice) of an observation layout (values ``slice`` or ``(start, stop)``).

    The latent is the ``latent`` part, or the last ``latent_dim`` entries of ``context`` where the
    layout groups the reference frame and latent under that name.
    """

    def as_slice(v: object) -> slice:
        if isinstance(v, slice):
            return v
        start, stop = v  # type: ignore[misc]
        return slice(int(start), int(stop))

    if "proprio" not in layout:
        raise AmorError(
            "the run's observation has no 'proprio' part: an HLP discriminator needs a tracking run"
        )
    proprio = as_slice(layout["proprio"])
    if "latent" in layout:
        latent = as_slice(layout["latent"])
    elif "context" in layout:
        ctx = as_slice(layout["context"])
        latent = slice(ctx.stop - latent_dim, ctx.stop)
    else:
        raise AmorError("the run's observation has no 'latent' (or 'context') part for z")
    if latent.stop - latent.start != latent_dim:
        raise AmorError(
            f"the run's observation carries {latent.stop - latent.start} latent entries, "
            f"its motion dataset {latent_dim}"
        )
    return proprio, latent


class WindowHistory:
    """The last V frame features of each of N envs: ``buf`` [N, V, F], oldest first, and
    ``count`` [N], how many real frames each window holds (at most V)."""

    def __init__(self, num_envs: int, spec: WindowSpec) -> None:
        self.spec = spec
        self.buf = np.zeros((num_envs, spec.window, spec.frame_features), dtype=np.float32)
        self.count = np.zeros(num_envs, dtype=np.int64)

    def reset(self, ids: np.ndarray, feat: np.ndarray) -> None:
        """Start envs ``ids`` [k] anew: their window is ``feat`` [k, F] repeated V times."""
        self.buf[ids] = feat[:, None, :]
        self.count[ids] = 1

    def push(self, feat: np.ndarray) -> None:
        """Append this step's features [N, F] to every env's window."""
        self.buf[:, :-1] = self.buf[:, 1:]
        self.buf[:, -1] = feat
        self.count = np.minimum(self.count + 1, self.spec.window)

    def full(self) -> np.ndarray:
        """[N] bool: the window holds V real frames (no padding)."""
        return self.count >= self.spec.window

    def windows(self) -> np.ndarray:
        """[N, V * F] float32 flat windows."""
        return self.buf.reshape(self.buf.shape[0], -1).copy()


class DatasetWindows:
    """Windows and latents of a motion library's clips: the discriminator's positives.

    Args:
        library: the run's motion dataset.
        spec: window size and character sizes.
        clips: indices of the clips to sample (None: every clip with at least 2 frames).
    """

    def __init__(self, library: MotionLibrary, spec: WindowSpec, clips: Sequence[int] | None = None) -> None:
        if library.latent_dim == 0:
            raise AmorError(
                "the run's motion dataset has no latents z (L = 0): the discriminator is conditioned on z"
            )
        self.spec = spec
        self.feats = spec.features(np.asarray(library.frames, dtype=np.float32))  # [F_lib, F]
        self.z = np.asarray(library.z, dtype=np.float32)
        starts, lengths = library.starts, library.lengths
        chosen = np.flatnonzero(lengths >= 2) if clips is None else np.asarray(clips, dtype=np.int64)
        if len(chosen) == 0:
            raise AmorError("no clip with at least 2 frames to draw dataset windows from")
        # end frames f with a full window inside the clip and a next frame f + 1 in it (z[f + 1]
        # pairs with the window); padded windows only if no chosen clip is long enough
        v = spec.window
        padded = not any(lengths[c] >= v + 1 for c in chosen)
        ends, clip_of, first = [], [], []
        for c in chosen:
            lo = starts[c] if padded else starts[c] + v - 1
            f = np.arange(lo, starts[c] + lengths[c] - 1)
            ends.append(f)
            clip_of.append(np.full(len(f), c))
            first.append(np.full(len(f), starts[c]))
        self.ends = np.concatenate(ends)
        self.clip_of = np.concatenate(clip_of)
        self.first = np.concatenate(first)

    def __len__(self) -> int:
        return len(self.ends)

    def windows_at(self, rows: np.ndarray) -> np.ndarray:
        """[k, V * F] windows ending at ``self.ends[rows]`` (clamped to their clip's first frame)."""
        v = self.spec.window
        idx = self.ends[rows][:, None] + np.arange(-v + 1, 1)[None]
        idx = np.maximum(idx, self.first[rows][:, None])
        return self.feats[idx].reshape(len(rows), -1)

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """n random windows: (windows [n, V*F], z [n, L], rows [n])."""
        rows = rng.integers(len(self.ends), size=n)
        return self.windows_at(rows), self.z[self.ends[rows] + 1], rows

    def mismatched(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """n dataset windows paired with the latent of another random frame (of another clip when
        there is more than one): negatives that only z tells apart."""
        rows = rng.integers(len(self.ends), size=n)
        other = rng.integers(len(self.ends), size=n)
        if len(np.unique(self.clip_of)) > 1:
            for _ in range(16):  # redraw those that landed in the same clip
                same = self.clip_of[other] == self.clip_of[rows]
                if not same.any():
                    break
                other[same] = rng.integers(len(self.ends), size=int(same.sum()))
        return self.windows_at(rows), self.z[self.ends[other] + 1]
