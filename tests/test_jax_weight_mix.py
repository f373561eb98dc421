"""jax-mjx's ``[weights]`` mixture draws what torch-cpu's :class:`WeightSampler` draws (the same
shares of corner, edge, sweep-line and Dirichlet weights; the same Dirichlet concentration)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("jax")

import jax

from amorctl.core.errors import AmorError
from amorctl.core.weight_sampling import WeightSampler
from amorctl.plugins.backends.jax_mjx.core import MjxTracking
from amorctl.plugins.backends.jax_mjx.weight_mix import WeightMix, draw

M, N = 7, 20_000


def kind_masks(w: np.ndarray) -> np.ndarray:
    """[4, N] masks of the corner, edge-midpoint, sweep-line (heavy entry above the rest) and
    other (Dirichlet) rows."""
    top = np.sort(w, axis=1)
    corner = np.isclose(top[:, -1], 1.0)
    edge = np.isclose(top[:, -2:], 0.5).all(1)
    axis = np.isclose(top[:, :-1], top[:, [0]]).all(1) & ~corner & ~edge
    return np.stack([corner, edge, axis, ~(corner | edge | axis)])


def kinds(w: np.ndarray) -> np.ndarray:
    """Shares [4] of the kinds of :func:`kind_masks`."""
    return kind_masks(w).mean(1)


MIXES = [(1.0, 0.1, 0.0, 0.3), (0.5, 0.2, 0.15, 0.25)]


@pytest.mark.parametrize(("alpha", "corner", "edge", "axis"), MIXES)
def test_the_mixture_has_the_numpy_samplers_distribution(
    alpha: float, corner: float, edge: float, axis: float
) -> None:
    ours = np.asarray(draw(jax.random.PRNGKey(0), N, M, WeightMix(alpha, corner, edge, axis)))
    theirs = WeightSampler(M, alpha, corner, edge, axis).sample(np.random.default_rng(0), N)
    assert ours.shape == (N, M) and ours.dtype == np.float32
    np.testing.assert_allclose(ours.sum(1), 1.0, atol=1e-5)
    assert ours.min() >= 0
    # 4 sigma of a binomial share at N = 20,000 is below 0.013
    np.testing.assert_allclose(kinds(ours), kinds(theirs), atol=0.015)
    assert kinds(ours)[0] == pytest.approx(corner, abs=0.015)
    # Dirichlet draws alone (a tiny sweep-line share keeps the mix on): their spread follows
    # alpha, Var w_k = (M - 1) / (M^2 (M alpha + 1))
    dirichlet = np.asarray(draw(jax.random.PRNGKey(1), N, M, WeightMix(alpha, axis=1e-9)))
    assert dirichlet[:, 0].var() == pytest.approx((M - 1) / (M**2 * (M * alpha + 1)), rel=0.06)


def test_per_env_keys_draw_each_envs_own_weights() -> None:
    mix = WeightMix(1.0, 0.3, 0.2, 0.3)
    keys = jax.random.split(jax.random.PRNGKey(3), 6)
    all_six = np.asarray(draw(keys, 6, M, mix))
    np.testing.assert_array_equal(np.asarray(draw(keys[2:4], 2, M, mix)), all_six[2:4])


def test_the_env_core_draws_the_mixture_and_keeps_the_papers_draw_without_it() -> None:
    key = jax.random.PRNGKey(1)
    corners = SimpleNamespace(fixed_weights=None, weight_mix=WeightMix(corner=1.0), m=M)
    w = np.asarray(MjxTracking._sample_weights(corners, key, 64))
    assert (np.sort(w, axis=1)[:, -1] == 1.0).all()
    plain = SimpleNamespace(fixed_weights=None, weight_mix=WeightMix(), m=M)
    paper = np.asarray(MjxTracking._sample_weights(plain, key, 64))
    assert kinds(paper)[3] == 1.0  # Dirichlet(1) only


def test_adaptive_draws_are_refused_with_the_setting_named() -> None:
    with pytest.raises(AmorError, match=r"adaptive_fraction > 0 is torch-cpu only"):
        WeightMix.of_sampler(WeightSampler(M, adaptive_fraction=0.2))
    assert WeightMix.of_sampler(WeightSampler(M, 0.5, 0.1, 0.0, 0.3)) == WeightMix(0.5, 0.1, 0.0, 0.3)
