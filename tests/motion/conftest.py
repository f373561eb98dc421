"""Fixtures for the motion-data tests: the real DeepMimic clips (skipped without pybullet_data)."""

from __future__ import annotations

from pathlib import Path

import pytest

from amorctl.motion.builtin import pybullet_data_path


@pytest.fixture(scope="session")
def deepmimic_dir() -> Path:
    root = pybullet_data_path()
    if root is None or not (root / "data" / "motions" / "humanoid3d_walk.txt").is_file():
        pytest.skip("pybullet_data (pip install pybullet) is not installed: no DeepMimic clips")
    return root / "data" / "motions"


@pytest.fixture(scope="session")
def clip_path(deepmimic_dir: Path):
    """clip_path("walk") / clip_path("walker/turn_left0") -> the file."""

    def find(name: str) -> Path:
        if name.startswith("walker/"):
            return deepmimic_dir / "walker" / f"{name.removeprefix('walker/')}.txt"
        return deepmimic_dir / f"humanoid3d_{name}.txt"

    return find


@pytest.fixture(scope="session")
def kinematics():
    """kinematics("humanoid36") -> CharacterKinematics, compiled once per session."""
    from amorctl.motion.kinematics import character_kinematics
    from amorctl.registry import get_registry

    cache = {}

    def get(name: str):
        if name not in cache:
            cache[name] = character_kinematics(get_registry().character(name))
        return cache[name]

    return get
