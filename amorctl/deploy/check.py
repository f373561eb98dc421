"""``amorctl deploy check``: a sim2sim report, uniform weights vs chosen weights or a schedule.

Both conditions run the same episodes: episode i tracks clip ``i mod C`` (or the chosen motion)
from its first frame, with the dynamics and pushes drawn from seed ``seed + i``, for ``seconds``
(the reference loops its clip), ending at a fall. Per condition: survival (share of episodes that
never fell or diverged), joint MAE (degrees, mean over episodes of each episode's mean absolute
joint error against the reference frame each step reached, until the fall), action rate (mean
``||q*_t - q*_{t-1}||²`` of the PD targets sent, rad²), mean time survived. Torch-free.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.deploy.runtime import EpisodeResult, Runtime

if TYPE_CHECKING:  # the schedule module (tomlkit) is imported only when one is used
    from amorctl.core.schedule import Schedule


@dataclass
class ConditionSummary:
    """Aggregates of one weight condition over the episodes."""

    label: str
    episodes: list[EpisodeResult]

    def to_dict(self) -> dict[str, Any]:
        eps = self.episodes
        return {
            "label": self.label,
            "episodes": len(eps),
            "survival": float(np.mean([e.survived for e in eps])),
            "joint_mae_deg": float(np.mean([e.joint_mae_deg for e in eps])),
            "action_rate": float(np.mean([e.action_rate for e in eps])),
            "mean_seconds": float(np.mean([e.seconds for e in eps])),
            "falls": int(sum(e.fell_at is not None for e in eps)),
            "diverged": int(sum(e.diverged for e in eps)),
        }


def run_check(
    runtime: Runtime,
    weights: np.ndarray | Schedule,
    *,
    label: str,
    episodes: int = 8,
    seconds: float = 10.0,
    motion: str | None = None,
    seed: int = 0,
) -> dict[str, Any]:
    """Run uniform weights and ``weights`` over the same ``episodes`` (module docstring).

    Returns a JSON-ready report: ``conditions`` (one summary per condition, uniform first),
    ``per_episode`` (motion, seed, dynamics and both conditions' outcomes) and the settings.
    """
    if episodes < 1:
        raise AmorError(f"--episodes must be >= 1, got {episodes}")
    if not np.isfinite(seconds) or seconds <= 0:
        raise AmorError(f"--seconds must be a positive number, got {seconds}")
    names = runtime.motions.names
    clips = [runtime.motions.resolve(motion)] if motion is not None else list(range(len(names)))
    clips = [c for c in clips if runtime.motions.clip_lengths[c] >= 2]
    uniform = np.full(runtime.m, 1.0 / runtime.m)
    results: dict[str, list[EpisodeResult]] = {"uniform": [], label: []}
    per_episode = []
    for i in range(episodes):
        clip = names[clips[i % len(clips)]]
        row: dict[str, Any] = {"episode": i, "motion": clip, "seed": seed + i}
        for key, source in (("uniform", uniform), (label, weights)):
            res = runtime.run(source, motion=clip, seconds=seconds, seed=seed + i)
            results[key].append(res)
            row[key] = {
                "survived": res.survived,
                "fell_at": res.fell_at,
                "joint_mae_deg": res.joint_mae_deg,
                "action_rate": res.action_rate,
            }
            row["dynamics"] = res.dynamics
        per_episode.append(row)
    return {
        "bundle": str(runtime.bundle.path),
        "episodes": episodes,
        "seconds": seconds,
        "seed": seed,
        "randomization": runtime.randomization.to_dict(),
        "randomization_file": runtime.randomization.source,
        "conditions": [ConditionSummary(k, v).to_dict() for k, v in results.items()],
        "per_episode": per_episode,
    }
