"""The ``[weights]`` mixture of episode weights in JAX (torch-cpu's :class:`WeightSampler` draws).

Per env, one of four kinds of draw, chosen with the configured shares (docs/moppo.md, "Levers"):
a simplex corner ``e_k``; an edge midpoint ``(e_j + e_k) / 2``; a point of objective k's sweep
line (``w_k = u ~ U(0, 1)``, the rest ``(1 - u) / (m - 1)``); the rest ``Dirichlet(alpha)``. The
distribution is the numpy sampler's (tests/test_jax_mjx_env.py compares them); the random streams
are JAX's, so the draws themselves differ. The adaptive share stays torch-cpu's (its lags live on
the host).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from amorctl.core.errors import AmorError


@dataclass(frozen=True)
class WeightMix:
    """Shares of the corner, edge and axis draws and the Dirichlet concentration (hashable)."""

    alpha: float = 1.0
    corner: float = 0.0
    edge: float = 0.0
    axis: float = 0.0

    @classmethod
    def of_sampler(cls, sampler: object) -> WeightMix:
        """The mix of a :class:`~amorctl.core.weight_sampling.WeightSampler` (no adaptive share)."""
        corner, edge, axis, adaptive = (float(x) for x in sampler.fractions)  # type: ignore[attr-defined]
        if adaptive > 0:
            raise AmorError(
                "[weights] adaptive_fraction > 0 is torch-cpu only (its anchors' lags are host state); "
                "jax-mjx implements corner_fraction, edge_fraction, axis_fraction and alpha"
            )
        return cls(float(sampler.alpha), corner, edge, axis)  # type: ignore[attr-defined]

    @property
    def plain(self) -> bool:
        """True for the paper's draw, Dirichlet(1)."""
        return self.alpha == 1.0 and self.corner == self.edge == self.axis == 0.0


def draw_one(key: jax.Array, m: int, mix: WeightMix) -> jax.Array:
    """One weight vector [m] float32 on the simplex from ``key`` [2]."""
    k_kind, k_pick, k_other, k_level, k_dir = jax.random.split(key, 5)
    u = jax.random.uniform(k_kind)
    pick = jax.random.randint(k_pick, (), 0, m)
    other = (pick + 1 + jax.random.randint(k_other, (), 0, max(m - 1, 1))) % m
    level = jax.random.uniform(k_level)
    e_pick, e_other = jax.nn.one_hot(pick, m), jax.nn.one_hot(other, m)
    rest = (1.0 - level) / max(m - 1, 1)
    axis = jnp.where(e_pick > 0, level, rest)
    dirichlet = jax.random.dirichlet(k_dir, jnp.full(m, mix.alpha))
    kinds = jnp.stack([e_pick, 0.5 * (e_pick + e_other), axis, dirichlet])  # [4, m]
    bounds = jnp.cumsum(jnp.asarray([mix.corner, mix.edge, mix.axis]))
    kind = jnp.searchsorted(bounds, u, side="right")  # 0 corner, 1 edge, 2 axis, 3 Dirichlet
    w = kinds[kind]
    return (w / jnp.sum(w)).astype(jnp.float32)


def draw(key: jax.Array, n: int, m: int, mix: WeightMix) -> jax.Array:
    """Weights [N, m]: N draws from the batch's key [2], or one per env from per-env keys [N, 2]."""
    keys = jax.random.split(key, n) if key.ndim == 1 else key
    return jax.vmap(lambda k: draw_one(k, m, mix))(keys)
