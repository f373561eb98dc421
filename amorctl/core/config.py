"""Training configuration: frozen dataclasses are the schema, TOML is the file format.

A config is built in layers, each overriding the one before: the dataclass defaults (which equal
the ``quick`` preset), a preset file (``amorctl/presets/<name>.toml``), the user's ``--config``
file, then command-line options. Every layer is partial TOML with the sections ``[run]``,
``[env]``, ``[network]``, ``[ppo]``, ``[weights]`` and ``[distill]``; a key that is not in the
schema is rejected by name.
Every number has bounds in its field's metadata (``min``/``max``, ``gt`` for an exclusive lower
bound); a value outside them is refused naming the file (or command-line flag) and the key:
``runs/x/config.toml: [ppo] num_steps = 100000000 is out of range (1..100000)``.
:func:`to_toml` writes the fully resolved config with ``tomlkit`` (every field's doc as a
comment), which :func:`load_config` reads back to the same object.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any, get_type_hints

import tomlkit

from amorctl.core.config_values import coerce_value
from amorctl.core.errors import AmorError
from amorctl.core.levers import lever_checks
from amorctl.core.weights import parse_weight_pairs

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def _doc(
    default: Any,
    text: str,
    *,
    min: float | None = None,
    max: float | None = None,
    gt: float | None = None,
    choices: tuple[str, ...] | None = None,
    max_len: int | None = None,
    min_len: int | None = None,
) -> Any:
    """A dataclass field with a one-line doc and its bounds, kept in the field's metadata.

    ``min``/``max``: inclusive bounds of a number (of each entry of a tuple); ``gt``: exclusive
    lower bound; ``choices``: the allowed strings; ``max_len`` / ``min_len``: the most / fewest
    entries of a tuple (fewest: 1 unless told).
    """
    meta = {
        "doc": text,
        "min": min,
        "max": max,
        "gt": gt,
        "choices": choices,
        "max_len": max_len,
        "min_len": min_len,
    }
    return field(default=default, metadata={k: v for k, v in meta.items() if v is not None})


PRESETS: tuple[str, ...] = ("quick", "paper", "science", "science_sc")
ENV_KINDS: tuple[str, ...] = ("tracking", "toy", "toy-smooth", "gym")
LR_SCHEDULES: tuple[str, ...] = ("fixed", "adaptive")
ACTION_MODES: tuple[str, ...] = ("residual", "absolute")
CLIP_CONTINUATIONS: tuple[str, ...] = ("random", "same")
PRECISIONS: tuple[str, ...] = ("auto", "fp32", "bf16")
RETURN_NORMS: tuple[str, ...] = ("off", "value", "value+advantage")
#: The largest rollout batch (num_envs * num_steps) a config may ask for: 32x the paper's.
MAX_BATCH = 1 << 22


@dataclass(frozen=True)
class RunConfig:
    """How long to train, with what, and how the run is recorded."""

    iterations: int = _doc(
        1000, "training iterations (one rollout and one update each)", min=0, max=100_000_000
    )
    seed: int = _doc(
        0, "seed of the env, the network initialisation and the action noise", min=0, max=2**32 - 1
    )
    backend: str = _doc("torch-cpu", "training backend plugin (see `amorctl plugins`)")
    checkpoint_every: int = _doc(
        50, "save a checkpoint every this many iterations (and on exit)", min=1, max=100_000_000
    )
    keep_checkpoints: int = _doc(
        3, "how many recent checkpoints to keep (0 = keep all)", min=0, max=1_000_000
    )
    threads: int = _doc(0, "CPU threads for the network (0 = the backend's default)", min=0, max=4096)
    tensorboard: bool = _doc(True, "also write metrics as TensorBoard scalars under tb/")
    init_from: str = _doc(
        "",
        "a run (directory or pretrained:NAME, optionally @ITERATION) whose networks and observation "
        "normalizer a new run starts from; empty = random initialization (stored absolute, with "
        "the iteration)",
    )
    init_from_std: float = _doc(
        0.0,
        "with init_from: the Gaussian actions' standard deviation the new run starts at (0 = the "
        "source's own); a smaller one keeps fine-tuning rollouts near the policy's mean",
        min=0,
        max=100,
    )


@dataclass(frozen=True)
class EnvConfig:
    """Which environment is trained, and how many copies run in parallel."""

    kind: str = _doc(
        "tracking",
        "environment: tracking (motion tracking), toy, toy-smooth (two-objective toys), gym",
        choices=ENV_KINDS,
    )
    character: str = _doc("biped20", "character plugin (kind=tracking)")
    dataset: str = _doc(
        "", "motion dataset file (stored absolute by train); empty = the character's built-in clips"
    )
    dataset_sha256: str = _doc(
        "", "SHA-256 of the dataset file, recorded by train: --data finds the dataset if it moved"
    )
    objective_set: str = _doc("tracking7", "objective-set plugin (kind=tracking)")
    num_envs: int = _doc(256, "environments stepped in parallel (N)", min=1, max=65536)
    episode_seconds: float = _doc(
        10.0, "time limit of an episode in seconds (truncation, bootstrapped)", gt=0, max=3600
    )
    action_mode: str = _doc(
        "residual",
        "tracking action: residual (PD target = reference + a) or absolute",
        choices=ACTION_MODES,
    )
    gym_id: str = _doc("", "Gymnasium / MO-Gymnasium id with a vector reward (kind=gym)")
    fixed_weights: str = _doc("", "empty: w ~ Dirichlet(1) per episode (MOPPO); else one fixed w (PPO)")
    adaptive_starts: float = _doc(
        0.0,
        "share of random episode starts drawn where the policy falls, per clip and phase bin "
        "(kind=tracking; 0 = uniform RSI, the paper)",
        min=0,
        max=1,
    )
    start_bin_seconds: float = _doc(
        1.0, "length of the phase bins adaptive_starts counts falls in", gt=0, max=60
    )
    termination_distance: float = _doc(
        0.0,
        "also end a training episode when an end effector (root-relative) or the root height is "
        "farther than this from the reference, m (kind=tracking; 0 = falls only, the paper)",
        min=0,
        max=100,
    )
    clip_continuation: str = _doc(
        "random",
        "what a training episode tracks when its clip ends: random (a random clip from its first "
        "frame, the default) or same (its own clip again, as evaluation loops one) (kind=tracking)",
        choices=CLIP_CONTINUATIONS,
    )
    survival_bonus_scale: float = _doc(
        1.0,
        "multiplies the objective set's survival bonus, added to every objective on each step "
        "that does not end a training episode (kind=tracking; 1 = the paper's c_alive, 0 = none)",
        min=0,
        max=100,
    )


@dataclass(frozen=True)
class NetworkConfig:
    """Actor pi(a | s, c, w) and critic V(s, c, w) in R^m: ELU MLPs."""

    actor_hidden: tuple[int, ...] = _doc(
        (256, 256, 256), "hidden layer widths of the actor", min=1, max=8192, max_len=16
    )
    critic_hidden: tuple[int, ...] = _doc(
        (256, 256, 256), "hidden layer widths of the critic", min=1, max=8192, max_len=16
    )
    init_std: float = _doc(
        0.1, "initial standard deviation of the Gaussian actions (state-independent)", gt=0, max=100
    )
    obs_clip: float = _doc(
        10.0, "normalized observations are clipped to [-obs_clip, obs_clip]", gt=0, max=1e6
    )


@dataclass(frozen=True)
class PPOConfig:
    """MOPPO: PPO with a vector critic and advantages scalarized by each episode's weights."""

    num_steps: int = _doc(24, "rollout horizon T: control steps per env per iteration", min=1, max=100_000)
    num_epochs: int = _doc(5, "passes over the rollout batch per iteration", min=1, max=1000)
    num_minibatches: int = _doc(
        4, "minibatches per epoch (batch = num_envs * num_steps)", min=1, max=MAX_BATCH
    )
    gamma: float = _doc(0.99, "discount factor", min=0, max=1)
    gae_lambda: float = _doc(0.95, "GAE lambda, applied per objective", min=0, max=1)
    clip_coef: float = _doc(0.2, "PPO ratio clipping epsilon", gt=0, max=10)
    clip_value_loss: bool = _doc(True, "clip the value update around the rollout's values as PPO does")
    value_coef: float = _doc(
        1.0, "weight of the value loss (mean over the batch and the m outputs)", min=0, max=1e6
    )
    entropy_coef: float = _doc(0.0, "weight of the entropy bonus", min=0, max=1e6)
    learning_rate: float = _doc(
        5e-5, "Adam learning rate (the start value when lr_schedule=adaptive)", gt=0, max=10
    )
    lr_schedule: str = _doc(
        "adaptive",
        "fixed, or adaptive: scale the rate by 1.5 to keep KL near desired_kl",
        choices=LR_SCHEDULES,
    )
    desired_kl: float = _doc(0.02, "target KL per minibatch for the adaptive learning rate", gt=0, max=100)
    min_learning_rate: float = _doc(
        1e-6, "the adaptive learning rate's floor (docs/moppo.md)", gt=0, max=1e-2
    )
    max_grad_norm: float = _doc(1.0, "clip the global gradient norm to this", gt=0, max=1e6)
    normalize_obs: bool = _doc(True, "running mean/std observation normalization (saved with the policy)")
    precision: str = _doc(
        "auto",
        "fp32, bf16 (autocast; fp32 weights and losses), or auto: bf16 if the CPU has it",
        choices=PRECISIONS,
    )
    return_norm: str = _doc(
        "off",
        "off (the paper); value: per-objective value errors over running return stds; "
        "value+advantage: also A_k over running advantage stds before A·w",
        choices=RETURN_NORMS,
    )
    survival_channel: bool = _doc(
        False,
        "false (the paper); true: the survival bonus shared by all objectives gets its own critic "
        "and advantage channel (weight survival_weight) instead of sitting inside every objective's",
    )
    survival_weight: float = _doc(
        1.0,
        "survival_channel: the bonus channel's weight in the scalarized advantage (1 = sum of w, "
        "the same policy gradient as without the channel unless advantages are scaled)",
        gt=0,
        max=1000,
    )


@dataclass(frozen=True)
class WeightsConfig:
    """Where on the simplex training episodes draw w (docs/moppo.md, Levers)."""

    alpha: float = _doc(
        1.0, "Dirichlet concentration of w (1 = uniform on the simplex, the paper)", gt=0, max=1000
    )
    corner_fraction: float = _doc(
        0.0, "share of episodes whose w is a simplex corner (one objective)", min=0, max=1
    )
    edge_fraction: float = _doc(
        0.0, "share of episodes whose w is an edge midpoint (two objectives, 1/2 each)", min=0, max=1
    )
    axis_fraction: float = _doc(
        0.0, "share of episodes on a sweep line: w_k ~ U(0, 1), the other objectives equal", min=0, max=1
    )
    adaptive_fraction: float = _doc(
        0.0, "share of episodes near anchors whose achieved return lags the critic's prediction", min=0, max=1
    )

    @property
    def plain(self) -> bool:
        """True for the paper's Dirichlet(1) and no mixing."""
        return self == WeightsConfig()


@dataclass(frozen=True)
class DistillConfig:
    """Teacher-student training (docs/distill.md): the student imitates per-clip teacher policies
    on the states it visits itself, instead of learning from rewards (or, with ``rewards``, beside
    them: kickstarting)."""

    teachers: tuple[str, ...] = _doc(
        (),
        "runs (directories or pretrained:NAME) whose policies teach the clips of their datasets; "
        "a clip is taught by the first teacher that holds it (empty = MOPPO from rewards)",
        max_len=64,
        min_len=0,
    )
    learning_rate: float = _doc(
        5e-4,
        "the Adam learning rate of a student (and of a kickstarted run), fixed (MOPPO's [ppo] "
        "learning_rate and lr_schedule do not apply: its KL rule would stop a student that follows "
        "its teachers quickly)",
        gt=0,
        max=1,
    )
    rewards: bool = _doc(
        False,
        "kickstarting: learn from the rewards as MOPPO does and keep kl_coef x KL(teacher || student) "
        "beside its loss (false = imitate the teachers alone)",
    )
    kl_coef: float = _doc(
        1.0, "with rewards = true: the weight of the teachers' KL term at iteration 0", min=0, max=1e3
    )
    kl_fade_iterations: int = _doc(
        0,
        "with rewards = true: iterations over which kl_coef falls linearly to 0 (0 = it stays)",
        min=0,
        max=10**9,
    )


@dataclass(frozen=True)
class TrainConfig:
    """The whole training configuration; sections map to TOML tables."""

    run: RunConfig = field(default_factory=RunConfig)
    env: EnvConfig = field(default_factory=EnvConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    weights: WeightsConfig = field(default_factory=WeightsConfig)
    distill: DistillConfig = field(default_factory=DistillConfig)


SECTIONS: dict[str, type] = {
    "run": RunConfig,
    "env": EnvConfig,
    "network": NetworkConfig,
    "ppo": PPOConfig,
    "weights": WeightsConfig,
    "distill": DistillConfig,
}


def merge(base: TrainConfig, data: Mapping[str, Any], source: str = "config") -> TrainConfig:
    """Override ``base`` with a partial config given as nested TOML data.

    ``source`` names where ``data`` came from (a file, or a command-line flag such as
    ``--num-envs``); every message starts with it.

    Raises:
        AmorError: an unknown section or key (named, with the source), a value of the wrong type
            or out of its bounds.
    """
    if not isinstance(data, Mapping):
        raise AmorError(f"{source}: expected tables {', '.join(f'[{s}]' for s in SECTIONS)}")
    sections: dict[str, Any] = {}
    for section, values in data.items():
        if section not in SECTIONS:
            raise AmorError(f"{source}: unknown section [{section}] (known: {', '.join(SECTIONS)})")
        if not isinstance(values, Mapping):
            raise AmorError(f"{source}: [{section}] must be a table")
        cls = SECTIONS[section]
        hints = get_type_hints(cls)
        schema = {f.name: f for f in fields(cls)}
        changes = {}
        for key, value in values.items():
            if key not in schema:
                raise AmorError(f"{source}: unknown key {key!r} in [{section}] (known: {', '.join(schema)})")
            changes[key] = coerce_value(
                value, hints[key], f"{source}: [{section}] {key}", schema[key].metadata
            )
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
    """Check every field's bounds and the rules between fields; returns ``config`` unchanged.

    Raises:
        AmorError: naming ``source`` and the first bad field.
    """
    for section, cls in SECTIONS.items():
        obj = getattr(config, section)
        hints = get_type_hints(cls)
        for f in fields(obj):
            coerce_value(getattr(obj, f.name), hints[f.name], f"{source}: [{section}] {f.name}", f.metadata)
    e, p = config.env, config.ppo
    batch = e.num_envs * p.num_steps
    checks = [
        (e.kind != "gym" or bool(e.gym_id), "[env] gym_id is required when kind = 'gym'"),
        (
            batch <= MAX_BATCH,
            f"[env] num_envs x [ppo] num_steps = {batch} exceeds the largest rollout batch ({MAX_BATCH})",
        ),
        (
            p.num_minibatches <= batch,
            f"[ppo] num_minibatches = {p.num_minibatches} exceeds the batch size ({batch})",
        ),
    ]
    checks += lever_checks(config)
    for ok, message in checks:
        if not ok:
            raise AmorError(f"{source}: {message}")
    if e.fixed_weights and e.fixed_weights.strip().lower() != "uniform":
        parse_weight_pairs(e.fixed_weights, source=f"{source}: [env] fixed_weights")
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
    except RecursionError:
        raise AmorError(f"{path}: not valid TOML: nested too deeply") from None
    except OSError as exc:
        raise AmorError(f"{path}: cannot read the config file: {exc.strerror}") from None


def load_config(path: str | Path, base: TrainConfig | None = None) -> TrainConfig:
    """Read a (partial) TOML config file on top of ``base`` (default: the schema defaults)."""
    return merge(base or TrainConfig(), read_toml(path), str(path))


def preset_path(name: str) -> Path:
    """The TOML file of a built-in preset. Raises AmorError for an unknown name."""
    if name not in PRESETS:
        raise AmorError(f"unknown preset {name!r} (presets: {', '.join(PRESETS)})")
    return Path(str(resources.files("amorctl.presets").joinpath(f"{name}.toml")))


def load_preset(name: str) -> TrainConfig:
    """A built-in preset (``quick``, ``paper`` or ``science``) as a full config."""
    return load_config(preset_path(name))


def to_toml(config: TrainConfig) -> str:
    """The fully resolved config as TOML (written by tomlkit), each field with its doc as a
    comment; :func:`load_config` reads it back to an equal config."""
    return sections_to_toml(config, SECTIONS, "amorctl training config, fully resolved")


def sections_to_toml(config: Any, sections: Sequence[str], title: str) -> str:
    """A config dataclass made of section dataclasses as TOML (tomlkit): one table per section,
    each field commented with its ``doc`` metadata. Shared by the training and HLP configs."""
    doc = tomlkit.document()
    doc.add(tomlkit.comment(title))
    for section in sections:
        obj = getattr(config, section)
        table = tomlkit.table()
        for f in fields(obj):
            value = getattr(obj, f.name)
            item = tomlkit.item(list(value) if isinstance(value, tuple) else value)
            item.comment(f.metadata["doc"])
            table.add(f.name, item)
        doc.add(section, table)
    return tomlkit.dumps(doc)


def config_docs() -> dict[str, dict[str, str]]:
    """Every field's one-line doc, by section and key (for help texts and docs)."""
    return {s: {f.name: f.metadata["doc"] for f in fields(cls)} for s, cls in SECTIONS.items()}
