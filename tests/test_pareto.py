"""Pareto metrics against hand-computed fronts and against moocore."""

from __future__ import annotations

import math

import moocore
import numpy as np
import pytest

from amorctl.analysis.front import (
    default_reference_point,
    dominates,
    exact_hypervolume_limit,
    expected_utility,
    hypervolume,
    non_dominated,
    non_dominated_fraction,
    non_dominated_mask,
    pairwise_non_dominated_masks,
    sparsity,
    summarize_front,
)
from amorctl.core.errors import AmorError
from amorctl.core.weights import sample_dirichlet, simplex_grid

# ---------------------------------------------------------------- dominance and filtering


def test_dominates_needs_one_strict_improvement() -> None:
    assert dominates([2, 2], [1, 2])  # tie in one objective, better in the other
    assert not dominates([1, 2], [1, 2])  # equal points do not dominate each other
    assert not dominates([3, 0], [0, 3])  # a trade-off
    assert not dominates([1, 2], [2, 2])
    # broadcasting: [3, 2] vs [2]
    a = np.array([[2.0, 2.0], [1.0, 1.0], [0.0, 5.0]])
    np.testing.assert_array_equal(dominates(a, np.array([1.0, 1.0])), [True, False, False])


def test_non_dominated_with_ties() -> None:
    pts = np.array([[1.0, 2.0], [1.0, 3.0], [2.0, 1.0], [2.0, 1.0 - 1e-12]])
    # [1,3] beats [1,2] on a tie; [2,1] beats [2,1-eps]
    np.testing.assert_array_equal(non_dominated_mask(pts), [False, True, True, False])


def test_duplicates_kept_unless_asked() -> None:
    pts = np.array([[1.0, 1.0], [0.0, 2.0], [1.0, 1.0], [0.0, 0.0]])
    np.testing.assert_array_equal(non_dominated_mask(pts), [True, True, True, False])
    np.testing.assert_array_equal(non_dominated_mask(pts, keep_duplicates=False), [True, True, False, False])
    np.testing.assert_array_equal(non_dominated(pts, keep_duplicates=False), [[1.0, 1.0], [0.0, 2.0]])
    assert non_dominated_fraction(pts) == pytest.approx(0.75)


def test_one_point_and_all_dominated() -> None:
    np.testing.assert_array_equal(non_dominated_mask(np.array([[-4.0, 7.0, 0.0]])), [True])
    pts = np.array([[1.0, 2.0], [2.0, 1.0], [0.0, 0.0], [3.0, 3.0]])
    np.testing.assert_array_equal(non_dominated_mask(pts), [False, False, False, True])
    assert non_dominated_fraction(pts) == pytest.approx(0.25)
    # all identical: every copy is non-dominated
    assert non_dominated_mask(np.ones((5, 3))).all()


def test_non_dominated_matches_moocore_on_random_sets() -> None:
    rng = np.random.default_rng(3)
    for m in (2, 3, 5):
        # rounded values make ties and duplicates common
        pts = np.round(rng.normal(size=(700, m)), 1)
        expected = moocore.is_nondominated(pts, maximise=True, keep_weakly=True)
        np.testing.assert_array_equal(non_dominated_mask(pts), expected)


def test_pairwise_masks() -> None:
    pts = np.array([[3.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 3.0], [1.0, 1.0, 1.0]])
    masks = pairwise_non_dominated_masks(pts)
    assert list(masks) == [(0, 1), (0, 2), (1, 2)]
    np.testing.assert_array_equal(masks[(0, 1)], [True, True, False, True])
    np.testing.assert_array_equal(masks[(0, 2)], [True, False, True, True])
    np.testing.assert_array_equal(masks[(1, 2)], [False, True, True, True])
    assert non_dominated_mask(pts).all()


def test_bad_point_sets() -> None:
    with pytest.raises(AmorError, match="non-empty"):
        non_dominated_mask(np.zeros((0, 2)))
    with pytest.raises(AmorError, match="NaN"):
        non_dominated_mask(np.array([[1.0, np.nan]]))
    with pytest.raises(AmorError, match="at least 2 objectives"):
        pairwise_non_dominated_masks(np.ones((3, 1)))


# ---------------------------------------------------------------- hypervolume


def test_hypervolume_2d_hand_computed() -> None:
    # staircase: [0,1]x[0,3] + [1,2]x[0,2] + [2,3]x[0,1] = 3 + 2 + 1
    pts = np.array([[1.0, 3.0], [2.0, 2.0], [3.0, 1.0], [1.0, 1.0], [2.0, 2.0]])
    hv = hypervolume(pts, [0.0, 0.0])
    assert hv.method == "exact"
    assert hv.value == pytest.approx(6.0)
    assert hv.ci_low == hv.ci_high == hv.value
    assert hv.n_points == 3  # the dominated point and the duplicate are dropped
    # shifting the reference by (-1, -1) adds a 1-wide strip on both sides: 6 + 3 + 3 + 1
    assert hypervolume(pts, [-1.0, -1.0]).value == pytest.approx(13.0)


def test_hypervolume_3d_hand_computed() -> None:
    assert hypervolume(np.array([[1.0, 2.0, 3.0]]), np.zeros(3)).value == pytest.approx(6.0)
    # three 2-boxes overlapping in the unit cube: 3*2 - 3*1 + 1
    pts = np.array([[2.0, 1.0, 1.0], [1.0, 2.0, 1.0], [1.0, 1.0, 2.0]])
    assert hypervolume(pts, np.zeros(3)).value == pytest.approx(4.0)
    # add (2,2,2): inclusion-exclusion 17 - 9 + 4 - 1
    pts4 = np.vstack([3 * np.eye(3) + (1 - np.eye(3)), [2.0, 2.0, 2.0]])
    assert hypervolume(pts4, np.zeros(3)).value == pytest.approx(11.0)


def test_hypervolume_ignores_points_not_beyond_reference() -> None:
    pts = np.array([[2.0, 2.0], [5.0, -1.0]])  # the second is below the reference in objective 1
    assert hypervolume(pts, [0.0, 0.0]).value == pytest.approx(4.0)
    empty = hypervolume(np.array([[-1.0, -1.0]]), [0.0, 0.0])
    assert empty.value == 0.0 and empty.n_points == 0


def test_hypervolume_matches_moocore_maximise() -> None:
    rng = np.random.default_rng(0)
    for m in (2, 3, 4):
        pts = rng.uniform(1, 2, size=(60, m))
        ref = np.full(m, 0.5)
        expected = moocore.hypervolume(pts, ref=ref, maximise=True)
        assert hypervolume(pts, ref).value == pytest.approx(expected, rel=1e-12)


def test_default_reference_point_rule() -> None:
    pts = np.array([[0.0, 10.0], [10.0, 0.0], [5.0, 5.0]])
    np.testing.assert_allclose(default_reference_point(pts), [-1.0, -1.0])
    np.testing.assert_allclose(default_reference_point(pts, margin=0.5), [-5.0, -5.0])
    # zero range: max(|min|, 1) stands in for the range
    np.testing.assert_allclose(default_reference_point(np.array([[5.0, -2.0, 0.0]])), [4.5, -2.2, -0.1])
    # the default reference (-1, -1) is used when none is given; inclusion-exclusion of 3 boxes
    assert hypervolume(pts).value == pytest.approx(11 + 11 + 36 - 1 - 6 - 6 + 1)


def test_monte_carlo_contains_exact_value() -> None:
    rng = np.random.default_rng(1)
    x = np.abs(rng.normal(size=(200, 5)))
    pts = x / np.linalg.norm(x, axis=1, keepdims=True)  # on a concave front: all non-dominated
    ref = np.zeros(5)
    exact = hypervolume(pts, ref, method="exact")
    mc = hypervolume(pts, ref, method="monte_carlo", n_samples=65_536, n_batches=16, seed=7)
    assert mc.method == "monte_carlo" and mc.n_samples == 65_536 and mc.confidence == 0.95
    assert mc.ci_low < exact.value < mc.ci_high
    assert (mc.ci_high - mc.ci_low) / exact.value < 0.02  # and the interval is informative
    # auto switches to Monte Carlo above the threshold and says so
    auto = hypervolume(pts, ref, max_exact_points=100, n_samples=4096, n_batches=4)
    assert auto.method == "monte_carlo" and auto.n_points == 200
    assert hypervolume(pts, ref, max_exact_points=200).method == "exact"


def test_exact_threshold_table() -> None:
    assert exact_hypervolume_limit(2) is None and exact_hypervolume_limit(3) is None
    assert exact_hypervolume_limit(7) == 256
    assert exact_hypervolume_limit(12) == 64


def test_hypervolume_bad_reference() -> None:
    with pytest.raises(AmorError, match="reference point"):
        hypervolume(np.ones((2, 3)), [0.0, 0.0])
    with pytest.raises(AmorError, match="method"):
        hypervolume(np.ones((2, 2)), [0.0, 0.0], method="magic")  # type: ignore[arg-type]


# ---------------------------------------------------------------- EUM, sparsity, summary


def test_expected_utility_hand_computed() -> None:
    pts = np.array([[1.0, 0.0], [0.0, 1.0], [0.2, 0.2]])
    w = np.array([[1.0, 0.0], [0.0, 1.0], [0.5, 0.5]])
    assert expected_utility(pts, w) == pytest.approx((1 + 1 + 0.5) / 3)
    # a point on the diagonal raises only the middle weight's best utility
    pts2 = np.vstack([pts, [0.8, 0.8]])
    assert expected_utility(pts2, w) == pytest.approx((1 + 1 + 0.8) / 3)
    with pytest.raises(AmorError, match="objectives"):
        expected_utility(pts, np.ones((2, 3)) / 3)


def test_sparsity_hand_computed() -> None:
    front = np.array([[0.0, 3.0], [1.0, 1.0], [3.0, 0.0]])
    # per objective sorted gaps 1 and 2 -> 1 + 4 = 5; two objectives -> 10; / (3 - 1)
    assert sparsity(front) == pytest.approx(5.0)
    assert sparsity(front[:1]) == 0.0
    assert sparsity(np.array([[0.0, 0.0], [2.0, 1.0]])) == pytest.approx(5.0)


def test_summarize_front() -> None:
    pts = np.array([[0.0, 3.0], [1.0, 1.0], [3.0, 0.0], [1.0, 1.0], [0.5, 0.5]])
    w = np.array([[1.0, 0.0], [0.0, 1.0]])
    s = summarize_front(pts, w, [0.0, 0.0])
    np.testing.assert_array_equal(s.non_dominated, [True, True, True, True, False])
    assert s.non_dominated_fraction == pytest.approx(0.8)
    assert s.sparsity == pytest.approx(5.0)  # on the distinct front
    assert s.expected_utility == pytest.approx(3.0)
    # boxes 0x3 (none), 1x1, 3x0 (none) -> only the (1,1) box has volume
    assert s.hypervolume.value == pytest.approx(1.0)
    assert s.hypervolume.to_dict()["reference_point"] == [0.0, 0.0]
    assert set(s.pairwise) == {(0, 1)}


# ---------------------------------------------------------------- weight grid (weights.py)


def test_simplex_grid() -> None:
    g = simplex_grid(3, 2)
    assert g.shape == (math.comb(4, 2), 3)
    np.testing.assert_allclose(g.sum(axis=1), 1.0)
    assert len(np.unique(g, axis=0)) == len(g)
    assert {tuple(r) for r in g} >= {(1.0, 0.0, 0.0), (0.5, 0.5, 0.0), (0.0, 0.0, 1.0)}
    assert simplex_grid(7, 7).shape == (math.comb(13, 6), 7)
    assert np.any(np.all(np.isclose(simplex_grid(7, 7), 1 / 7), axis=1))  # equal weights included
    np.testing.assert_array_equal(simplex_grid(1, 4), [[1.0]])
    with pytest.raises(AmorError):
        simplex_grid(3, 0)


def test_expected_utility_over_sampled_weights_prefers_larger_front() -> None:
    w = sample_dirichlet(np.random.default_rng(0), 256, 2).astype(np.float64)
    small = np.array([[1.0, 0.0], [0.0, 1.0]])
    larger = np.vstack([small, [0.7, 0.7]])
    assert expected_utility(larger, w) > expected_utility(small, w)


# ---------------------------------------------------------------- survivors' front


def test_survivor_means_skip_fallen_episodes() -> None:
    from amorctl.analysis.front import survivor_means

    returns = np.array([[[10.0, 1.0], [2.0, 0.0]], [[1.0, 1.0], [3.0, 3.0]]])  # [K=2, E=2, m=2]
    survived = np.array([[1, 0], [0, 0]])
    got = survivor_means(returns, survived)
    np.testing.assert_array_equal(got[0], [10.0, 1.0])  # the fallen episode (2, 0) is left out
    assert np.isnan(got[1]).all()  # every episode fell


def test_summarize_fronts_shares_the_reference_and_drops_the_fallen() -> None:
    from amorctl.analysis.front import shared_reference_point, summarize_fronts

    # two survivors on a trade-off, one fallen point low in both objectives
    points = np.array([[10.0, 1.0], [1.0, 10.0], [0.5, 0.5]])
    surv = np.array([[10.0, 1.0], [1.0, 10.0], [np.nan, np.nan]])
    w = np.array([[0.9, 0.1], [0.1, 0.9], [0.5, 0.5]])
    summary, survivors = summarize_fronts(points, surv, w)
    ref = shared_reference_point(points, surv)
    np.testing.assert_allclose(ref, [0.5 - 0.95, 0.5 - 0.95])  # min - 0.1 * range over all rows
    np.testing.assert_allclose(summary.hypervolume.reference_point, ref)
    np.testing.assert_allclose(survivors.summary.hypervolume.reference_point, ref)
    np.testing.assert_array_equal(survivors.survived, [True, True, False])
    np.testing.assert_array_equal(survivors.non_dominated, [True, True, False])
    # the fallen point is dominated here, so both fronts hold the same two points: same volume
    assert survivors.summary.hypervolume.value == pytest.approx(summary.hypervolume.value)
    # hand value: union of [ref, (10, 1)] and [ref, (1, 10)] boxes
    r = ref[0]
    assert summary.hypervolume.value == pytest.approx(2 * (10 - r) * (1 - r) - (1 - r) ** 2)
    # EUM of the survivors uses their own weights: rows 0 and 1
    assert survivors.summary.expected_utility == pytest.approx(expected_utility(points[:2], w[:2]))


def test_summarize_fronts_without_survivors() -> None:
    from amorctl.analysis.front import summarize_fronts

    points = np.array([[1.0, 2.0], [2.0, 1.0]])
    summary, survivors = summarize_fronts(points, np.full((2, 2), np.nan), np.full((2, 2), 0.5))
    assert survivors.summary is None and not survivors.survived.any()
    assert summary.non_dominated_fraction == 1.0


def _fake_sweep(fallen: int) -> object:
    """A ParetoSweep of 3 objectives: 20 survivors near (100, 100, 100) and ``fallen`` points at 0."""
    from amorctl.analysis.front import summarize_fronts
    from amorctl.analysis.sweeps import ParetoGroup, ParetoSweep

    rng = np.random.default_rng(0)
    k = 20 + fallen
    pts = 100 + rng.normal(size=(k, 3))
    pts[20:] = 1.0 + rng.uniform(size=(fallen, 3))
    surv = pts.copy()
    surv[20:] = np.nan
    w = sample_dirichlet(np.random.default_rng(1), k, 3)
    summary, survivors = summarize_fronts(pts, surv, w)
    grp = ParetoGroup("walk", pts, np.zeros_like(pts), (np.arange(k) < 20).astype(float), pts[:20].mean(0),
                      summary, surv, survivors)  # fmt: skip
    return ParetoSweep(("a", "b", "c"), w, "dirichlet(1)", 1, 10.0, [grp], k + 1, 100, 1.0, "rule")


def test_pareto_figure_zooms_on_survivors(tmp_path, monkeypatch) -> None:
    """The axes span the survivors (near 100), not the fallen points (near 1), which are counted."""
    from amorctl.outputs import plots

    captured = {}
    real_save = plots._save

    def keep(fig, paths):
        captured["fig"] = fig
        real_save(fig, paths)

    monkeypatch.setattr(plots, "_save", keep)
    plots.pareto_figure(_fake_sweep(3), [tmp_path / "p.png"])
    fig = captured["fig"]
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert len(visible) == 3  # m = 3: panels (a,b), (a,c), (b,c)
    for ax in visible:
        lo, hi = ax.get_xlim()
        assert 90 < lo < hi < 110, (lo, hi)
    assert "3 fell" in fig._suptitle.get_text()
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any("fell in every episode: 3 of 23" in t for t in labels)
    assert (tmp_path / "p.png").stat().st_size > 1000


def test_pareto_json_reports_both_fronts(toy_run, tmp_path, capsys) -> None:
    import json

    import jsonschema

    from amorctl.analysis.schemas import PARETO_JSON_SCHEMA
    from amorctl.cli.main import main

    code = main(["pareto", str(toy_run), "-k", "6", "--out", str(tmp_path), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads(out)
    jsonschema.validate(doc, PARETO_JSON_SCHEMA)
    grp = doc["motions"][0]
    sv = grp["survivors"]
    assert sv["count"] + sv["fallen"] == 6
    assert sv["count"] == sum(1 for s in grp["survival"] if s > 0)
    assert sv["hypervolume"]["reference_point"] == grp["hypervolume"]["reference_point"]
    header = (tmp_path / "pareto.csv").read_text().splitlines()[0].split(",")
    assert "non_dominated_survivors" in header and "J_right_survivors" in header
