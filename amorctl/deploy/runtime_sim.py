"""The simulated robot of the sim2sim runtime: one MuJoCo ``MjData`` stepped at the physics rate.

It reproduces what training simulated (:class:`amorctl.sim.batch_sim.BatchSim`) for one env with
a plain ``mj_step`` loop, the way a robot-side simulator would: the same compiled model and
sensors (:func:`~amorctl.sim.batch_sim.build_model`), the same actuator model (PD characters:
MuJoCo position actuators holding the target for all substeps; servo characters: training's
reference servo path, :func:`~amorctl.sim.actuators.servo_torque` on the command delayed by
:class:`~amorctl.sim.actuators.CommandDelay`, computed every physics step, as a motor driver
would; it agrees with training's native MuJoCo servo within the 1e-5 rad the tests state),
amorctl's sensors looked up by name (a model's own sensors stay where they are), the same solver
warm start between calls, the same end-effector readings (sensors of the last substep), so with
nominal dynamics it follows ``amorctl tune``'s trajectory. The joint torques of every substep are
kept (``torque`` [S, J]) for the ``smooth`` objective. Per episode it applies a
:class:`~amorctl.deploy.randomize.Sample` to a copy of the model (friction, link masses and
centres of mass, armature, PD gains, motor strength) and applies pushes (a horizontal force on
the root body for a number of physics steps, through ``xfrc_applied``).

Imports only numpy, mujoco and torch-free amorctl modules. Shapes: J actuated joints, E end
effectors, D frame length, nq/nv MuJoCo sizes.
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np

from amorctl.core.frame_layout import frame_features
from amorctl.core.geometry import quat_conj, quat_rotate
from amorctl.core.specs import CharacterSpec
from amorctl.deploy.bundle import Motions
from amorctl.deploy.randomize import Sample
from amorctl.sim.actuators import CommandDelay, servo_torque
from amorctl.sim.batch_sim import MAX_QVEL, _joint_actuator, build_model
from amorctl.sim.prepare import sensor_addresses

#: damping added while the watchdog holds a pose, as a fraction of each joint's kp (seconds).
HOLD_DAMPING = 0.1


class CharacterSim:
    """One character in MuJoCo, reset from reference frames, stepped one control step at a time.

    Args:
        spec: the character (from the bundle metadata and the installed MJCF).
        motions: the reference clips (reference-state initialization).
    """

    def __init__(self, spec: CharacterSpec, motions: Motions) -> None:
        self.spec = spec
        self.motions = motions
        # servo characters: the numpy servo between single physics steps (training's reference
        # servo path), so the randomized gains, strength and hold damping apply per step
        self.base_model = build_model(spec, "python")
        m = self.base_model
        root = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, spec.root_body)
        free = int(m.body_jntadr[root])
        self.root_qpos, self.root_dof = int(m.jnt_qposadr[free]), int(m.jnt_dofadr[free])
        jids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in spec.joint_names()]
        self.joint_qpos = m.jnt_qposadr[jids].astype(np.int64)
        self.joint_dof = m.jnt_dofadr[jids].astype(np.int64)
        # as training finds them: the actuator driving each joint, amorctl's sensors by name (a
        # model with its own sensors, e.g. IMUs, keeps them at their own addresses)
        self.actuators = np.array([_joint_actuator(m, int(j)) for j in jids])
        self.sensors = sensor_addresses(m, spec)
        self.gear = m.actuator_gear[self.actuators, 0].copy()
        self.servo = spec.actuator.kind == "servo"
        self.substeps = spec.substeps
        self.num_joints, self.num_ee = len(jids), len(spec.end_effectors)
        self.joint_low = np.array([j.range[0] for j in spec.joints])
        self.joint_high = np.array([j.range[1] for j in spec.joints])
        self.model = m
        self.data = mujoco.MjData(m)
        self.root_body = int(root)
        self.push_force = np.zeros(2)
        self.push_steps = 0
        #: [S, J] joint torques of every physics substep of the last control step, N·m
        self.torque = np.zeros((self.substeps, self.num_joints))

    # --- episodes ---------------------------------------------------------------------------

    def reset(self, frame: int, sample: Sample) -> None:
        """Start an episode in the reference state of library ``frame`` with dynamics ``sample``."""
        m = copy.deepcopy(self.base_model)
        s = sample
        m.geom_friction[:, 0] *= s.friction_scale
        m.body_mass[1:] *= s.mass_scale[1:]
        m.body_inertia[1:] *= s.mass_scale[1:, None]
        m.body_ipos[1:] += s.com_offset[1:]
        m.dof_armature[self.joint_dof] *= s.armature_scale
        spec = self.spec
        self.kp = np.array([j.kp for j in spec.joints]) * s.kp_scale
        self.kd = np.array([j.kd for j in spec.joints]) * s.kd_scale
        self.torque_limit = np.array([j.torque_limit for j in spec.joints]) * s.strength_scale
        if not self.servo:  # MuJoCo position actuators carry the gains and the force range
            a = self.actuators
            m.actuator_gainprm[a, 0] *= s.kp_scale
            m.actuator_biasprm[a, 1] *= s.kp_scale
            m.actuator_biasprm[a, 2] *= s.kd_scale
            m.actuator_forcerange[a] *= s.strength_scale[:, None]
        self.model = m
        self.data = d = mujoco.MjData(m)
        mot = self.motions
        mujoco.mj_resetData(m, d)
        q0, v0 = self.root_qpos, self.root_dof
        quat = mot.root_quat[frame] / np.linalg.norm(mot.root_quat[frame])
        d.qpos[q0 : q0 + 3] = mot.root_pos[frame]
        d.qpos[q0 + 3 : q0 + 7] = quat
        d.qvel[v0 : v0 + 3] = mot.root_lin_vel[frame]
        d.qvel[v0 + 3 : v0 + 6] = quat_rotate(quat_conj(mot.root_quat[frame]), mot.root_ang_vel[frame])
        d.qpos[self.joint_qpos] = mot.joint_pos[frame]
        d.qvel[self.joint_dof] = mot.joint_vel[frame]
        self.warmstart = np.zeros(m.nv)
        self.torque = np.zeros((self.substeps, self.num_joints))
        self.push_steps = 0
        self.ee_pos = mot.ee_pos[frame].copy()
        self.ee_quat = mot.ee_quat[frame].copy()
        self.ee_lin_vel = mot.ee_lin_vel[frame].copy()
        if self.servo:
            self.delay = CommandDelay(
                spec.actuator.latency_steps, 1, self.num_joints, initial=mot.joint_pos[frame]
            )
            self.no_load_speed = spec.actuator.no_load_speed

    # --- stepping ---------------------------------------------------------------------------

    def step(self, pd_target: np.ndarray, hold: bool = False) -> bool:
        """One control step toward PD targets [J] (rad); ``hold`` adds watchdog damping.
        Returns True if the simulation diverged."""
        m, d = self.model, self.data
        dt = m.opt.timestep
        time0 = d.time
        extra_kd = HOLD_DAMPING * self.kp if hold else 0.0
        target = np.asarray(pd_target, dtype=np.float64)[None]
        if not self.servo:
            a = self.actuators
            if hold:
                m.actuator_biasprm[a, 2] -= extra_kd
            d.ctrl[a] = target[0]
            d.qacc_warmstart[:] = self.warmstart
            for sub in range(self.substeps):
                if sub == self.substeps - 1:
                    qv_prev = d.qvel.copy()
                self._apply_push()
                mujoco.mj_step(m, d)
                self.torque[sub] = d.sensordata[self.sensors.torque] * self.gear
            if hold:
                m.actuator_biasprm[a, 2] += extra_kd
            self.warmstart = (d.qvel - qv_prev) / dt
        else:
            for sub in range(self.substeps):
                delayed = self.delay.push(target)
                q, qd = d.qpos[self.joint_qpos][None], d.qvel[self.joint_dof][None]
                tau = servo_torque(
                    delayed, q, qd, self.kp, self.kd + extra_kd, self.torque_limit, self.no_load_speed
                )
                self.torque[sub] = tau[0]
                d.ctrl[self.actuators] = tau[0] / self.gear
                qv_prev = d.qvel.copy()
                d.qacc_warmstart[:] = self.warmstart
                self._apply_push()
                mujoco.mj_step(m, d)
                self.warmstart = (d.qvel - qv_prev) / dt
        sens = d.sensordata[self.sensors.ee]  # [E, 10]
        self.ee_pos, self.ee_quat, self.ee_lin_vel = (
            sens[:, 0:3].copy(),
            sens[:, 3:7].copy(),
            sens[:, 7:10].copy(),
        )
        finite = np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all() and np.isfinite(sens).all()
        diverged = not finite or bool((np.abs(d.qvel) > MAX_QVEL).any())
        diverged |= abs(d.time - (time0 + self.substeps * dt)) > 0.5 * dt
        if not np.isfinite(self.warmstart).all():
            self.warmstart[:] = 0.0
        return bool(diverged)

    def push(self, force_xy: np.ndarray, seconds: float) -> None:
        """Push the root body with a horizontal force [2] N for ``seconds`` (whole physics steps,
        at least one), starting with the next physics step."""
        self.push_force = np.asarray(force_xy, dtype=np.float64)
        self.push_steps = max(1, round(seconds / self.model.opt.timestep))

    def _apply_push(self) -> None:
        """Set this physics step's external force on the root body (zero when no push is on)."""
        xfrc = self.data.xfrc_applied[self.root_body]
        if self.push_steps > 0:
            xfrc[:2] = self.push_force
            self.push_steps -= 1
        else:
            xfrc[:2] = 0.0

    # --- state ------------------------------------------------------------------------------

    @property
    def qpos(self) -> np.ndarray:
        return self.data.qpos.copy()

    def joint_pos(self) -> np.ndarray:
        """[J] rad."""
        return self.data.qpos[self.joint_qpos].copy()

    def joint_vel(self) -> np.ndarray:
        """[J] rad/s."""
        return self.data.qvel[self.joint_dof].copy()

    def root_height(self) -> float:
        return float(self.data.qpos[self.root_qpos + 2])

    def frame(self) -> np.ndarray:
        """[D] the simulated state as a heading-frame frame vector (the observation's proprio)."""
        d, q0, v0 = self.data, self.root_qpos, self.root_dof
        quat = d.qpos[q0 + 3 : q0 + 7][None]
        return frame_features(
            d.qpos[q0 : q0 + 3][None],
            quat,
            d.qvel[v0 : v0 + 3][None],
            quat_rotate(quat, d.qvel[v0 + 3 : v0 + 6][None]),
            d.qpos[self.joint_qpos][None],
            d.qvel[self.joint_dof][None],
            self.ee_pos[None],
            self.ee_quat[None],
            self.ee_lin_vel[None],
        )[0]
