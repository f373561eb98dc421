"""Env steps per second of both backends side by side, and the jax-mjx compile time.

For each character and env count: torch-cpu's env (MuJoCo C, threaded rollout pool) and the
jax-mjx env (MJX, one jitted step vmapped over envs) step with zero residual actions from RSI
states; episodes auto-reset as in training. Prints one row per (character, envs, backend) with
steps/s, the first call's time (jax-mjx: tracing + XLA compilation) and, with ``--train``, the
training throughput of one jax-mjx iteration (fused rollout + update) after compilation.

    python benchmarks/backend_throughput.py                       # biped20 + humanoid36, 256/1024/4096
    python benchmarks/backend_throughput.py --characters biped20 --envs 256 --steps 20
    python benchmarks/backend_throughput.py --envs 4096 16384 --jax-steps 20 --train --skip-torch  # a GPU

Every measurement runs in its own Python process (``--one``), with a time limit: one backend's
threads never share a process with the other's (an earlier in-process version stalled in the
jax-mjx row, asleep on a futex after the torch-cpu row, see docs/backends.md), and a stall shows
as a ``timeout`` row instead of a hung benchmark.

Run it under the shared lock on the CPU machines (``flock /tmp/amorctl-heavy.lock ...``).
Results and protocol: docs/backends.md.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import numpy as np


def make_envs(character: str, n: int, backend: str, seconds: float = 10.0):
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.registry import get_registry

    ch = get_registry().character(character)
    lib = synthetic_library(ch, num_clips=4, seconds=4.0, seed=0)
    steps = round(seconds * ch.control_hz)
    if backend == "torch-cpu":
        from amorctl.envs.tracking_env import TrackingEnv

        return TrackingEnv(ch, lib, num_envs=n, max_episode_steps=steps, action_mode="residual", seed=0)
    from amorctl.plugins.backends.jax_mjx.env import MjxTrackingEnv

    return MjxTrackingEnv(ch, lib, num_envs=n, max_episode_steps=steps, action_mode="residual", seed=0)


def env_throughput(character: str, n: int, backend: str, steps: int) -> dict[str, float]:
    env = make_envs(character, n, backend)
    env.reset(seed=0)
    a = np.zeros((n, env.action_dim), np.float32)
    t0 = time.perf_counter()
    env.step(a)  # jax-mjx: trace + compile + one step
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(a)
    elapsed = time.perf_counter() - t0
    env.close()
    return {"steps_per_s": n * steps / elapsed, "first_call_s": first}


def train_throughput(character: str, n: int, iterations: int) -> dict[str, float]:
    """jax-mjx training env steps/s (fused rollout of 24 steps + 5 epochs x 4 minibatches)."""
    from amorctl.core.config import TrainConfig, override
    from amorctl.plugins.backends.jax_mjx import JaxMjxBackend

    config = override(TrainConfig(), env__num_envs=n, run__backend="jax-mjx", ppo__precision="fp32")
    env = make_envs(character, n, "jax-mjx")
    t0 = time.perf_counter()
    trainer = JaxMjxBackend().make_trainer(env, config)
    trainer.iteration()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(iterations):
        metrics = trainer.iteration()
    elapsed = time.perf_counter() - t0
    return {
        "train_steps_per_s": iterations * n * config.ppo.num_steps / elapsed,
        "train_first_iteration_s": compile_s,
        "loss_finite": float(np.isfinite(metrics["loss/total"])),
    }


def measure(args: argparse.Namespace) -> dict[str, float | str | int]:
    """The row of ``--one CHARACTER ENVS BACKEND`` (in this process)."""
    character, n, backend = args.one[0], int(args.one[1]), args.one[2]
    row: dict[str, float | str | int] = {"character": character, "envs": n, "backend": backend}
    row.update(env_throughput(character, n, backend, args.steps))
    if backend == "jax-mjx" and args.train:
        row.update(train_throughput(character, n, args.iterations))
    return row


def run_isolated(args: argparse.Namespace, character: str, n: int, backend: str) -> dict[str, object]:
    """One measurement in a fresh Python process; a ``timeout``/``error`` row when it fails."""
    steps = args.jax_steps if backend == "jax-mjx" else args.steps
    command = [sys.executable, __file__, "--one", character, str(n), backend, "--steps", str(steps),
               "--iterations", str(args.iterations)] + ["--train"] * args.train  # fmt: skip
    row: dict[str, object] = {"character": character, "envs": n, "backend": backend}
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(command, capture_output=True, text=True, timeout=args.timeout)
    except subprocess.TimeoutExpired:
        return {**row, "status": f"timeout after {args.timeout:.0f} s"}
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        return {**row, "status": "error: " + (proc.stderr.strip().splitlines() or ["?"])[-1]}
    return {**json.loads(lines[-1]), "status": "ok", "process_s": time.perf_counter() - t0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--characters", nargs="+", default=["biped20", "humanoid36"])
    parser.add_argument("--envs", nargs="+", type=int, default=[256, 1024, 4096])
    parser.add_argument("--steps", type=int, default=20, help="timed torch-cpu control steps")
    parser.add_argument("--jax-steps", type=int, default=3, help="timed jax-mjx control steps")
    parser.add_argument("--train", action="store_true", help="also time jax-mjx training iterations")
    parser.add_argument("--iterations", type=int, default=3, help="timed training iterations")
    parser.add_argument("--skip-torch", action="store_true", help="only jax-mjx (a GPU machine)")
    parser.add_argument("--json", action="store_true", help="one JSON line per row")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds per measurement process")
    parser.add_argument("--one", nargs=3, metavar=("CHARACTER", "ENVS", "BACKEND"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:  # a child: one measurement, one JSON line
        print(json.dumps(measure(args)), flush=True)
        return

    import jax

    print(f"# jax {jax.__version__} devices: {jax.devices()}")
    print(f"{'character':<11} {'envs':>6} {'backend':<10} {'steps/s':>10} {'first call s':>13}  extra")
    for character in args.characters:
        for n in args.envs:
            backends = ["jax-mjx"] if args.skip_torch else ["torch-cpu", "jax-mjx"]
            for backend in backends:
                row = run_isolated(args, character, n, backend)
                if args.json:
                    print(json.dumps(row), flush=True)
                    continue
                if row["status"] != "ok":
                    print(f"{character:<11} {n:>6} {backend:<10} {row['status']}", flush=True)
                    continue
                extra = (
                    f"train {row['train_steps_per_s']:.0f} steps/s (first iteration "
                    f"{row['train_first_iteration_s']:.0f} s)"
                    if "train_steps_per_s" in row
                    else ""
                )
                print(
                    f"{character:<11} {n:>6} {backend:<10} {row['steps_per_s']:>10.0f} "
                    f"{row['first_call_s']:>13.1f}  {extra}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
