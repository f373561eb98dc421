"""Servo actuator model: a PD position loop driving a DC motor, on a delayed command.

MuJoCo expresses armature, Coulomb friction (``frictionloss``) and viscous friction (``damping``)
as joint properties. The servo on top (``ActuatorModel(kind="servo")``, see
``amorctl/core/specs.py``) is a PD law on a command delayed by ``latency_steps`` physics steps,
whose torque is limited by the DC motor's torque–speed range (:func:`torque_bounds`). Two
implementations, which agree to rounding under MuJoCo's Euler integrator
(``tests/test_actuators.py``, ``tests/test_env.py``). Under ``implicitfast`` MuJoCo also puts the
native servo's velocity derivative (−kd in the PD range, the back-EMF slope while the voltage
clamp binds) into the implicit step, which the reference applies explicitly: up to 1e-3 rad of
``qpos`` apart after a saturating control step (docs/environment.md; jax-mjx adds the same
derivative, ``jax_mjx/physics.py``):

- **native** (:func:`native_servo`, what :class:`~amorctl.sim.batch_sim.BatchSim` runs): each joint
  actuator becomes a MuJoCo ``dcmotor`` with a position controller (``input="pos"``), a clamp on its
  drive voltage, a torque saturation, and a ``delay`` read from MuJoCo's control history buffer.
  MuJoCo computes it inside ``mj_step``: one rollout call per control step, no Python per substep.
- **reference** (the functions below, pure over arrays ``[N, J]``, vectorized over envs; the array
  namespace ``xp`` is numpy by default, ``jax.numpy`` runs the same code): used by the jax backend,
  the deploy runtime and the tests. Per physics step ``t``::

    delay = CommandDelay(latency_steps, num_envs, num_joints, initial=standing_targets)
    for t in range(substeps):
        target = delay.push(policy_targets)          # the command issued at step t - k
        ctrl = servo_torque(target, q, qd, kp, kd, torque_limit, no_load_speed)
        data.ctrl[:] = ctrl; mujoco.mj_step(model, data)

Shapes: N envs, J actuated joints. Per-joint parameters (``kp``, ``kd``, ``torque_limit``,
``no_load_speed``) may be scalars or arrays of shape ``[J]``; they broadcast against ``[N, J]``.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from amorctl.core.specs import CharacterSpec
from amorctl.sim.prepare import joint_actuators, torque_sensor_name

#: Drive voltage of the native dcmotor, V. Any positive value gives the same torques (only the
#: stall torque and the no-load speed enter the servo law); 12 V is the XM430's nominal supply.
SUPPLY_VOLTAGE = 12.0


def torque_bounds(qd: Any, torque_limit: Any, no_load_speed: Any | None, xp: Any = np) -> tuple[Any, Any]:
    """Torque range of a DC servo at joint speed ``qd``: ``(low, high)``, each ``[N, J]``.

    A DC motor on a limited supply voltage loses torque to back-EMF in proportion to its speed:
    the voltage limit allows ``[-torque_limit - b, torque_limit - b]`` with
    ``b = torque_limit * qd / no_load_speed`` (full stall torque at rest, none when driving at the
    no-load speed, more than stall torque's worth of voltage when braking), and the driver's
    current limit caps ``|tau|`` at ``torque_limit``. This is MuJoCo's ``dcmotor`` actuator with a
    voltage-clamped controller and a torque saturation (see :func:`native_servo`), so the two agree.
    With ``no_load_speed=None`` only the current limit applies.

    Args:
        qd: joint velocities, rad/s, ``[N, J]``.
        torque_limit: stall torque, N·m, scalar or ``[J]``.
        no_load_speed: speed at which the driving torque reaches zero, rad/s, scalar or ``[J]``, or None.
    """
    if no_load_speed is None:
        return -torque_limit + 0.0 * qd, torque_limit + 0.0 * qd
    back = torque_limit * qd / no_load_speed  # back-EMF, in units of torque
    high = xp.minimum(torque_limit, torque_limit - back)
    low = xp.maximum(-torque_limit, -torque_limit - back)
    return xp.minimum(low, torque_limit), xp.maximum(high, -torque_limit)


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
    """PD torque of a position servo, clipped to its DC motor's range (:func:`torque_bounds`).

    ``tau = clip(kp (q_target - q) - kd qd, low, high)``: driving (``tau`` along ``qd``) is limited
    to ``torque_limit (1 - |qd| / no_load_speed)``, braking to ``torque_limit``; past the no-load
    speed the motor brakes even when asked to drive.

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
    low, high = torque_bounds(qd, torque_limit, no_load_speed, xp=xp)
    return xp.minimum(xp.maximum(tau, low), high)


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


def native_servo(spec: mujoco.MjSpec, character: CharacterSpec) -> None:
    """Make the servo character's joint actuators compute the servo law inside MuJoCo, in place.

    Each actuated joint's actuator (as :func:`amorctl.sim.prepare.prepare_spec` left it: a motor)
    becomes a ``dcmotor`` with gear 1 whose ``ctrl`` is the joint's PD target (rad):
    controller ``kp``/``kd`` in torque space, drive voltage clamped at :data:`SUPPLY_VOLTAGE`, motor
    constant ``K = V / no_load_speed`` and resistance ``R = K V / torque_limit`` (so the voltage
    clamp gives :func:`torque_bounds`' speed-dependent range) and torque saturation
    ``torque_limit``. The command delay is MuJoCo's: a history of ``latency_steps`` samples read
    ``latency_steps`` physics steps back (zero-order hold), part of the physics state. Adds one
    ``actuatorfrc`` sensor per joint, named :func:`~amorctl.sim.prepare.torque_sensor_name`.
    Call it after ``prepare_spec`` and before compiling; the model's timestep must then be
    ``1 / character.physics_hz``.
    """
    act_model = character.actuator
    acts = joint_actuators(spec, character, character.mjcf_path)
    dt = 1.0 / character.physics_hz
    pos_input = int(mujoco.mjtCtrlInput.mjINPUT_POS)
    for joint in character.joints:
        act = acts[joint.name]
        act.gear = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        limit = float(joint.torque_limit)
        if act_model.no_load_speed is None:  # no voltage clamp: any K, R deliver the PD torque
            k, r, vmax = 1.0, 1.0, 0.0
        else:
            vmax = SUPPLY_VOLTAGE
            k = vmax / float(act_model.no_load_speed)
            r = k * vmax / limit
        act.set_to_dcmotor(
            motorconst=[k, k],
            resistance=r,
            saturation=[limit, 0.0, 0.0],
            controller=[float(joint.kp), 0.0, float(joint.kd), 0.0, 0.0, vmax],
            ctrlspec=pos_input,
        )
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        if act_model.latency_steps > 0:
            act.nsample = act_model.latency_steps
            act.delay = act_model.latency_steps * dt
            act.interp = 0  # zero-order hold: the command of exactly k steps ago
        sensor = spec.add_sensor()
        sensor.name = torque_sensor_name(joint.name)
        sensor.type = mujoco.mjtSensor.mjSENS_ACTUATORFRC
        sensor.objtype = mujoco.mjtObj.mjOBJ_ACTUATOR
        sensor.objname = act.name
