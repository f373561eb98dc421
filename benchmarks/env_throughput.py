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
        [--breakdown]

``--breakdown`` prints, instead, where a step's time goes: the whole ``env.step`` against the
bare rollout call of the same batch on the env's pool and on a 1-thread pool, and against the
single-thread ``mj_step`` loop the bound uses (all in env steps/s, best of 15 alternating windows).
"""

from __future__ import annotations

import argparse
import time

import mujoco
import mujoco.rollout
import numpy as np

from amorctl.envs.synthetic import synthetic_library
from amorctl.envs.tracking_env import TrackingEnv
from amorctl.registry import get_registry
from amorctl.sim.batch_sim import STATE_SPEC, BatchSim
from amorctl.sim.cpus import available_cpus


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


def rollout_breakdown(env: TrackingEnv, lib: object, windows: int = 15, steps: int = 5) -> dict[str, float]:
    """Where an env step's time goes, in env steps/s (best window of each, timed alternately in
    one process): ``env`` (whole ``env.step``), ``rollout`` (the bare pool call of the same batch
    and controls, ``nthread`` threads), ``rollout_1`` (the same on a 1-thread pool) and
    ``single`` (the single-thread ``mj_step`` loop of the bound, per env step)."""
    sim, n = env.sim, env.num_envs
    pool_1 = mujoco.rollout.Rollout(nthread=1)
    rng = np.random.default_rng(0)
    best = dict.fromkeys(("env", "rollout", "rollout_1", "single"), 0.0)

    def timed(key: str, fn: object, count: int) -> None:
        t0 = time.perf_counter()
        fn()  # type: ignore[operator]
        best[key] = max(best[key], count / (time.perf_counter() - t0))

    def env_steps() -> None:
        for _ in range(steps):
            env.step(lib.joint_pos[env.ref_idx + 1] + 0.05 * rng.standard_normal((n, env.action_dim)))  # type: ignore[attr-defined]

    def pool_calls(pool: mujoco.rollout.Rollout | None, datas: list[mujoco.MjData] | None) -> None:
        for _ in range(steps):
            sim._rollout(sim.ctrl.shape[1], pool, datas)  # the env's own call, state not advanced

    for _ in range(windows):
        timed("env", env_steps, steps * n)
        timed("rollout", lambda: pool_calls(None, None), steps * n)
        timed("rollout_1", lambda: pool_calls(pool_1, sim._datas[:1]), steps * n)
        best["single"] = max(best["single"], single_thread_rate(env, samples=64, repeats=1) / sim.substeps)
    pool_1.close()
    return best


class _Setting:
    """One env under measurement: its best window rate, the single-thread bound, time shares."""

    def __init__(self, env: TrackingEnv, lib: object, rng: np.random.Generator) -> None:
        self.env, self.lib, self.rng = env, lib, rng
        self.best = self.single = self.sim_time = self.total = 0.0
        self.steps = self.resets = 0
        sim_step = env.sim.step

        def timed_sim_step(target: np.ndarray) -> object:  # physics + actuator model, for the share
            t = time.perf_counter()
            out = sim_step(target)
            self.sim_time += time.perf_counter() - t
            return out

        env.sim.step = timed_sim_step  # type: ignore[method-assign]

    def window(self, steps: int = 5) -> None:
        """Time ``steps`` env steps (reference targets + 0.05 rad noise, the "policy")."""
        env, n = self.env, self.env.num_envs
        noise = 0.05 * self.rng.standard_normal((steps, n, env.action_dim))
        t0 = time.perf_counter()
        for step_noise in noise:
            _, _, term, trunc, _ = env.step(self.lib.joint_pos[env.ref_idx + 1] + step_noise)  # type: ignore[attr-defined]
            self.resets += int(term.sum() + trunc.sum())
        elapsed = time.perf_counter() - t0
        self.best = max(self.best, steps * n / elapsed)
        self.total += elapsed
        self.steps += steps


def measure(
    character: str,
    num_envs: int,
    nthread: int,
    seconds: float,
    clips: str = "synthetic",
    seed: int = 0,
    servo_models: tuple[str, ...] = ("native",),
) -> dict[str, dict[str, float]]:
    """Env steps/s and the ratio for one character and batch size, per servo model.

    ``clips``: ``"synthetic"`` (swaying clips, no data needed) or ``"builtin"`` (the character's
    preprocessed DeepMimic dataset from the user cache; built on first use, which takes minutes).
    ``servo_models``: ``"native"`` and/or ``"python"`` (servo characters; PD characters measure
    one setting). The settings are timed alternately, window by window, for ``seconds`` each, so
    that load from other processes hits them alike; every rate is a best-of (other processes only
    ever slow a window down).
    """
    ch = get_registry().character(character)
    if clips == "builtin":
        from amorctl.motion.cache import default_dataset
        from amorctl.motion.dataset import load_dataset

        lib = load_dataset(default_dataset(character))
    else:
        lib = synthetic_library(ch, num_clips=4, seconds=4.0, seed=seed)
    models = servo_models if ch.actuator.kind == "servo" else ("native",)
    settings = {}
    for model in models:
        env = TrackingEnv(ch, lib, num_envs=num_envs, nthread=nthread, seed=seed, max_episode_steps=200)
        if model != "native":  # the reference servo, for comparison
            env.sim.close()
            env.sim = BatchSim(ch, num_envs, nthread=nthread, servo_model=model)  # type: ignore[arg-type]
        env.reset(seed=seed)
        for _ in range(5):
            env.step(lib.joint_pos[env.ref_idx + 1])
        settings[model] = _Setting(env, lib, np.random.default_rng(seed))
    t_start = time.perf_counter()
    while (
        time.perf_counter() - t_start < seconds * len(settings)
        or min(s.steps for s in settings.values()) < 10
    ):
        for setting in settings.values():
            setting.window()
            setting.single = max(setting.single, single_thread_rate(setting.env, samples=16, repeats=1))
    out = {}
    for model, st in settings.items():
        st.single = max(st.single, single_thread_rate(st.env))
        st.env.close()
        ideal = st.single / ch.substeps * nthread
        out[model] = {
            "env_steps_per_s": st.best,
            "single_thread_physics_per_s": st.single,
            "ideal_env_steps_per_s": ideal,
            "resets_per_step": st.resets / st.steps,
            "physics_share": st.sim_time / st.total,
            "ratio": st.best / ideal,
        }
    return out


def print_breakdown(character: str, num_envs: int, nthread: int, clips: str) -> None:
    """One line of :func:`rollout_breakdown`'s rates and their ratios (the env's own servo model)."""
    ch = get_registry().character(character)
    if clips == "builtin":
        from amorctl.motion.cache import default_dataset
        from amorctl.motion.dataset import load_dataset

        lib = load_dataset(default_dataset(character))
    else:
        lib = synthetic_library(ch, num_clips=4, seconds=4.0, seed=0)
    env = TrackingEnv(ch, lib, num_envs=num_envs, nthread=nthread, seed=0, max_episode_steps=200)
    env.reset(seed=0)
    for _ in range(5):
        env.step(lib.joint_pos[env.ref_idx + 1])
    r = rollout_breakdown(env, lib)
    env.close()
    print(
        f"{character:<12} envs: {num_envs:5d}  env {r['env']:8.0f}  rollout ({nthread} threads) "
        f"{r['rollout']:8.0f}  rollout (1 thread) {r['rollout_1']:8.0f}  mj_step loop {r['single']:8.0f}  "
        f"env/rollout: {r['env'] / r['rollout']:.2f}  rollout/({nthread} x loop): "
        f"{r['rollout'] / (nthread * r['single']):.2f}  "
        f"1-thread rollout/loop: {r['rollout_1'] / r['single']:.2f}  "
        f"threads: {r['rollout'] / r['rollout_1']:.2f}x",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--characters", nargs="+", default=["humanoid36", "biped20"])
    parser.add_argument("--envs", nargs="+", type=int, default=[256, 1024])
    parser.add_argument("--nthread", type=int, default=available_cpus(), help="default: the affinity's cores")
    parser.add_argument(
        "--seconds",
        type=float,
        default=4.0,
        help="timed seconds per setting (settings alternate window by window)",
    )
    parser.add_argument("--clips", choices=["synthetic", "builtin"], default="synthetic")
    parser.add_argument(
        "--servo-models", nargs="+", choices=["native", "python"], default=["native", "python"],
        help="servo implementations to measure for servo characters",
    )  # fmt: skip
    parser.add_argument(
        "--breakdown", action="store_true",
        help="instead: where the step time goes (env vs bare rollout vs 1-thread rollout vs mj_step loop)",
    )  # fmt: skip
    args = parser.parse_args()
    for character in args.characters:
        for n in args.envs:
            if args.breakdown:
                print_breakdown(character, n, args.nthread, args.clips)
                continue
            results = measure(
                character, n, args.nthread, args.seconds, args.clips, servo_models=tuple(args.servo_models)
            )
            servo = get_registry().character(character).actuator.kind == "servo"
            for model, r in results.items():
                label = f"{character}/{model}" if servo else character
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
