"""The tracking vector env and its batched simulation (synthetic clips, small batches)."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from amorctl.core.contracts import TrackingView, tracking_view
from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import frame_dim
from amorctl.core.vecenv import VectorEnv
from amorctl.core.weights import sample_dirichlet
from amorctl.envs.synthetic import synthetic_library
from amorctl.envs.tracking_env import TrackingEnv
from amorctl.envs.wrappers import FixedWeights
from amorctl.registry import get_registry
from amorctl.sim.batch_sim import STATE_SPEC, BatchSim


def _character(name: str):
    registry = get_registry()
    if name not in registry.names("character"):
        pytest.skip(f"character {name} not installed")
    return registry.character(name)


def _pd_character():
    names = get_registry().names("character")
    for name in ("humanoid36", "stickman12"):
        if name in names:
            return _character(name)
    pytest.skip("no PD character installed")


def _make(name_or_spec, num_envs: int = 4, **kwargs) -> tuple[TrackingEnv, object]:
    ch = _character(name_or_spec) if isinstance(name_or_spec, str) else name_or_spec
    lib = synthetic_library(ch, num_clips=3, seconds=2.0, seed=1)
    env = TrackingEnv(ch, lib, num_envs=num_envs, nthread=2, **kwargs)
    return env, lib


def _pairs() -> list[tuple[str, str]]:
    registry = get_registry()
    return [(c, o) for c in registry.names("character") for o in registry.names("objective-set")]


@pytest.mark.parametrize(("character", "objective_set"), _pairs())
def test_every_character_and_objective_set_steps(character: str, objective_set: str) -> None:
    ch = get_registry().character(character)
    lib = synthetic_library(ch, num_clips=2, seconds=1.0)
    env = TrackingEnv(ch, lib, objective_set, num_envs=6, seed=3)
    assert isinstance(env, VectorEnv)
    m = len(get_registry().objective_set(objective_set).objectives)
    obs, _ = env.reset(seed=3)
    assert obs.shape == (6, env.obs_dim) and obs.dtype == np.float32
    assert env.reward_space.shape == (m,)
    rng = np.random.default_rng(0)
    lo, hi = env.joint_low, env.joint_high
    for _ in range(50):
        actions = rng.uniform(lo, hi, size=(6, env.action_dim))
        obs, r, term, trunc, info = env.step(actions)
        assert obs.shape == (6, env.obs_dim) and r.shape == (6, m)
        assert term.shape == trunc.shape == (6,) and term.dtype == trunc.dtype == bool
        assert info["final_obs"].shape == obs.shape
        assert np.isfinite(obs).all() and np.isfinite(r).all() and np.isfinite(info["final_obs"]).all()
        np.testing.assert_array_equal(obs[:, -m:], env.weights)
    env.close()


def test_observation_layout_at_reset() -> None:
    env, lib = _make(_pd_character(), num_envs=5, future_frames=(3,), seed=0)
    obs, _ = env.reset(seed=2)
    j, e = env.num_joints, env.num_ee
    d = frame_dim(j, e)
    lay = env.obs_layout
    assert list(lay) == ["proprio", "prev_targets", "ref_frame", "latent", "future_frames", "weights"]
    assert env.obs_dim == 2 * d + 2 * j + lib.latent_dim + d + env.m
    idx = env.ref_idx
    # RSI: the proprioceptive part equals the reference frame the env starts at
    np.testing.assert_allclose(obs[:, lay["proprio"]], lib.frames[idx], atol=1e-5)
    np.testing.assert_allclose(obs[:, lay["prev_targets"]], np.tile(lib.joint_pos[idx], 2), atol=1e-6)
    np.testing.assert_allclose(obs[:, lay["ref_frame"]], lib.frames[idx + 1])
    np.testing.assert_allclose(obs[:, lay["latent"]], lib.z[idx + 1])
    future = np.minimum(idx + 4, env.clip_end - 1)
    np.testing.assert_allclose(obs[:, lay["future_frames"]], lib.frames[future])
    np.testing.assert_allclose(obs[:, lay["weights"]], env.weights)
    assert env.frame_mismatch < 1e-6


def test_open_loop_reference_replay_tracks_then_drifts() -> None:
    env, lib = _make(_pd_character(), num_envs=8, seed=0, max_episode_steps=1000)
    env.reset(seed=0)
    c = env.objectives.alive_bonus
    rewards = []
    for _ in range(60):
        _, r, _, _, _ = env.step(lib.joint_pos[env.ref_idx + 1])
        rewards.append(r.mean(axis=0))
    rewards = np.array(rewards) - c
    first = rewards[0]
    assert (first[[0, 1, 2, 4]] > 0.98).all(), first  # joints, height, root orientation
    assert first[3] > 0.8 and first[5] > 0.8, first  # end effectors, velocities
    assert rewards[0, :6].sum() > rewards[30:, :6].sum(axis=1).mean() + 0.1


def test_seed_determinism() -> None:
    ch = _pd_character()
    runs = []
    for _ in range(2):
        env, lib = _make(ch, num_envs=4, seed=7)
        obs, _ = env.reset(seed=11)
        rng = np.random.default_rng(5)
        out = [obs]
        for _ in range(15):
            a = lib.joint_pos[env.ref_idx + 1] + 0.3 * rng.standard_normal((4, env.action_dim))
            obs, r, term, trunc, _ = env.step(a)
            out += [obs, r, term, trunc]
        runs.append(out)
        env.close()
    for a, b in zip(*runs, strict=True):
        np.testing.assert_array_equal(a, b)
    first, _ = _make(ch, num_envs=4)
    second, _ = _make(ch, num_envs=4)
    first.reset(seed=11)
    second.reset(seed=12)
    assert not np.array_equal(first.weights, second.weights)


def test_dirichlet_weights_on_simplex_with_mean_one_over_m() -> None:
    w = sample_dirichlet(np.random.default_rng(0), 20000, 7)
    assert w.shape == (20000, 7) and w.dtype == np.float32
    assert (w >= 0).all()
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(w.mean(axis=0), 1.0 / 7.0, atol=0.005)
    env, _ = _make(_pd_character(), num_envs=64)
    env.reset(seed=1)
    np.testing.assert_allclose(env.weights.sum(axis=1), 1.0, atol=1e-5)
    assert len(np.unique(env.weights[:, 0])) == 64


def test_env_weights_are_the_shared_dirichlet_sampler_bit_for_bit() -> None:
    env, _ = _make(_pd_character(), num_envs=5)
    env.reset(seed=4)
    # the env's first draw after RSI's clip and frame draws: replay them on a twin generator
    rng = np.random.default_rng(4)
    rng.integers(len(env.all_valid_clips), size=5)
    rng.integers(0, env.clip_ends[env.clip_id] - env.clip_starts[env.clip_id] - 1)
    want = rng.dirichlet(np.ones(env.m), size=5).astype(np.float32)
    np.testing.assert_array_equal(env.weights, want)


def test_tracking_view_reads_the_env_and_forwards_through_fixed_weights() -> None:
    ch = _pd_character()
    env, lib = _make(ch, num_envs=3, max_episode_steps=50)
    view = tracking_view(env)
    assert isinstance(view, TrackingView)
    env.reset(seed=2)
    env.step(lib.joint_pos[env.ref_idx + 1])
    np.testing.assert_array_equal(view.reference_index(), env.ref_idx)
    np.testing.assert_array_equal(view.clip_index(), env.clip_id)
    assert view.clip_names == tuple(c.name for c in lib.clips)
    np.testing.assert_array_equal(view.clip_frame_counts, lib.lengths)
    np.testing.assert_allclose(view.clip_seconds, [lib.clip_duration(c) for c in lib.clips])
    assert view.joint_names == ch.joint_names() and view.dt == env.dt and view.num_envs == 3
    assert view.max_episode_steps == 50 and view.model.nq == env.sim.model.nq
    assert {k: slice(*v) for k, v in view.observation_layout.items()} == env.obs_layout
    np.testing.assert_array_equal(view.qpos(), env.sim.qpos)
    np.testing.assert_array_equal(view.joint_pos(), env.sim.joint_pos())
    np.testing.assert_array_equal(view.joint_vel(), env.sim.joint_vel())
    obs = env._observe()
    p = view.observation_layout["proprio"]
    proprio_ee = obs[:, p[0] : p[1]][:, 13 + 2 * ch.num_joints :][:, : 9 * len(ch.end_effectors)]
    np.testing.assert_allclose(view.end_effector_pos(), proprio_ee.reshape(3, -1, 9)[:, :, :3], atol=1e-5)
    f = view.reference_index()
    np.testing.assert_array_equal(view.reference_frames(f), env.ref_frames[f])
    np.testing.assert_array_equal(view.reference_joint_pos(f), lib.joint_pos[f])
    ref_q = view.reference_qpos(f)
    assert ref_q.shape == (3, env.sim.model.nq)
    np.testing.assert_array_equal(ref_q[:, env.sim.joint_qpos], lib.joint_pos[f])
    np.testing.assert_array_equal(ref_q[:, :3], lib.root_pos[f])
    view.qpos()[:] = 0.0  # copies: the env is untouched
    assert np.abs(env.sim.qpos).sum() > 0
    view.select_clips(env_clips=np.array([1, 1, 1]), from_start=True)
    env.reset(seed=0)
    np.testing.assert_array_equal(view.clip_index(), [1, 1, 1])
    np.testing.assert_array_equal(view.reference_index(), lib.starts[[1, 1, 1]])

    wrapped = FixedWeights(env, np.eye(env.m)[0])
    wview = tracking_view(wrapped)
    assert isinstance(wview, TrackingView)
    np.testing.assert_array_equal(wview.weights, np.tile(np.eye(env.m, dtype=np.float32)[0], (3, 1)))
    np.testing.assert_array_equal(wview.reference_index(), view.reference_index())


def test_envs_without_motions_have_no_tracking_view() -> None:
    from amorctl.envs.toy import ToyTradeoffEnv

    toy = ToyTradeoffEnv(4, max_steps=5)
    assert tracking_view(toy) is None
    assert tracking_view(FixedWeights(toy, np.array([0.5, 0.5]))) is None


def test_fixed_weights_and_validation() -> None:
    ch = _pd_character()
    w = np.array([0.4, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1])
    env, lib = _make(ch, num_envs=3, fixed_weights=w, max_episode_steps=2)
    env.reset(seed=0)
    for _ in range(3):
        env.step(lib.joint_pos[env.ref_idx + 1])
        np.testing.assert_allclose(env.weights, np.tile(w, (3, 1)), atol=1e-7)
    with pytest.raises(AmorError, match="fixed weights"):
        _make(ch, fixed_weights=np.array([0.5, 0.6, 0, 0, 0, 0, 0]))
    with pytest.raises(AmorError, match="fixed weights"):
        _make(ch, fixed_weights=np.ones(3) / 3)


def test_truncation_is_separate_from_termination() -> None:
    env, lib = _make(_pd_character(), num_envs=4, max_episode_steps=3)
    obs, _ = env.reset(seed=0)
    w0 = env.weights.copy()
    for step in range(3):
        obs, r, term, trunc, info = env.step(lib.joint_pos[env.ref_idx + 1])
        assert not term.any()
        assert trunc.all() == (step == 2)
    # the final obs of the ended episode keeps its weights; the new episode has new ones
    m = env.m
    np.testing.assert_allclose(info["final_obs"][:, -m:], w0)
    assert not np.allclose(obs[:, -m:], w0)
    assert (env.episode_steps == 0).all()
    assert (r[:, :6] >= env.objectives.alive_bonus).all()  # not terminal: survival bonus paid


def test_fall_terminates_without_survival_bonus() -> None:
    env, lib = _make(_pd_character(), num_envs=4)
    env.reset(seed=0)
    env.fall_drop = -10.0  # any height counts as fallen
    _, r, term, trunc, info = env.step(lib.joint_pos[env.ref_idx + 1])
    assert term.all() and not trunc.any() and info["fell"].all() and not info["diverged"].any()
    assert (r[:, :6] <= 1.0).all()  # no survival bonus on the terminal step


def test_diverged_env_is_reset_and_counted() -> None:
    env, lib = _make(_pd_character(), num_envs=4)
    env.reset(seed=0)
    env.sim.qvel[1, :] = np.nan
    env.sim.qvel[2, 0] = 1e7
    obs, r, term, _, info = env.step(lib.joint_pos[env.ref_idx + 1])
    np.testing.assert_array_equal(info["diverged"], [False, True, True, False])
    assert info["diverged_total"] == 2
    np.testing.assert_array_equal(term, [False, True, True, False])
    assert (r[1:3] == 0).all() and np.isfinite(r).all()
    assert np.isfinite(obs).all() and np.isfinite(info["final_obs"]).all()
    assert np.isfinite(env.sim.state).all() and (env.episode_steps[1:3] == 0).all()
    _, _, _, _, info = env.step(lib.joint_pos[env.ref_idx + 1])
    assert info["diverged_total"] == 2 and not info["diverged"].any()


def test_clip_switch_keeps_weights_and_episode() -> None:
    ch = _pd_character()
    lib = synthetic_library(ch, num_clips=3, seconds=0.1, seed=2)  # 6 frames per clip
    env = TrackingEnv(ch, lib, num_envs=4, seed=0)
    env.reset(seed=0)
    w0 = env.weights.copy()
    switched = np.zeros(4, dtype=bool)
    for _ in range(6):
        _, _, term, trunc, info = env.step(lib.joint_pos[env.ref_idx + 1])
        assert not (term | trunc).any()
        switched |= info["clip_switched"]
        starts = lib.starts[env.clip_id[info["clip_switched"]]]
        np.testing.assert_array_equal(env.ref_idx[info["clip_switched"]], starts)
    assert switched.all()
    np.testing.assert_array_equal(env.weights, w0)
    assert (env.episode_steps == 6).all()


def test_bad_arguments_raise_amor_error() -> None:
    ch = _pd_character()
    lib = synthetic_library(ch, num_clips=1, seconds=0.2)
    with pytest.raises(AmorError, match="action_mode"):
        TrackingEnv(ch, lib, action_mode="delta")  # type: ignore[arg-type]
    with pytest.raises(AmorError, match="character"):
        TrackingEnv(ch, dataclasses.replace(lib, character="other"))
    env = TrackingEnv(ch, lib, num_envs=2)
    env.reset(seed=0)
    with pytest.raises(AmorError, match="shape"):
        env.step(np.zeros((3, env.action_dim)))


def test_residual_actions_offset_the_reference() -> None:
    ch = _pd_character()
    env_a, lib = _make(ch, num_envs=3, seed=4)
    env_r, _ = _make(ch, num_envs=3, seed=4, action_mode="residual")
    env_a.reset(seed=4)
    env_r.reset(seed=4)
    for _ in range(3):
        ref = lib.joint_pos[env_a.ref_idx + 1]
        o_a, r_a, *_ = env_a.step(ref)
        o_r, r_r, *_ = env_r.step(np.zeros_like(ref))
        np.testing.assert_array_equal(o_a, o_r)
        np.testing.assert_array_equal(r_a, r_r)


# --- the batched simulation against plain per-env MjData stepping ----------------------------------


def test_pd_batch_matches_per_env_mjdata() -> None:
    ch = _pd_character()
    env, lib = _make(ch, num_envs=3, seed=0)
    env.reset(seed=0)
    sim = env.sim
    m = sim.model
    datas = []
    for i in range(3):
        d = mujoco.MjData(m)
        mujoco.mj_setState(m, d, sim.state[i], STATE_SPEC)
        datas.append(d)
    for _ in range(10):
        target = np.clip(lib.joint_pos[env.ref_idx + 1], env.joint_low, env.joint_high)
        for i, d in enumerate(datas):
            d.ctrl[sim.actuators] = target[i]
            for _ in range(sim.substeps):
                mujoco.mj_step(m, d)
        env.step(target)
    np.testing.assert_allclose(np.stack([d.qpos for d in datas]), sim.qpos, atol=1e-9)


def test_servo_batch_applies_delayed_servo_torque_every_substep() -> None:
    ch = _character("biped20")
    from amorctl.sim.actuators import servo_torque
    from amorctl.sim.batch_sim import build_model

    env, lib = _make(ch, num_envs=3, seed=0)
    env.reset(seed=0)
    sim = env.sim
    # The env's servo runs inside MuJoCo (dcmotor + history delay); the reference is the numpy
    # servo on the motor model. Euler makes both apply actuator forces explicitly: equal to
    # rounding (under implicitfast they differ by the implicit back-EMF, tests/test_actuators.py).
    m, k = build_model(ch, "python"), ch.actuator.latency_steps
    m.opt.integrator = sim.model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    assert k > 0
    datas, pending = [], []
    for i in range(3):
        d = mujoco.MjData(m)
        d.time, d.qpos[:], d.qvel[:] = sim.state[i, 0], sim.qpos[i], sim.qvel[i]
        datas.append(d)
        pending.append([sim.joint_pos()[i].copy()] * k)  # delayed commands start at the pose
    for _ in range(6):
        target = np.clip(lib.joint_pos[env.ref_idx + 1], env.joint_low, env.joint_high)
        for i, d in enumerate(datas):
            for _ in range(sim.substeps):
                pending[i].append(target[i])
                cmd = pending[i].pop(0)
                q, qd = d.qpos[sim.joint_qpos], d.qvel[sim.joint_dof]
                tau = servo_torque(
                    cmd[None], q[None], qd[None], sim.kp, sim.kd, sim.torque_limit, sim.no_load_speed
                )[0]
                d.ctrl[sim.actuators] = tau / sim.gear
                mujoco.mj_step(m, d)
        env.step(target)
    np.testing.assert_allclose(np.stack([d.qpos for d in datas]), sim.qpos, atol=1e-9)
    assert (np.abs(sim.torque) <= sim.torque_limit + 1e-9).all()  # never above stall torque


def test_batch_sim_rejects_unknown_names() -> None:
    ch = _pd_character()
    with pytest.raises(AmorError, match="root body"):
        BatchSim(dataclasses.replace(ch, root_body="nope"), 2)
    with pytest.raises(AmorError, match="num_envs"):
        BatchSim(ch, 0)


def test_frame_features_match_the_geometry_definition() -> None:
    from amorctl.core.frame_layout import frame_features, split_frame
    from amorctl.core.geometry import heading_quat_inv, quat_mul, quat_rotate, quat_to_6d

    rng = np.random.default_rng(0)
    n, j, e = 20, 5, 3

    def unit(x: np.ndarray) -> np.ndarray:
        return x / np.linalg.norm(x, axis=-1, keepdims=True)

    rp, lv, av = rng.standard_normal((3, n, 3))
    rq = unit(rng.standard_normal((n, 4)))
    rq[0] = [np.cos(np.pi / 4), 0.0, -np.sin(np.pi / 4), 0.0]  # x axis straight up: heading 0
    q, qd = rng.standard_normal((2, n, j))
    ep, ev = rng.standard_normal((2, n, e, 3))
    eq = unit(rng.standard_normal((n, e, 4)))
    f = split_frame(frame_features(rp, rq, lv, av, q, qd, ep, eq, ev), j, e)
    h = heading_quat_inv(rq)
    he = np.broadcast_to(h[:, None], (n, e, 4))
    np.testing.assert_allclose(f.h, rp[:, 2])
    np.testing.assert_allclose(f.root_rot6d, quat_to_6d(quat_mul(h, rq)), atol=1e-12)
    np.testing.assert_allclose(f.root_lin_vel, quat_rotate(h, lv), atol=1e-12)
    np.testing.assert_allclose(f.root_ang_vel, quat_rotate(h, av), atol=1e-12)
    np.testing.assert_allclose(f.joint_pos, q)
    np.testing.assert_allclose(f.joint_vel, qd)
    np.testing.assert_allclose(f.ee_pos, quat_rotate(he, ep - rp[:, None]), atol=1e-12)
    np.testing.assert_allclose(f.ee_rot6d, quat_to_6d(quat_mul(he, eq)), atol=1e-12)
    np.testing.assert_allclose(f.ee_vel, quat_rotate(he, ev - lv[:, None]), atol=1e-12)
