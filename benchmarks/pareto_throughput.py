"""Time of a Pareto sweep (K weights x one episode) against the physics-only lower bound.

``amorctl pareto`` evaluates K weight vectors in one batched rollout: K envs, one episode each,
every control step running the policy (one batched forward pass), the tracking env (physics,
observations, rewards, resets) and the rollout bookkeeping. The lower bound is the physics alone:
the same :class:`~amorctl.sim.batch_sim.BatchSim` stepped the same number of batched control steps
from the same start states, with no policy, observations or rewards. The ratio
``sweep time / physics time`` is the overhead of everything else (goal: <= 1.2).

Without ``--run``, the policy is an untrained network of the run config's size (its cost is the
same as a trained one's; episodes may end earlier when it falls, and then the physics bound is
stepped just as long). One result line ends in ``ratio: X.XX``. Run with ``nice -n 10`` on shared
machines; figures are noisy there.

    python benchmarks/pareto_throughput.py [--run RUN] [--samples 1024] [--seconds 10]
        [--preset quick] [--threads 2]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import Any

import torch

from amorctl.analysis.eval_env import make_eval_env, sweep_weights
from amorctl.analysis.rollout import rollout
from amorctl.core.config import TrainConfig, load_preset
from amorctl.envs.tracking_env import TrackingEnv
from amorctl.envs.wrappers import FixedWeights
from amorctl.registry import get_registry
from amorctl.train.rundir import RunDir


def untrained_policy(config: TrainConfig, env: Any) -> Any:
    """A freshly initialized policy of the config's network size (for timing only)."""
    backend = get_registry().backend(config.run.backend).make()
    trainer = backend.make_trainer(env, config)
    return backend.load_policy(trainer.state_dict(), config)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--run", type=Path, default=None, help="trained run directory (default: untrained)")
    parser.add_argument("--preset", default="quick", help="config preset when no --run is given")
    parser.add_argument("--samples", type=int, default=1024, help="K weight vectors (= envs)")
    parser.add_argument("--seconds", type=float, default=10.0, help="episode time limit")
    parser.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch threads for the policy (1: MuJoCo's pool already uses the cores)",
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    if args.run is not None:
        opened = RunDir.open(args.run)
        policy, config = opened.policy(), opened.config
    else:
        policy, config = None, load_preset(args.preset)
    config = dataclasses.replace(config, env=dataclasses.replace(config.env, episode_seconds=args.seconds))
    env, _ = make_eval_env(config, args.samples, seed=args.seed)
    # the physics-only bound below steps the torch-cpu env's own simulation: this benchmark
    # measures that backend, so it (unlike analysis code) opens the concrete env
    inner = env.env if isinstance(env, FixedWeights) else env
    if not isinstance(inner, TrackingEnv):
        raise SystemExit("this benchmark needs a torch-cpu motion-tracking run or preset")
    if policy is None:
        policy = untrained_policy(config, env)
    weights, _ = sweep_weights(len(env.reward_space.names), args.samples, seed=args.seed)

    # --- the sweep: one batched rollout, one episode per env ---------------------------------
    env.reset(seed=args.seed)
    start_state = inner.sim.state.copy()
    start_target = inner.library.joint_pos[inner.ref_idx + 1].copy()
    t0 = time.perf_counter()
    ro = rollout(policy, env, weights, episodes=1, seed=args.seed, record_steps=False)
    sweep_s = time.perf_counter() - t0
    batched_steps = ro.batched_steps

    # --- the physics-only lower bound: the same batched steps of the same simulation ----------
    sim = inner.sim
    sim.state[:] = start_state
    sim.warmstart[:] = 0.0
    t0 = time.perf_counter()
    for _ in range(batched_steps):
        sim.step(start_target)
    physics_s = time.perf_counter() - t0
    env.close()  # type: ignore[attr-defined]

    n = args.samples
    env_steps = batched_steps * n
    eps = ro.episodes
    print(
        f"{inner.character.name}: {n} weights x one {args.seconds:g} s episode "
        f"({batched_steps} batched steps, {env_steps:,} env steps; "
        f"survival {eps.survived.mean():.0%}, policy {'trained' if args.run else 'untrained'}, "
        f"{sim.nthread} physics threads, {args.threads} torch threads)"
    )
    print(
        f"sweep {sweep_s:.1f} s ({env_steps / sweep_s:,.0f} env steps/s)  "
        f"physics only {physics_s:.1f} s ({env_steps / physics_s:,.0f} env steps/s)  "
        f"ratio: {sweep_s / physics_s:.2f}"
    )


if __name__ == "__main__":
    main()
