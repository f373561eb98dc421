"""The ``torch-cpu`` backend plugin: MuJoCo (C, threaded) for physics, PyTorch on the CPU for MOPPO.

``BackendSpec.make()`` returns a :class:`TorchCpuBackend`, which makes the motion-tracking env
(``make_env``) and the MOPPO trainer (``make_trainer``, implementing :class:`amorctl.core.contracts.Trainer`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from amorctl.api import hookimpl
from amorctl.core.config import TrainConfig
from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.core.levers import LEVERS
from amorctl.core.specs import BackendSpec
from amorctl.core.vecenv import VectorEnv
from amorctl.plugins.backends.host import build_tracking_env

NAME = "torch-cpu"


class TorchCpuBackend:
    """Env and trainer factory of the torch-cpu backend."""

    name = NAME

    def make_env(
        self,
        *,
        character: str,
        dataset: str | Path | None = None,
        objective_set: str = "tracking7",
        num_envs: int = 256,
        episode_seconds: float = 10.0,
        seed: int = 0,
        **options: Any,
    ) -> VectorEnv:
        """The motion-tracking env for ``character`` on ``dataset`` (default: the built-in clips,
        preprocessed into a cache on first use). Extra ``options`` go to the env's constructor."""
        from amorctl.envs.tracking_env import TrackingEnv

        if "nthread" not in options:  # the cores this process may use, shared among the node's ranks
            options["nthread"] = _threads_per_local_rank()
        return build_tracking_env(
            TrackingEnv,
            character=character,
            dataset=dataset,
            objective_set=objective_set,
            num_envs=num_envs,
            episode_seconds=episode_seconds,
            seed=seed,
            **options,
        )

    def make_trainer(self, env: VectorEnv, config: TrainConfig) -> Any:
        """A :class:`~amorctl.plugins.backends.torch_cpu.moppo.MOPPOTrainer` for ``env`` (with
        ``[distill] teachers``: its student variant, :mod:`~amorctl.plugins.backends.torch_cpu.distill`)."""
        from amorctl.plugins.backends.torch_cpu.moppo import MOPPOTrainer

        if config.run.threads > 0:
            torch.set_num_threads(config.run.threads)
        if config.ppo.precision == "bf16" and not bf16_supported():
            raise AmorError('[ppo] precision = "bf16", but this CPU has no native bf16 (AVX512-BF16 or AMX)')
        bf16 = config.ppo.precision == "bf16" or (config.ppo.precision == "auto" and bf16_supported())
        distributed = _process_group_size() > 1  # under torchrun: data-parallel over the group
        if config.distill.teachers:  # the student of the teachers the env carries (docs/distill.md)
            from amorctl.plugins.backends.torch_cpu.distill import DistillTrainer

            return DistillTrainer(
                env,
                config.network,
                config.ppo,
                seed=config.run.seed,
                learning_rate=config.distill.learning_rate,
                bf16=bf16,
                distributed=distributed,
                kickstart=(config.distill.kl_coef, config.distill.kl_fade_iterations)
                if config.distill.rewards
                else None,
            )
        return MOPPOTrainer(
            env, config.network, config.ppo, seed=config.run.seed, bf16=bf16, distributed=distributed
        )

    def load_policy(self, trainer_state: Snapshot, config: TrainConfig) -> Any:
        """A :class:`~amorctl.plugins.backends.torch_cpu.policy.TorchPolicy` from a checkpoint's
        trainer state (inference only: actor, critic, normalizer)."""
        from amorctl.plugins.backends.torch_cpu.policy import TorchPolicy

        return TorchPolicy(trainer_state, config.network)


def _process_group_size() -> int:
    """The size of the initialized ``torch.distributed`` default group (1 without one)."""
    import torch.distributed as dist

    return dist.get_world_size() if dist.is_available() and dist.is_initialized() else 1


def _threads_per_local_rank() -> int:
    """MuJoCo rollout threads per rank: the cores this process may run on (its CPU affinity, so
    ``taskset -c 1 amorctl train`` gets 1) over the ranks on this machine (torchrun's
    ``LOCAL_WORLD_SIZE``), at least one."""
    from amorctl.sim.cpus import available_cpus

    try:
        local = max(1, int(os.environ.get("LOCAL_WORLD_SIZE", "1")))
    except ValueError:
        local = 1
    return max(1, available_cpus() // local)


def bf16_supported() -> bool:
    """Whether the CPU runs bf16 matrix products natively (AVX512-BF16 / AMX), per /proc/cpuinfo."""
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return "avx512_bf16" in flags or "amx_bf16" in flags


@hookimpl
def amorctl_register_backends(register: Any) -> None:
    """Register ``torch-cpu``."""
    register(
        BackendSpec(
            name=NAME,
            description="MuJoCo C physics + PyTorch MOPPO on the CPU",
            make=TorchCpuBackend,
            levers=frozenset(LEVERS),
        )
    )
