"""What overlapping sampling with inference would buy here, measured before building it.

The rollout alternates the policy's forward pass (actor and critic on the whole batch) with the
env's step (MuJoCo's pool on every core, then the env's numpy work on one). Double-buffered
sampling (Sample Factory, EnvPool's async mode) splits the envs into two groups: while one
group's step runs in a worker thread (MuJoCo releases the GIL), the main thread computes the
other group's actions. This script measures, side by side in one run and on the env and networks
``amorctl train`` builds (biped20, built-in clips, ``--preset``), milliseconds per control step of
every env for:

* **sequential**: forward pass on N envs, then ``env.step`` on N envs (what the trainer does);
* **sequential, forward on one torch thread**: the same, the forward pass on one core;
* **overlapped**: two envs of N/2, each group's step in one worker thread while the main thread
  runs the other group's forward pass (the pipeline a double-buffered sampler would run);
* **overlapped, forward on one torch thread**: the same, the forward pass leaving the other core
  to the physics;
* **overlapped, one physics thread per group**: the same, with each group's MuJoCo pool on one
  thread, so the two groups' physics and the forward pass share the cores instead of queueing.

The ceiling is what the forward passes and the env's numpy work take (the physics already keeps
the cores busy); the figures say how much of it the overlap recovers on this machine.

Usage: python benchmarks/overlap.py [--preset science] [--steps 48] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager

import mujoco
import mujoco.rollout
import numpy as np
import torch

from amorctl.core.config import load_preset, override
from amorctl.envs.factory import make_env
from amorctl.plugins.backends.torch_cpu import TorchCpuBackend
from amorctl.sim.cpus import cpu_description


def policy_step(trainer, obs: np.ndarray) -> np.ndarray:
    """Sampled actions [n, A] for observations [n, D]: actor and critic, as the rollout runs them."""
    with torch.no_grad():
        mean, _ = trainer._forward(torch.as_tensor(obs, dtype=torch.float32))
        return (mean + torch.exp(trainer.actor.log_std) * torch.randn(mean.shape)).numpy()


def sequential(trainer, env, steps: int) -> tuple[float, float]:
    """(ms per control step, share of it in the forward pass)."""
    obs, _ = env.reset(seed=0)
    forward = 0.0
    t0 = time.perf_counter()
    for _ in range(steps):
        t1 = time.perf_counter()
        actions = policy_step(trainer, obs)
        forward += time.perf_counter() - t1
        obs = env.step(actions)[0]
    total = time.perf_counter() - t0
    return 1e3 * total / steps, forward / total


def overlapped(trainer, groups: list, steps: int) -> float:
    """ms per control step of both groups, each group's step in a worker thread."""
    obs = [g.reset(seed=i)[0] for i, g in enumerate(groups)]
    pending: list[Future | None] = [None] * len(groups)
    with ThreadPoolExecutor(max_workers=len(groups)) as pool:
        t0 = time.perf_counter()
        for _ in range(steps):
            for i, group in enumerate(groups):
                if pending[i] is not None:
                    obs[i] = pending[i].result()[0]
                pending[i] = pool.submit(group.step, policy_step(trainer, obs[i]))
        for future in pending:
            assert future is not None
            future.result()
        total = time.perf_counter() - t0
    return 1e3 * total / steps


@contextmanager
def one_physics_thread(envs: list) -> Iterator[None]:
    """Each env's MuJoCo pool on one thread (and one MjData) for the duration."""
    saved = [(e.sim._pool, e.sim._datas) for e in envs]
    for e in envs:
        e.sim._pool, e.sim._datas = mujoco.rollout.Rollout(nthread=1), e.sim._datas[:1]
    try:
        yield
    finally:
        for e, (pool, datas) in zip(envs, saved, strict=True):
            e.sim._pool.close()
            e.sim._pool, e.sim._datas = pool, datas


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--preset", default="science")
    parser.add_argument("--steps", type=int, default=48, help="control steps per measurement")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    config = load_preset(args.preset)
    n = config.env.num_envs
    backend = TorchCpuBackend()
    whole = make_env(config, backend)
    trainer = backend.make_trainer(whole, config)
    halves = [make_env(override(config, env__num_envs=n // 2), backend) for _ in range(2)]
    print(f"CPU: {cpu_description()}; torch threads {torch.get_num_threads()}")
    print(f"{args.preset}: {n} envs, {args.steps} control steps per measurement, median of {args.repeats}")
    names = (
        "sequential",
        "sequential, forward on 1 torch thread",
        "overlapped",
        "overlapped, forward on 1 torch thread",
        "overlapped, 1 physics thread each",
    )
    rows: dict[str, list[float]] = {name: [] for name in names}
    shares = []
    try:
        for _ in range(args.repeats):  # interleaved: each repeat measures every variant back to back
            ms, share = sequential(trainer, whole, args.steps)
            rows["sequential"].append(ms)
            shares.append(share)
            rows["overlapped"].append(overlapped(trainer, halves, args.steps))
            threads = torch.get_num_threads()
            torch.set_num_threads(1)
            rows["sequential, forward on 1 torch thread"].append(sequential(trainer, whole, args.steps)[0])
            rows["overlapped, forward on 1 torch thread"].append(overlapped(trainer, halves, args.steps))
            torch.set_num_threads(threads)
            with one_physics_thread(halves):
                rows["overlapped, 1 physics thread each"].append(overlapped(trainer, halves, args.steps))
    finally:
        for env in (whole, *halves):
            env.close()
    base = statistics.median(rows["sequential"])
    print(f"forward passes: {statistics.median(shares):.0%} of a sequential step")
    for name, values in rows.items():
        ms = statistics.median(values)
        print(f"  {name:36s} {ms:7.2f} ms/step   x{base / ms:.2f}")


if __name__ == "__main__":
    main()
