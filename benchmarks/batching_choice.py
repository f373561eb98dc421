"""Which way to step N MuJoCo envs on CPU threads: the rollout pool or per-env MjData on threads.

Both step the same N states for one control step (``substeps`` physics steps, constant controls)
and end with the batch state in one numpy array, which the env needs for observations:

* ``rollout``: one reused ``mujoco.rollout.Rollout(nthread)`` call with ``nstep=substeps``,
  passing each env's warm start; the result lands in a preallocated ``[N, nstep, nstate]`` array.
* ``threads``: N ``MjData`` kept alive (their warm start with them), split over ``nthread``
  Python threads that call ``mj_step`` (which releases the GIL) and copy qpos/qvel out.

Prints physics steps/s of each and their ratio to ``nthread`` x the single-thread rate.

    python benchmarks/batching_choice.py [--characters humanoid36 biped20] [--envs 256 1024]
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import mujoco
import mujoco.rollout
import numpy as np

from amorctl.envs.synthetic import synthetic_library
from amorctl.envs.tracking_env import TrackingEnv
from amorctl.registry import get_registry
from amorctl.sim.batch_sim import CTRL_SPEC, STATE_SPEC, BatchSim


def states_of(character: str, n: int) -> tuple[BatchSim, np.ndarray, np.ndarray, np.ndarray]:
    """N realistic states (RSI + a few tracking steps), their warm starts and PD-like controls."""
    ch = get_registry().character(character)
    lib = synthetic_library(ch, num_clips=4, seconds=4.0)
    env = TrackingEnv(ch, lib, num_envs=n, seed=0)
    env.reset(seed=0)
    for _ in range(5):
        env.step(lib.joint_pos[env.ref_idx + 1])
    sim = env.sim
    ctrl = np.zeros((n, sim.model.nu))
    ctrl[:, sim.actuators] = sim.ctrl[:, 0, sim.actuators] if not sim.python_servo else sim.torque[:, -1]
    return sim, sim.state.copy(), sim.warmstart.copy(), ctrl


def step_slice(
    m: mujoco.MjModel,
    steps: int,
    envs: list[mujoco.MjData],
    qpos: np.ndarray,
    qvel: np.ndarray,
    lo: int,
    hi: int,
) -> None:
    """One thread's share: step envs[lo:hi] ``steps`` times, copy their qpos/qvel out."""
    for i in range(lo, hi):
        d = envs[i]
        for _ in range(steps):
            mujoco.mj_step(m, d)
        qpos[i] = d.qpos
        qvel[i] = d.qvel


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--characters", nargs="+", default=["humanoid36", "biped20"])
    parser.add_argument("--envs", nargs="+", type=int, default=[256, 1024])
    parser.add_argument("--nthread", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    nt = args.nthread
    for character in args.characters:
        for n in args.envs:
            sim, state, warm, ctrl = states_of(character, n)
            m, steps = sim.model, sim.substeps
            sim.close()
            # single thread
            d = mujoco.MjData(m)
            t0 = time.perf_counter()
            for i in range(min(n, 128)):
                mujoco.mj_setState(m, d, state[i], STATE_SPEC)
                d.qacc_warmstart[:] = warm[i]
                d.ctrl[:] = ctrl[i]
                for _ in range(steps):
                    mujoco.mj_step(m, d)
            single = min(n, 128) * steps / (time.perf_counter() - t0)
            # rollout pool
            pool = mujoco.rollout.Rollout(nthread=nt)
            datas = [mujoco.MjData(m) for _ in range(nt)]
            control = np.repeat(ctrl[:, None, :], steps, axis=1)
            out = np.empty((n, steps, state.shape[1]))
            sens = np.empty((n, steps, m.nsensordata))
            best_r = 0.0
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                pool.rollout(
                    [m] * n,
                    datas,
                    state,
                    control,
                    control_spec=CTRL_SPEC,
                    skip_checks=True,
                    nstep=steps,
                    initial_warmstart=warm,
                    state=out,
                    sensordata=sens,
                    chunk_size=max(1, min(8, n // (nt * 16))),
                )
                best_r = max(best_r, n * steps / (time.perf_counter() - t0))
            pool.close()
            # per-env MjData on Python threads
            envs = [mujoco.MjData(m) for _ in range(n)]
            qpos, qvel = np.empty((n, m.nq)), np.empty((n, m.nv))

            work = partial(step_slice, m, steps, envs, qpos, qvel)
            bounds = np.linspace(0, n, nt + 1).astype(int)
            best_t = 0.0
            with ThreadPoolExecutor(nt) as ex:
                for _ in range(args.repeats):
                    for i, di in enumerate(envs):  # same start states (not timed)
                        mujoco.mj_setState(m, di, state[i], STATE_SPEC)
                        di.qacc_warmstart[:] = warm[i]
                        di.ctrl[:] = ctrl[i]
                    t0 = time.perf_counter()
                    list(ex.map(work, bounds[:-1], bounds[1:]))
                    best_t = max(best_t, n * steps / (time.perf_counter() - t0))
            ideal = nt * single
            print(
                f"{character:<12} envs: {n:5d}  1-thread: {single:7.0f}  rollout: {best_r:7.0f} "
                f"({best_r / ideal:.2f})  threads: {best_t:7.0f} ({best_t / ideal:.2f})  "
                f"threads/rollout: {best_t / best_r:.2f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
