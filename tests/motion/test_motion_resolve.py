"""``--motion NAME`` resolution: exact, unique prefix, unique suffix; clear errors otherwise."""

from __future__ import annotations

import pytest

from amorctl.core.errors import AmorError
from amorctl.motion.resolve import resolve_name

NAMES = ["walk", "walker/0walk_forward", "walker/turn_left0", "walker/turn_left1", "run", "spin", "spinkick"]


def test_exact_prefix_suffix():
    assert resolve_name("walk", NAMES) == "walk"  # exact beats the prefix of walker/...
    assert resolve_name("spin", NAMES) == "spin"
    assert resolve_name("spink", NAMES) == "spinkick"
    assert resolve_name("r", NAMES) == "run"
    assert resolve_name("turn_left0", NAMES) == "walker/turn_left0"
    assert resolve_name("0walk_forward", NAMES) == "walker/0walk_forward"


def test_ambiguous_and_unknown_names_list_candidates():
    with pytest.raises(AmorError, match=r"ambiguous.*walker/turn_left0, walker/turn_left1"):
        resolve_name("walker/turn", NAMES)
    with pytest.raises(AmorError, match=r"no motion 'fly'.*clips: run, spin"):
        resolve_name("fly", NAMES)
