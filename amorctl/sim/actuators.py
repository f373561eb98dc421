"""Servo actuator model applied every physics substep, vectorized over envs.

MuJoCo expresses armature, Coulomb friction (``frictionloss``) and viscous friction (``damping``)
natively; what it cannot express is a PD servo whose torque is limited by a torque–speed curve
and that acts on a delayed command. That part lives here, as pure functions over arrays so the
batched simulators reuse it (``ActuatorModel(kind="servo")``, see ``amorctl/core/specs.py``).

Shapes: N envs, J actuated joints. Per-joint parameters (``kp``, ``kd``, ``torque_limit``,
``no_load_speed``) may be scalars or arrays of shape ``[J]``; they broadcast against ``[N, J]``.
Like the objective kernels, the functions take the array namespace ``xp`` (numpy by default;
``jax.numpy`` runs the same code).

Per physics step ``t`` of a batched simulation::

    delay = CommandDelay(latency_steps, num_envs, num_joints, initial=standing_targets)
    for t in range(substeps):
        target = delay.push(policy_targets)          # the command issued at step t - k
        ctrl = servo_torque(target, q, qd, kp, kd, torque_limit, no_load_speed)
        data.ctrl[:] = ctrl; mujoco.mj_step(model, data)
"""

from __future__ import annotations

from typing import Any

import numpy as np


def available_torque(qd: Any, torque_limit: Any, no_load_speed: Any | None, xp: Any = np) -> Any:
    """Largest torque magnitude the servo can give at joint speed ``qd``.

    Linear torque–speed curve: ``torque_limit * max(0, 1 - |qd| / no_load_speed)``; with
    ``no_load_speed=None`` the limit does not depend on speed.

    Args:
        qd: joint velocities, rad/s, ``[N, J]``.
        torque_limit: stall torque, N·m, scalar or ``[J]``.
        no_load_speed: speed at which the torque reaches zero, rad/s, scalar or ``[J]``, or None.

    Returns:
        ``[N, J]`` non-negative torque bounds, N·m.
    """
    if no_load_speed is None:
        return torque_limit + 0.0 * qd
    return torque_limit * xp.maximum(0.0, 1.0 - xp.abs(qd) / no_load_speed)


def servo_torque(
    q_target: Any,
    q: Any,
    qd: Any,
    kp: Any,
    kd: Any,
    torque_limit: Any,
    no_load_speed: Any | None,
    xp: Any = np,
) -> Any:
    """PD torque of a position servo, clipped by its torque–speed curve.

    ``tau = clip(kp (q_target - q) - kd qd, -a, a)`` with ``a = available_torque(qd, ...)``.

    Args:
        q_target: commanded joint positions, rad, ``[N, J]`` (already delayed, see CommandDelay).
        q: joint positions, rad, ``[N, J]``.
        qd: joint velocities, rad/s, ``[N, J]``.
        kp: stiffness, N·m/rad, scalar or ``[J]``.
        kd: damping, N·m·s/rad, scalar or ``[J]``.
        torque_limit: stall torque, N·m, scalar or ``[J]``.
        no_load_speed: rad/s, scalar or ``[J]``, or None for no speed dependence.

    Returns:
        joint torques, N·m, ``[N, J]`` (the ``ctrl`` of MuJoCo motor actuators with gear 1).
    """
    tau = kp * (q_target - q) - kd * qd
    bound = available_torque(qd, torque_limit, no_load_speed, xp=xp)
    return xp.minimum(xp.maximum(tau, -bound), bound)


class CommandDelay:
    """Delay commands by ``k`` physics steps: ``push`` at step t returns the command of step t-k.

    A ring buffer of shape ``[k + 1, N, J]``. Before k commands have been pushed, ``push`` returns
    the initial value (set at construction and by :meth:`reset`). ``k = 0`` returns its input.
    Numpy only: the jax backend keeps the same buffer as part of its state.
    """

    def __init__(self, k: int, num_envs: int, num_joints: int, initial: Any = 0.0) -> None:
        """
        Args:
            k: latency in physics steps, >= 0.
            num_envs: N.
            num_joints: J.
            initial: value the delayed command holds until real commands arrive: scalar, ``[J]``
                or ``[N, J]``.
        """
        if k < 0:
            raise ValueError(f"latency must be >= 0 physics steps, got {k}")
        self.k = k
        self.buffer = np.empty((k + 1, num_envs, num_joints), dtype=np.float64)
        self.buffer[:] = initial
        self._head = 0  # slot the next push writes

    def push(self, cmd: Any) -> np.ndarray:
        """Store this step's command ``[N, J]``; return the one issued ``k`` steps ago ``[N, J]``."""
        self.buffer[self._head] = cmd
        self._head = (self._head + 1) % (self.k + 1)
        # After the increment, the head is the oldest slot: written k pushes ago (or initial).
        return self.buffer[self._head].copy()

    def reset(self, env_mask: Any, value: Any = 0.0) -> None:
        """Forget the pending commands of the envs where ``env_mask`` (``[N]`` bool) is true.

        Args:
            env_mask: ``[N]`` bool, the envs being reset.
            value: what their delayed command holds until new commands arrive: scalar, ``[J]``, or
                ``[M, J]`` for the M selected envs.
        """
        mask = np.asarray(env_mask, dtype=bool)
        self.buffer[:, mask] = value

    def snapshot(self) -> dict[str, np.ndarray]:
        """The pending commands as arrays (for checkpoints): ``buffer`` ``[k + 1, N, J]`` float64
        and ``head`` ``[1]`` int64, the slot the next :meth:`push` writes. Copies."""
        return {"buffer": self.buffer.copy(), "head": np.array([self._head], dtype=np.int64)}

    def restore(self, arrays: dict[str, np.ndarray]) -> None:
        """Restore :meth:`snapshot`: the next :meth:`push` returns what it would have then.

        Raises:
            ValueError: the buffer's shape differs (another latency, env or joint count) or the
                head is out of range.
        """
        buffer = np.asarray(arrays["buffer"])
        head = int(np.asarray(arrays["head"]).reshape(-1)[0])
        if buffer.shape != self.buffer.shape:
            raise ValueError(f"command delay buffer has shape {buffer.shape}, expected {self.buffer.shape}")
        if not 0 <= head <= self.k:
            raise ValueError(f"command delay head {head} out of range [0, {self.k}]")
        self.buffer[:] = buffer
        self._head = head
