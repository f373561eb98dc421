"""Per-objective rewards of the sim2sim runtime, from the bundle's objective set (numpy kernels).

The bundle records the objective set of its run and the plugin that registered it
(``deploy.json`` ``objective_set``); :func:`load_reward_meter` loads only that plugin
(:func:`amorctl.registry.load_plugin`, no other plugin and no torch) and binds it to the bundle's
character, with the character's ``scale_profile`` and ``objective_scales`` from the metadata, so the
scales are the run's. Each control tick the meter builds the same :class:`TrackingInputs` the
tracking env builds after a step: the simulated frame, the reference frame the step reached
(features of the clip's world-frame arrays, as the env computes them), the torques of every
physics substep, the PD targets and their history, and the joint acceleration; the objective set
evaluates them with ``xp=numpy``. ``alive`` is 0 on the tick that falls (as the env terminates it);
a diverged tick gets zero rewards.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import TrackingInputs, frame_features, split_frame
from amorctl.deploy.bundle import Bundle, Motions


class RewardMeter:
    """The objective set of a bundle bound to its character: one reward vector [m] per tick.

    Attributes:
        names: the m objective names (the bundle's order).
        low, high: [m] bounds of one step's reward.
    """

    def __init__(self, objectives: Any, motions: Motions, num_joints: int, num_ee: int) -> None:
        self.objectives = objectives
        self.names = tuple(objectives.names)
        self.low = np.asarray(objectives.low, dtype=np.float64)
        self.high = np.asarray(objectives.high, dtype=np.float64)
        self.num_joints, self.num_ee = num_joints, num_ee
        mot = motions
        self.ref_frames = frame_features(
            mot.root_pos,
            mot.root_quat,
            mot.root_lin_vel,
            mot.root_ang_vel,
            mot.joint_pos,
            mot.joint_vel,
            mot.ee_pos,
            mot.ee_quat,
            mot.ee_lin_vel,
        )

    def __call__(
        self,
        sim_frame: np.ndarray,
        frame: int,
        torque: np.ndarray,
        pd_target: np.ndarray,
        pd_target_prev: np.ndarray,
        pd_target_prev2: np.ndarray,
        joint_acc: np.ndarray,
        alive: bool,
        diverged: bool = False,
    ) -> np.ndarray:
        """Rewards [m] float64 of one tick.

        Args:
            sim_frame: [D] the simulated frame after the step.
            frame: library index of the reference frame the step reached.
            torque: [S, J] joint torques of every physics substep, N·m.
            pd_target, pd_target_prev, pd_target_prev2: [J] targets at t, t-1, t-2, rad.
            joint_acc: [J] (q̇_{t+1} - q̇_t) / Δt, rad/s².
            alive: False on a tick that ends in a fall (no survival bonus).
            diverged: the simulation diverged (rewards are zero, as in training).
        """
        if diverged:
            return np.zeros(len(self.names))
        j, e = self.num_joints, self.num_ee
        inputs = TrackingInputs(
            sim=split_frame(np.asarray(sim_frame, dtype=np.float64)[None], j, e),
            ref=split_frame(self.ref_frames[frame][None], j, e),
            torque=np.asarray(torque, dtype=np.float64)[None],
            pd_target=np.asarray(pd_target, dtype=np.float64)[None],
            pd_target_prev=np.asarray(pd_target_prev, dtype=np.float64)[None],
            pd_target_prev2=np.asarray(pd_target_prev2, dtype=np.float64)[None],
            joint_acc=np.asarray(joint_acc, dtype=np.float64)[None],
        )
        with np.errstate(invalid="ignore", over="ignore"):
            r = self.objectives(inputs, np.array([1.0 if alive else 0.0]), np)
        return np.asarray(r, dtype=np.float64)[0]


def load_reward_meter(bundle: Bundle) -> RewardMeter:
    """The bundle's objective set bound to its character (module docstring).

    Raises:
        AmorError: the bundle records no objective set, its plugin is not installed, or the set's
            objectives differ from the bundle's.
    """
    from amorctl.registry import load_plugin

    info = bundle.meta.get("objective_set")
    if not info or bundle.spec is None or bundle.motions is None:
        raise AmorError(f"{bundle.path}: the bundle records no objective set; rewards cannot be computed")
    spec = load_plugin(str(info["plugin"])).objective_set(str(info["name"]))
    if tuple(spec.objectives) != bundle.objectives:
        raise AmorError(
            f"{bundle.path}: installed objective set {spec.name!r} has objectives {list(spec.objectives)}, "
            f"the bundle {list(bundle.objectives)}"
        )
    objectives = spec.make(bundle.spec)
    return RewardMeter(objectives, bundle.motions, bundle.spec.num_joints, len(bundle.spec.end_effectors))
