"""A testing kit for amorctl plugin authors: contract suites and pytest fixtures.

Call the suites from your plugin's tests (``amorctl plugins new`` writes such a test)::

    from amorctl.testing import check_character
    from my_plugin import SPEC

    def test_my_robot_meets_the_contract():
        check_character(SPEC)

- :func:`check_character`: DoF counts, names, groups, key points, rates, the model as amorctl
  prepares it (actuators, sensors, gains, floor, standing height) and a 5 s PD hold test;
- :func:`check_objective_set`: names, shapes, bounds of the rewards, numpy vs ``jax.numpy``
  parity where jax is installed;
- :func:`check_backend`: a tiny tracking run: bit-exact resume from a trainer snapshot and
  parity between the trainer's deterministic actions and the loaded :class:`Policy`.

Each raises ``AssertionError`` naming what broke. The pytest plugin (entry point ``pytest11``,
module :mod:`amorctl.testing.pytest_plugin`) adds the fixtures ``amorctl_registry`` and
``register_character``. See docs/plugins.md.
"""

from __future__ import annotations

from amorctl.testing.suites import (
    check_backend,
    check_character,
    check_objective_set,
    tiny_dataset,
    with_characters,
)

__all__ = ["check_backend", "check_character", "check_objective_set", "tiny_dataset", "with_characters"]
