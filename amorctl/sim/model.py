"""The one MJCF compiler: a character's model file -> ``MjModel`` at the character's physics rate.

Everything that needs a character's model (kinematics and retargeting, ``characters show``, the
batched simulation, video rendering, deploy bundles) compiles it here, so all of them see the same
model: the file as :func:`amorctl.sim.prepare.prepare_spec` makes it fit the
:class:`~amorctl.core.specs.CharacterSpec` (actuator gains, joint properties, floor). The batched
simulation asks for amorctl's tracking sensors on top; they add sensors only (no bodies, joints or
actuators), so ``nq``, ``nv``, ``nu`` and every mass and inertia are the same with or without them.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco

from amorctl.core.errors import AmorError
from amorctl.core.specs import CharacterSpec
from amorctl.sim.prepare import prepare_spec


def load_model(
    spec: CharacterSpec,
    tracking_sensors: bool = False,
    edit: Callable[[mujoco.MjSpec, CharacterSpec], None] | None = None,
) -> mujoco.MjModel:
    """Compile ``spec.mjcf_path``; the timestep is set to ``1 / spec.physics_hz``.

    Args:
        spec: the character.
        tracking_sensors: also add amorctl's named end-effector and torque sensors
            (:func:`amorctl.sim.prepare.add_tracking_sensors`), as the batched simulation needs.
        edit: a last edit of the prepared spec before it compiles (the batched simulation's
            native servo actuators, :func:`amorctl.sim.actuators.native_servo`).

    Raises:
        AmorError: the file is missing, a named body, joint or actuator does not exist or does not
            fit the spec, or MuJoCo rejects the file (the message names it).
    """
    path = spec.mjcf_path
    if not path.is_file():
        raise AmorError(f"{path}: character {spec.name!r} model file not found")
    try:
        mjspec = mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:
        raise AmorError(f"{path}: MuJoCo could not parse it: {exc}") from None
    prepare_spec(mjspec, spec, path, sensors=tracking_sensors)
    if edit is not None:
        mjspec.option.timestep = 1.0 / spec.physics_hz  # history buffers are timed in physics steps
        edit(mjspec, spec)
    try:
        model = mjspec.compile()
    except ValueError as exc:
        raise AmorError(f"{path}: character {spec.name!r}: MuJoCo could not compile it: {exc}") from None
    model.opt.timestep = 1.0 / spec.physics_hz
    return model
