"""Learning bar: train the ``quick`` preset on biped20's walking clips, then evaluate.

Trains MOPPO (``quick`` preset, torch-cpu) on the walking clips of the built-in DeepMimic set
(``walk``, ``walker/*``) for a wall-clock budget, then reports, under uniform weights
``w = (1/7, ..., 1/7)`` and the deterministic policy (the Gaussian mean):

- survival: the fraction of evaluation envs whose first 10 s episode reaches the time limit
  without terminating (falling);
- joint MAE: mean |q - q_ref| over actuated joints and over the steps before each env's first
  episode ends, in degrees;

and the same two numbers for open-loop replay: the reference's next joint angles sent as PD
targets. It writes the learning curve (training survival, episode length, scalarized return vs
env steps) to a PNG beside the run directory and prints one line per figure. A benchmark, not a
test: no timed assertion. The training wall time depends on how busy the machine is: the
iteration count and env steps it prints are the comparable figures.

Usage: python benchmarks/learn_biped20_walk.py [--minutes 20 | --budget-steps N]
       [--out runs/bench-biped20-walk] [--eval-envs 64] [--precision auto|fp32|bf16]
       [--set ppo.desired_kl=0.02 ...]
       [--resume]  (train the run further)   [--eval-only]  (evaluate its newest checkpoint)
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from pathlib import Path

import numpy as np
import tomllib

from amorctl.core.config import load_config, load_preset, merge, override
from amorctl.envs.factory import make_env
from amorctl.envs.tracking_env import TrackingEnv
from amorctl.motion.cache import default_dataset
from amorctl.motion.clips import MotionLibrary
from amorctl.motion.dataset import load_dataset, write_dataset
from amorctl.plugins.backends.torch_cpu import TorchCpuBackend, bf16_supported
from amorctl.registry import get_registry
from amorctl.train.loop import train_run
from amorctl.train.metrics import total_wall_time
from amorctl.train.rundir import CHECKPOINT_DIR, RunDir

WALKING = ("walk", "walker/")


def walking_subset(lib: MotionLibrary) -> MotionLibrary:
    """The library restricted to its walking clips (names ``walk`` and ``walker/*``)."""
    keep = [c.name for c in lib.clips if c.name == "walk" or c.name.startswith("walker/")]
    if not keep:
        raise SystemExit(f"no walking clips in the dataset (clips: {[c.name for c in lib.clips]})")
    return lib.subset(keep)


def save_subset(lib: MotionLibrary, path: Path) -> Path:
    """Write the subset as a dataset file the trainer can load by path."""
    write_dataset(path, lib)
    return path


def evaluate(env: TrackingEnv, policy, steps: int) -> tuple[float, np.ndarray]:
    """Survival fraction and per-step joint errors of each env's first episode under ``policy``.

    Returns:
        survival: fraction of envs whose first episode reaches the time limit.
        errors: [steps, N] mean |q - q_ref| over joints in radians, NaN where the env's first
            episode has ended (or its reference just switched clips).
    Every call resets with the same seed, so two policies start from the same states.
    """
    obs, _ = env.reset(seed=12345)
    n = env.num_envs
    active = np.ones(n, dtype=bool)  # still in its first episode
    survived = np.zeros(n, dtype=bool)
    errors = np.full((steps, n), np.nan)
    for t in range(steps):
        obs, _, terminated, truncated, info = env.step(policy(obs))
        ended = terminated | truncated
        ok = active & ~ended & ~info["clip_switched"]
        if ok.any():
            q = env.sim.joint_pos()[ok]
            q_ref = env.library.joint_pos[env.ref_idx[ok]]
            errors[t, ok] = np.abs(q - q_ref).mean(axis=1)
        survived |= active & truncated
        active &= ~ended
        if not active.any():
            break
    return float(survived.mean()), errors


def mae_degrees(errors: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean of the finite per-step errors [steps, N] (optionally only where ``mask``), in degrees."""
    keep = np.isfinite(errors) if mask is None else np.isfinite(errors) & mask
    return math.degrees(float(errors[keep].mean())) if keep.any() else math.nan


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--minutes", type=float, default=20.0, help="training wall-clock budget")
    parser.add_argument(
        "--budget-steps", type=int, default=None, help="training budget in env steps instead of --minutes"
    )
    parser.add_argument("--out", type=Path, default=Path("runs/bench-biped20-walk"))
    parser.add_argument("--eval-envs", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--resume", action="store_true", help="continue a previous benchmark run")
    parser.add_argument("--eval-only", action="store_true", help="evaluate the run's newest checkpoint")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override a config field of the quick preset (TOML value), e.g. ppo.desired_kl=0.02",
    )
    parser.add_argument(
        "--precision",
        choices=("auto", "fp32", "bf16"),
        default="auto",
        help="network precision; auto = bf16 autocast where the CPU has native bf16",
    )
    args = parser.parse_args()
    if args.budget_steps is not None and args.budget_steps < 1:
        parser.error(f"--budget-steps must be >= 1, got {args.budget_steps}")

    character = "biped20"
    dataset = args.out.parent / f"{args.out.name}-walking.mcap"
    if not dataset.exists():
        full = load_dataset(default_dataset(character))
        save_subset(walking_subset(full), dataset)
    lib = load_dataset(dataset)
    print(f"dataset: {dataset} ({len(lib.clips)} walking clips, {lib.num_frames / lib.fps:.1f} s)")

    config = override(
        load_config(args.out / "config.toml") if args.eval_only else load_preset("quick"),
        env__character=character,
        env__dataset=str(dataset),
        run__seed=args.seed,
        run__iterations=1_000_000,
        run__checkpoint_every=25,
        ppo__precision=args.precision,
    )
    for item in args.set:
        key, _, value = item.partition("=")
        section, _, field = key.partition(".")
        config = merge(config, {section: {field: tomllib.loads(f"v = {value}")["v"]}}, "--set")
    changed = f", overrides: {' '.join(args.set)}" if args.set else ""
    bf16 = config.ppo.precision == "bf16" or (config.ppo.precision == "auto" and bf16_supported())
    print(f"config: quick preset, bf16 autocast {'on' if bf16 else 'off'}{changed}")
    budget = args.minutes * 60.0
    began = time.perf_counter()
    if not args.eval_only:
        result = train_run(
            config,
            args.out,
            resume=args.resume,
            stop_when=lambda m: (
                m.get("env_steps", 0) >= args.budget_steps
                if args.budget_steps
                else time.perf_counter() - began > budget
            ),
        )
        trained_s = time.perf_counter() - began
        print(
            f"trained {result.end_iteration - result.start_iteration} iterations "
            f"in {trained_s / 60:.1f} min; "
            f"{result.last_metrics.get('env_steps', 0):,.0f} env steps total"
        )

    # --- evaluation: uniform weights, deterministic policy, 10 s episodes
    spec = get_registry().character(character)
    steps = int(10 * spec.control_hz)
    uniform = np.full(7, 1 / 7)
    env = TrackingEnv(
        spec,
        lib,
        "tracking7",
        num_envs=args.eval_envs,
        max_episode_steps=steps,
        action_mode=config.env.action_mode,
        fixed_weights=uniform,
        seed=1,
    )
    trainer = TorchCpuBackend().make_trainer(make_env(override(config, env__num_envs=4)), config)
    trainer.load_state_dict(RunDir(args.out).checkpoint().trainer)
    surv, err_policy = evaluate(env, lambda o: trainer.act(o), steps)

    def replay(_obs: np.ndarray) -> np.ndarray:
        targets = env.library.joint_pos[env.ref_idx + 1]
        return targets if env.action_mode == "absolute" else np.zeros_like(targets)

    surv_open, err_open = evaluate(env, replay, steps)
    mae, mae_open = mae_degrees(err_policy), mae_degrees(err_open)
    # like for like: the policy's error on the same steps (same starts) on which the replay is up
    mae_same = mae_degrees(err_policy, np.isfinite(err_open))
    mae_open_same = mae_degrees(err_open, np.isfinite(err_policy))
    print(f"policy (uniform w):  survival over 10 s: {100 * surv:.1f}%   joint MAE: {mae:.2f} deg")
    print(f"open-loop replay:    survival over 10 s: {100 * surv_open:.1f}%   joint MAE: {mae_open:.2f} deg")
    print(
        f"same steps (both up, same starts): policy {mae_same:.2f} deg, open loop {mae_open_same:.2f} deg "
        f"over {int((np.isfinite(err_open) & np.isfinite(err_policy)).sum())} env steps"
    )

    # --- learning curve
    rows = list(csv.DictReader((args.out / "metrics.csv").open()))
    steps = np.array([float(r["env_steps"]) for r in rows]) / 1e6
    total_min = total_wall_time([float(r["wall_time_s"]) for r in rows]) / 60
    png = args.out.parent / f"{args.out.name}-curve.png"
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
        for ax, key, label in zip(
            axes,
            ("episode/survival", "episode/length", "return/scalarized"),
            ("training survival (last 100 episodes)", "episode length (steps)", "return · w"),
            strict=True,
        ):
            ax.plot(steps, [float(r[key]) for r in rows])
            ax.set_xlabel(f"env steps (millions; {len(rows)} iterations, {total_min:.0f} min here)")
            ax.set_title(label)
            ax.grid(alpha=0.3)
        fig.suptitle(
            f"biped20 walking, quick preset: eval survival {100 * surv:.0f}% "
            f"(open loop {100 * surv_open:.0f}%), MAE {mae:.1f}° (open loop {mae_open:.1f}°)"
        )
        fig.tight_layout()
        fig.savefig(png, dpi=110)
        print(f"learning curve: {png}")
    except ImportError:
        print("learning curve: matplotlib not installed, skipped")
    print(f"checkpoints: {args.out / CHECKPOINT_DIR}")


if __name__ == "__main__":
    main()
