"""Compile a character's MJCF into an MjModel with the character's physics rate."""

from __future__ import annotations

import mujoco

from amorctl.core.errors import AmorError
from amorctl.core.specs import CharacterSpec


def load_model(spec: CharacterSpec) -> mujoco.MjModel:
    """Compile ``spec.mjcf_path``; the timestep is set to ``1 / spec.physics_hz``.

    Raises:
        AmorError: the file is missing or MuJoCo rejects it (message names the file).
    """
    if not spec.mjcf_path.is_file():
        raise AmorError(f"{spec.mjcf_path}: character {spec.name!r} model file not found")
    try:
        model = mujoco.MjModel.from_xml_path(str(spec.mjcf_path))
    except ValueError as exc:
        raise AmorError(f"{spec.mjcf_path}: MuJoCo could not compile it: {exc}") from None
    model.opt.timestep = 1.0 / spec.physics_hz
    return model
