"""Env steps/s of the tracking env, and its ratio to the ideal multi-threaded physics rate.

For each character and batch size the script times full ``TrackingEnv.step`` calls (physics,
actuator model, observations, rewards, resets) while replaying the reference with a little noise,
and, in the same run, the single-thread ``mj_step`` rate on the same model from the same states.
The ratio is ``env steps/s / (single-thread mj_step rate / substeps * nthread)``; 1.0 would be
perfect scaling with no glue cost. By default the clips are synthetic (swaying in place), so no
dataset is needed; ``--clips builtin`` tracks the preprocessed DeepMimic clips instead. One line
per setting, ending in ``ratio: X.XX``. Servo characters (biped20) are measured with both servo
implementations, side by side: ``native`` (MuJoCo's dcmotor + history delay, what the env runs)
and ``python`` (the numpy reference between single physics steps; the state before the servo
moved into MuJoCo); ``--servo-models`` picks. Each setting's bound uses its own model, so the
native one's bound includes the servo's cost in C. Run under the shared lock (and ``taskset`` to
pin cores); figures are noisy on shared machines.

    python benchmarks/env_throughput.py [--characters humanoid36 biped20] [--envs 256 1024]
        [--clips synthetic|builtin] [--seconds 4] [--nthread 2] [--servo-models native python]
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

from amorctl.envs.synthetic import synthetic_library
from amorctl.envs.tracking_env import TrackingEnv
from amorctl.registry import get_registry
from amorctl.sim.batch_sim import STATE_SPEC, BatchSim


def single_thread_rate(env: TrackingEnv, samples: int = 128, repeats: int = 3) -> float:
    """Physics steps/s of ``mj_step`` on one thread, from the env's current states and controls."""
    sim = env.sim
    m = sim.model
    d = mujoco.MjData(m)
    ids = np.linspace(0, env.num_envs - 1, min(samples, env.num_envs)).astype(int)
    ctrl = sim.ctrl[:, 0].copy()  # timed actions include noise; these are the last ones applied
    if sim.python_servo:  # motor actuators: replay the last computed servo torques
        ctrl[:, sim.actuators] = sim.torque[:, -1] / sim.gear
    best = 0.0
    for _ in range(repeats):
        elapsed = 0.0
        for i in ids:
            mujoco.mj_setState(m, d, sim.state[i], STATE_SPEC)
            d.qacc_warmstart[:] = sim.warmstart[i]
            d.ctrl[:] = ctrl[i]
            t0 = time.perf_counter()
            for _ in range(sim.substeps):
                mujoco.mj_step(m, d)
            elapsed += time.perf_counter() - t0
        best = max(best, len(ids) * sim.substeps / elapsed)
    return best


def measure(
    character: str,
    num_envs: int,
    nthread: int,
    seconds: float,
    clips: str = "synthetic",
    seed: int = 0,
    servo_model: str = "native",
) -> dict[str, float]:
    """Env steps/s and the ratio for one setting.

    ``clips``: ``"synthetic"`` (swaying clips, no data needed) or ``"builtin"`` (the character's
    preprocessed DeepMimic dataset from the user cache; built on first use, which takes minutes).
    ``servo_model``: ``"native"`` or ``"python"`` (servo characters; see the module docstring).
    """
    ch = get_registry().character(character)
    if clips == "builtin":
        from amorctl.motion.cache import default_dataset
        from amorctl.motion.dataset import load_dataset

        lib = load_dataset(default_dataset(character))
    else:
        lib = synthetic_library(ch, num_clips=4, seconds=4.0, seed=seed)
    env = TrackingEnv(ch, lib, num_envs=num_envs, nthread=nthread, seed=seed, max_episode_steps=200)
    if ch.actuator.kind == "servo" and servo_model != "native":  # the reference servo, for comparison
        env.sim.close()
        env.sim = BatchSim(ch, num_envs, nthread=nthread, servo_model=servo_model)  # type: ignore[arg-type]
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)

    def act() -> np.ndarray:
        return lib.joint_pos[env.ref_idx + 1] + 0.05 * rng.standard_normal((num_envs, env.action_dim))

    for _ in range(5):
        env.step(act())
    base_before = single_thread_rate(env)
    # Time windows of a few steps and keep the best: other processes on a shared machine only
    # ever slow a window down, and the single-thread rate is a best-of as well.
    sim_step = env.sim.step
    sim_time = [0.0]

    def timed_sim_step(target: np.ndarray) -> object:  # physics + actuator model, for the share
        t = time.perf_counter()
        out = sim_step(target)
        sim_time[0] += time.perf_counter() - t
        return out

    env.sim.step = timed_sim_step  # type: ignore[method-assign]
    steps, resets, best, t_start = 0, 0, 0.0, time.perf_counter()
    while time.perf_counter() - t_start < seconds or steps < 10:
        window = 0.05 * rng.standard_normal((5, num_envs, env.action_dim))
        t0 = time.perf_counter()
        for noise in window:  # reference targets + noise, the "policy"
            _, _, term, trunc, _ = env.step(lib.joint_pos[env.ref_idx + 1] + noise)
            resets += int(term.sum() + trunc.sum())
        best = max(best, len(window) * num_envs / (time.perf_counter() - t0))
        steps += len(window)
    total = time.perf_counter() - t_start
    base_after = single_thread_rate(env)
    env.close()
    rate = best
    single = max(base_before, base_after)
    ideal = single / ch.substeps * nthread
    return {
        "env_steps_per_s": rate,
        "single_thread_physics_per_s": single,
        "ideal_env_steps_per_s": ideal,
        "resets_per_step": resets / steps,
        "physics_share": sim_time[0] / total,
        "ratio": rate / ideal,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--characters", nargs="+", default=["humanoid36", "biped20"])
    parser.add_argument("--envs", nargs="+", type=int, default=[256, 1024])
    parser.add_argument("--nthread", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=4.0, help="timed seconds per setting")
    parser.add_argument("--clips", choices=["synthetic", "builtin"], default="synthetic")
    parser.add_argument(
        "--servo-models", nargs="+", choices=["native", "python"], default=["native", "python"],
        help="servo implementations to measure for servo characters",
    )  # fmt: skip
    args = parser.parse_args()
    registry = get_registry()
    for character in args.characters:
        servo = registry.character(character).actuator.kind == "servo"
        for n in args.envs:
            for model in args.servo_models if servo else ["native"]:
                report(character, n, model if servo else "", args)


def report(character: str, n: int, servo_model: str, args: argparse.Namespace) -> None:
    """Measure one setting and print its line."""
    r = measure(character, n, args.nthread, args.seconds, args.clips, servo_model=servo_model or "native")
    label = f"{character}/{servo_model}" if servo_model else character
    print(
        f"{label:<18} envs: {n:5d}  env steps/s: {r['env_steps_per_s']:8.0f}  "
        f"1-thread mj_step/s: {r['single_thread_physics_per_s']:8.0f}  "
        f"ideal ({args.nthread} threads): {r['ideal_env_steps_per_s']:8.0f}  "
        f"resets/step: {r['resets_per_step']:.2f}  physics share: {r['physics_share']:.0%}  "
        f"ratio: {r['ratio']:.2f}",
        flush=True,
    )


if __name__ == "__main__":
    main()
