"""The MJX tracking env against torch-cpu's (same state and action -> same rewards and
observations) and MJX physics against MuJoCo C over 50 control steps. Compiling one MJX env step
takes about a minute on 2 CPU cores, so these are ``slow``; docs/backends.md has the numbers."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("jax")
pytest.importorskip("mujoco.mjx")

import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402

from amorctl.envs.synthetic import synthetic_library  # noqa: E402
from amorctl.envs.tracking_env import TrackingEnv  # noqa: E402
from amorctl.registry import get_registry  # noqa: E402

N = 4


def env_pair(character: str, contacts: bool = True, seconds: float = 2.0):
    """A torch-cpu env and an MJX env of ``character`` in the same state (the C env's reset)."""
    from amorctl.plugins.backends.jax_mjx.env import MjxTrackingEnv

    ch = get_registry().character(character)
    lib = synthetic_library(ch, num_clips=2, seconds=seconds, seed=3)
    kw = dict(num_envs=N, max_episode_steps=200, action_mode="residual", seed=0)
    c = TrackingEnv(ch, lib, nthread=1, **kw)
    j = MjxTrackingEnv(ch, lib, **kw)
    if not contacts:
        from mujoco import mjx

        c.sim.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
        j.core.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
        j.core.mx = mjx.put_model(j.core.model)
    for env in (c, j):
        env.select_clips(from_start=True)  # no clip ends within the 50 steps of a 2 s clip
    obs, _ = c.reset(seed=0)
    j.reset(seed=0)
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
    return c, j


def run_pair(c, j, steps: int, scale: float, seed: int = 0):
    """Step both envs with the same actions; per-step max |Δreward|, max |Δobs|, max |Δqpos|."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(steps):
        a = scale * rng.normal(size=(N, c.action_dim))
        oj, rj, tj, _, _ = j.step(a)
        oc, rc, tc, _, _ = c.step(a)
        assert not tc.any() and not tj.any()  # no reset: the states stay comparable
        dq = np.abs(np.asarray(j.state.data.qpos) - c.sim.qpos).max()
        out.append((np.abs(rj - rc).max(), np.abs(oj - oc).max(), dq))
    return np.array(out)


@pytest.mark.slow
@pytest.mark.parametrize(("character", "contacts"), [("biped20", True), ("humanoid36", False)])
def test_mjx_env_rewards_and_observations_equal_torch_cpus(character: str, contacts: bool) -> None:
    """Same state and actions for 10 control steps: rewards and observations within 1e-4.

    biped20 (servo model in the jitted substeps, box feet) with contacts; humanoid36 without
    contacts, because MJX's capsule–plane collider makes fewer contacts than MuJoCo C's (see
    test_mjx_physics_tracks_mujoco_c and docs/backends.md)."""
    c, j = env_pair(character, contacts)
    diffs = run_pair(c, j, 10, 0.05)
    print(character, "max |Δr|, |Δobs|, |Δqpos| per step:\n", diffs)
    assert diffs[:, 0].max() < 1e-4 and diffs[:, 1].max() < 1e-4, diffs


@pytest.mark.slow
@pytest.mark.parametrize(("character", "bound"), [("biped20", 1e-3), ("humanoid36", 0.5)])
def test_mjx_physics_tracks_mujoco_c(character: str, bound: float) -> None:
    """50 control steps (250 physics steps) under PD holding the reference (zero residual), with
    contacts: the largest qpos difference stays within the documented bound."""
    c, j = env_pair(character, contacts=True)
    diffs = run_pair(c, j, 50, 0.0)
    print(character, "max |Δqpos| at steps 1, 10, 25, 50:", diffs[[0, 9, 24, 49], 2])
    assert np.isfinite(diffs).all()
    assert diffs[:, 2].max() < bound, diffs[:, 2]
