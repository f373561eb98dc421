"""MJX physics of one control step: ``substeps`` MJX steps toward PD targets, as MuJoCo C steps them.

PD characters (humanoid36) drive MuJoCo position actuators (``kp``, ``kv``, ``forcerange``);
servo characters (biped20) get the servo model's torque (PD on the command delayed by
``latency_steps`` physics steps, torque–speed clip: :func:`amorctl.sim.actuators.servo_torque`
with ``xp = jax.numpy``) written to their motors in every substep, inside the jitted scan.

One semantic difference between MJX 3.17 and MuJoCo C is corrected here (:func:`mjx_step`):
with the ``implicitfast`` integrator, MuJoCo C's ``mjd_actuator_vel`` leaves out the velocity
derivative (``kv``) of every actuator whose force is clamped by its ``forcerange``: a saturated
actuator's force no longer depends on velocity. MJX's ``deriv_smooth_vel`` adds it for all
actuators, so MJX over-damped humanoid36's saturated joints (0.03 rad qpos error after two
control steps, docs/backends.md). Everything else is MJX's own ``mjx.step``.
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
from mujoco.mjx._src.types import GeomType, IntegratorType

from amorctl.core.errors import AmorError
from amorctl.core.specs import CharacterSpec
from amorctl.sim.actuators import servo_torque
from amorctl.sim.batch_sim import build_model


def _joint_actuator(model: mujoco.MjModel, joint: int, character: str) -> int:
    """The actuator driving ``joint``, preferring one named like it (as torch-cpu's BatchSim)."""
    drives = (model.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT) & (model.actuator_trnid[:, 0] == joint)
    hits = [int(a) for a in np.flatnonzero(drives)]
    same = [a for a in hits if model.actuator(a).name == model.joint(joint).name]
    if not hits:
        raise AmorError(f"character {character!r}: joint {model.joint(joint).name!r} has no actuator")
    return (same or hits)[0]


def mjx_step(m: Any, d: Any) -> Any:
    """One physics step of one env (``mjx.step``), with MuJoCo C's implicitfast actuator rule:
    actuators whose force sits at a ``forcerange`` bound contribute no ``kv`` to the implicit
    velocity derivative (``mjd_actuator_vel`` in MuJoCo's engine_derivative.c)."""
    if m.opt.integrator != IntegratorType.IMPLICITFAST:
        return mjx.step(m, d)
    d = mjx.forward(m, d)
    force, lo, hi = d.actuator_force, m.actuator_forcerange[:, 0], m.actuator_forcerange[:, 1]
    live = ~(m.actuator_forcelimited & ((force <= lo) | (force >= hi)))
    scale = live.astype(m.actuator_biasprm.dtype)
    unclamped = m.replace(
        actuator_biasprm=m.actuator_biasprm.at[:, 2].multiply(scale),
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
        jn = self.num_joints

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
                data = step(self.mx, data.replace(ctrl=ctrl))
            else:
                ctrl = data.ctrl.at[:, self.actuators].set(target)
                data = step(self.mx, data.replace(ctrl=ctrl))
                nsens = self.num_ee * 10  # actuatorfrc sensors follow the end effectors' 10 each
                tau = data.sensordata[:, nsens : nsens + jn] * self.gear
            return (data, delay, head), (tau, data.sensordata)

        (data, delay, head), (torque, sens) = jax.lax.scan(
            sub, (data, delay, head), None, length=self.substeps
        )
        return data, jnp.swapaxes(torque, 0, 1), sens[-1], (delay, head)
