"""How a run's tracking changes along its checkpoints: the stage evaluation at many iterations.

Evaluates the checkpoints of one run (``--every K`` iterations, or ``--iterations ...``) under
uniform ``w`` on every clip (``benchmarks/stage.py``'s evaluation: ``--episodes`` per clip, seed
``--seed``), and prints one line per checkpoint: env steps, clips with survival >= 90 %, mean
survival, and the joint MAE averaged over the clips of ``--family`` (a clip-name prefix, default
``walk``: walk and walker/*). Results are cached in ``--cache`` (JSON, one entry per iteration), so
a run still training can be measured again later; ``--figure`` draws the three against env steps.
A run kept with ``--set run.keep_checkpoints=0`` has every checkpoint to measure.

    python benchmarks/eval_curve.py --run runs/levers/work/biped20-repertoire-ent0 --every 300 \\
        --cache runs/ent0-curve.json --figure docs/img/repertoire-entropy.png
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from stage import evaluate_clips, write_figure

from amorctl.train.rundir import RunDir


def summary(clips: dict[str, dict[str, float]], family: str) -> dict[str, float]:
    """Clips >= 90 % survival, mean survival, and the mean MAE of the clips named ``family``*."""
    survival = [c["survival"] for c in clips.values()]
    family_mae = [c["joint_mae_deg"] for name, c in clips.items() if name.startswith(family)]
    return {
        "clips_90": float(sum(s >= 0.9 for s in survival)),
        "mean_survival": float(np.mean(survival)),
        "family_mae_deg": float(np.mean(family_mae)) if family_mae else float("nan"),
    }


def measure(run: RunDir, iterations: list[int], cache: dict[str, Any], episodes: int, seed: int) -> None:
    """Fill ``cache`` (iteration -> {env_steps, clips}) for every iteration it lacks."""
    for it in iterations:
        if str(it) not in cache:
            env_steps = int(run.checkpoint(it).trainer.meta["env_steps"])
            cache[str(it)] = {"env_steps": env_steps, "clips": evaluate_clips(run, episodes, seed, it)}


def plot(points: list[tuple[int, dict[str, float]]], family: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = np.array([s for s, _ in points]) / 1e6
    panels = (("clips_90", "clips with survival ≥ 90 %"), ("mean_survival", "mean survival"),
              ("family_mae_deg", f"joint MAE (deg), {family}* clips"))  # fmt: skip
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.4))
    for ax, (key, title) in zip(axes, panels, strict=True):
        ax.plot(steps, [p[key] for _, p in points], marker="o", lw=1)
        ax.set(xlabel="env steps (M)", title=title)
        ax.grid(alpha=0.3)
    write_figure(fig, path)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--run", required=True, help="run directory")
    parser.add_argument("--every", type=int, default=0, help="every this many iterations")
    parser.add_argument("--iterations", type=int, nargs="*", default=[], help="these iterations")
    parser.add_argument("--family", default="walk", help="clip-name prefix of the MAE column")
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--cache", default="", help="JSON file keeping the evaluations")
    parser.add_argument("--figure", default="", help="PNG of the curves")
    args = parser.parse_args(argv)
    run = RunDir.open(args.run)
    saved = [it for it, _ in run.checkpoints()]
    wanted = sorted({*args.iterations, *(it for it in saved if args.every and it % args.every == 0)})
    missing = [it for it in wanted if it not in saved]
    if not wanted or missing:
        parser.error(
            f"no checkpoint at iteration(s) {missing or 'given'}; the run has {saved[:3]}...{saved[-3:]}"
        )
    cache_path = Path(args.cache) if args.cache else None
    cache = json.loads(cache_path.read_text()) if cache_path and cache_path.is_file() else {}
    measure(run, wanted, cache, args.episodes, args.seed)
    if cache_path:
        cache_path.write_text(json.dumps(cache, indent=1))
    points = [(cache[str(it)]["env_steps"], summary(cache[str(it)]["clips"], args.family)) for it in wanted]
    print(f"| iteration | env steps | clips ≥ 90 % | mean survival | MAE {args.family}* |")
    print("| --- | --- | --- | --- | --- |")
    for it, (steps, p) in zip(wanted, points, strict=True):
        cells = f"{p['clips_90']:.0f} | {p['mean_survival']:.0%} | {p['family_mae_deg']:.2f}°"
        print(f"| {it} | {steps / 1e6:.1f} M | {cells} |")
    if args.figure:
        plot(points, args.family, Path(args.figure))
        print(f"figure: {args.figure}")


if __name__ == "__main__":
    main()
