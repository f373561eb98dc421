"""The ``tracking7`` objective set: the AMOR paper's seven motion-tracking objectives (Table 1).

Reward vector index -> name (fixed order, as MO-Gymnasium documents its reward spaces):

    0: up      upper-body joint positions and root height
    1: lo      lower-body joint positions
    2: feet    foot (ankle) joint positions
    3: rbs     end-effector position, rotation and linear velocity (relative to the root)
    4: root    root orientation (in its heading frame)
    5: vel     root linear and angular velocity (in the heading frame)
    6: smooth  torque, action rate, action second difference, joint acceleration (penalties)

A tracking objective with several terms is the MEAN of its terms' ``exp(-scale * err)``, so every
tracking objective lies in [0, 1] whatever its number of terms (the prior scales are meant to put
the objectives on one footing, and a mean keeps partial credit: a product ``exp(-Σ scale·err)``
collapses to 0 when one term is bad and hides progress on the others). ``smooth`` is the SUM of
its negative scaled penalties. Every objective then gets the survival bonus ``alive`` (default
1.0) on every step that does not terminate. See docs/objectives.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from amorctl.api import AmorError, CharacterSpec, ObjectiveSetSpec, TrackingInputs, hookimpl
from amorctl.plugins.objectives import tracking7_kernels as k

NAME = "tracking7"

OBJECTIVES: tuple[str, ...] = ("up", "lo", "feet", "rbs", "root", "vel", "smooth")

DESCRIPTIONS: tuple[str, ...] = (
    "upper-body joint positions and root height",
    "lower-body joint positions",
    "foot joint positions",
    "end-effector position, rotation and linear velocity",
    "root orientation",
    "root linear and angular velocity",
    "smoothness: torque, action rate, action second difference, joint acceleration",
)

#: Default survival bonus c_alive, added to every objective on every non-terminal step.
ALIVE_BONUS = 1.0

#: Prior scales of Table 1, one column per ``CharacterSpec.scale_profile``. ``up_height`` (the
#: root-height term of ``up``, which Table 1 describes but lists no scale for) takes the joint
#: term's scale (also when a character overrides ``up`` only); ``alive`` is the survival bonus.
PRIOR_SCALES: dict[str, dict[str, float]] = {
    "humanoid": {
        "up": 1.0,
        "up_height": 1.0,
        "lo": 1.0,
        "feet": 1.0,
        "rbs_pos": 1.0,
        "rbs_rot": 1.0,
        "rbs_vel": 1.0,
        "root": 1.0,
        "vel_lin": 1.0,
        "vel_ang": 1.0,
        "smooth_torque": 1.0e-5,
        "smooth_action_rate": 1.0e-5,
        "smooth_action_acc": 1.0e-5,
        "smooth_joint_acc": 1.0e-6,
        "alive": ALIVE_BONUS,
    },
    "robot": {
        "up": 7.0,
        "up_height": 7.0,
        "lo": 7.0,
        "feet": 7.0,
        "rbs_pos": 1.0,
        "rbs_rot": 1.0,
        "rbs_vel": 1.0,
        "root": 1.0,
        "vel_lin": 2.0,
        "vel_ang": 2.0,
        "smooth_torque": 1.0e-4,
        "smooth_action_rate": 1.5,
        "smooth_action_acc": 0.45,
        "smooth_joint_acc": 2.5e-6,
        "alive": ALIVE_BONUS,
    },
}


def resolve_scales(character: CharacterSpec) -> dict[str, float]:
    """The scales the set uses for ``character``: its profile's column, then its overrides.

    Raises:
        AmorError: unknown profile, or an override names a key that is not a scale.
    """
    try:
        scales = dict(PRIOR_SCALES[character.scale_profile])
    except KeyError:
        known = ", ".join(sorted(PRIOR_SCALES))
        raise AmorError(
            f"character {character.name!r}: unknown scale_profile {character.scale_profile!r} "
            f"for objective set {NAME!r} (known: {known})"
        ) from None
    overrides: Mapping[str, float] = character.objective_scales.get(NAME, {})
    unknown = sorted(set(overrides) - set(scales))
    if unknown:
        raise AmorError(
            f"character {character.name!r}: objective_scales[{NAME!r}] has unknown keys "
            f"{', '.join(unknown)} (known: {', '.join(scales)})"
        )
    for key, value in overrides.items():
        if not np.isfinite(value) or value < 0:
            raise AmorError(f"character {character.name!r}: scale {key!r} must be >= 0, got {value}")
        scales[key] = float(value)
    if "up" in overrides and "up_height" not in overrides:
        scales["up_height"] = scales["up"]  # the height term follows the joint term's scale
    return scales


class Tracking7:
    """The bound objective set: ``r = tracking7(inputs, alive)`` with r [N, 7].

    Attributes:
        scales: the resolved prior scales (see :data:`PRIOR_SCALES`).
        alive_bonus: c_alive.
        names, descriptions: index -> objective.
        low, high: [7] bounds of one step's reward.
    """

    names = OBJECTIVES
    descriptions = DESCRIPTIONS

    def __init__(self, character: CharacterSpec) -> None:
        self.character = character.name
        self.scales = resolve_scales(character)
        self.alive_bonus = self.scales["alive"]
        self.upper = np.asarray(character.group_indices("upper"), dtype=np.int64)
        self.lower = np.asarray(character.group_indices("lower"), dtype=np.int64)
        self.feet = np.asarray(character.group_indices("feet"), dtype=np.int64)
        c = self.alive_bonus
        self.low = np.array([0.0] * 6 + [-np.inf])
        self.high = np.array([1.0 + c] * 6 + [c])

    def terms(self, x: TrackingInputs, xp: Any = np) -> dict[str, Any]:
        """Every term's value before combination, name -> [N] (for logging per-term sums)."""
        s, sim, ref = self.scales, x.sim, x.ref
        return {
            "up": k.joint_pos_error_exp(
                sim.joint_pos[:, self.upper], ref.joint_pos[:, self.upper], s["up"], xp
            ),
            "up_height": k.root_height_error_exp(sim.h, ref.h, s["up_height"], xp),
            "lo": k.joint_pos_error_exp(
                sim.joint_pos[:, self.lower], ref.joint_pos[:, self.lower], s["lo"], xp
            ),
            "feet": k.joint_pos_error_exp(
                sim.joint_pos[:, self.feet], ref.joint_pos[:, self.feet], s["feet"], xp
            ),
            "rbs_pos": k.body_pos_error_exp(sim.ee_pos, ref.ee_pos, s["rbs_pos"], xp),
            "rbs_rot": k.body_rot_error_exp(sim.ee_rot6d, ref.ee_rot6d, s["rbs_rot"], xp),
            "rbs_vel": k.body_vel_error_exp(sim.ee_vel, ref.ee_vel, s["rbs_vel"], xp),
            "root": k.root_rot_error_exp(sim.root_rot6d, ref.root_rot6d, s["root"], xp),
            "vel_lin": k.root_lin_vel_error_exp(sim.root_lin_vel, ref.root_lin_vel, s["vel_lin"], xp),
            "vel_ang": k.root_ang_vel_error_exp(sim.root_ang_vel, ref.root_ang_vel, s["vel_ang"], xp),
            "smooth_torque": k.torque_l2(x.torque, s["smooth_torque"], xp),
            "smooth_action_rate": k.action_rate_l2(
                x.pd_target, x.pd_target_prev, s["smooth_action_rate"], xp
            ),
            "smooth_action_acc": k.action_acc_l2(
                x.pd_target, x.pd_target_prev, x.pd_target_prev2, s["smooth_action_acc"], xp
            ),
            "smooth_joint_acc": k.joint_acc_l2(x.joint_acc, s["smooth_joint_acc"], xp),
        }

    def __call__(self, inputs: TrackingInputs, alive: Any, xp: Any = np) -> Any:
        """Vector reward of one transition.

        Args:
            inputs: the simulated and reference quantities (see :class:`TrackingInputs`).
            alive: [N] 1.0 where the transition did not terminate, else 0.0 (no survival bonus).
            xp: array namespace.
        Returns:
            r [N, 7] in the order of :data:`OBJECTIVES`.
        """
        t = self.terms(inputs, xp)
        r = xp.stack(
            [
                0.5 * (t["up"] + t["up_height"]),
                t["lo"],
                t["feet"],
                (t["rbs_pos"] + t["rbs_rot"] + t["rbs_vel"]) / 3.0,
                t["root"],
                0.5 * (t["vel_lin"] + t["vel_ang"]),
                t["smooth_torque"] + t["smooth_action_rate"] + t["smooth_action_acc"] + t["smooth_joint_acc"],
            ],
            axis=-1,
        )
        return r + self.alive_bonus * xp.asarray(alive, dtype=r.dtype)[:, None]


SPEC = ObjectiveSetSpec(
    name=NAME,
    description="The AMOR paper's 7 motion-tracking objectives (Table 1) with the survival bonus",
    objectives=OBJECTIVES,
    make=Tracking7,
)


@hookimpl
def amorctl_register_objective_sets(register: Any) -> None:
    """Register ``tracking7``."""
    register(SPEC)
