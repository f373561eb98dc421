"""Per-clip-family survival and the training weights' coverage of the simplex, for any backend.

:class:`EpisodeRecorder` wraps the training env (every attribute is the env's) and watches
``step``: before it, the weights and (for tracking envs, through the
:class:`~amorctl.core.contracts.TrackingView`) the clip of each env's episode; after it, which
episodes ended and whether they survived (truncated at the time limit, not terminated). Once per
iteration :meth:`EpisodeRecorder.metrics` adds to the loop's metrics (docs/train.md, "Metrics"):

- ``survival/<family>``: the share of the last :data:`WINDOW` ended episodes of each clip family
  that survived (NaN before the first one). One number over all clips is pinned near 0 by the
  acrobatic clips while walking is learnt; per family the progress shows.
- ``wcount/<region>``: how many episodes that ended in this iteration had their ``w`` in each
  simplex region (:mod:`amorctl.core.simplex_regions`), so ``amorctl pareto --coverage`` can set
  training effort beside the policy's accuracy per region.

The recorder's windows are not checkpointed: after ``--resume`` they fill up again. Under
torchrun every rank records its envs and the counts are summed over the ranks.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from amorctl.core.contracts import tracking_view
from amorctl.core.simplex_regions import NUM_BINS, region_index, region_labels

#: Ended episodes per family in the survival window (the trainer's own survival uses 100 too).
WINDOW = 100
SURVIVAL_PREFIX = "survival/"
WCOUNT_PREFIX = "wcount/"


def clip_family(name: str) -> str:
    """A clip's family: its folder (``walker/turn_left0`` -> ``walker``), else its name without a
    trailing number or one-letter variant (``dance_a`` -> ``dance``, ``run2`` -> ``run``)."""
    if "/" in name:
        return name.split("/", 1)[0]
    base = re.sub(r"(_[a-z]|\d+)$", "", name)
    return base or name


class EpisodeRecorder:
    """The training env with episode bookkeeping (see the module docstring).

    Args:
        env: the training :class:`~amorctl.core.vecenv.VectorEnv`.
        window: ended episodes per family in the survival window.
    """

    def __init__(self, env: Any, window: int = WINDOW) -> None:
        self.env = env
        self.names = tuple(env.reward_space.names)
        self.m = len(self.names)
        self.regions = region_labels(self.names)
        self._view = tracking_view(env)
        clips = tuple(self._view.clip_names) if self._view is not None else ()
        self.families: tuple[str, ...] = tuple(dict.fromkeys(clip_family(c) for c in clips))
        self._family_of = np.array([self.families.index(clip_family(c)) for c in clips], dtype=np.int64)
        f = len(self.families)
        self._recent = np.full((f, window), np.nan)  # 1 survived, 0 fell, per family (ring)
        self._ptr = np.zeros(f, dtype=np.int64)
        self._wcount = np.zeros(self.m * NUM_BINS, dtype=np.int64)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    def tracking_view(self) -> Any:
        """The wrapped env's tracking view (None without motions)."""
        return tracking_view(self.env)

    def step(self, actions: np.ndarray) -> tuple[Any, ...]:
        """The env's ``step``, recording the episodes it ends."""
        weights = np.asarray(self.env.weights)  # w of the episodes this step belongs to
        clips = self._view.clip_index() if self._view is not None else None
        out = self.env.step(actions)
        terminated, truncated = np.asarray(out[2]), np.asarray(out[3])
        ended = np.flatnonzero(terminated | truncated)
        if ended.size:
            self._wcount += np.bincount(region_index(weights[ended]), minlength=len(self._wcount))
            if clips is not None and self.families:
                self._record_survival(self._family_of[clips[ended]], ~terminated[ended])
        return out

    def _record_survival(self, families: np.ndarray, survived: np.ndarray) -> None:
        window = self._recent.shape[1]
        for fam, ok in zip(families.tolist(), survived.tolist(), strict=True):
            self._recent[fam, self._ptr[fam] % window] = float(ok)
            self._ptr[fam] += 1

    def metrics(self, world: Any = None) -> dict[str, float]:
        """``survival/<family>`` and ``wcount/<region>`` (then the region counts restart at 0).

        Args:
            world: a :class:`amorctl.train.distributed.World` to sum over ranks (None: this process).
        """
        filled = np.isfinite(self._recent)
        parts = np.concatenate([self._wcount, np.where(filled, self._recent, 0.0).sum(1), filled.sum(1)])
        if world is not None and getattr(world, "distributed", False):
            parts = world.sum(parts)
        self._wcount[:] = 0
        r, f = len(self.regions), len(self.families)
        counts, ok, seen = parts[:r], parts[r : r + f], parts[r + f :]
        out = {
            f"{SURVIVAL_PREFIX}{fam}": (float(ok[i] / seen[i]) if seen[i] else float("nan"))
            for i, fam in enumerate(self.families)
        }
        out.update({f"{WCOUNT_PREFIX}{label}": float(counts[i]) for i, label in enumerate(self.regions)})
        return out
