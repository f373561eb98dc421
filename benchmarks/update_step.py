"""Where a training iteration's time goes, and what the ecosystem's CPU options change.

Builds the tracking env and the MOPPO trainer exactly as ``amorctl train`` does (biped20, built-in
clips, ``--preset``), collects one real rollout batch, and measures side by side in one run:

* **env.step**: the share spent in MuJoCo's rollout pool (physics, the GIL released, all cores)
  against the env's own numpy work (observations, rewards, resets: one core). Only the numpy share
  and the policy's forward passes could hide behind the physics by overlapping sampling with
  inference; the physics already keeps every core busy.
* **the PPO update** (``num_epochs`` x ``num_minibatches`` Adam steps on that batch), per variant:
  as shipped (eager, ``foreach`` Adam), Adam with ``fused=True``, the actor and critic MLPs under
  ``torch.compile`` (inductor, CPU), both, and one torch thread instead of all. Compilation happens
  in an untimed warm-up update. The update's arithmetic is the same in these variants. Then two
  that change it (their sample efficiency is not measured here): two minibatches twice as large
  (the same FLOPs in half the Adam steps) and three epochs instead of five (60 % of the FLOPs).

Usage: python benchmarks/update_step.py [--preset science] [--repeats 3] [--threads 2]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np
import torch

from amorctl.core.config import load_preset, override
from amorctl.envs.factory import make_env
from amorctl.plugins.backends.torch_cpu import TorchCpuBackend
from amorctl.plugins.backends.torch_cpu.moppo import MOPPOTrainer
from amorctl.sim.cpus import cpu_description


def env_split(env, steps: int = 60) -> tuple[float, float]:
    """(ms per env.step, share of it inside the physics pool) under zero residual actions."""
    sim, actions = env.sim, np.zeros((env.num_envs, env.action_dim), np.float32)
    pool = sim._rollout
    spent = [0.0]

    def timed(*args, **kwargs) -> None:
        t0 = time.perf_counter()
        pool(*args, **kwargs)
        spent[0] += time.perf_counter() - t0

    sim._rollout = timed
    try:
        env.step(actions)
        spent[0] = 0.0
        t0 = time.perf_counter()
        for _ in range(steps):
            env.step(actions)
        total = time.perf_counter() - t0
    finally:
        sim._rollout = pool
    return 1e3 * total / steps, spent[0] / total


def fused_adam(trainer: MOPPOTrainer) -> None:
    trainer.optimizer = torch.optim.Adam(trainer.params, lr=trainer.learning_rate, fused=True)


def compiled_networks(trainer: MOPPOTrainer) -> None:
    trainer.actor.net = torch.compile(trainer.actor.net)
    trainer.critic.net = torch.compile(trainer.critic.net)


def both(trainer: MOPPOTrainer) -> None:
    fused_adam(trainer)
    compiled_networks(trainer)


#: name -> (a change to the trainer, torch threads (None: --threads), [ppo] overrides)
VARIANTS: dict[str, tuple[Callable[[MOPPOTrainer], None] | None, int | None, dict[str, int]]] = {
    "as shipped (eager, foreach Adam)": (None, None, {}),
    "Adam fused=True": (fused_adam, None, {}),
    "torch.compile (inductor) MLPs": (compiled_networks, None, {}),
    "fused Adam + torch.compile": (both, None, {}),
    "one torch thread": (None, 1, {}),
    "2 minibatches (twice as large)": (None, None, {"ppo__num_minibatches": 2}),
    "3 epochs": (None, None, {"ppo__num_epochs": 3}),
}


def time_update(preset: str, change, threads: int, repeats: int, ppo: dict[str, int]) -> float:
    """Median seconds of one update on a fresh trainer's first rollout batch, after a warm-up."""
    config = override(load_preset(preset), **ppo)
    backend = TorchCpuBackend()
    env = make_env(config, backend)
    torch.set_num_threads(threads)
    trainer = backend.make_trainer(env, config)
    try:
        if change is not None:
            change(trainer)
        batch, _ = trainer.collect_rollout()
        trainer.compute_returns(batch)
        trainer.update(batch)  # warm-up (and compilation)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            trainer.update(batch)
            times.append(time.perf_counter() - t0)
    finally:
        env.close()
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--preset", default="science")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    config = load_preset(args.preset)
    p = config.ppo
    steps = p.num_epochs * p.num_minibatches
    print(f"CPU: {cpu_description()}; torch threads {args.threads}")
    env = make_env(config, TorchCpuBackend())
    env.reset(seed=0)
    ms, share = env_split(env)
    env.close()
    print(
        f"{args.preset}: {config.env.num_envs} envs, env.step {ms:.1f} ms: physics pool {share:.0%}, "
        f"numpy {1 - share:.0%}"
    )
    print(
        f"update: {p.num_epochs} epochs x {p.num_minibatches} minibatches of "
        f"{config.env.num_envs * p.num_steps // p.num_minibatches} samples ({steps} Adam steps)"
    )
    base = None
    for name, (change, threads, ppo) in VARIANTS.items():
        seconds = time_update(args.preset, change, threads or args.threads, args.repeats, ppo)
        base = base or seconds
        cfg = override(config, **ppo).ppo
        print(
            f"  {name:34s} {1e3 * seconds:7.1f} ms/update  "
            f"{1e3 * seconds / (cfg.num_epochs * cfg.num_minibatches):6.2f} ms/Adam step  "
            f"x{base / seconds:.2f}"
        )
    torch.set_num_threads(args.threads)


if __name__ == "__main__":
    main()
