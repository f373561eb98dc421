"""The HLP's configuration: frozen dataclasses are the schema, TOML presets are the files.

Layers as for ``amorctl train``: the dataclass defaults (= the ``hlp_v30`` preset), a preset
(``amorctl/presets/hlp_<name>.toml``), the user's ``--config`` file, then command-line options.
Sections ``[run]``, ``[env]``, ``[policy]``, ``[ppo]``, ``[discriminator]``; unknown keys are
rejected by name. Every default and its source is listed in ``docs/hlp.md``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any, get_type_hints

from amorctl.core.config import read_toml, sections_to_toml
from amorctl.core.config_values import coerce_value
from amorctl.core.errors import AmorError


def _doc(default: Any, text: str) -> Any:
    return field(default=default, metadata={"doc": text})


@dataclass(frozen=True)
class HlpRunConfig:
    """How long, with what seed, and how the HLP run is recorded."""

    iterations: int = _doc(200, "PPO iterations (one rollout, k discriminator steps, one PPO update)")
    seed: int = _doc(0, "seed of the env, the networks, the action noise and dataset sampling")
    checkpoint_every: int = _doc(25, "save a checkpoint every this many iterations (and on exit)")
    keep_checkpoints: int = _doc(3, "how many recent checkpoints to keep (0 = keep all)")
    threads: int = _doc(1, "torch CPU threads (0 = torch's default)")
    tensorboard: bool = _doc(True, "also write metrics as TensorBoard scalars under tb/")
    llp_iteration: int = _doc(-1, "checkpoint iteration of the frozen low-level policy (-1 = newest)")


@dataclass(frozen=True)
class HlpEnvConfig:
    """The frozen AMOR policy's env, as the HLP drives it."""

    num_envs: int = _doc(32, "environments stepped in parallel")
    episode_seconds: float = _doc(10.0, "episode time limit in seconds (truncation, bootstrapped)")
    motions: tuple[str, ...] = _doc((), "clip names the episodes draw from (empty = every clip)")
    decision_interval: int = _doc(1, "the HLP picks w every this many control steps and holds it between")


@dataclass(frozen=True)
class HlpPolicyConfig:
    """pi_H(w | s, c): Gaussian over m logits, softmax onto the simplex; ELU MLPs."""

    actor_hidden: tuple[int, ...] = _doc((128, 128, 128), "actor hidden widths (3-layer ELU MLP)")
    critic_hidden: tuple[int, ...] = _doc((128, 128, 128), "critic hidden widths (3-layer ELU MLP)")
    init_std: float = _doc(1.0, "initial std of the Gaussian over logits (state-independent)")
    obs_clip: float = _doc(10.0, "normalized observations are clipped to [-obs_clip, obs_clip]")


@dataclass(frozen=True)
class HlpPPOConfig:
    """Single-objective PPO on the discriminator reward."""

    num_steps: int = _doc(32, "HLP decisions per env per iteration")
    num_epochs: int = _doc(4, "passes over the rollout per iteration")
    num_minibatches: int = _doc(4, "minibatches per epoch")
    gamma: float = _doc(0.95, "discount factor")
    gae_lambda: float = _doc(0.95, "GAE lambda")
    clip_coef: float = _doc(0.2, "PPO ratio clipping epsilon")
    value_coef: float = _doc(0.5, "weight of the value loss")
    entropy_coef: float = _doc(0.0, "weight of the entropy bonus")
    learning_rate: float = _doc(3e-4, "Adam learning rate of actor and critic")
    max_grad_norm: float = _doc(1.0, "clip the global gradient norm to this")


@dataclass(frozen=True)
class DiscriminatorConfig:
    """D(O_t | z_t) and the reward r^D = -log(max(1 - D, clamp))."""

    reward: str = _doc(
        "discriminator", "the HLP's reward: discriminator, or objective:<name> (that env objective)"
    )
    window: int = _doc(30, "V, frames per observation window O_t")
    hidden: tuple[int, ...] = _doc(
        (256, 128), "D's hidden widths (ELU); the paper-size preset uses 1024, 512"
    )
    z_hidden: tuple[int, ...] = _doc((64,), "the z encoder's hidden widths before concatenation")
    grad_penalty: float = _doc(5.0, "c_gp, gradient penalty on dataset samples")
    logit_l2: float = _doc(0.01, "L2 on the logit layer's weights")
    weight_decay: float = _doc(1e-4, "L2 on every weight of D (added to the loss)")
    learning_rate: float = _doc(5e-5, "Adam learning rate of D")
    steps_per_iteration: int = _doc(4, "k discriminator steps per PPO iteration")
    batch_size: int = _doc(256, "dataset windows per D step (negatives: as many)")
    replay_size: int = _doc(20000, "capacity of the replay buffer of policy windows")
    replay_fraction: float = _doc(0.5, "share of policy negatives drawn from the replay buffer")
    mismatched_fraction: float = _doc(0.25, "share of negatives that are dataset windows with a wrong z")
    reward_clamp: float = _doc(1e-4, "r^D = -log(max(1 - D, reward_clamp))")


@dataclass(frozen=True)
class HlpConfig:
    """The whole HLP configuration."""

    run: HlpRunConfig = field(default_factory=HlpRunConfig)
    env: HlpEnvConfig = field(default_factory=HlpEnvConfig)
    policy: HlpPolicyConfig = field(default_factory=HlpPolicyConfig)
    ppo: HlpPPOConfig = field(default_factory=HlpPPOConfig)
    discriminator: DiscriminatorConfig = field(default_factory=DiscriminatorConfig)


SECTIONS: dict[str, type] = {
    "run": HlpRunConfig,
    "env": HlpEnvConfig,
    "policy": HlpPolicyConfig,
    "ppo": HlpPPOConfig,
    "discriminator": DiscriminatorConfig,
}
PRESETS: tuple[str, ...] = ("v30", "v2", "paper")


def merge(base: HlpConfig, data: Mapping[str, Any], source: str = "config") -> HlpConfig:
    """Override ``base`` with partial nested TOML data; AmorError names an unknown or bad key."""
    sections: dict[str, Any] = {}
    for section, values in data.items():
        if section not in SECTIONS:
            raise AmorError(f"{source}: unknown section [{section}] (known: {', '.join(SECTIONS)})")
        if not isinstance(values, Mapping):
            raise AmorError(f"{source}: [{section}] must be a table")
        cls = SECTIONS[section]
        hints, known = get_type_hints(cls), [f.name for f in fields(cls)]
        changes = {}
        for key, value in values.items():
            if key not in known:
                raise AmorError(f"{source}: unknown key {key!r} in [{section}] (known: {', '.join(known)})")
            # type checks only (the HLP fields carry no bounds); lists may be empty
            changes[key] = coerce_value(value, hints[key], f"{source}: [{section}] {key}", {"min_len": 0})
        sections[section] = dataclasses.replace(getattr(base, section), **changes)
    return validate(dataclasses.replace(base, **sections), source)


def validate(config: HlpConfig, source: str = "config") -> HlpConfig:
    """Check ranges; AmorError names the first bad field."""
    r, e, p, o, d = config.run, config.env, config.policy, config.ppo, config.discriminator
    checks = [
        (r.iterations >= 0, "[run] iterations must be >= 0"),
        (r.checkpoint_every >= 1, "[run] checkpoint_every must be >= 1"),
        (r.keep_checkpoints >= 0, "[run] keep_checkpoints must be >= 0"),
        (r.threads >= 0, "[run] threads must be >= 0"),
        (e.num_envs >= 1, "[env] num_envs must be >= 1"),
        (e.episode_seconds > 0, "[env] episode_seconds must be > 0"),
        (e.decision_interval >= 1, "[env] decision_interval must be >= 1"),
        (all(h >= 1 for h in p.actor_hidden + p.critic_hidden), "[policy] layer widths must be >= 1"),
        (p.init_std > 0, "[policy] init_std must be > 0"),
        (p.obs_clip > 0, "[policy] obs_clip must be > 0"),
        (o.num_steps >= 1, "[ppo] num_steps must be >= 1"),
        (o.num_epochs >= 1, "[ppo] num_epochs must be >= 1"),
        (1 <= o.num_minibatches <= e.num_envs * o.num_steps, "[ppo] num_minibatches must be in [1, batch]"),
        (0 <= o.gamma <= 1 and 0 <= o.gae_lambda <= 1, "[ppo] gamma and gae_lambda must be in [0, 1]"),
        (o.clip_coef > 0 and o.learning_rate > 0, "[ppo] clip_coef and learning_rate must be > 0"),
        (o.max_grad_norm > 0, "[ppo] max_grad_norm must be > 0"),
        (d.window >= 1, f"[discriminator] window (V) must be >= 1, got {d.window}"),
        (
            d.reward == "discriminator" or d.reward.startswith("objective:"),
            f"[discriminator] reward must be discriminator or objective:<name>, got {d.reward!r}",
        ),
        (all(h >= 1 for h in d.hidden + d.z_hidden), "[discriminator] layer widths must be >= 1"),
        (min(d.grad_penalty, d.logit_l2, d.weight_decay) >= 0, "[discriminator] penalties must be >= 0"),
        (d.learning_rate > 0, "[discriminator] learning_rate must be > 0"),
        (d.steps_per_iteration >= 0, "[discriminator] steps_per_iteration must be >= 0"),
        (d.batch_size >= 2, "[discriminator] batch_size must be >= 2"),
        (d.replay_size >= 1, "[discriminator] replay_size must be >= 1"),
        (0 <= d.replay_fraction <= 1, "[discriminator] replay_fraction must be in [0, 1]"),
        (0 <= d.mismatched_fraction < 1, "[discriminator] mismatched_fraction must be in [0, 1)"),
        (0 < d.reward_clamp < 1, "[discriminator] reward_clamp must be in (0, 1)"),
    ]
    for ok, message in checks:
        if not ok:
            raise AmorError(f"{source}: {message}")
    return config


def load_hlp_config(path: str | Path, base: HlpConfig | None = None) -> HlpConfig:
    """A (partial) HLP TOML file on top of ``base`` (default: the schema defaults)."""
    return merge(base or HlpConfig(), read_toml(path), str(path))


def load_hlp_preset(name: str) -> HlpConfig:
    """A built-in HLP preset: ``v30`` (default), ``v2`` or ``paper`` (GPU-sized D)."""
    if name not in PRESETS:
        raise AmorError(f"unknown HLP preset {name!r} (presets: {', '.join(PRESETS)})")
    return load_hlp_config(Path(str(resources.files("amorctl.presets").joinpath(f"hlp_{name}.toml"))))


def to_toml(config: HlpConfig) -> str:
    """The fully resolved config as commented TOML (tomlkit); :func:`merge` reads it back."""
    return sections_to_toml(config, SECTIONS, "amorctl HLP config, fully resolved")
