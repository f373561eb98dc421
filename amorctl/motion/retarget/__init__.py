"""Retargeting a source skeleton animation onto a character.

The method is part of the character's spec (``CharacterSpec.retarget``):

- ``direct``: the character is built on the canonical DeepMimic skeleton (``humanoid36``); joint
  rotations map onto same-named hinge triplets, see :mod:`amorctl.motion.retarget.direct`.
- ``ik`` (the default): inverse kinematics on key points, see :mod:`amorctl.motion.retarget.ik`.

Both finish with :func:`~amorctl.motion.retarget.common.finish` (floor lift, key-point errors).
"""

from __future__ import annotations

from amorctl.core.errors import AmorError
from amorctl.motion.kinematics import CharacterKinematics
from amorctl.motion.retarget.common import Retargeter, finish, keypoint_errors, lift_to_floor, smooth_lift
from amorctl.motion.retarget.direct import retarget_direct
from amorctl.motion.source import CharacterMotion, SourceMotion

__all__ = [
    "Retargeter",
    "finish",
    "keypoint_errors",
    "lift_to_floor",
    "retarget",
    "retarget_direct",
    "retargeter_for",
    "smooth_lift",
]


def retargeter_for(method: str, character: str = "?") -> Retargeter:
    """The retargeting function of a method name (``"direct"`` or ``"ik"``)."""
    if method == "direct":
        return retarget_direct
    if method == "ik":
        # mink (and its QP solver) load only when a character needs IK.
        from amorctl.motion.retarget.ik import retarget_ik

        return retarget_ik
    raise AmorError(f"character {character!r}: unknown retargeting method {method!r} (known: direct, ik)")


def retarget(
    motion: SourceMotion, kin: CharacterKinematics, max_joint_speed: float | None = None
) -> CharacterMotion:
    """Retarget with the method the character's spec names (``kin.spec.retarget``);
    ``max_joint_speed`` (rad/s, IK only; None = the method's default) bounds every joint's speed."""
    if max_joint_speed is None:
        return retargeter_for(kin.spec.retarget, kin.spec.name)(motion, kin)
    if kin.spec.retarget != "ik":
        raise AmorError(
            f"character {kin.spec.name!r}: a joint-speed bound needs IK retargeting, "
            f"not {kin.spec.retarget!r}"
        )
    from amorctl.motion.retarget.ik import retarget_ik

    return retarget_ik(motion, kin, max_joint_speed=max_joint_speed)
