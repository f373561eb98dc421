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
