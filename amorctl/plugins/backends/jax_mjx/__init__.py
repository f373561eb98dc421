"""The ``jax-mjx`` backend plugin: MuJoCo MJX physics and MOPPO in JAX, on every local device.

It is interchangeable with ``torch-cpu``: the same config, CLI, run directory and checkpoint
format (safetensors + JSON, the torch-cpu array names for the actor, critic and normalizer), so a
jax-mjx run's policy loads through either backend's inference path. See docs/backends.md.

JAX, MJX, flax and optax come from the optional extra ``amorctl[jax]``; this module imports none
of them, so ``amorctl plugins`` lists the backend without the extra, and using it without the
extra raises one :class:`AmorError` naming the extra.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import io
from pathlib import Path
from typing import Any

from amorctl.api import hookimpl
from amorctl.core.config import TrainConfig
from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.core.specs import BackendSpec
from amorctl.core.vecenv import VectorEnv
from amorctl.plugins.backends.host import build_tracking_env
from amorctl.plugins.backends.jax_mjx.xla_cpu import disable_concurrency_optimized_scheduler

disable_concurrency_optimized_scheduler()

NAME = "jax-mjx"
#: import name -> distribution of the packages the ``jax`` extra installs
EXTRA_MODULES = {"jax": "jax", "mujoco.mjx": "mujoco-mjx", "flax": "flax", "optax": "optax"}
INSTALL_HINT = 'pip install "amorctl[jax]"'
#: The training levers (docs/moppo.md, "Levers") jax-mjx implements: return normalization
#: (moppo_math.py, trainer.py) and the weight mixture (weight_mix.py). The survival channel and
#: adaptive weights stay torch-cpu's.
LEVERS = frozenset({"return_norm", "weight_sampling", "termination_distance"})


def missing_modules() -> list[str]:
    """Distributions of the ``jax`` extra that are not importable (empty when it is installed)."""
    missing = []
    for module, dist in EXTRA_MODULES.items():
        try:
            found = importlib.util.find_spec(module) is not None
        except ModuleNotFoundError:  # the parent package (e.g. mujoco) is absent
            found = False
        if not found:
            missing.append(dist)
    return missing


def require_extra() -> None:
    """Raise AmorError naming the ``jax`` extra when any of its packages is missing."""
    missing = missing_modules()
    if missing:
        raise AmorError(
            f"backend {NAME!r} needs the optional extra 'jax' ({', '.join(missing)} not installed): "
            f"{INSTALL_HINT}"
        )


class JaxMjxBackend:
    """Env and trainer factory of the jax-mjx backend (checks for the extra when made)."""

    name = NAME

    def __init__(self) -> None:
        require_extra()

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
        """The MJX motion-tracking env (:class:`~.env.MjxTrackingEnv`) for ``character``."""
        import_mjx_quietly()
        from amorctl.plugins.backends.jax_mjx.env import MjxTrackingEnv

        return build_tracking_env(
            MjxTrackingEnv,
            character=character,
            dataset=dataset,
            objective_set=objective_set,
            num_envs=num_envs,
            episode_seconds=episode_seconds,
            seed=seed,
            **options,
        )

    def make_trainer(self, env: VectorEnv, config: TrainConfig) -> Any:
        """A :class:`~.trainer.JaxMOPPOTrainer` for ``env`` (data-parallel over local devices)."""
        from amorctl.plugins.backends.jax_mjx.trainer import JaxMOPPOTrainer

        if config.ppo.precision == "bf16":
            raise AmorError('[ppo] precision = "bf16" is torch-cpu only; jax-mjx trains in fp32')
        return JaxMOPPOTrainer(env, config.network, config.ppo, seed=config.run.seed)

    def load_policy(self, trainer_state: Snapshot, config: TrainConfig) -> Any:
        """A :class:`~.policy.JaxPolicy` from a checkpoint's trainer state."""
        from amorctl.plugins.backends.jax_mjx.policy import JaxPolicy

        return JaxPolicy(trainer_state, config.network)


def import_mjx_quietly() -> None:
    """Import ``mujoco.mjx`` without its chatter: where warp is not installed it prints ``Failed
    to import warp: ...`` and ``Failed to import mujoco_warp: ...`` on stdout. The backend uses
    MJX's JAX implementation, never warp, so the lines say nothing to its users."""
    with contextlib.redirect_stdout(io.StringIO()):
        importlib.import_module("mujoco.mjx")


@hookimpl
def amorctl_register_backends(register: Any) -> None:
    """Register ``jax-mjx`` (whether or not the extra is installed: using it then names the extra)."""
    register(
        BackendSpec(
            name=NAME,
            description=f"MuJoCo MJX physics + JAX MOPPO, sharded over devices (extra: {INSTALL_HINT})",
            make=JaxMjxBackend,
            levers=LEVERS,
        )
    )
