"""N copies of a character simulated together by MuJoCo's C thread pool (``mujoco.rollout``).

One :class:`BatchSim` owns the batch state ``[N, nstate]`` (MuJoCo's ``mjSTATE_FULLPHYSICS``),
a per-env solver warm start ``[N, nv]`` and one reused :class:`mujoco.rollout.Rollout` pool. A
control step is one ``rollout`` call of ``substeps`` physics steps: MuJoCo's actuators hold the
control step's target through the substeps, PD characters with ``position`` actuators, servo
characters with the native servo (``dcmotor`` actuators on a delayed command,
:func:`amorctl.sim.actuators.native_servo`; the delay's history is part of the state). The
reference servo path (``servo_model="python"``) instead runs ``substeps`` calls of one physics
step and computes the motor torques between them in numpy (``servo_torque`` on the command
delayed by ``CommandDelay``); it is kept to check the native one and to measure its gain. Why the
rollout pool and not per-env ``MjData`` on Python threads: docs/environment.md.
:meth:`BatchSim.snapshot` / :meth:`BatchSim.restore` save and restore all of it as plain arrays
(checkpoints).

Body poses come from frame sensors added to the model at load time (``framepos``,
``framequat``, ``framelinvel`` on each end effector's body frame), joint torques from
``actuatorfrc`` sensors. MuJoCo computes sensors at the start of a physics step, so the
end-effector readings of a control step describe the state one physics substep (4 ms at 250 Hz)
before the final ``qpos``/``qvel``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import mujoco
import mujoco.rollout
import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.geometry import quat_conj, quat_rotate
from amorctl.core.specs import CharacterSpec
from amorctl.sim.actuators import CommandDelay, native_servo, servo_torque
from amorctl.sim.cpus import available_cpus
from amorctl.sim.model import load_model
from amorctl.sim.prepare import sensor_addresses, torque_sensor_name

STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS
CTRL_SPEC = mujoco.mjtState.mjSTATE_CTRL

#: |q̇| above this (rad/s or m/s) counts as a diverged simulation.
MAX_QVEL = 1.0e3

ServoModel = Literal["native", "python"]


def build_model(character: CharacterSpec, servo_model: ServoModel = "native") -> mujoco.MjModel:
    """The character's model, compiled by :func:`amorctl.sim.model.load_model` with the sensors the
    tracking env reads (:func:`amorctl.sim.prepare.add_tracking_sensors`; found by name with
    :func:`~amorctl.sim.prepare.sensor_addresses`). The timestep is ``1 / physics_hz``. Servo
    characters get the native servo actuators (:func:`amorctl.sim.actuators.native_servo`) unless
    ``servo_model="python"`` (motors whose ``ctrl`` is the torque).

    Raises:
        AmorError: the file is missing, a named body or actuator does not exist, or MuJoCo rejects it.
    """
    native = character.actuator.kind == "servo" and servo_model == "native"
    return load_model(character, tracking_sensors=True, edit=native_servo if native else None)


def _history_columns(model: mujoco.MjModel, actuators: np.ndarray, nstate: int) -> np.ndarray:
    """``[J, k]`` columns of the state vector holding each actuator's ``k`` delayed commands.

    Found by writing markers with ``mj_initCtrlHistory`` and reading the state back, so nothing
    depends on how MuJoCo lays the history buffer out.
    """
    data = mujoco.MjData(model)
    mujoco.mj_resetData(model, data)
    k = int(model.actuator_history[actuators[0], 0])
    markers = 1.0e6 + np.arange(len(actuators) * k, dtype=np.float64).reshape(len(actuators), k)
    for a, values in zip(actuators, markers, strict=True):
        mujoco.mj_initCtrlHistory(model, data, int(a), None, values)
    state = np.empty(nstate)
    mujoco.mj_getState(model, data, state, STATE_SPEC)
    cols = np.array([[int(np.flatnonzero(state == v)[0]) for v in row] for row in markers])
    return cols


def _id(model: mujoco.MjModel, obj: mujoco.mjtObj, name: str, what: str, character: str) -> int:
    i = mujoco.mj_name2id(model, obj, name)
    if i < 0:
        raise AmorError(f"character {character!r}: {what} {name!r} not found in its MJCF")
    return int(i)


def _joint_actuator(model: mujoco.MjModel, joint: int) -> int:
    """The actuator driving ``joint``, preferring one named like it (as prepare_spec chose)."""
    drives = (model.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT) & (model.actuator_trnid[:, 0] == joint)
    hits = [int(a) for a in np.flatnonzero(drives)]
    same = [a for a in hits if model.actuator(a).name == model.joint(joint).name]
    return (same or hits)[0]


def _check_array(arrays: dict[str, np.ndarray], name: str, shape: tuple[int, ...]) -> np.ndarray:
    """``arrays[name]``, checked to have ``shape``; AmorError naming it otherwise."""
    if name not in arrays:
        raise AmorError(f"simulation snapshot has no array {name!r}")
    value = np.asarray(arrays[name])
    if value.shape != tuple(shape):
        raise AmorError(
            f"simulation snapshot array {name!r} has shape {value.shape}, expected {tuple(shape)}"
        )
    return value


@dataclass(frozen=True)
class StepOutput:
    """What one control step of the batch produced.

    torque [N, S, J] joint torques of every substep; ee_pos [N, E, 3], ee_quat [N, E, 4],
    ee_lin_vel [N, E, 3] world-frame end-effector state (sensor readings of the last substep);
    diverged [N] bool: the env's simulation blew up (non-finite or huge state, or MuJoCo reset it).
    """

    torque: np.ndarray
    ee_pos: np.ndarray
    ee_quat: np.ndarray
    ee_lin_vel: np.ndarray
    diverged: np.ndarray


class BatchSim:
    """N environments of one character, stepped in parallel by a reused MuJoCo rollout pool.

    Args:
        character: the character to simulate.
        num_envs: N.
        nthread: threads of the rollout pool (default: the cores this process may use).
        servo_model: servo characters only: ``"native"`` (MuJoCo computes the servo inside its
            step) or ``"python"`` (the numpy reference between single physics steps).
    """

    def __init__(
        self,
        character: CharacterSpec,
        num_envs: int,
        nthread: int | None = None,
        servo_model: ServoModel = "native",
    ) -> None:
        if num_envs < 1:
            raise AmorError(f"num_envs must be >= 1, got {num_envs}")
        if servo_model not in ("native", "python"):
            raise AmorError(f"servo_model must be 'native' or 'python', got {servo_model!r}")
        self.character = character
        self.num_envs = n = int(num_envs)
        self.nthread = int(nthread) if nthread else available_cpus()
        self.model = m = build_model(character, servo_model)
        self.substeps = character.substeps
        self.dt = float(m.opt.timestep)
        name = character.name
        root = _id(m, mujoco.mjtObj.mjOBJ_BODY, character.root_body, "root body", name)
        if m.body_jntnum[root] < 1 or m.jnt_type[m.body_jntadr[root]] != mujoco.mjtJoint.mjJNT_FREE:
            raise AmorError(f"character {name!r}: root body {character.root_body!r} has no free joint")
        free = int(m.body_jntadr[root])
        self.root_qpos = int(m.jnt_qposadr[free])
        self.root_dof = int(m.jnt_dofadr[free])
        jids = [_id(m, mujoco.mjtObj.mjOBJ_JOINT, j, "joint", name) for j in character.joint_names()]
        self.joint_qpos = m.jnt_qposadr[jids].astype(np.int64)
        self.joint_dof = m.jnt_dofadr[jids].astype(np.int64)
        self.actuators = np.array([_joint_actuator(m, int(j)) for j in jids])
        self.sensors = sensor_addresses(m, character)
        self.gear = m.actuator_gear[self.actuators, 0].copy()
        self.num_joints = len(jids)
        self.num_ee = len(character.end_effectors)
        self.servo = character.actuator.kind == "servo"
        #: numpy servo between single physics steps (the reference); False: all inside MuJoCo
        self.python_servo = self.servo and servo_model == "python"

        # State layout of mjSTATE_FULLPHYSICS: time, qpos, qvel, then act/history/plugin/plastic.
        self.nstate = mujoco.mj_stateSize(m, STATE_SPEC)
        self.s_time = 0
        self.s_qpos = slice(1, 1 + m.nq)
        self.s_qvel = slice(1 + m.nq, 1 + m.nq + m.nv)
        data = mujoco.MjData(m)
        mujoco.mj_resetData(m, data)
        self.template = np.empty(self.nstate)
        mujoco.mj_getState(m, data, self.template, STATE_SPEC)
        self.state = np.tile(self.template, (n, 1))
        self.warmstart = np.zeros((n, m.nv))
        steps = 1 if self.python_servo else self.substeps
        self.ctrl = np.zeros((n, steps, m.nu))
        self._out_state = np.empty((n, steps, self.nstate))
        self._out_sens = np.empty((n, steps, m.nsensordata))
        self._models = [m] * n
        self._datas = [mujoco.MjData(m) for _ in range(self.nthread)]
        self._pool = mujoco.rollout.Rollout(nthread=self.nthread)
        # Small chunks balance the load when a core is shared with other processes; the
        # per-chunk cost is negligible next to substeps x mj_step.
        self._chunk = max(1, min(8, n // (self.nthread * 16)))
        self.torque = np.zeros((n, self.substeps, self.num_joints))

        # Joint torques: actuatorfrc sensors (PD and native servo); the python servo records its own.
        self.torque_adr = self.sensors.torque
        self.history_cols = np.zeros((self.num_joints, 0), dtype=np.int64)
        if self.servo and not self.python_servo:
            ids = [
                mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, torque_sensor_name(j))
                for j in character.joint_names()
            ]
            self.torque_adr = m.sensor_adr[ids].astype(np.int64)
            if character.actuator.latency_steps > 0:  # pending commands live in the state
                self.history_cols = _history_columns(m, self.actuators, self.nstate)
        if self.servo:  # [J] servo parameters (the python servo's inputs; informative otherwise)
            joints = character.joints
            self.kp = np.array([j.kp for j in joints])
            self.kd = np.array([j.kd for j in joints])
            self.torque_limit = np.array([j.torque_limit for j in joints])
            self.no_load_speed = character.actuator.no_load_speed
        if self.python_servo:
            self.delay = CommandDelay(character.actuator.latency_steps, n, self.num_joints)

    # --- state access ---------------------------------------------------------------------------

    @property
    def qpos(self) -> np.ndarray:
        """[N, nq] view into the batch state."""
        return self.state[:, self.s_qpos]

    @property
    def qvel(self) -> np.ndarray:
        """[N, nv] view into the batch state."""
        return self.state[:, self.s_qvel]

    def root_pos(self) -> np.ndarray:
        """[N, 3] world root position."""
        return self.state[:, 1 + self.root_qpos : 4 + self.root_qpos]

    def root_quat(self) -> np.ndarray:
        """[N, 4] world root orientation (w, x, y, z)."""
        return self.state[:, 4 + self.root_qpos : 8 + self.root_qpos]

    def root_lin_vel(self) -> np.ndarray:
        """[N, 3] world root linear velocity (MuJoCo's free joint stores it in world frame)."""
        o = self.s_qvel.start + self.root_dof
        return self.state[:, o : o + 3]

    def root_ang_vel(self) -> np.ndarray:
        """[N, 3] world root angular velocity (the free joint stores it in the body frame)."""
        o = self.s_qvel.start + self.root_dof
        return quat_rotate(self.root_quat(), self.state[:, o + 3 : o + 6])

    def joint_pos(self) -> np.ndarray:
        """[N, J] actuated joint positions, character order."""
        return self.state[:, 1 + self.joint_qpos]

    def joint_vel(self) -> np.ndarray:
        """[N, J] actuated joint velocities, character order."""
        return self.state[:, self.s_qvel.start + self.joint_dof]

    def set_state(
        self,
        env_ids: np.ndarray,
        root_pos: np.ndarray,
        root_quat: np.ndarray,
        root_lin_vel: np.ndarray,
        root_ang_vel: np.ndarray,
        joint_pos: np.ndarray,
        joint_vel: np.ndarray,
    ) -> None:
        """Put envs ``env_ids`` [k] into the given world-frame state; clears their warm start.

        Shapes: root_pos [k, 3], root_quat [k, 4], root_lin_vel [k, 3] and root_ang_vel [k, 3]
        (world), joint_pos [k, J], joint_vel [k, J]. Joints the character does not actuate keep
        the model's default pose, and time restarts at 0.
        """
        s = np.tile(self.template, (len(env_ids), 1))
        q0, v0 = 1 + self.root_qpos, self.s_qvel.start + self.root_dof
        s[:, q0 : q0 + 3] = root_pos
        s[:, q0 + 3 : q0 + 7] = root_quat / np.linalg.norm(root_quat, axis=-1, keepdims=True)
        s[:, v0 : v0 + 3] = root_lin_vel
        s[:, v0 + 3 : v0 + 6] = quat_rotate(quat_conj(root_quat), root_ang_vel)
        s[:, 1 + self.joint_qpos] = joint_pos
        s[:, self.s_qvel.start + self.joint_dof] = joint_vel
        if self.history_cols.size:  # native servo: pending commands of reset envs = their pose
            s[:, self.history_cols] = np.asarray(joint_pos)[:, :, None]
        self.state[env_ids] = s
        self.warmstart[env_ids] = 0.0
        if self.python_servo:  # pending commands of reset envs become their initial pose
            mask = np.zeros(self.num_envs, dtype=bool)
            mask[env_ids] = True
            order = np.argsort(env_ids)
            self.delay.reset(mask, np.asarray(joint_pos)[order])

    # --- snapshots ------------------------------------------------------------------------------

    #: The arrays that carry over from one control step to the next (everything else BatchSim
    #: holds is rewritten before it is read): the physics state (with the native servo's pending
    #: commands in its history), the solver warm start, the controls; the python servo adds its
    #: command delay's ``delay/buffer`` and ``delay/head``.
    SNAPSHOT_ARRAYS = ("state", "warmstart", "ctrl")

    def snapshot(self) -> dict[str, np.ndarray]:
        """Every env's simulation state as named arrays (copies), for checkpoints.

        ``state`` [N, nstate] (``mjSTATE_FULLPHYSICS``: time, qpos, qvel, act, history, ...),
        ``warmstart`` [N, nv], ``ctrl``, and for the python servo the pending commands
        ``delay/buffer`` [k + 1, N, J] and ``delay/head`` [1]. :meth:`restore` puts them back so
        the next :meth:`step` equals the one that followed the snapshot, bit for bit.
        """
        arrays = {name: getattr(self, name).copy() for name in self.SNAPSHOT_ARRAYS}
        if self.python_servo:
            arrays.update({f"delay/{k}": v for k, v in self.delay.snapshot().items()})
        return arrays

    def restore(self, arrays: dict[str, np.ndarray]) -> None:
        """Restore :meth:`snapshot` (extra keys are ignored). A native-servo simulation also takes
        the python servo's snapshots (checkpoints written before the servo moved into MuJoCo): its
        ``delay/*`` commands go into the state's history.

        Raises:
            AmorError: an array is missing or has another shape (another character or env count).
        """
        arrays = dict(arrays)
        if self.history_cols.size and "delay/buffer" in arrays:
            arrays = self._from_python_servo(arrays)
        for name in self.SNAPSHOT_ARRAYS:
            _check_array(arrays, name, getattr(self, name).shape)
        if self.python_servo:
            delay = {k: _check_array(arrays, f"delay/{k}", v.shape) for k, v in self.delay.snapshot().items()}
            try:
                self.delay.restore(delay)
            except ValueError as exc:
                raise AmorError(f"simulation snapshot: {exc}") from None
        self.state[:] = arrays["state"]
        self.warmstart = np.array(arrays["warmstart"], dtype=np.float64)
        self.ctrl[:] = arrays["ctrl"]

    def _from_python_servo(self, arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """A python-servo snapshot as a native one: the state gains the history buffer (after
        ``act``), filled from the delay ring; ``ctrl`` [N, 1, nu] of torques becomes the targets."""
        m, k = self.model, self.history_cols.shape[1]
        n, j = self.num_envs, self.num_joints
        old = _check_array(arrays, "state", (n, self.nstate - m.nhistory))
        buffer = _check_array(arrays, "delay/buffer", (k + 1, n, j))
        head = int(np.asarray(arrays["delay/head"]).reshape(-1)[0]) % (k + 1)
        pending = buffer[[(head + 1 + i) % (k + 1) for i in range(k)]]  # [k, N, J], oldest first
        at = 1 + m.nq + m.nv + m.na
        state = np.concatenate(
            [old[:, :at], np.tile(self.template[at : at + m.nhistory], (n, 1)), old[:, at:]], 1
        )
        data = mujoco.MjData(m)
        for e in range(n):  # timestamps follow each env's clock: let MuJoCo write the buffer
            mujoco.mj_setState(m, data, state[e], STATE_SPEC)
            times = data.time - self.dt * np.arange(k, 0, -1)
            for jj, a in enumerate(self.actuators):
                mujoco.mj_initCtrlHistory(m, data, int(a), times, np.ascontiguousarray(pending[:, e, jj]))
            mujoco.mj_getState(m, data, state[e], STATE_SPEC)
        ctrl = np.zeros_like(self.ctrl)
        ctrl[:, :, self.actuators] = pending[-1][:, None, :]
        return {**arrays, "state": state, "ctrl": ctrl}

    # --- stepping -------------------------------------------------------------------------------

    def _rollout(
        self, nstep: int, pool: mujoco.rollout.Rollout | None = None, datas: list[mujoco.MjData] | None = None
    ) -> None:
        """``nstep`` physics steps of every env on the env's pool (or on ``pool`` with its
        ``datas``, one per thread: benchmarks time other pool sizes on the same batch)."""
        (self._pool if pool is None else pool).rollout(
            self._models,
            self._datas if datas is None else datas,
            self.state,
            self.ctrl,
            control_spec=CTRL_SPEC,
            skip_checks=True,
            nstep=nstep,
            initial_warmstart=self.warmstart,
            state=self._out_state,
            sensordata=self._out_sens,
            chunk_size=self._chunk,
        )

    def step(self, pd_target: np.ndarray) -> StepOutput:
        """Advance every env by one control step toward PD targets [N, J] (rad)."""
        time0 = self.state[:, 0].copy()
        if not self.python_servo:  # MuJoCo's actuators act in every substep: one pool call
            self.ctrl[:, :, self.actuators] = pd_target[:, None, :]
            self._rollout(self.substeps)
            out = self._out_state
            qv_prev, qv_last = (
                out[:, -2, self.s_qvel] if self.substeps > 1 else self.qvel,
                out[:, -1, self.s_qvel],
            )
            self.warmstart = (qv_last - qv_prev) / self.dt
            self.state[:] = out[:, -1]
            self.torque[:] = self._out_sens[:, :, self.torque_adr] * self.gear
        else:
            for sub in range(self.substeps):
                target = self.delay.push(pd_target)  # the command of `latency_steps` ago
                tau = servo_torque(
                    target,
                    self.joint_pos(),
                    self.joint_vel(),
                    self.kp,
                    self.kd,
                    self.torque_limit,
                    self.no_load_speed,
                )
                self.torque[:, sub] = tau
                self.ctrl[:, 0, self.actuators] = tau / self.gear
                qv_prev = self.qvel.copy()
                self._rollout(1)
                self.state[:] = self._out_state[:, 0]
                self.warmstart = (self.qvel - qv_prev) / self.dt
        sens = self._out_sens[:, -1][:, self.sensors.ee]  # [N, E, 10]
        expected = time0 + self.substeps * self.dt
        finite = np.isfinite(self.state).all(axis=1) & np.isfinite(sens).all(axis=(1, 2))
        diverged = ~finite | (np.abs(self.qvel) > MAX_QVEL).any(axis=1)
        diverged |= np.abs(self.state[:, 0] - expected) > 0.5 * self.dt  # MuJoCo reset the env itself
        self.warmstart[~np.isfinite(self.warmstart).all(axis=1)] = 0.0
        return StepOutput(
            torque=self.torque,
            ee_pos=sens[:, :, 0:3],
            ee_quat=sens[:, :, 3:7],
            ee_lin_vel=sens[:, :, 7:10],
            diverged=diverged,
        )

    def close(self) -> None:
        """Shut the thread pool down."""
        self._pool.close()
