"""amorctl's pytest plugin (entry point ``pytest11``): fixtures for plugin authors' tests.

- ``amorctl_registry``: a freshly loaded plugin registry (and forgotten again after the test);
- ``register_character``: call it with a :class:`~amorctl.core.specs.CharacterSpec` to make it
  resolvable by name (``amorctl`` commands, ``make_env``, ``train_run``) for this test only;
- ``tiny_dataset_for``: call it with a character to get a two-clip synthetic dataset path.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from amorctl.core.specs import CharacterSpec
from amorctl.registry import Provided, Registry, get_registry, reset_registry


@pytest.fixture
def amorctl_registry() -> Iterator[Registry]:
    """The installed plugins' registry, loaded fresh for this test."""
    reset_registry()
    yield get_registry()
    reset_registry()


@pytest.fixture
def register_character(amorctl_registry: Registry) -> Callable[[CharacterSpec], CharacterSpec]:
    """``register_character(spec)`` adds a character to the registry for this test; returns it."""

    def register(spec: CharacterSpec) -> CharacterSpec:
        amorctl_registry.items["character"][spec.name] = spec
        amorctl_registry.provided.append(Provided(spec.name, "character", "test", "0", spec.name))
        return spec

    return register


@pytest.fixture
def tiny_dataset_for(tmp_path: Path) -> Callable[[CharacterSpec], Path]:
    """``tiny_dataset_for(spec)``: a two-clip synthetic dataset of that character (1 s each)."""
    from amorctl.testing.suites import tiny_dataset

    def make(spec: CharacterSpec) -> Path:
        return tiny_dataset(spec, tmp_path / f"{spec.name}-tiny.mcap")

    return make
