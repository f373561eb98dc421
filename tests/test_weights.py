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
