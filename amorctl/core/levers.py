"""The training levers (docs/moppo.md, "Levers"): which a config turns on, which env kinds each
needs, and the check that the configured backend implements them (it declares its own in
``BackendSpec.levers``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from amorctl.core.errors import AmorError

if TYPE_CHECKING:
    from amorctl.core.config import TrainConfig

#: Training levers (docs/moppo.md, "Levers") a backend may implement; it declares which in
#: ``BackendSpec.levers``. The paper's MOPPO needs none of them.
LEVERS: tuple[str, ...] = (
    "return_norm",
    "survival_channel",
    "weight_sampling",
    "adaptive_weights",
    "adaptive_starts",
    "termination_distance",
    "clip_continuation",
    "survival_bonus_scale",
    "distill",
    "init_from",
)
#: ``[env]`` fields that shape training episodes only. Evaluation, sweeps and tuning set them to 0,
#: so every run is judged by the same episodes (falls end them; nothing else does).
TRAINING_ONLY_ENV: dict[str, float | str] = {
    "adaptive_starts": 0.0,
    "termination_distance": 0.0,
    "clip_continuation": "random",
    "survival_bonus_scale": 1.0,
}
#: Env kinds whose objectives share a survival bonus the trainer can split off.
SURVIVAL_BONUS_KINDS: tuple[str, ...] = ("tracking", "gym")
#: Env kinds whose state (and so an adaptive weight sampler's) is checkpointed.
SNAPSHOT_KINDS: tuple[str, ...] = ("tracking", "toy", "toy-smooth")


def lever_checks(config: TrainConfig) -> list[tuple[bool, str]]:
    """The training levers' rules that do not depend on the backend: the weight-sampling shares
    fit in one, and each lever's env kinds (:func:`check_backend_levers` asks the backend)."""
    w, p, kind = config.weights, config.ppo, config.env.kind
    shares = w.corner_fraction + w.edge_fraction + w.axis_fraction + w.adaptive_fraction
    return [
        (shares <= 1 + 1e-9, f"[weights] corner + edge + axis + adaptive fractions = {shares:g} exceed 1"),
        (
            w.adaptive_fraction == 0 or kind in SNAPSHOT_KINDS,
            f"[weights] adaptive_fraction needs an env whose state is checkpointed (env.kind in "
            f"{', '.join(map(repr, SNAPSHOT_KINDS))}; got {kind!r})",
        ),
        (
            config.env.adaptive_starts == 0 or kind == "tracking",
            f"[env] adaptive_starts needs the tracking env (env.kind = 'tracking'; got {kind!r})",
        ),
        (
            config.env.termination_distance == 0 or kind == "tracking",
            f"[env] termination_distance needs the tracking env (env.kind = 'tracking'; got {kind!r})",
        ),
        (
            config.env.clip_continuation == "random" or kind == "tracking",
            f"[env] clip_continuation needs the tracking env (env.kind = 'tracking'; got {kind!r})",
        ),
        (
            not config.distill.teachers or kind == "tracking",
            f"[distill] teachers need the tracking env (env.kind = 'tracking'; got {kind!r})",
        ),
        (
            config.distill.teachers or not _kickstart_settings(config),
            f"[distill] {_needs(_kickstart_settings(config))} [distill] teachers",
        ),
        (
            config.distill.rewards or not _kickstart_settings(config, with_rewards=False),
            f"[distill] {_needs(_kickstart_settings(config, with_rewards=False))} [distill] rewards = "
            "true (an imitating student's loss is the KL alone)",
        ),
        (
            config.run.init_from_std == 0 or bool(config.run.init_from),
            f"[run] init_from_std = {config.run.init_from_std:g} needs [run] init_from",
        ),
        (
            config.env.survival_bonus_scale == 1.0 or kind == "tracking",
            f"[env] survival_bonus_scale needs the tracking env (env.kind = 'tracking'; got {kind!r})",
        ),
        (
            not p.survival_channel or config.env.survival_bonus_scale > 0,
            "[ppo] survival_channel = true needs a survival bonus ([env] survival_bonus_scale = 0 "
            "removes it)",
        ),
        (
            p.survival_weight == 1.0 or p.survival_channel,
            f"[ppo] survival_weight = {p.survival_weight:g} needs survival_channel = true",
        ),
        (
            not p.survival_channel or kind in SURVIVAL_BONUS_KINDS,
            f"[ppo] survival_channel = true needs objectives that share a survival bonus (env.kind in "
            f"{', '.join(map(repr, SURVIVAL_BONUS_KINDS))}; got {kind!r})",
        ),
    ]


def _kickstart_settings(config: TrainConfig, with_rewards: bool = True) -> list[str]:
    """The kickstarting settings of ``[distill]`` that differ from their defaults."""
    d = config.distill
    settings = ["rewards = true"] if with_rewards and d.rewards else []
    if d.kl_coef != 1.0:
        settings.append(f"kl_coef = {d.kl_coef:g}")
    if d.kl_fade_iterations != 0:
        settings.append(f"kl_fade_iterations = {d.kl_fade_iterations}")
    return settings


def _needs(settings: list[str]) -> str:
    """``"a = 1 needs"`` / ``"a = 1, b = 2 need"``."""
    return f"{', '.join(settings)} {'needs' if len(settings) == 1 else 'need'}"


def levers_in_use(config: TrainConfig) -> dict[str, str]:
    """The levers ``config`` turns on that its backend must implement: {lever: the setting asking
    for it}. ``[weights]`` draws need the backend only for the tracking env (the backend makes it);
    the toy and gym envs draw them themselves, and adaptive draws need the trainer's feedback."""
    w, p = config.weights, config.ppo
    used: dict[str, str] = {}
    if p.return_norm != "off":
        used["return_norm"] = f"[ppo] return_norm = {p.return_norm!r}"
    if p.survival_channel:
        used["survival_channel"] = "[ppo] survival_channel = true"
    if not w.plain and config.env.kind == "tracking":
        used["weight_sampling"] = "[weights] options other than the defaults"
    if w.adaptive_fraction > 0:
        used["adaptive_weights"] = f"[weights] adaptive_fraction = {w.adaptive_fraction:g}"
    if config.env.adaptive_starts > 0:
        used["adaptive_starts"] = f"[env] adaptive_starts = {config.env.adaptive_starts:g}"
    if config.env.termination_distance > 0:
        used["termination_distance"] = f"[env] termination_distance = {config.env.termination_distance:g}"
    if config.env.clip_continuation != "random":
        used["clip_continuation"] = f"[env] clip_continuation = {config.env.clip_continuation!r}"
    if config.env.survival_bonus_scale != 1.0:
        used["survival_bonus_scale"] = f"[env] survival_bonus_scale = {config.env.survival_bonus_scale:g}"
    if config.distill.teachers:
        used["distill"] = f"[distill] teachers = {list(config.distill.teachers)!r}"
    if config.run.init_from:
        used["init_from"] = f"[run] init_from = {config.run.init_from!r}"
        if config.run.init_from_std:
            used["init_from"] += f", init_from_std = {config.run.init_from_std:g}"
    return used


def check_backend_levers(config: TrainConfig, levers: frozenset[str], source: str = "config") -> None:
    """Refuse a config whose levers its backend (``run.backend``, declaring ``levers``) lacks.

    Raises:
        AmorError: naming ``source``, the setting and the backend.
    """
    for lever, setting in levers_in_use(config).items():
        if lever not in levers:
            raise AmorError(
                f"{source}: {setting} needs a backend that implements it; run.backend = "
                f"{config.run.backend!r} does not (`amorctl plugins` lists each backend's levers)"
            )
