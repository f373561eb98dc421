"""The MJX tracking env against torch-cpu's (same state and action -> same rewards and
observations) and MJX physics against MuJoCo C over 50 control steps. Compiling one MJX env step
takes about a minute on 2 CPU cores, so these are ``slow``; docs/backends.md has the numbers."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("jax")
pytest.importorskip("mujoco.mjx")

import jax.numpy as jnp
import mujoco

from amorctl.envs.synthetic import synthetic_library
from amorctl.envs.tracking_env import TrackingEnv
from amorctl.registry import get_registry

N = 4


def env_pair(character: str, contacts: bool = True, seconds: float = 2.0, **extra):
    """A torch-cpu env and an MJX env of ``character`` in the same state (the C env's reset);
    ``extra``: constructor options of both."""
    from amorctl.plugins.backends.jax_mjx.env import MjxTrackingEnv

    ch = get_registry().character(character)
    lib = synthetic_library(ch, num_clips=2, seconds=seconds, seed=3)
    j = MjxTrackingEnv(ch, lib, **env_kwargs(), **extra)
    c = c_env(character, lib, **extra)
    if not contacts:
        c.sim.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
        model = j.core.model
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
        j.core.physics.set_model(model)  # a new MJX model and template without contact slots
    j.select_clips(from_start=True)
    obs, _ = c.reset(seed=0)
    j.reset(seed=0)
    sync(c, j, obs)
    return c, j


def env_kwargs() -> dict:
    return dict(num_envs=N, max_episode_steps=200, action_mode="residual", seed=0)


def c_env(character: str, lib, servo: str = "native", **extra) -> TrackingEnv:
    """torch-cpu's env (``servo="python"``: a servo character on the reference servo,
    ``BatchSim(servo_model="python")``, instead of MuJoCo's native one)."""
    from amorctl.sim.batch_sim import BatchSim

    ch = get_registry().character(character)
    c = TrackingEnv(ch, lib, nthread=1, **env_kwargs(), **extra)
    if servo != "native":
        c.sim = BatchSim(ch, N, nthread=1, servo_model=servo)  # before reset: the env's only sim
    c.select_clips(from_start=True)  # no clip ends within the 50 steps of a 2 s clip
    return c


def sync(c, j, obs: np.ndarray) -> None:
    """Put the MJX env into the C env's current state (``obs``: the C env's last observation).
    Every pending servo command is the last target (the latency is below the substep count)."""
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    st = j.state
    j.state = st._replace(
        data=st.data.replace(qpos=f32(c.sim.qpos), qvel=f32(c.sim.qvel)),
        ref_idx=jnp.asarray(c.ref_idx, jnp.int32), clip_end=jnp.asarray(c.clip_end, jnp.int32),
        clip_id=jnp.asarray(c.clip_id, jnp.int32), weights=f32(c.weights),
        target_prev=f32(c.target_prev), target_prev2=f32(c.target_prev2),
        joint_vel_prev=f32(c.joint_vel_prev), ee_pos=f32(c.ee_pos), ee_quat=f32(c.ee_quat),
        ee_lin_vel=f32(c.ee_lin_vel), delay=jnp.broadcast_to(f32(c.target_prev), st.delay.shape),
        obs=f32(obs),
    )  # fmt: skip


def sync_c(c: TrackingEnv, p: TrackingEnv) -> None:
    """Put the C env ``p`` (reference servo) into the C env ``c``'s state (native servo)."""
    p.sim.state[:, : c.sim.s_qvel.stop] = c.sim.state[:, : c.sim.s_qvel.stop]  # time, qpos, qvel
    p.sim.warmstart[:] = c.sim.warmstart
    p.sim.delay.buffer[:] = c.target_prev  # every pending command is the last target
    for name in ("ref_idx", "clip_end", "clip_id", "_weights", "target_prev", "target_prev2",
                 "joint_vel_prev", "ee_pos", "ee_quat", "ee_lin_vel", "episode_steps"):  # fmt: skip
        setattr(p, name, getattr(c, name).copy())


def run_pair(c, j, steps: int, scale: float, seed: int = 0, resync: bool = False, explicit=None):
    """Step both envs with the same actions; per step max |Δreward|, max |Δobs|, max |Δqpos|
    (no env may terminate: a reset would make the states incomparable). ``resync``: before
    every step put the MJX env into the C env's state (each step then starts from the same
    state). ``explicit``: a third env, torch-cpu's on the reference servo, also put into the C
    env's state before every step; a fourth column holds its max |Δobs| from the C env."""
    rng = np.random.default_rng(seed)
    out = []
    oc = np.asarray(j.state.obs)  # the C env's observation (env_pair synced it)
    for _ in range(steps):
        a = scale * rng.normal(size=(N, c.action_dim))
        if resync:
            sync(c, j, oc)
        if explicit is not None:
            sync_c(c, explicit)
        oj, rj, tj, _, _ = j.step(a)
        oc, rc, tc, _, _ = c.step(a)
        assert not tc.any() and not tj.any()  # no reset: the states stay comparable
        dq = np.abs(np.asarray(j.state.data.qpos) - c.sim.qpos).max()
        row = [np.abs(rj - rc).max(), np.abs(oj - oc).max(), dq]
        if explicit is not None:
            row.append(np.abs(explicit.step(a)[0] - oc).max())
        out.append(row)
    return np.array(out)


#: (character, contacts, resync); every case: max |Δreward| and max |Δobs| below 1e-4
ENV_CASES = [("biped20", True, True), ("humanoid36", True, True), ("humanoid36", False, False)]


@pytest.mark.slow
def test_mjx_env_terminates_on_tracking_error_as_torch_cpus_does() -> None:
    """``termination_distance``: from the same state and action both envs end the same episodes,
    those whose tracking error (measured on a third, plain env) exceeds the distance."""
    from amorctl.core.frame_layout import split_frame
    from amorctl.core.termination import tracking_error

    actions = 0.4 * np.random.default_rng(1).normal(size=(N, 20))
    ch = get_registry().character("biped20")
    plain = c_env("biped20", synthetic_library(ch, num_clips=2, seconds=2.0, seed=3))
    plain.reset(seed=0)  # the state env_pair starts both envs in
    plain.step(actions)
    parts = [
        split_frame(f, plain.num_joints, plain.num_ee)
        for f in (plain._sim_frames(), plain.ref_frames[plain.ref_idx])
    ]
    error = np.sort(tracking_error(*parts))
    distance = float(error[1] + error[2]) / 2  # two of the four envs drift farther
    c, j = env_pair("biped20", termination_distance=distance)
    _, _, tj, _, ij = j.step(actions)
    _, _, tc, _, ic = c.step(actions)
    expected = tracking_error(*parts) > distance
    np.testing.assert_array_equal(ic["far"], expected)
    np.testing.assert_array_equal(np.asarray(ij["far"]), expected)
    np.testing.assert_array_equal(np.asarray(tj), tc)


@pytest.mark.slow
@pytest.mark.parametrize(("character", "contacts", "resync"), ENV_CASES)
def test_mjx_env_rewards_and_observations_equal_torch_cpus(
    character: str, contacts: bool, resync: bool
) -> None:
    """Same state and action -> rewards and observations within 1e-4, over 10 control steps of
    random residual actions from RSI states of the synthetic clips (docs/backends.md).

    With contacts every step starts from the C env's state (``resync``): across steps the two
    float precisions part at contact events, after which the states differ by more than a single
    step's rounding. humanoid36 without contacts runs 10 steps freely: its position actuators
    saturate, the case of :func:`amorctl.plugins.backends.jax_mjx.physics.mjx_step`.

    biped20: in one of these 40 env steps (env 2, step 8) r_ank_roll drives at its torque–speed
    limit, where MuJoCo C integrates the native servo's back-EMF slope implicitly. MJX adds that
    derivative (:func:`~amorctl.plugins.backends.jax_mjx.physics.servo_velocity_derivative`); the
    C env on the reference servo, which applies the servo torque explicitly, departs from the
    native one there (an observed joint velocity by 1.6e-2), so this case does exercise it."""
    c, j = env_pair(character, contacts)
    assert j.reward_space.survival_bonus == c.reward_space.survival_bonus == 1.0  # declared alike
    explicit = None
    if character == "biped20":
        explicit = c_env(character, c.library, servo="python")
        explicit.reset(seed=0)
    diffs = run_pair(c, j, 10, 0.05, resync=resync, explicit=explicit)
    print(character, contacts, "max |Δr|, |Δobs|, |Δqpos| (, |Δobs| explicit servo) per step:\n", diffs)
    assert diffs[:, 0].max() < 1e-4 and diffs[:, 1].max() < 1e-4, diffs
    if explicit is not None:
        assert diffs[:, 3].max() > 1e-3, diffs


@pytest.mark.parametrize("kd", [0.0, 0.3])
def test_servo_velocity_derivative_is_mujoco_cs_for_the_native_servo(kd: float) -> None:
    """The servo's velocity derivative MJX adds to its implicit step equals the one MuJoCo C's
    implicitfast integrator takes from torch-cpu's native ``dcmotor`` servo (qDeriv less the
    joints' damping), in all three regimes: PD (``-kd``), drive voltage clamped by the back-EMF
    (``-torque_limit / no_load_speed``) and current limit (0)."""
    import dataclasses

    from amorctl.plugins.backends.jax_mjx.physics import servo_velocity_derivative
    from amorctl.sim.actuators import servo_torque
    from amorctl.sim.batch_sim import BatchSim

    base = get_registry().character("biped20")
    ch = dataclasses.replace(base, joints=tuple(dataclasses.replace(j, kd=kd) for j in base.joints))
    sim = BatchSim(ch, 1, nthread=1)
    m, d = sim.model, mujoco.MjData(sim.model)
    mujoco.mj_resetData(m, d)
    J = len(sim.joint_dof)
    qd = np.linspace(-4.5, 4.5, J)
    err = np.tile([-0.3, -0.15, -0.05, 0.05, 0.15, 0.3, 0.01, -0.01, 0.25, -0.25], 2)  # target - q
    d.qvel[sim.joint_dof] = qd
    d.ctrl[sim.actuators] = d.qpos[sim.joint_qpos] + err
    for a in sim.actuators:  # the delayed commands are the current target
        mujoco.mj_initCtrlHistory(m, d, int(a), None, np.full(int(m.actuator_history[a, 0]), d.ctrl[a]))
    mujoco.mj_step(m, d)
    c_deriv = d.qDeriv[m.D_rowadr + m.D_diag][sim.joint_dof] + m.dof_damping[sim.joint_dof]
    q, target = d.qpos[sim.joint_qpos] * 0.0, err  # only the error enters
    args = (target, q, qd, sim.kp, sim.kd, sim.torque_limit, ch.actuator.no_load_speed)
    ours = servo_velocity_derivative(*args)
    np.testing.assert_allclose(ours, c_deriv, atol=1e-12)
    np.testing.assert_allclose(servo_torque(*args), d.actuator_force[sim.actuators], atol=1e-12)
    slope = -5.0 / ch.actuator.no_load_speed
    assert {round(float(x), 6) for x in ours} == {round(-kd, 6) + 0.0, 0.0, round(slope, 6)}


def standing_pose(model: mujoco.MjModel) -> np.ndarray:
    """[nq] the model's qpos0 lowered until its lowest geom sinks 0.5 mm into the floor."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    floor = int(np.flatnonzero(model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE)[0])
    solid = [
        g for g in range(model.ngeom) if g != floor and model.geom_contype[g] | model.geom_conaffinity[g]
    ]
    low = min(mujoco.mj_geomDistance(model, data, floor, g, 10.0, None) for g in solid)
    q = model.qpos0.copy()
    q[2] -= low + 5e-4
    return q


#: (character, PD target amplitude around the standing pose, rad, bound on max |Δqpos|)
PHYSICS_CASES = [("biped20", 0.0, 1e-4), ("humanoid36", 0.3, 1e-4)]


@pytest.mark.slow
@pytest.mark.parametrize(("character", "amplitude", "bound"), PHYSICS_CASES)
def test_mjx_physics_tracks_mujoco_c(character: str, amplitude: float, bound: float) -> None:
    """Raw physics, no episode logic: torch-cpu's MuJoCo C ``BatchSim`` (float64; biped20 with
    MuJoCo's native servo) and :class:`MjxPhysics` (float32; biped20 with the reference servo in
    the jitted substeps) from the same standing pose on the floor, 50 control steps (250 physics
    steps) of PD targets oscillating around it (1 Hz, the two envs in opposite phase): the largest
    qpos difference stays within ``bound``. docs/backends.md has the measured numbers."""
    import jax

    from amorctl.plugins.backends.jax_mjx.physics import MjxPhysics
    from amorctl.sim.batch_sim import BatchSim

    ch = get_registry().character(character)
    c, j = BatchSim(ch, 2, nthread=1), MjxPhysics(ch)
    q0 = standing_pose(j.model)
    jp0 = q0[np.asarray(j.joint_qpos)]
    zeros = np.zeros((2, 3))
    c.set_state(np.arange(2), np.tile(q0[:3], (2, 1)), np.tile(q0[3:7], (2, 1)), zeros, zeros,
                np.tile(jp0, (2, 1)), np.zeros((2, len(jp0))))  # fmt: skip
    data = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (2, *jnp.shape(x))), j.template)
    data = data.replace(qpos=jnp.asarray(np.tile(q0, (2, 1)), jnp.float32))
    delay = jnp.broadcast_to(jnp.asarray(jp0, jnp.float32), (j.latency + 1, 2, len(jp0)))
    head = jnp.zeros((), jnp.int32)
    step = jax.jit(j.control_step)
    phase = np.array([1.0, -1.0])[:, None]
    dq = []
    for t in range(50):
        target = jp0 + amplitude * np.sin(2 * np.pi * t / ch.control_hz) * phase
        c.step(target)
        data, _, _, (delay, head) = step(data, delay, head, jnp.asarray(target, jnp.float32))
        dq.append(np.abs(np.asarray(data.qpos, np.float64) - c.qpos).max())
    dq = np.array(dq)
    print(character, "max |Δqpos| after control steps 1, 10, 20, 30, 40, 50:", dq[[0, 9, 19, 29, 39, 49]])
    assert np.isfinite(dq).all()
    assert dq.max() < bound, dq


@pytest.mark.slow
def test_fused_training_on_mjx_tracking_env_resumes_exactly(tmp_path, capsys) -> None:
    """`train_run` with backend jax-mjx on a biped20 tracking env: the fused rollout (policy + MJX
    in one scan) trains, checkpoints, resumes to the same numbers, and torch-cpu's inference path
    reads its policy; `evaluate`, `pareto`, `deploy export`, `tune` and `hlp` run on the jax-mjx run
    unchanged."""
    import csv
    import dataclasses

    from amorctl.core.config import TrainConfig, merge
    from amorctl.motion.dataset import write_dataset
    from amorctl.plugins.backends.torch_cpu.policy import TorchPolicy
    from amorctl.train.loop import train_run
    from amorctl.train.rundir import RunDir

    lib = synthetic_library(get_registry().character("biped20"), num_clips=2, seconds=1.0, seed=3)
    lib = dataclasses.replace(lib, clips=tuple(lib.clips))
    write_dataset(tmp_path / "ds.mcap", lib)
    config = merge(
        TrainConfig(),
        {
            "run": {"iterations": 3, "checkpoint_every": 1, "tensorboard": False, "backend": "jax-mjx"},
            "env": {"kind": "tracking", "character": "biped20", "dataset": str(tmp_path / "ds.mcap"),
                    "num_envs": 4, "episode_seconds": 0.2},
            "network": {"actor_hidden": [16], "critic_hidden": [16]},
            # the science preset's levers: weight mixture on the device, per-objective return scale
            "ppo": {"num_steps": 4, "num_epochs": 1, "num_minibatches": 2, "precision": "fp32",
                    "return_norm": "value+advantage", "entropy_coef": 0.005},
            "weights": {"corner_fraction": 0.1, "axis_fraction": 0.3},
        },
        "test",
    )  # fmt: skip
    train_run(config, tmp_path / "full")
    train_run(config, tmp_path / "part", stop_after=2)
    train_run(config, tmp_path / "part", resume=True)

    def rows(run: str) -> list[dict[str, str]]:
        with open(tmp_path / run / "metrics.csv") as f:
            return list(csv.DictReader(f))

    a, b = rows("full"), rows("part")
    assert len(a) == len(b) == 3
    for ra, rb in zip(a, b, strict=True):
        for key in ("loss/total", "loss/value", "kl", "reward/up", "episodes"):
            assert ra[key] == rb[key], (ra["iteration"], key)
    assert float(a[-1]["episodes"]) > 0 and np.isfinite(float(a[-1]["loss/total"]))
    assert a[-1]["return_scale/advantage_std/smooth"] == b[-1]["return_scale/advantage_std/smooth"]
    run = RunDir.open(tmp_path / "full")
    scale = run.checkpoint().trainer.arrays["return_scale.adv_sq"]
    assert scale.shape == (7,) and np.isfinite(scale).all() and (scale > 0).all()
    policy = run.policy()
    torch_policy = TorchPolicy(run.checkpoint().trainer, run.config.network)
    obs = run.env(num_envs=4).reset(seed=1)[0]
    np.testing.assert_allclose(policy(obs), torch_policy(obs), atol=1e-5)
    assert policy.observation_layout["weights"] == (policy.obs_dim - 7, policy.obs_dim)

    from amorctl.core.contracts import TrackingView, tracking_view

    env = run.env(num_envs=4)
    view = tracking_view(env)
    assert isinstance(view, TrackingView)
    assert view.clip_names == tuple(c.name for c in lib.clips)
    np.testing.assert_allclose(
        view.reference_joint_pos(view.reference_index()), view.joint_pos(), atol=1e-5
    )  # RSI: the state is the reference frame
    assert view.end_effector_pos().shape == (4, len(view.character.end_effectors), 3)

    import json

    from amorctl.cli.main import main

    full, motion = str(tmp_path / "full"), lib.clips[0].name
    capsys.readouterr()
    assert main(["evaluate", full, "--motion", motion, "--episodes", "1", "--json"]) == 0
    metrics = json.loads(capsys.readouterr().out)["settings"][0]["metrics"]
    assert metrics["episodes"] == 1 and 0 <= metrics["joint_mae_deg"] < 90
    assert main(["pareto", full, "--samples", "2", "--out", str(tmp_path / "p"), "--json"]) == 0
    front = json.loads(capsys.readouterr().out)
    assert len(front["weights"]) == 2 and front["objectives"] == list(policy.objectives)
    assert main(["deploy", "export", full, "--out", str(tmp_path / "bundle")]) == 0
    assert (tmp_path / "bundle" / "policy.onnx").is_file()
    capsys.readouterr()
    tuned = []
    for weights in ("up=1", "smooth=1"):
        args = ["tune", full, "--motion", motion, "--weights", weights, "--seconds", "0.2", "--json"]
        assert main(args) == 0
        tuned.append(json.loads(capsys.readouterr().out))
    assert [t["steps"] for t in tuned] == [round(0.2 * view.character.control_hz)] * 2
    assert all(np.isfinite(list(t["returns"].values())).all() for t in tuned)
    assert tuned[0]["mean_action_rate"] != tuned[1]["mean_action_rate"]  # w reaches the policy

    from amorctl.hlp.config import HlpConfig, to_toml
    from amorctl.hlp.config import merge as hlp_merge

    hlp_config = hlp_merge(HlpConfig(), {
        "run": {"iterations": 2, "checkpoint_every": 1, "tensorboard": False, "threads": 1},
        "env": {"num_envs": 4, "episode_seconds": 0.3},
        "policy": {"actor_hidden": [16], "critic_hidden": [16]},
        "ppo": {"num_steps": 4, "num_epochs": 1, "num_minibatches": 2},
        "discriminator": {"window": 4, "hidden": [16], "z_hidden": [8], "batch_size": 16, "replay_size": 32,
                          "steps_per_iteration": 1},
    }, "test")  # fmt: skip
    (tmp_path / "hlp.toml").write_text(to_toml(hlp_config))
    hlp_out, hlp_toml = str(tmp_path / "hlp"), str(tmp_path / "hlp.toml")
    assert main(["hlp", "train", full, "--out", hlp_out, "--config", hlp_toml, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["end_iteration"] == 2
    assert main(["hlp", "trace", hlp_out, "--motion", motion, "--json"]) == 0
    segments = json.loads(capsys.readouterr().out)["traces"][0]["segments"]
    assert all(sum(s["mean_w"].values()) == pytest.approx(1.0, abs=1e-5) for s in segments)
