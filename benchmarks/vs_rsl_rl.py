"""Training throughput beside a peer: rsl-rl-lib's PPO vs amorctl's MOPPO on the same biped20 env.

Both trainers drive their own copy of the same env (the run config's tracking env, default the
``quick`` preset: biped20 on its built-in clips, 256 envs, 24 steps per iteration, 5 epochs of 4
minibatches), with the same network sizes (ELU MLPs, actor and critic hidden layers from the
config), observation normalization, adaptive learning rate, clipping and discount. rsl-rl's PPO
is single-objective: the adapter hands it the reward scalarized with each env's own weights
``w · r`` (the weights are part of the observation, as for MOPPO), so the only algorithmic
difference is MOPPO's m-dimensional critic. The two run alternately (one iteration each, after
one warm-up iteration each) so that a machine-load change hits both; env steps/s of an iteration
is ``num_envs x num_steps / wall time`` (rollout with policy inference + update), the median over
``--iterations`` is reported, and the ratio MOPPO / rsl-rl (target >= 1.2).

rsl-rl-lib is an optional dependency (the ``bench`` extra). Install it without letting it replace
torch: ``pip install --no-deps rsl-rl-lib==5.5.1 tensordict==0.15.3 pyvers==0.2.3`` and
``pip install tensorboard==2.21.0`` (rsl-rl imports it; its own dependencies leave torch alone).

    python benchmarks/vs_rsl_rl.py [--preset quick] [--iterations 5] [--num-envs N]
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np
import torch

from amorctl.core.config import TrainConfig, load_preset, override
from amorctl.envs.factory import make_env
from amorctl.plugins.backends.torch_cpu import TorchCpuBackend

RSL_RL_PIN = "5.5.1"
INSTALL = (
    f"pip install --no-deps rsl-rl-lib=={RSL_RL_PIN} tensordict==0.15.3 pyvers==0.2.3 "
    "&& pip install tensorboard==2.21.0"
)


def _require_rsl_rl() -> Any:
    """The ``rsl_rl`` package, or exit with how to install it."""
    try:
        import rsl_rl.algorithms  # noqa: F401  (imports tensordict and tensorboard)
    except ImportError as exc:
        raise SystemExit(f"this benchmark needs rsl-rl-lib ({exc.name} is missing): {INSTALL}") from None
    from importlib.metadata import version

    return version("rsl-rl-lib")


class RslAdapter:
    """Our vector env as rsl-rl's ``VecEnv``: TensorDict observations (group ``policy``), the
    reward scalarized with each env's weights at the step, ``dones = terminated | truncated`` and
    ``extras["time_outs"] = truncated`` (so rsl-rl bootstraps time-outs, as MOPPO does)."""

    def __init__(self, env: Any) -> None:
        self.env = env
        self.num_envs = env.num_envs
        self.num_actions = int(env.action_dim)
        self.max_episode_length = int(getattr(env, "max_episode_steps", 500))
        self.episode_length_buf = torch.zeros(self.num_envs, dtype=torch.long)
        self.device = "cpu"
        self.cfg: dict = {}
        obs, _ = env.reset(seed=0)
        self._obs = obs

    def _pack(self, obs: np.ndarray) -> Any:
        from tensordict import TensorDict

        return TensorDict(
            {"policy": torch.from_numpy(np.asarray(obs, dtype=np.float32))}, batch_size=[self.num_envs]
        )

    def get_observations(self) -> Any:
        """The current observations as a TensorDict ``{"policy": [N, obs_dim]}``."""
        return self._pack(self._obs)

    def step(self, actions: torch.Tensor) -> tuple[Any, torch.Tensor, torch.Tensor, dict]:
        """One env step: observations, scalarized rewards [N], dones [N], extras."""
        weights = np.array(self.env.weights, copy=True)  # this step's weights (auto-reset redraws)
        obs, reward, terminated, truncated, _ = self.env.step(actions.detach().numpy())
        self._obs = obs
        done = np.logical_or(terminated, truncated)
        self.episode_length_buf += 1
        self.episode_length_buf[torch.from_numpy(done)] = 0
        scalar = torch.from_numpy((np.asarray(reward) * weights).sum(axis=1).astype(np.float32))
        extras = {"time_outs": torch.from_numpy(np.asarray(truncated))}
        return self._pack(obs), scalar, torch.from_numpy(done).to(torch.long), extras


def rsl_rl_config(config: TrainConfig) -> dict:
    """rsl-rl's runner config mirroring the amorctl config's PPO and network settings."""
    p, n = config.ppo, config.network
    dist = {"class_name": "GaussianDistribution", "init_std": n.init_std}
    return {
        "num_steps_per_env": p.num_steps,
        "obs_groups": {"actor": ["policy"], "critic": ["policy"]},
        "multi_gpu": None,
        "algorithm": {
            "class_name": "PPO",
            "num_learning_epochs": p.num_epochs,
            "num_mini_batches": p.num_minibatches,
            "clip_param": p.clip_coef,
            "gamma": p.gamma,
            "lam": p.gae_lambda,
            "value_loss_coef": p.value_coef,
            "entropy_coef": p.entropy_coef,
            "learning_rate": p.learning_rate,
            "max_grad_norm": p.max_grad_norm,
            "schedule": "adaptive" if p.lr_schedule == "adaptive" else "fixed",
            "desired_kl": p.desired_kl,
        },
        "actor": {
            "class_name": "MLPModel",
            "hidden_dims": list(n.actor_hidden),
            "activation": "elu",
            "obs_normalization": True,
            "distribution_cfg": dist,
        },
        "critic": {
            "class_name": "MLPModel",
            "hidden_dims": list(n.critic_hidden),
            "activation": "elu",
            "obs_normalization": True,
        },
    }


class RslTrainer:
    """rsl-rl's PPO with the loop of its ``OnPolicyRunner.learn`` (without its logger, which needs
    GitPython and tensorboard): rollout under inference mode, returns, update."""

    def __init__(self, env: RslAdapter, cfg: dict) -> None:
        import contextlib
        import io

        from rsl_rl.algorithms import PPO

        self.env, self.cfg = env, cfg
        with contextlib.redirect_stdout(io.StringIO()):  # it prints both models
            self.alg = PPO.construct_algorithm(env.get_observations(), env, cfg, "cpu")
        self.alg.train_mode()
        self.obs = env.get_observations()

    def iteration(self) -> float:
        """One collect + update; returns its env steps/s."""
        t0 = time.perf_counter()
        with torch.inference_mode():
            for _ in range(self.cfg["num_steps_per_env"]):
                actions = self.alg.act(self.obs)
                self.obs, rewards, dones, extras = self.env.step(actions)
                self.alg.process_env_step(self.obs, rewards, dones, extras)
            self.alg.compute_returns(self.obs)
        self.alg.update()
        return self.env.num_envs * self.cfg["num_steps_per_env"] / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--iterations", type=int, default=5, help="timed iterations of each trainer")
    parser.add_argument("--num-envs", type=int, default=None)
    args = parser.parse_args()
    rsl_version = _require_rsl_rl()
    config = load_preset(args.preset)
    if args.num_envs:
        config = override(config, env__num_envs=args.num_envs)
    backend = TorchCpuBackend()
    amor_env = make_env(config, backend)
    moppo = backend.make_trainer(amor_env, config)
    rsl = RslTrainer(RslAdapter(make_env(config, backend)), rsl_rl_config(config))
    moppo.iteration(), rsl.iteration()  # warm-up: allocations, first resets
    amor, peer = [], []
    for _ in range(args.iterations):
        amor.append(moppo.iteration()["env_steps_per_s"])
        peer.append(rsl.iteration())
    a, r = statistics.median(amor), statistics.median(peer)
    e = config.env
    print(
        f"{e.character}, {e.num_envs} envs x {config.ppo.num_steps} steps, "
        f"actor {list(config.network.actor_hidden)}, critic {list(config.network.critic_hidden)}, "
        f"{torch.get_num_threads()} torch threads, "
        f"rsl-rl-lib {rsl_version}, median of {args.iterations} alternating iterations"
    )
    print(f"amorctl MOPPO: {a:8,.0f} env steps/s  rsl-rl PPO: {r:8,.0f} env steps/s  ratio: {a / r:.2f}")


if __name__ == "__main__":
    main()
