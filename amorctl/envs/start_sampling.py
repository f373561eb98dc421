"""Where tracking episodes start: reference state initialization (RSI) biased toward the parts of
the clips where the policy falls (``[env] adaptive_starts``; docs/environment.md, "Episodes").

Plain RSI (the paper) picks a clip uniformly, then a frame uniformly within it, so a hard second
of a long clip is visited as rarely as an easy one. :class:`StartSampler` splits every clip into
phase bins of a fixed number of frames, keeps an exponential moving average of the falls that
happen in each bin, and draws a share of the starts from the bins in proportion to their falls,
spread backward over the bins that lead into them (the state that causes a fall comes before
it) — the adaptive sampling of BeyondMimic (Liao et al., 2025), per clip and per phase bin. The
rest of the starts stay plain RSI, so every part of every clip keeps being visited.

Pure numpy; its state (the fall averages) is JSON, saved with the env's snapshot, so runs resume
bit-exactly.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from amorctl.core.env_random import EnvRandom
from amorctl.core.errors import AmorError

#: Weight of a fall in bin b given to bins b, b - 1, b - 2 of the same clip.
KERNEL = (1.0, 0.5, 0.25)
#: Per-step rate of the falls' moving average (~1,000 control steps of memory, a few episodes).
FALL_RATE = 1e-3


class StartSampler:
    """Adaptive episode starts over a motion library's clips (see the module docstring).

    Args:
        clip_starts, clip_ends: [C] first frame and exclusive end of each clip in the library.
        bin_frames: frames per phase bin (a clip's last bin may be shorter).
        fraction: share of starts drawn from the falls, in (0, 1]; the rest are plain RSI.
    """

    def __init__(
        self, clip_starts: np.ndarray, clip_ends: np.ndarray, bin_frames: int, fraction: float
    ) -> None:
        if not 0 < fraction <= 1 or bin_frames < 1:
            raise AmorError(
                f"adaptive starts: need 0 < fraction <= 1 and bin_frames >= 1, got {fraction}, {bin_frames}"
            )
        starts, ends = np.asarray(clip_starts, np.int64), np.asarray(clip_ends, np.int64)
        self.fraction = float(fraction)
        lo, clip = [], []
        for c, (s, e) in enumerate(zip(starts, ends, strict=True)):
            last_start = e - 1  # an episode cannot start on a clip's last frame (RSI's rule)
            for b in range(s, max(s + 1, last_start), bin_frames):
                lo.append(b)
                clip.append(c)
        self.bin_lo = np.array(lo, np.int64)  # [B] first frame of each bin
        self.bin_clip = np.array(clip, np.int64)  # [B] its clip
        hi = np.append(self.bin_lo[1:], 0)
        last_of_clip = np.append(self.bin_clip[1:] != self.bin_clip[:-1], True)
        self.bin_hi = np.where(last_of_clip, np.maximum(ends[self.bin_clip] - 1, self.bin_lo + 1), hi)  # [B]
        self.frame_bin = np.full(int(ends.max(initial=0)), -1, np.int64)  # [F] frame -> bin (-1: none)
        for b, (a, z) in enumerate(zip(self.bin_lo, self.bin_hi, strict=True)):
            self.frame_bin[a:z] = b
        self.falls = np.zeros(len(self.bin_lo))  # [B] EMA of falls per control step

    @property
    def num_bins(self) -> int:
        return len(self.bin_lo)

    def record(self, fall_frames: np.ndarray) -> None:
        """One control step's falls: ``fall_frames`` [k] the reference frames the fallen envs had
        reached (frames of no bin, a clip's last frame, are ignored)."""
        bins = self.frame_bin[np.asarray(fall_frames, np.int64)]
        counts = np.bincount(bins[bins >= 0], minlength=self.num_bins)
        self.falls = (1.0 - FALL_RATE) * self.falls + FALL_RATE * counts

    def probabilities(self, valid_clips: np.ndarray) -> np.ndarray | None:
        """[B] start probability of each bin among ``valid_clips``: the falls spread backward by
        :data:`KERNEL` within each clip; None while no valid bin has seen a fall."""
        spread = np.zeros(self.num_bins)
        for k, weight in enumerate(KERNEL):
            same_clip = self.bin_clip[k:] == self.bin_clip[: self.num_bins - k]
            spread[: self.num_bins - k] += weight * np.where(same_clip, self.falls[k:], 0.0)
        spread *= np.isin(self.bin_clip, valid_clips)
        total = spread.sum()
        return spread / total if total > 0 else None

    def draw(
        self, rand: EnvRandom, ids: np.ndarray, valid_clips: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Which of the envs ``ids`` [k] start from the falls, and where.

        Returns ``(chosen [j] positions into ids, clips [j], frames [j])``; empty while no fall
        has been seen. Draws ``rand.random(ids)`` always, then for the chosen envs one uniform
        number (the bin) and one integer (the frame within it).
        """
        pick = rand.random(ids) < self.fraction
        p = self.probabilities(valid_clips)
        if p is None or not pick.any():
            empty = np.zeros(0, np.int64)
            return empty, empty, empty
        chosen = np.flatnonzero(pick)
        sub = np.asarray(ids)[chosen]
        cdf = np.cumsum(p)
        cdf /= cdf[-1]  # ends at exactly 1: u < 1 never lands past the last bin with a fall
        bins = np.searchsorted(cdf, rand.random(sub), side="right")
        frames = self.bin_lo[bins] + rand.integers(sub, self.bin_hi[bins] - self.bin_lo[bins])
        return chosen, self.bin_clip[bins], frames

    def state(self) -> dict[str, Any]:
        """JSON-ready state: the fall averages per bin."""
        return {"falls": self.falls.tolist()}

    def load_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`state` (of a sampler over the same clips and bins).

        Raises:
            AmorError: another number of bins, or a value that is negative or not finite.
        """
        falls = np.asarray(state.get("falls", []), dtype=np.float64)
        if falls.shape != self.falls.shape or not np.isfinite(falls).all() or (falls < 0).any():
            raise AmorError(
                f"env snapshot: adaptive-start state has {falls.size} bins (need {self.num_bins}, "
                "finite and >= 0)"
            )
        self.falls = falls
