"""bf16 autocast speed-up of the MOPPO update on this CPU, for the quick and paper network sizes.

Times ``MOPPOTrainer.update`` (forward + backward + Adam over ``num_epochs`` x ``num_minibatches``)
on a fixed random batch shaped like biped20 tracking (obs 251, actions 20, 7 objectives), fp32 vs
bf16 autocast, and prints samples/s for each and the ratio. The env is a stand-in that only gives
the shapes; the update does not depend on where the batch came from. A benchmark, not a test.

Usage: python benchmarks/bf16_speedup.py [--batch 6144] [--repeats 3] [--threads 2]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

from amorctl.core.config import load_preset, override
from amorctl.core.vecenv import RewardSpace
from amorctl.plugins.backends.torch_cpu import bf16_supported
from amorctl.plugins.backends.torch_cpu.moppo import MOPPOTrainer

OBS, ACT, M = 251, 20, 7


class ShapeEnv:
    """Random observations and rewards of the tracking env's shapes (just enough for a rollout)."""

    obs_dim, action_dim = OBS, ACT
    reward_space = RewardSpace(tuple(f"o{i}" for i in range(M)), ("",) * M, np.zeros(M), np.ones(M))

    def __init__(self, num_envs: int) -> None:
        self.num_envs = num_envs
        self.rng = np.random.default_rng(0)
        self.w = self.rng.dirichlet(np.ones(M), size=num_envs).astype(np.float32)

    @property
    def weights(self) -> np.ndarray:
        return self.w.copy()

    def _obs(self) -> np.ndarray:
        return np.concatenate([self.rng.normal(size=(self.num_envs, OBS - M)), self.w], 1).astype(np.float32)

    def reset(self, seed: int | None = None):
        return self._obs(), {}

    def step(self, actions: np.ndarray):
        n = self.num_envs
        r = self.rng.uniform(size=(n, M)).astype(np.float32)
        done = np.zeros(n, dtype=bool)
        obs = self._obs()
        return obs, r, done, done, {"final_obs": obs}


def time_update(preset: str, bf16: bool, batch: int, repeats: int) -> float:
    """Median samples/s of one update pass (epochs x minibatches) over a batch of ``batch`` samples."""
    config = load_preset(preset)
    steps = config.ppo.num_steps
    config = override(config, ppo__precision="bf16" if bf16 else "fp32", ppo__lr_schedule="fixed")
    env = ShapeEnv(max(1, batch // steps))
    trainer = MOPPOTrainer(env, config.network, config.ppo, seed=0, bf16=bf16)
    data, _ = trainer.collect_rollout()
    trainer.compute_returns(data)
    trainer.update(data)  # warm-up
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        trainer.update(data)
        elapsed = time.perf_counter() - t0
        rates.append(data.obs.shape[0] * config.ppo.num_epochs / elapsed)
    return statistics.median(rates)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--batch", type=int, default=6144, help="samples per update (quick: 256 x 24)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    if not bf16_supported():
        print("this CPU has no native bf16 (AVX512-BF16 / AMX): nothing to compare")
        return
    for preset in ("quick", "paper"):
        net = load_preset(preset).network.actor_hidden
        fp32 = time_update(preset, False, args.batch, args.repeats)
        bf16 = time_update(preset, True, args.batch, args.repeats)
        print(
            f"{preset:6s} nets {len(net)}x{net[0]:<5d} update samples/s (fwd+bwd+Adam, actor+critic): "
            f"fp32 {fp32:,.0f}  bf16 {bf16:,.0f}  speed-up: {bf16 / fp32:.2f}x"
        )


if __name__ == "__main__":
    main()
