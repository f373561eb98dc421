"""MJX physics of one control step: ``substeps`` MJX steps toward PD targets, as MuJoCo C steps them.

PD characters (humanoid36) drive MuJoCo position actuators (``kp``, ``kv``, ``forcerange``);
servo characters (biped20) get the servo model's torque (PD on the command delayed by
``latency_steps`` physics steps, torque–speed clip: :func:`amorctl.sim.actuators.servo_torque`
with ``xp = jax.numpy``) written to their motors in every substep, inside the jitted scan.

Two differences from MuJoCo C are corrected here (:func:`mjx_step`), both in the velocity
derivative the ``implicitfast`` integrator folds into the mass matrix:

- MuJoCo C's ``mjd_actuator_vel`` leaves out the velocity derivative (``kv``) of every actuator
  whose force is clamped by its ``forcerange``: a saturated actuator's force no longer depends on
  velocity. MJX's ``deriv_smooth_vel`` adds it for all actuators, so MJX over-damped humanoid36's
  saturated joints (0.03 rad qpos error after two control steps, docs/backends.md).
- torch-cpu's native servo is a MuJoCo ``dcmotor``, whose force MuJoCo C differentiates with
  respect to velocity (:func:`servo_velocity_derivative`): ``-kd`` in the PD range, the back-EMF
  slope ``-torque_limit / no_load_speed`` where the drive voltage is clamped (the torque–speed
  limit), none at the current limit. MJX runs the servo as motors whose ``ctrl`` is the torque
  (no derivative), so it integrated the servo's damping explicitly: at a step where a joint rode
  the torque–speed limit, biped20's joint velocity then parted from torch-cpu's by 1.6e-2 rad/s.

Everything else is MJX's own ``mjx.step``.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from mujoco.mjx._src import collision_driver, collision_primitive, math
from mujoco.mjx._src import forward as mjx_forward
from mujoco.mjx._src.types import BiasType, GeomType, IntegratorType

from amorctl.core.errors import AmorError
from amorctl.core.specs import CharacterSpec
from amorctl.sim.actuators import servo_torque
from amorctl.sim.batch_sim import build_model
from amorctl.sim.prepare import sensor_addresses


def _joint_actuator(model: mujoco.MjModel, joint: int, character: str) -> int:
    """The actuator driving ``joint``, preferring one named like it (as torch-cpu's BatchSim)."""
    drives = (model.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT) & (model.actuator_trnid[:, 0] == joint)
    hits = [int(a) for a in np.flatnonzero(drives)]
    same = [a for a in hits if model.actuator(a).name == model.joint(joint).name]
    if not hits:
        raise AmorError(f"character {character!r}: joint {model.joint(joint).name!r} has no actuator")
    return (same or hits)[0]


def servo_velocity_derivative(
    q_target: Any,
    q: Any,
    qd: Any,
    kp: Any,
    kd: Any,
    torque_limit: Any,
    no_load_speed: Any | None,
    xp: Any = np,
) -> Any:
    """d tau / d qd [N, J] of the servo as MuJoCo C differentiates its native ``dcmotor`` servo
    (:func:`amorctl.sim.actuators.native_servo`; arguments as
    :func:`~amorctl.sim.actuators.servo_torque`): ``-kd`` while the PD torque lies within the drive
    voltage's range ``[-torque_limit - b, torque_limit - b]`` (``b`` the back-EMF,
    :func:`~amorctl.sim.actuators.torque_bounds`), the back-EMF slope ``-torque_limit /
    no_load_speed`` where the voltage is clamped, and 0 where the torque sits at the current
    limit ``±torque_limit`` (the actuator's ``forcerange``: ``mjd_actuator_vel`` skips it)."""
    tau_pd = kp * (q_target - q) - kd * qd
    tau = servo_torque(q_target, q, qd, kp, kd, torque_limit, no_load_speed, xp=xp)
    slope = -kd + 0.0 * qd
    if no_load_speed is not None:
        back = torque_limit * qd / no_load_speed
        clamped = (tau_pd > torque_limit - back) | (tau_pd < -torque_limit - back)
        slope = xp.where(clamped, -torque_limit / no_load_speed + 0.0 * qd, slope)
    return xp.where(xp.abs(tau) >= torque_limit, 0.0, slope)


def mjx_step(m: Any, d: Any, servo_vel: jax.Array | None = None) -> Any:
    """One physics step of one env (``mjx.step``), with MuJoCo C's implicitfast actuator rule:
    actuators whose force sits at a ``forcerange`` bound contribute no ``kv`` to the implicit
    velocity derivative (``mjd_actuator_vel`` in MuJoCo's engine_derivative.c).

    ``servo_vel`` [nu]: d force / d velocity of the actuators that have no bias (the servo
    motors, whose force the caller computes; 0 for the others), added to the implicit
    derivative as MuJoCo C adds its native servo's (:func:`servo_velocity_derivative`)."""
    if m.opt.integrator != IntegratorType.IMPLICITFAST:
        return mjx.step(m, d)
    d = mjx.forward(m, d)
    force, lo, hi = d.actuator_force, m.actuator_forcerange[:, 0], m.actuator_forcerange[:, 1]
    live = ~(m.actuator_forcelimited & ((force <= lo) | (force >= hi)))
    scale = live.astype(m.actuator_biasprm.dtype)
    bias_kv = m.actuator_biasprm[:, 2] * scale
    biastype = m.actuator_biastype
    if servo_vel is not None:  # motors become affine in velocity for the derivative only
        free = np.asarray(biastype == BiasType.NONE)
        bias_kv = jnp.where(free, servo_vel * scale, bias_kv)
        biastype = np.where(free, BiasType.AFFINE, biastype)
    unclamped = m.replace(
        actuator_biasprm=m.actuator_biasprm.at[:, 2].set(bias_kv),
        actuator_biastype=biastype,
        actuator_gainprm=m.actuator_gainprm.at[:, 2].multiply(scale),
    )
    return mjx_forward.implicit(unclamped, d)


#: box corners in MuJoCo C's order (corner i: x, y, z signs from bits 0, 1, 2 of i)
_CORNERS = np.array([[(i & 1) * 2 - 1, (i & 2) - 1, (i & 4) / 2 - 1] for i in range(8)], np.float32)


@collision_primitive.collider(ncon=4)
def plane_box(plane: Any, box: Any) -> Any:
    """MuJoCo C's plane–box contacts (``mjc_PlaneBox``): every box corner on the plane's side of
    the box centre, the first four in corner order, at half the penetration. MJX's own collider
    (``plane_convex``) keeps only corners within 1 mm of the deepest, so a tilted foot touched the
    floor at fewer points than in MuJoCo C. Returns dist [4], pos [4, 3], frame [4, 3, 3];
    unused slots have dist 1 (beyond any margin: no contact)."""
    n = plane.mat[:, 2]
    centre = jnp.dot(box.pos - plane.pos, n)
    corners = (jnp.asarray(_CORNERS) * box.size) @ box.mat.T  # [8, 3] world offsets from the centre
    ldist = corners @ n
    below = ldist <= 0
    order = jnp.argsort(~below, stable=True)[:4]  # the first four corners below the centre
    dist = jnp.where(below[order], centre + ldist[order], 1.0)
    pos = box.pos + corners[order] - 0.5 * dist[:, None] * n
    frame = jnp.broadcast_to(math.make_frame(n), (4, 3, 3))
    return dist, pos, frame


def use_c_plane_box() -> None:
    """Make MJX collide planes with boxes as MuJoCo C does (:func:`plane_box`), process-wide.

    MJX looks its pair colliders up in ``collision_driver._COLLISION_FUNC`` when it traces a step;
    amorctl uses MJX only through this backend, so replacing the plane–box entry there changes
    nothing else. The ``mujoco-mjx`` pin (``<3.18``) keeps that private table as it was tested."""
    table = collision_driver._COLLISION_FUNC
    table[(GeomType.PLANE, GeomType.BOX)] = plane_box


class MjxPhysics:
    """One character's MJX model and its control step (PD targets -> ``substeps`` physics steps)."""

    def __init__(self, character: CharacterSpec) -> None:
        ch = character
        self.character = ch
        # servo characters: motors whose ctrl is the torque of the reference servo model below
        # (MJX has no dcmotor actuator or control history, which torch-cpu's native servo uses)
        model = build_model(ch, servo_model="python")
        self.substeps = ch.substeps
        self.servo = ch.actuator.kind == "servo"
        root = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, ch.root_body)
        free = int(model.body_jntadr[root])
        self.root_qpos, self.root_dof = int(model.jnt_qposadr[free]), int(model.jnt_dofadr[free])
        jids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in ch.joint_names()]
        if min(jids) < 0:
            raise AmorError(f"character {ch.name!r}: a joint of its spec is not in its MJCF")
        self.joint_qpos = jnp.asarray(model.jnt_qposadr[jids], jnp.int32)
        self.joint_dof = jnp.asarray(model.jnt_dofadr[jids], jnp.int32)
        acts = [_joint_actuator(model, int(j), ch.name) for j in jids]
        self.actuators = jnp.asarray(acts, jnp.int32)
        self.gear = jnp.asarray(model.actuator_gear[acts, 0], jnp.float32)
        self.num_joints, self.num_ee = len(jids), len(ch.end_effectors)
        # amorctl's sensors by name: a model's own sensors (an IMU) come first and shift them
        sensors = sensor_addresses(model, ch)
        self.ee_adr = jnp.asarray(sensors.ee, jnp.int32)  # [E, 10]: pos, quat, linvel
        self.torque_adr = jnp.asarray(sensors.torque, jnp.int32)  # [J] actuatorfrc (PD only)
        if self.servo:
            self.kp = jnp.asarray([j.kp for j in ch.joints], jnp.float32)
            self.kd = jnp.asarray([j.kd for j in ch.joints], jnp.float32)
            self.torque_limit = jnp.asarray([j.torque_limit for j in ch.joints], jnp.float32)
            self.no_load_speed = ch.actuator.no_load_speed
            self.latency = int(ch.actuator.latency_steps)
        else:
            self.latency = 0
        use_c_plane_box()
        self.set_model(model)

    def set_model(self, model: mujoco.MjModel) -> None:
        """Use ``model`` (the same character, e.g. with other options) from the next trace on."""
        self.model = model
        self.mx = mjx.put_model(model)
        self.template = mjx.make_data(self.mx)

    def control_step(
        self, data: Any, delay: jax.Array, head: jax.Array, target: jax.Array
    ) -> tuple[Any, jax.Array, jax.Array, tuple[jax.Array, jax.Array]]:
        """``substeps`` MJX steps of N envs toward PD targets [N, J].

        data: mjx.Data with leaves [N, ...]; delay [k + 1, N, J] pending servo commands and head []
        (the slot the next push writes; unused for PD characters). Returns (data, torque
        [N, S, J], sensor readings of the last substep [N, nsensordata], (delay, head)).
        """
        step = jax.vmap(mjx_step, in_axes=(None, 0))
        step_servo = jax.vmap(mjx_step, in_axes=(None, 0, 0))

        def sub(carry: tuple[Any, jax.Array, jax.Array], _: Any) -> tuple[Any, tuple[jax.Array, jax.Array]]:
            data, delay, head = carry
            if self.servo:
                delay = delay.at[head].set(target)
                head = (head + 1) % (self.latency + 1)
                cmd = delay[head]  # the command of `latency` physics steps ago
                q, qd = data.qpos[:, self.joint_qpos], data.qvel[:, self.joint_dof]
                tau = servo_torque(
                    cmd, q, qd, self.kp, self.kd, self.torque_limit, self.no_load_speed, xp=jnp
                )
                ctrl = data.ctrl.at[:, self.actuators].set(tau / self.gear)
                dtau = servo_velocity_derivative(
                    cmd, q, qd, self.kp, self.kd, self.torque_limit, self.no_load_speed, xp=jnp
                )
                vel = jnp.zeros_like(data.ctrl).at[:, self.actuators].set(dtau / self.gear**2)
                data = step_servo(self.mx, data.replace(ctrl=ctrl), vel)
            else:
                ctrl = data.ctrl.at[:, self.actuators].set(target)
                data = step(self.mx, data.replace(ctrl=ctrl))
                tau = data.sensordata[:, self.torque_adr] * self.gear
            return (data, delay, head), (tau, data.sensordata)

        (data, delay, head), (torque, sens) = jax.lax.scan(
            sub, (data, delay, head), None, length=self.substeps
        )
        return data, jnp.swapaxes(torque, 0, 1), sens[-1], (delay, head)
