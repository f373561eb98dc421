"""Host-side bookkeeping both backends share (numpy and plain Python, no framework).

What a backend does the same way whatever computes its networks: loading the motion library it
tracks, the metadata of an exported policy, the checks a checkpoint's metadata must pass before
its arrays are read, and the run counters it restores.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError

#: Format tag of a policy's ``export_arrays()`` (the backend-neutral names both backends emit).
EXPORT_FORMAT = "amorctl-mlp-policy/1"
#: Checkpoint name of the actor's state-independent log standard deviation.
LOG_STD = "actor.log_std"


def linear_param_name(net: str, i: int, part: str) -> str:
    """Checkpoint name of ``part`` (``weight`` [out, in] or ``bias`` [out]) of linear layer ``i``
    of ``net`` (``actor``, ``critic``, ``survival_critic``): torch-cpu's ``nn.Sequential`` names,
    where linear layers and activations alternate (linear i is module 2i). The jax-mjx backend
    writes the same names, so the two backends' checkpoints interchange
    (tests/test_jax_mjx.py pins both sides to this function)."""
    return f"{net}.net.{2 * i}.{part}"


#: Checkpoint metadata -> trainer attribute of the counters every MOPPO trainer keeps.
COUNTERS: dict[str, str] = {"iteration": "iteration_count", "env_steps": "env_steps"}


def load_library(character: str, dataset: str | Path | None) -> Any:
    """The motion library to track: ``dataset`` if given, else the character's built-in clips
    (preprocessed into the user cache on first use).

    Raises:
        AmorError: the file is missing or holds another character's clips.
    """
    from amorctl.motion.cache import default_dataset
    from amorctl.motion.dataset import load_dataset

    path = Path(dataset) if dataset else default_dataset(character)
    if not path.is_file():
        raise AmorError(f"{path}: motion dataset not found")
    library = load_dataset(path)
    if library.character != character:
        raise AmorError(f"{path}: dataset is for character {library.character!r}, not {character!r}")
    return library


def build_tracking_env(
    env_cls: Any,
    *,
    character: str,
    dataset: str | Path | None,
    objective_set: str,
    num_envs: int,
    episode_seconds: float,
    seed: int,
    **options: Any,
) -> Any:
    """A backend's tracking env: ``env_cls(spec, library, objective_set, num_envs=...,
    max_episode_steps=..., seed=..., **options)`` for the registered ``character`` on ``dataset``
    (default: its built-in clips), episodes of ``episode_seconds`` at its control rate.

    Raises:
        AmorError: an unknown character, a missing dataset or one of another character.
    """
    from amorctl.registry import get_registry

    spec = get_registry().character(character)  # unknown names fail here, clearly
    library = load_library(character, dataset)
    steps = max(1, round(episode_seconds * spec.control_hz))
    return env_cls(
        spec, library, objective_set, num_envs=num_envs, max_episode_steps=steps, seed=seed, **options
    )


def export_snapshot(policy: Any, arrays: dict[str, Any], layers: Mapping[str, int]) -> Snapshot:
    """A policy's ``export_arrays()``: its backend-neutral ``arrays`` and the metadata (format,
    activation, observation clip, the number of linear layers of ``actor`` and ``critic``
    (``layers``), dimensions, objective names, observation layout {part: [start, stop]}) read
    from ``policy`` (``normalizer.clip``, ``obs_dim``, ``action_dim``, ``objectives``,
    ``observation_layout``)."""
    meta = {
        "format": EXPORT_FORMAT,
        "activation": "elu",
        "obs_clip": float(policy.normalizer.clip),
        "actor_layers": int(layers["actor"]),
        "critic_layers": int(layers["critic"]),
        "obs_dim": int(policy.obs_dim),
        "action_dim": int(policy.action_dim),
        "objectives": list(policy.objectives),
        "observation_layout": {k: list(v) for k, v in policy.observation_layout.items()},
    }
    return Snapshot(arrays, meta)


def check_env_meta(meta: Mapping[str, Any], env: Any, objectives: Sequence[str]) -> None:
    """Refuse a checkpoint made for another env: its ``obs_dim``, ``action_dim`` and objective
    names must be ``env``'s."""
    expect = {"obs_dim": env.obs_dim, "action_dim": env.action_dim, "objectives": list(objectives)}
    for key, value in expect.items():
        if meta.get(key) != value:
            raise AmorError(f"checkpoint has {key} = {meta.get(key)!r}, this environment has {value!r}")


def load_counters(trainer: Any, meta: Mapping[str, Any]) -> None:
    """Set the trainer's run counters (:data:`COUNTERS`) from checkpoint metadata."""
    for key, attr in COUNTERS.items():
        setattr(trainer, attr, int(meta[key]))
