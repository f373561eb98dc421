"""The env factory: the configured environment of a run (tracking env from its backend, toy, gym)."""

from __future__ import annotations

from typing import Any

from amorctl.core.config import TrainConfig
from amorctl.core.vecenv import VectorEnv
from amorctl.core.weight_sampling import WeightSampler
from amorctl.core.weights import parse_weights
from amorctl.registry import get_registry

TOY_CONTROL_HZ = 50  # the toy env's nominal control rate (episode_seconds -> steps)


def make_env(config: TrainConfig, backend: Any | None = None) -> VectorEnv:
    """Build the configured env, seeded with ``run.seed``, wrapped for fixed weights if asked.

    ``kind="tracking"`` asks the backend (its ``make_env``) for the motion-tracking env;
    ``toy``, ``toy-smooth`` and ``gym`` are backend-independent numpy envs.
    """
    e, seed = config.env, config.run.seed
    env: Any
    steps = max(1, round(e.episode_seconds * TOY_CONTROL_HZ))
    if e.kind == "toy":
        from amorctl.envs.toy import ToyTradeoffEnv

        env = ToyTradeoffEnv(e.num_envs, max_steps=steps, seed=seed, weight_sampler=weight_sampler(config, 2))
    elif e.kind == "toy-smooth":
        from amorctl.envs.toy import ToySmoothEnv

        env = ToySmoothEnv(e.num_envs, max_steps=steps, seed=seed, weight_sampler=weight_sampler(config, 2))
    elif e.kind == "gym":
        from amorctl.envs.mo_gym import make_gym_env

        env = make_gym_env(e.gym_id, e.num_envs, seed=seed)
        if not config.weights.plain or config.weights.alpha != 1.0:  # m is known once the env is made
            env.weight_sampler = weight_sampler(config, env.num_objectives)
    else:
        if backend is None:
            backend = get_registry().backend(config.run.backend).make()
        options: dict[str, Any] = {}
        if not config.weights.plain:  # the [weights] levers (a backend that declares them; config checks it)
            m = len(get_registry().objective_set(e.objective_set).objectives)
            options["weight_sampler"] = weight_sampler(config, m)
        if e.adaptive_starts > 0:  # a lever too: only a backend that declares it gets here
            options.update(adaptive_starts=e.adaptive_starts, start_bin_seconds=e.start_bin_seconds)
        if e.termination_distance > 0:  # a lever as well
            options["termination_distance"] = e.termination_distance
        if e.clip_continuation != "random":  # and another
            options["clip_continuation"] = e.clip_continuation
        if e.survival_bonus_scale != 1.0:  # and another
            options["survival_bonus_scale"] = e.survival_bonus_scale
        env = backend.make_env(
            character=e.character,
            dataset=e.dataset or None,
            objective_set=e.objective_set,
            num_envs=e.num_envs,
            episode_seconds=e.episode_seconds,
            seed=seed,
            action_mode=e.action_mode,
            **options,
        )
    if e.fixed_weights:
        from amorctl.envs.wrappers import FixedWeights

        w = parse_weights(e.fixed_weights, env.reward_space.names, source="[env] fixed_weights")
        env = FixedWeights(env, w)
    return env


def weight_sampler(config: TrainConfig, m: int) -> WeightSampler:
    """The per-episode weight sampler of ``config``'s ``[weights]`` section for m objectives."""
    w = config.weights
    return WeightSampler(m, w.alpha, w.corner_fraction, w.edge_fraction, w.axis_fraction, w.adaptive_fraction)
