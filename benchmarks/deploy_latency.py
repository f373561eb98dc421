"""Per-tick policy latency of a deploy bundle (onnxruntime) vs the torch policy, and runtime steps/s.

Exports ``--run`` (default: a fresh one-iteration biped20 run on synthetic clips with the quick
preset's network, actor 256-256-256, so no dataset or long training is needed: latency depends
on the network's size, not its training) to a temporary bundle, then times:

- one policy evaluation at batch 1, as the runtime calls it every control tick: onnxruntime
  (1 intra-op thread) on the bundle's named inputs, and the torch policy (``torch`` with 1
  thread, ``Policy.__call__`` on the full observation), each ``--calls`` times on observations
  recorded from a runtime episode; median and p99 in microseconds;
- the sim2sim runtime (nominal dynamics, no log): control ticks per second of wall time
  (observation + ONNX + 5 physics steps with the servo model per tick), and the same as
  physics steps/s.

    python benchmarks/deploy_latency.py [--run RUN] [--calls 3000] [--seconds 10]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np
import torch


def tiny_run(root: Path) -> Path:
    """A one-iteration biped20 run with the quick preset's network on two synthetic clips."""
    from amorctl.core.config import TrainConfig, merge
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.motion.dataset import write_dataset
    from amorctl.registry import get_registry
    from amorctl.train.loop import train_run

    lib = synthetic_library(get_registry().character("biped20"), num_clips=2, seconds=4.0, seed=3)
    write_dataset(root / "ds.mcap", dataclasses.replace(lib))
    config = merge(
        TrainConfig(),
        {
            "run": {"iterations": 1, "checkpoint_every": 1, "tensorboard": False, "threads": 1},
            "env": {"kind": "tracking", "character": "biped20", "dataset": str(root / "ds.mcap"),
                    "num_envs": 8, "episode_seconds": 4.0, "action_mode": "residual"},
            "network": {"actor_hidden": [256, 256, 256], "critic_hidden": [256, 256, 256]},
            "ppo": {"num_steps": 8, "num_epochs": 1, "num_minibatches": 1},
        },
        "deploy_latency benchmark",
    )  # fmt: skip
    train_run(config, root / "run")
    return root / "run"


def stats_us(samples: list[float]) -> str:
    a = np.asarray(samples) * 1e6
    return f"median {np.median(a):8.1f} us   p99 {np.percentile(a, 99):8.1f} us"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=None, help="run directory (default: a fresh tiny run)")
    parser.add_argument("--calls", type=int, default=3000, help="timed policy calls per implementation")
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds of the runtime timing")
    args = parser.parse_args()
    torch.set_num_threads(1)

    from amorctl.deploy.bundle import read_bundle
    from amorctl.deploy.export import export_bundle
    from amorctl.deploy.runtime import Runtime
    from amorctl.train.rundir import RunDir

    with tempfile.TemporaryDirectory() as tmp:
        run = args.run or tiny_run(Path(tmp))
        res = export_bundle(run, Path(tmp) / "bundle")
        bundle = read_bundle(Path(tmp) / "bundle")
        policy = RunDir.open(run).policy(res.iteration)
        print(f"run {run} iteration {res.iteration}; inputs {res.inputs}")
        print(f"export parity: max |d| {res.parity_max_abs:.2e} over {res.parity_samples} observations")

        rt = Runtime(bundle)
        m = rt.m
        observations: list[np.ndarray] = []
        real_policy = rt.policy

        def recording(feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
            observations.append(feeds)
            return real_policy(feeds)

        rt.policy = recording
        rt.run(np.full(m, 1.0 / m), seconds=4.0, stop_on_fall=False)
        rt.policy = real_policy
        groups = bundle.meta["inputs"]
        layout_obs = []
        for feeds in observations:  # rebuild the full observation for the torch policy
            full = np.zeros(policy.obs_dim, dtype=np.float32)
            for name, spec in groups.items():
                col = 0
                for a, b in spec["parts"].values():
                    full[a:b] = feeds[name][0, col : col + b - a]
                    col += b - a
            layout_obs.append(full[None])

        def time_calls(fn, inputs) -> list[float]:
            for x in inputs[:50]:
                fn(x)
            out = []
            for k in range(args.calls):
                x = inputs[k % len(inputs)]
                t0 = time.perf_counter()
                fn(x)
                out.append(time.perf_counter() - t0)
            return out

        onnx_t = time_calls(bundle.evaluate, observations)
        torch_t = time_calls(policy, layout_obs)
        print(f"policy latency, batch 1, onnxruntime 1 thread : {stats_us(onnx_t)}")
        print(f"policy latency, batch 1, torch 1 thread       : {stats_us(torch_t)}")

        t0 = time.perf_counter()
        result = Runtime(bundle).run(np.full(m, 1.0 / m), seconds=args.seconds, stop_on_fall=False)
        wall = time.perf_counter() - t0
        substeps = bundle.spec.substeps if bundle.spec else 1
        print(f"runtime: {result.steps} control ticks in {wall:.2f} s = {result.steps / wall:,.0f} ticks/s "
              f"({result.steps * substeps / wall:,.0f} physics steps/s; real time needs "
              f"{bundle.meta['control_hz']} ticks/s)")  # fmt: skip


if __name__ == "__main__":
    main()
