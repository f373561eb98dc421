"""Weight strings, normalization onto the simplex, Dirichlet samples."""

from __future__ import annotations

import numpy as np
import pytest

from amorctl.core.errors import AmorError
from amorctl.core.weights import format_weights, parse_weights, sample_dirichlet

NAMES = ("up", "lo", "feet", "rbs", "root", "vel", "smooth")


def test_parse_weights_orders_and_normalizes() -> None:
    w = parse_weights("smooth=1, up=3", NAMES)
    assert w.tolist() == [0.75, 0, 0, 0, 0, 0, 0.25]
    assert parse_weights("uniform", NAMES) == pytest.approx(np.full(7, 1 / 7))
    assert parse_weights(format_weights(w, NAMES), NAMES) == pytest.approx(w)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("speed=1", "unknown objective 'speed'"),
        ("up=-1,lo=2", "negative"),
        ("up=nan", "not finite"),
        ("up=inf", "not finite"),
        ("up=0,lo=0", "all zero"),
        ("up", "not name=value"),
        ("up=x", "not a number"),
        ("up=1,up=2", "given twice"),
        ("", "empty"),
    ],
)
def test_parse_weights_rejects_bad_input(text: str, message: str) -> None:
    with pytest.raises(AmorError, match=message):
        parse_weights(text, NAMES)


def test_dirichlet_samples_lie_on_the_simplex_with_mean_one_over_m() -> None:
    w = sample_dirichlet(np.random.default_rng(0), 20000, 7)
    assert w.dtype == np.float32 and w.shape == (20000, 7)
    assert np.all(w >= 0)
    assert np.allclose(w.sum(1), 1, atol=1e-5)
    assert np.allclose(w.mean(0), 1 / 7, atol=0.005)


def test_normalization_cannot_overflow_and_errors_name_the_source() -> None:
    w = parse_weights("up=1e308,lo=1e308", NAMES, source="--weights")
    assert w.tolist() == [0.5, 0.5, 0, 0, 0, 0, 0]
    assert parse_weights("up=1e-320,lo=3e-320", NAMES) == pytest.approx([0.25, 0.75, 0, 0, 0, 0, 0])
    for text, message in [
        ("up=1,,lo=1", "--weights: empty item"),
        ("up=1,", "--weights: empty item"),
        ("", "--weights: empty weights"),
        ("=1", "--weights: '=1' has no objective name"),
        ("up=1e309", "--weights: up=1e309 is not finite"),
    ]:
        with pytest.raises(AmorError, match=message):
            parse_weights(text, NAMES, source="--weights")


def test_normalize_weights_rows_of_huge_values() -> None:
    from amorctl.core.weights import normalize_weights

    rows = normalize_weights(np.array([[1e308, 1e308, 1e308], [0.0, 2.0, 0.0]]))
    np.testing.assert_allclose(rows, [[1 / 3] * 3, [0, 1, 0]])
    with pytest.raises(AmorError, match="all zero"):
        normalize_weights(np.zeros((2, 3)))


# --- the per-episode weight sampler (amorctl.core.weight_sampling, docs/moppo.md Levers) ---------
def test_plain_sampler_is_the_papers_dirichlet_draw() -> None:
    from amorctl.core.env_random import BatchRandom
    from amorctl.core.weight_sampling import WeightSampler

    sampler = WeightSampler(7)
    a = sampler.draw(BatchRandom(np.random.default_rng(5)), np.arange(9))
    b = sample_dirichlet(np.random.default_rng(5), 9, 7)
    np.testing.assert_array_equal(a, b)  # same generator calls: runs without levers are unchanged


def test_sampler_mixes_corners_edges_and_sweep_lines_in_their_shares() -> None:
    from amorctl.core.weight_sampling import WeightSampler

    sampler = WeightSampler(7, corner_fraction=0.2, edge_fraction=0.1, axis_fraction=0.3)
    w = sampler.sample(np.random.default_rng(0), 20_000).astype(np.float64)
    assert np.allclose(w.sum(1), 1, atol=1e-6) and (w >= 0).all()
    corner = np.isclose(w.max(1), 1.0)
    edge = (np.isclose(w, 0.5).sum(1) == 2) & np.isclose(w.max(1), 0.5)
    top = w.max(1, keepdims=True)
    rest = np.where(np.isclose(w, top), np.nan, w)
    axis = ~corner & ~edge & (np.nanmax(rest, 1) - np.nanmin(rest, 1) < 1e-6)  # 6 equal entries
    assert corner.mean() == pytest.approx(0.2, abs=0.01)
    assert edge.mean() == pytest.approx(0.1, abs=0.01)
    assert axis.mean() == pytest.approx(0.3, abs=0.015)
    # P(w_k > 0.5) for some k: about 1.6% per k under Dirichlet(1); the sweep lines add 0.3 * 0.5
    assert (w.max(1) > 0.5).mean() > 0.2 + 0.15 - 0.02


def test_sampler_alpha_below_one_favours_the_corners() -> None:
    from amorctl.core.weight_sampling import WeightSampler

    rng = np.random.default_rng(1)
    peaks = {a: WeightSampler(7, alpha=a).sample(rng, 20_000).max(1).mean() for a in (0.3, 1.0, 3.0)}
    assert peaks[0.3] > peaks[1.0] + 0.15 > peaks[3.0] + 0.15
    # the mean of the largest of 7 Dirichlet(1) entries is H_7 / 7 ≈ 0.370
    assert peaks[1.0] == pytest.approx(sum(1 / k for k in range(1, 8)) / 7, abs=0.01)


def test_adaptive_sampling_moves_towards_lagging_anchors() -> None:
    from amorctl.core.weight_sampling import WeightSampler, anchor_weights

    sampler = WeightSampler(7, adaptive_fraction=1.0)
    anchors = anchor_weights(7)
    assert anchors.shape == (29, 7) and np.allclose(anchors.sum(1), 1)
    assert np.allclose(sampler.anchor_probabilities(), 1 / 29)  # nothing observed: uniform
    # synthetic gap: episodes near the smooth corner achieve 40% less than predicted, others as predicted
    rng = np.random.default_rng(2)
    for _ in range(30):
        w = sampler.sample(rng, 200).astype(np.float64)
        predicted = np.full(len(w), 100.0)
        lagging = w[:, 6] > 0.6
        achieved = np.where(lagging, 60.0, 100.0) + rng.normal(0, 1, len(w))
        sampler.observe(w, predicted, achieved)
    p = sampler.anchor_probabilities()
    heavy = anchors[:, 6] >= 0.75  # the smooth anchors at 0.75 and 1.0
    assert p[heavy].sum() > 0.3  # 2 of 29 anchors (7% when uniform) take the largest share
    assert p[heavy].min() > 5 * p[~heavy].max()
    w = sampler.sample(np.random.default_rng(3), 5000)
    assert (w[:, 6] > 0.6).mean() > 0.3  # the draws follow


def test_sampler_state_round_trips_and_checks_its_anchor_count() -> None:
    from amorctl.core.weight_sampling import WeightSampler

    a = WeightSampler(3, adaptive_fraction=0.5)
    a.observe(np.array([[1.0, 0, 0], [0, 0, 1.0]]), np.array([10.0, 10.0]), np.array([5.0, 10.0]))
    b = WeightSampler(3, adaptive_fraction=0.5)
    b.load_state(a.state())
    np.testing.assert_array_equal(a.anchor_probabilities(), b.anchor_probabilities())
    p = a.anchor_probabilities()  # [13]: the centre, then 4 sweep-line levels per objective
    assert p[4] == p.max() and p[12] == p.min() < p[4] / 10  # corner e_0 lags, e_2 delivers
    assert np.allclose(p[1:12], p[4])  # never observed anchors count as the most lagging one
    with pytest.raises(AmorError, match="anchors"):
        WeightSampler(4, adaptive_fraction=0.5).load_state(a.state())
    with pytest.raises(AmorError, match="at most 1"):
        WeightSampler(3, corner_fraction=0.6, axis_fraction=0.6)
