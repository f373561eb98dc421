"""Training throughput of the presets on this machine: env steps/s and where the time goes.

For each preset, builds the tracking env (biped20, built-in clips) and the MOPPO trainer exactly as
``amorctl train`` does, runs one warm-up iteration and ``--iterations`` timed ones, and prints env
steps/s with the fraction of wall time spent in the env (``env.step``: physics, rewards,
observations, resets), in the networks (rollout forward passes, GAE, the update) and in glue (the
rest: buffers, episode statistics, normalizer). ``--num-envs`` overrides the preset's env count
(the paper's 8192 envs take minutes per iteration on 2 cores; the per-step rates scale linearly).

Side by side, in the same run: the same envs stepping alone under a fixed policy (zero residual
actions: the reference's own targets) for as many steps as the timed iterations, and the ratio
training ÷ env-only (the share of what the simulation alone could deliver that training reaches).
The header names the CPU and the instruction sets that decide precision (AVX2, AVX-512,
AVX512-BF16, AMX-BF16).

Usage: python benchmarks/train_throughput.py [--presets quick paper] [--iterations 2]
       [--num-envs N] [--precision fp32|bf16|both] [--threads 2]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

from amorctl.core.config import load_preset, override
from amorctl.envs.factory import make_env
from amorctl.plugins.backends.torch_cpu import TorchCpuBackend, bf16_supported
from amorctl.sim.cpus import cpu_description


def env_only(env, steps: int) -> float:
    """Env steps/s of ``env`` stepping alone for ``steps`` control steps under zero actions."""
    actions = np.zeros((env.num_envs, env.action_dim), np.float32)
    env.step(actions)  # warm-up
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(actions)
    return steps * env.num_envs / (time.perf_counter() - t0)


def measure(preset: str, bf16: bool, iterations: int, num_envs: int | None) -> dict[str, float]:
    """Median env steps/s and time fractions over ``iterations`` iterations after one warm-up,
    and the same envs' env-only steps/s over as many steps."""
    config = override(load_preset(preset), ppo__precision="bf16" if bf16 else "fp32")
    if num_envs:
        config = override(config, env__num_envs=num_envs)
    backend = TorchCpuBackend()
    env = make_env(config, backend)
    trainer = backend.make_trainer(env, config)
    trainer.iteration()
    runs = [trainer.iteration() for _ in range(iterations)]
    alone = env_only(env, iterations * config.ppo.num_steps)
    env.close()
    keys = (
        "env_steps_per_s",
        "time/env_frac",
        "time/network_frac",
        "time/update_frac",
        "time/glue_frac",
        "time/iteration_s",
    )
    out = {k: statistics.median(r[k] for r in runs) for k in keys}
    out["num_envs"] = config.env.num_envs
    out["env_only_steps_per_s"] = alone
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--presets", nargs="+", default=["quick", "paper"])
    parser.add_argument("--iterations", type=int, default=2)
    parser.add_argument("--num-envs", type=int, default=None)
    parser.add_argument("--precision", choices=("fp32", "bf16", "both"), default="both")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    modes = {"fp32": [False], "bf16": [True], "both": [False, True]}[args.precision]
    if not bf16_supported():
        modes = [m for m in modes if not m] or [False]
    print(f"CPU: {cpu_description()}; torch threads {torch.get_num_threads()}")
    for preset in args.presets:
        for bf16 in modes:
            r = measure(preset, bf16, args.iterations, args.num_envs)
            print(
                f"{preset:6s} {'bf16' if bf16 else 'fp32'}  {int(r['num_envs']):5d} envs  "
                f"{r['env_steps_per_s']:8,.0f} env steps/s  ({r['time/iteration_s']:.1f} s/iteration)  "
                f"env {100 * r['time/env_frac']:4.1f}%  network {100 * r['time/network_frac']:4.1f}% "
                f"(update {100 * r['time/update_frac']:4.1f}%)  "
                f"glue {100 * r['time/glue_frac']:4.1f}%  |  env only {r['env_only_steps_per_s']:8,.0f}/s  "
                f"training / env only {r['env_steps_per_s'] / r['env_only_steps_per_s']:.2f}"
            )


if __name__ == "__main__":
    main()
