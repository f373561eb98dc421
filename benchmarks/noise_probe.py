"""How a tracking policy fares under its own training noise: survival and joint MAE per clip with
Gaussian noise added to the mean action, side by side with the deterministic policy.

A PPO rollout acts with the mean action plus Gaussian noise of the policy's std; evaluation (and
deployment) acts with the mean alone. Where a clip survives deterministically but falls under
the noise, the rollouts that train the policy see mostly falls the mean action would not have
made (docs/repertoire.md, "Kickstarting"). Each ``--std`` is a noise level: ``own`` is the
policy's std (``exp(actor.log_std)`` per action dimension), a number is that std in every
dimension, ``0`` the deterministic policy. Every level is evaluated on the same starts (uniform
``w``, ``--episodes`` per clip, seed ``--seed``).

    python benchmarks/noise_probe.py --run runs/levers/work/biped20-kick-a --std 0 --std 0.04 --std own
    python benchmarks/noise_probe.py --run pretrained:biped20-repertoire --clips jump walk
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from stage import load_library, one_line_errors

from amorctl.analysis.tracking_metrics import evaluate_setting
from amorctl.train.distill import action_log_std
from amorctl.train.rundir import RunDir


class NoisyPolicy:
    """A policy whose actions carry Gaussian noise of a fixed std [A] (``policy(obs [N, D]) ->
    actions [N, A]``); every other attribute is the wrapped policy's."""

    def __init__(self, policy: Any, std: np.ndarray, seed: int) -> None:
        self.policy, self.std = policy, np.asarray(std, dtype=np.float32)
        self.rng = np.random.default_rng(seed)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        mean = np.asarray(self.policy(obs), dtype=np.float32)
        return mean + self.std * self.rng.standard_normal(mean.shape).astype(np.float32)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.policy, name)


def own_std(policy: Any) -> np.ndarray:
    """The policy's state-independent std [A]."""
    return np.exp(action_log_std(policy))


def probe(run: RunDir, levels: list[str], clips: list[str], episodes: int, seed: int) -> dict[str, Any]:
    """{column head: {clip: (survival, joint MAE deg)}} per noise level (``own``, or a std >= 0; the
    head gives the mean std over the action dimensions)."""
    policy = run.policy()
    uniform = np.full(len(policy.objectives), 1.0 / len(policy.objectives))
    out: dict[str, Any] = {}
    for level in levels:
        std = own_std(policy) if level == "own" else np.full(policy.action_dim, float(level), np.float32)
        if std.any():
            acting = NoisyPolicy(policy, std, seed)
            head = f"std {float(std.mean()):.3g}" + (" (own)" if level == "own" else "")
        else:
            acting, head = policy, "deterministic"
        result = evaluate_setting(
            acting, run.config, uniform, label=level, motions=clips, episodes=episodes, seed=seed
        )
        out[head] = {
            clip: (float(m["survival_rate"]), float(m["joint_mae_deg"]))
            for clip, m in result.per_motion.items()
        }
    return out


def _is_std(text: str) -> bool:
    try:
        value = float(text)
    except ValueError:
        return False
    return math.isfinite(value) and value >= 0


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--run", required=True, help="a tracking run directory or pretrained:NAME")
    parser.add_argument(
        "--std", action="append", help="noise level: own, or a std (repeatable; default 0, own)"
    )
    parser.add_argument(
        "--clips", nargs="*", help="clips to probe (default: every clip of the run's dataset)"
    )
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    levels = args.std or ["0", "own"]
    for level in levels:
        if level != "own" and not _is_std(level):
            parser.error(f"--std {level!r}: use 'own' or a finite number >= 0")
    one_line_errors(report, args, levels)


def report(args: argparse.Namespace, levels: list[str]) -> None:
    """Probe ``args.run`` at each noise level and print the markdown table."""
    run = RunDir.open(args.run)
    character = run.config.env.character
    clips = args.clips or [c.name for c in load_library(character, run.dataset_path()).clips]
    table = probe(run, levels, clips, args.episodes, args.seed)
    heads = list(table)
    print(
        f"{run.label}: uniform w, {args.episodes} episodes per clip, seed {args.seed}; survival / joint MAE"
    )
    print("| clip | " + " | ".join(heads) + " |")
    print("| --- |" + " --- |" * len(heads))
    for clip in clips:
        cells = [f"{table[h][clip][0]:.0%} / {table[h][clip][1]:.1f}°" for h in heads]
        print(f"| {clip} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
