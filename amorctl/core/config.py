"""Training configuration: frozen dataclasses are the schema, TOML is the file format.

A config is built in layers, each overriding the one before: the dataclass defaults (which equal
the ``quick`` preset), a preset file (``amorctl/presets/<name>.toml``), the user's ``--config``
file, then command-line options. Every layer is partial TOML with the sections ``[run]``,
``[env]``, ``[network]`` and ``[ppo]``; a key that is not in the schema is rejected by name.
:func:`to_toml` writes the fully resolved config (with every field's doc as a comment), which
:func:`load_config` reads back to the same object.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any, get_args, get_origin, get_type_hints

from amorctl.core.errors import AmorError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def _doc(default: Any, text: str) -> Any:
    """A dataclass field with a one-line doc (kept in ``metadata["doc"]``)."""
    return field(default=default, metadata={"doc": text})


@dataclass(frozen=True)
class RunConfig:
    """How long to train, with what, and how the run is recorded."""

    iterations: int = _doc(1000, "training iterations (one rollout and one update each)")
    seed: int = _doc(0, "seed of the env, the network initialisation and the action noise")
    backend: str = _doc("torch-cpu", "training backend plugin (see `amorctl plugins`)")
    checkpoint_every: int = _doc(50, "save a checkpoint every this many iterations (and on exit)")
    keep_checkpoints: int = _doc(3, "how many recent checkpoints to keep (0 = keep all)")
    threads: int = _doc(0, "CPU threads for the network (0 = the backend's default)")
    tensorboard: bool = _doc(True, "also write metrics as TensorBoard scalars under tb/")


@dataclass(frozen=True)
class EnvConfig:
    """Which environment is trained, and how many copies run in parallel."""

    kind: str = _doc(
        "tracking", "environment: tracking (motion tracking), toy, toy-smooth (two-objective toys), gym"
    )
    character: str = _doc("biped20", "character plugin (kind=tracking)")
    dataset: str = _doc("", "motion dataset file; empty = the character's built-in default clips")
    objective_set: str = _doc("tracking7", "objective-set plugin (kind=tracking)")
    num_envs: int = _doc(256, "environments stepped in parallel (N)")
    episode_seconds: float = _doc(10.0, "time limit of an episode in seconds (truncation, bootstrapped)")
    action_mode: str = _doc("residual", "tracking action: residual (PD target = reference + a) or absolute")
    gym_id: str = _doc("", "Gymnasium / MO-Gymnasium id with a vector reward (kind=gym)")
    fixed_weights: str = _doc("", "empty: w ~ Dirichlet(1) per episode (MOPPO); else one fixed w (PPO)")


@dataclass(frozen=True)
class NetworkConfig:
    """Actor pi(a | s, c, w) and critic V(s, c, w) in R^m: ELU MLPs."""

    actor_hidden: tuple[int, ...] = _doc((256, 256, 256), "hidden layer widths of the actor")
    critic_hidden: tuple[int, ...] = _doc((256, 256, 256), "hidden layer widths of the critic")
    init_std: float = _doc(0.1, "initial standard deviation of the Gaussian actions (state-independent)")
    obs_clip: float = _doc(10.0, "normalized observations are clipped to [-obs_clip, obs_clip]")


@dataclass(frozen=True)
class PPOConfig:
    """MOPPO: PPO with a vector critic and advantages scalarized by each episode's weights."""

    num_steps: int = _doc(24, "rollout horizon T: control steps per env per iteration")
    num_epochs: int = _doc(5, "passes over the rollout batch per iteration")
    num_minibatches: int = _doc(4, "minibatches per epoch (batch = num_envs * num_steps)")
    gamma: float = _doc(0.99, "discount factor")
    gae_lambda: float = _doc(0.95, "GAE lambda, applied per objective")
    clip_coef: float = _doc(0.2, "PPO ratio clipping epsilon")
    clip_value_loss: bool = _doc(True, "clip the value update around the rollout's values as PPO does")
    value_coef: float = _doc(1.0, "weight of the value loss (mean over the batch and the m outputs)")
    entropy_coef: float = _doc(0.0, "weight of the entropy bonus")
    learning_rate: float = _doc(5e-5, "Adam learning rate (the start value when lr_schedule=adaptive)")
    lr_schedule: str = _doc(
        "adaptive", "fixed, or adaptive: scale the rate by 1.5 to keep KL near desired_kl"
    )
    desired_kl: float = _doc(0.02, "target KL per minibatch for the adaptive learning rate")
    max_grad_norm: float = _doc(1.0, "clip the global gradient norm to this")
    normalize_obs: bool = _doc(True, "running mean/std observation normalization (saved with the policy)")
    precision: str = _doc(
        "auto", "fp32, bf16 (autocast; fp32 weights and losses), or auto: bf16 if the CPU has it"
    )


@dataclass(frozen=True)
class TrainConfig:
    """The whole training configuration; sections map to TOML tables."""

    run: RunConfig = field(default_factory=RunConfig)
    env: EnvConfig = field(default_factory=EnvConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)


SECTIONS: dict[str, type] = {"run": RunConfig, "env": EnvConfig, "network": NetworkConfig, "ppo": PPOConfig}
PRESETS: tuple[str, ...] = ("quick", "paper")
ENV_KINDS: tuple[str, ...] = ("tracking", "toy", "toy-smooth", "gym")
LR_SCHEDULES: tuple[str, ...] = ("fixed", "adaptive")
ACTION_MODES: tuple[str, ...] = ("residual", "absolute")
PRECISIONS: tuple[str, ...] = ("auto", "fp32", "bf16")


def _coerce(value: Any, hint: Any, where: str) -> Any:
    """Check one TOML value against a field's type hint; ints are accepted for floats."""
    if get_origin(hint) is tuple:
        (item,) = get_args(hint)[:1]
        if not isinstance(value, list | tuple):
            raise AmorError(f"{where}: expected a list of {item.__name__}, got {value!r}")
        return tuple(_coerce(v, item, where) for v in value)
    if hint is bool:
        if not isinstance(value, bool):
            raise AmorError(f"{where}: expected true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise AmorError(f"{where}: expected an integer, got {value!r}")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise AmorError(f"{where}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise AmorError(f"{where}: expected a finite number, got {value!r}")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise AmorError(f"{where}: expected a string, got {value!r}")
        return value
    raise AssertionError(f"unsupported config type {hint}")  # pragma: no cover


def merge(base: TrainConfig, data: Mapping[str, Any], source: str = "config") -> TrainConfig:
    """Override ``base`` with a partial config given as nested TOML data.

    Raises:
        AmorError: an unknown section or key (named, with the source), or a value of the wrong type.
    """
    sections: dict[str, Any] = {}
    for section, values in data.items():
        if section not in SECTIONS:
            raise AmorError(f"{source}: unknown section [{section}] (known: {', '.join(SECTIONS)})")
        if not isinstance(values, Mapping):
            raise AmorError(f"{source}: [{section}] must be a table")
        cls = SECTIONS[section]
        hints = get_type_hints(cls)
        known = [f.name for f in fields(cls)]
        changes = {}
        for key, value in values.items():
            if key not in known:
                raise AmorError(f"{source}: unknown key {key!r} in [{section}] (known: {', '.join(known)})")
            changes[key] = _coerce(value, hints[key], f"{source}: [{section}] {key}")
        sections[section] = dataclasses.replace(getattr(base, section), **changes)
    return validate(dataclasses.replace(base, **sections), source)


def override(base: TrainConfig, **dotted: Any) -> TrainConfig:
    """Override single fields by ``section__key`` keyword, e.g. ``override(c, run__seed=3)``."""
    data: dict[str, dict[str, Any]] = {}
    for name, value in dotted.items():
        section, _, key = name.partition("__")
        data.setdefault(section, {})[key] = value
    return merge(base, data, "command line")


def validate(config: TrainConfig, source: str = "config") -> TrainConfig:
    """Check ranges and choices; returns ``config`` unchanged.

    Raises:
        AmorError: naming the first bad field.
    """
    r, e, n, p = config.run, config.env, config.network, config.ppo
    checks = [
        (r.iterations >= 0, "[run] iterations must be >= 0"),
        (r.checkpoint_every >= 1, "[run] checkpoint_every must be >= 1"),
        (r.keep_checkpoints >= 0, "[run] keep_checkpoints must be >= 0"),
        (r.threads >= 0, "[run] threads must be >= 0"),
        (e.kind in ENV_KINDS, f"[env] kind must be one of {', '.join(ENV_KINDS)}, got {e.kind!r}"),
        (e.num_envs >= 1, "[env] num_envs must be >= 1"),
        (e.episode_seconds > 0, "[env] episode_seconds must be > 0"),
        (e.kind != "gym" or bool(e.gym_id), "[env] gym_id is required when kind = 'gym'"),
        (e.action_mode in ACTION_MODES, f"[env] action_mode must be one of {', '.join(ACTION_MODES)}"),
        (all(h >= 1 for h in n.actor_hidden + n.critic_hidden), "[network] layer widths must be >= 1"),
        (n.init_std > 0, "[network] init_std must be > 0"),
        (n.obs_clip > 0, "[network] obs_clip must be > 0"),
        (p.num_steps >= 1, "[ppo] num_steps must be >= 1"),
        (p.num_epochs >= 1, "[ppo] num_epochs must be >= 1"),
        (p.num_minibatches >= 1, "[ppo] num_minibatches must be >= 1"),
        (p.num_minibatches <= e.num_envs * p.num_steps, "[ppo] num_minibatches exceeds the batch size"),
        (0 <= p.gamma <= 1, "[ppo] gamma must be in [0, 1]"),
        (0 <= p.gae_lambda <= 1, "[ppo] gae_lambda must be in [0, 1]"),
        (p.clip_coef > 0, "[ppo] clip_coef must be > 0"),
        (p.learning_rate > 0, "[ppo] learning_rate must be > 0"),
        (p.lr_schedule in LR_SCHEDULES, f"[ppo] lr_schedule must be one of {', '.join(LR_SCHEDULES)}"),
        (p.desired_kl > 0, "[ppo] desired_kl must be > 0"),
        (p.max_grad_norm > 0, "[ppo] max_grad_norm must be > 0"),
        (p.precision in PRECISIONS, f"[ppo] precision must be one of {', '.join(PRECISIONS)}"),
    ]
    for ok, message in checks:
        if not ok:
            raise AmorError(f"{source}: {message}")
    return config


def read_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML file. Raises AmorError naming the file if it is missing or malformed."""
    path = Path(path)
    if not path.is_file():
        raise AmorError(f"{path}: config file not found")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise AmorError(f"{path}: not valid TOML: {exc}") from None


def load_config(path: str | Path, base: TrainConfig | None = None) -> TrainConfig:
    """Read a (partial) TOML config file on top of ``base`` (default: the schema defaults)."""
    return merge(base or TrainConfig(), read_toml(path), str(path))


def preset_path(name: str) -> Path:
    """The TOML file of a built-in preset. Raises AmorError for an unknown name."""
    if name not in PRESETS:
        raise AmorError(f"unknown preset {name!r} (presets: {', '.join(PRESETS)})")
    return Path(str(resources.files("amorctl.presets").joinpath(f"{name}.toml")))


def load_preset(name: str) -> TrainConfig:
    """A built-in preset (``quick`` or ``paper``) as a full config."""
    return load_config(preset_path(name))


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        escaped = value.replace("\\", "\\\\").replace('"', '\\"')
        return f'"{escaped}"'
    if isinstance(value, tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise AssertionError(f"unsupported config value {value!r}")  # pragma: no cover


def to_toml(config: TrainConfig) -> str:
    """The fully resolved config as TOML, one commented line per field; ``merge`` reads it back."""
    lines = ["# amorctl training config, fully resolved", ""]
    for section in SECTIONS:
        obj = getattr(config, section)
        lines.append(f"[{section}]")
        for f in fields(obj):
            lines.append(f"{f.name} = {_toml_value(getattr(obj, f.name))}  # {f.metadata['doc']}")
        lines.append("")
    return "\n".join(lines)


def config_docs() -> dict[str, dict[str, str]]:
    """Every field's one-line doc, by section and key (for help texts and docs)."""
    return {s: {f.name: f.metadata["doc"] for f in fields(cls)} for s, cls in SECTIONS.items()}
