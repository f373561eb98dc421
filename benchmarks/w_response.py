"""Does the one weight-conditioned policy follow ``w``? A testbed that trains in minutes.

Trains MOPPO on an MO-Gymnasium task (default ``gym:mo-hopper-v5``: forward speed, jump height,
control energy, each with the survival bonus) for a fixed budget, once per lever and seed, then
measures the response to ``w`` with the science protocol (docs/science.md):

- **sweeps**: for each objective k, ``w_k`` in {0, .1, ..., 1} with the rest sharing ``1 - w_k``
  equally, ``--episodes`` episodes per level, deterministic policy; Spearman rho of k's return
  against ``w_k``, monotonicity of the level means, effect size ``(mean[1] - mean[0]) / std[0]``;
  the same rho over the episodes that survived, and of k's mean reward per step (return / length:
  what the policy does while it is up, whatever the episode's length);
- **front**: ``--front-samples`` Dirichlet(1) weights, one episode each; hypervolume (moocore,
  the fixed reference point of the report) and expected utility (EUM) over those weights.

Side by side, with the same budget, seeds and evaluation: morl-baselines' CAPQL (one
weight-conditioned SAC policy), installed by the ``bench`` extra and run with its logging off and
its default hyperparameters.

A lever is a named set of config changes (``LEVERS``, or ``--set`` for a one-off). ``--env toy``
is a seconds-long smoke version (tests/test_w_response.py).

    python benchmarks/w_response.py                                  # paper setting + CAPQL, 10 min
    python benchmarks/w_response.py --lever paper --lever advnorm --budget-steps 1000000 --no-capql
    python benchmarks/w_response.py --env toy --budget-minutes 0.1 --seeds 0 --no-capql --episodes 2
    python benchmarks/w_response.py --measure runs/w-response/paper-s0 --out runs/w-remeasured  # no training
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from science_report import level_stats
from science_runs import git_commit, machine

from amorctl.analysis.eval_env import sweep_weights
from amorctl.analysis.front import expected_utility, hypervolume, non_dominated_fraction
from amorctl.analysis.level_sweep import level_spearman, weight_sweep
from amorctl.analysis.sweeps import pareto_sweep
from amorctl.core.config import TrainConfig, override
from amorctl.train.loop import train_run
from amorctl.train.rundir import RunDir

ROOT = Path(__file__).resolve().parents[1]
LEVELS = tuple(round(0.1 * i, 1) for i in range(11))
#: fixed hypervolume reference points per testbed (morl-baselines' for mo-hopper)
REFERENCE = {"gym:mo-hopper-v5": (-100.0, -100.0, -100.0), "toy": (-100.0, -100.0)}

#: the levers compared, by name: config changes on top of the testbed's base config
LEVERS: dict[str, dict[str, Any]] = {
    "paper": {},
    "value_norm": {"ppo__return_norm": "value"},
    "advnorm": {"ppo__return_norm": "value+advantage"},
    "survival_channel": {"ppo__survival_channel": True},
    "survival_channel+advnorm": {"ppo__survival_channel": True, "ppo__return_norm": "value+advantage"},
    # the same 2048 samples per iteration from 4x as many episodes, so 4x as many weights
    "wide": {"env__num_envs": 256, "ppo__num_steps": 8},
    # the biped's clearest lever (docs/moppo.md): corners and the sweep lines trained on purpose
    "mix": {"weights__corner_fraction": 0.1, "weights__axis_fraction": 0.3},
    "mix+advnorm": {
        "weights__corner_fraction": 0.1,
        "weights__axis_fraction": 0.3,
        "ppo__return_norm": "value+advantage",
    },
    # the same, with rsl_rl's entropy bonus: mix+advnorm's action std collapses (0.6 -> 0.02 in 1 M steps)
    "mix+advnorm+entropy": {
        "weights__corner_fraction": 0.1,
        "weights__axis_fraction": 0.3,
        "ppo__return_norm": "value+advantage",
        "ppo__entropy_coef": 0.01,
    },
}


# ------------------------------------------------------------------------------------ configs
def base_config(env: str, seed: int) -> TrainConfig:
    """The testbed's MOPPO config on the gym adapter (or the toy env): 2 x 64 networks as CleanRL's
    MuJoCo PPO, 2048 samples per iteration from 64 envs, and rsl_rl's update (5 epochs of 4
    minibatches, adaptive learning rate): on 2 CPU cores CleanRL's 320 minibatch steps per
    iteration left the env idle 80 % of the time."""
    if env == "toy":
        return override(
            TrainConfig(),
            env__kind="toy",
            env__num_envs=64,
            env__episode_seconds=1.0,
            network__actor_hidden=(32, 32),
            network__critic_hidden=(32, 32),
            network__init_std=0.5,
            ppo__num_steps=16,
            ppo__learning_rate=1e-3,
            ppo__precision="fp32",
            run__seed=seed,
            run__iterations=100_000,
            run__checkpoint_every=10_000,
            run__tensorboard=False,
        )
    if not env.startswith("gym:"):
        raise SystemExit(f"--env: expected toy or gym:<id>, got {env!r}")
    return override(
        TrainConfig(),
        env__kind="gym",
        env__gym_id=env.removeprefix("gym:"),
        env__num_envs=64,
        network__actor_hidden=(64, 64),
        network__critic_hidden=(64, 64),
        network__init_std=0.6,
        ppo__num_steps=32,
        ppo__num_epochs=5,
        ppo__num_minibatches=4,
        ppo__learning_rate=3e-4,
        ppo__lr_schedule="adaptive",
        ppo__desired_kl=0.01,
        ppo__entropy_coef=0.0,
        ppo__max_grad_norm=1.0,
        ppo__precision="fp32",
        run__seed=seed,
        run__iterations=100_000,
        run__checkpoint_every=10_000,
        run__tensorboard=False,
    )


# ------------------------------------------------------------------------------------ training
def train_moppo(
    config: TrainConfig, out: Path, budget_s: float | None, budget_steps: int | None
) -> dict[str, Any]:
    """Train a new run in ``out`` until the wall-clock or env-step budget; returns its figures."""
    if RunDir(out).exists():
        import shutil

        shutil.rmtree(out)
    began = time.perf_counter()
    last: dict[str, float] = {}

    def stop(m: dict[str, float]) -> bool:
        last.update(m)
        if budget_steps is not None:
            return m.get("env_steps", 0) >= budget_steps
        return time.perf_counter() - began >= (budget_s or 0)

    train_run(config, out, stop_when=stop)
    return {
        "wall_s": time.perf_counter() - began,
        "env_steps": int(last.get("env_steps", 0)),
        "iterations": int(last.get("iteration", 0)),
        "train_survival": last.get("episode/survival"),
    }


class _Budget(Exception):
    """Raised inside a baseline's env once its budget is spent."""


def train_capql(
    env_id: str, seed: int, budget_s: float | None, budget_steps: int | None
) -> tuple[Any, dict[str, Any]]:
    """morl-baselines' CAPQL with its defaults and logging off, stopped at the budget."""
    import gymnasium as gym
    import mo_gymnasium as mo_gym
    from morl_baselines.multi_policy.capql.capql import CAPQL

    began = time.perf_counter()
    steps = [0]

    class Deadline(gym.Wrapper):
        def step(self, action: Any) -> Any:
            steps[0] += 1
            over = (
                steps[0] > budget_steps
                if budget_steps is not None
                else time.perf_counter() - began > (budget_s or 0)
            )
            if over:
                raise _Budget
            return self.env.step(action)

    env = Deadline(mo_gym.make(env_id))
    agent = CAPQL(env, log=False, seed=seed, device="cpu")
    with contextlib.suppress(_Budget):
        agent.train(total_timesteps=10**9, eval_env=mo_gym.make(env_id), ref_point=np.zeros(3))
    return agent, {"wall_s": time.perf_counter() - began, "env_steps": steps[0] - 1, "iterations": None}


class CAPQLPolicy:
    """A CAPQL agent as an amorctl policy: ``obs [N, D + m]`` (weights last) -> actions [N, A]."""

    def __init__(self, agent: Any, names: Sequence[str]) -> None:
        self.agent, self.objectives = agent, tuple(names)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        import torch

        m = len(self.objectives)
        with torch.no_grad():
            return np.asarray(self.agent.eval(obs[:, :-m].astype(np.float32), obs[:, -m:].astype(np.float32)))


# ------------------------------------------------------------------------------------ measuring
def measure(
    policy: Any, config: TrainConfig, env: str, *, episodes: int, samples: int, seed: int
) -> dict[str, Any]:
    """Sweeps of every objective and the front over Dirichlet weights (the module docstring)."""
    names = tuple(policy.objectives)
    sweeps: dict[str, Any] = {}
    for name in names:
        ws = weight_sweep(policy, config, name, levels=LEVELS, episodes=episodes, seed=seed)
        stats = level_stats(ws.levels, ws.returns, ws.survival)
        stats["spearman_rho"] = _rho(ws.spearman_rho)
        kept = np.asarray(ws.survived, dtype=bool)
        stats["survivors"] = int(kept.sum())
        stats["spearman_rho_survivors"] = _rho(
            level_spearman(ws.levels, np.where(kept, ws.returns, np.nan))[0]
        )
        per_step = ws.returns / np.maximum(np.asarray(ws.lengths, dtype=np.float64), 1.0)
        stats["spearman_rho_per_step"] = _rho(level_spearman(ws.levels, per_step)[0])
        sweeps[name] = stats
    ref = np.asarray(REFERENCE.get(env, np.full(len(names), -100.0)), dtype=np.float64)
    w, sampling = sweep_weights(len(names), samples, seed=seed)
    front = pareto_sweep(policy, config, w, episodes=1, reference_point=ref, seed=seed, sampling=sampling)
    points = front.groups[0].points
    return {
        "sweeps": sweeps,
        "front": {
            "samples": samples,
            "reference_point": ref.tolist(),
            "hypervolume": float(hypervolume(points, ref).value),
            "eum": expected_utility(points, w),
            "non_dominated_fraction": non_dominated_fraction(points),
            "equal_weights_point": [float(v) for v in front.groups[0].equal_point],
        },
    }


def _rho(value: float) -> float | None:
    return None if math.isnan(value) else float(value)


def _cell(values: Sequence[float | None], digits: int = 2) -> str:
    v = np.array([np.nan if x is None else x for x in values], dtype=np.float64)
    if np.isnan(v).all():
        return "–"
    mean, known = np.nanmean(v), int(np.isfinite(v).sum())
    if known < len(v):  # some seeds had no value (e.g. no episode survived): say over how many
        return (
            f"{mean:.{digits}f} (of {known})"
            if known == 1
            else f"{mean:.{digits}f} ± {np.nanstd(v):.{digits}f} (of {known})"
        )
    return f"{mean:.{digits}f} ± {np.nanstd(v):.{digits}f}" if len(v) > 1 else f"{mean:.{digits}f}"


def summarize(results: list[dict[str, Any]], names: Sequence[str]) -> list[str]:
    """Markdown rows: one per method, means ± std over seeds; then rho over survivors and of the
    reward per step."""
    rows = [
        "| method | seeds | env steps | " + " | ".join(f"ρ {n}" for n in names) + " | monotone | HV | EUM |",
        "|---|---|---|" + "---|" * len(names) + "---|---|---|",
    ]
    for method in dict.fromkeys(r["method"] for r in results):
        rs = [r for r in results if r["method"] == method]
        rho = [_cell([r["sweeps"][n]["spearman_rho"] for r in rs]) for n in names]
        mono = sum(r["sweeps"][n]["monotonic"] for r in rs for n in names)
        rows.append(
            f"| {method} | {len(rs)} | {_cell([r['env_steps'] for r in rs], 0)} | "
            + " | ".join(rho)
            + f" | {mono}/{len(rs) * len(names)} | {_cell([r['front']['hypervolume'] for r in rs], 0)}"
            f" | {_cell([r['front']['eum'] for r in rs], 1)} |"
        )
    survivors = " | ".join(f"ρ {n} (survivors)" for n in names)
    per_step = " | ".join(f"ρ {n} per step" for n in names)
    rows += ["", f"| method | {survivors} | {per_step} |", "|---|" + "---|" * (2 * len(names))]
    for method in dict.fromkeys(r["method"] for r in results):
        rs = [r for r in results if r["method"] == method]
        cells = [
            _cell([r["sweeps"][n].get(f"spearman_rho_{kind}") for r in rs])
            for kind in ("survivors", "per_step")
            for n in names
        ]
        rows.append(f"| {method} | " + " | ".join(cells) + " |")
    return rows


# ------------------------------------------------------------------------------------ main
def parse_set(text: str) -> tuple[str, Any]:
    import tomllib

    name, sep, value = text.partition("=")
    section, dot, key = name.strip().partition(".")
    if not sep or not dot:
        raise argparse.ArgumentTypeError(f"expected SECTION.KEY=VALUE, got {text!r}")
    return f"{section}__{key}", tomllib.loads(f"v = {value.strip()}")["v"]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="gym:mo-hopper-v5", help="gym:<MO-Gymnasium id> or toy")
    p.add_argument("--budget-minutes", type=float, default=10.0, help="training wall clock per run")
    p.add_argument("--budget-steps", type=int, default=None, help="env steps per run (overrides minutes)")
    p.add_argument("--seeds", default="0,1,2", help="comma-separated training seeds")
    p.add_argument("--lever", action="append", default=None, help=f"one of {', '.join(LEVERS)} (repeatable)")
    p.add_argument(
        "--set", action="append", type=parse_set, default=[], help="one-off lever: SECTION.KEY=VALUE"
    )
    p.add_argument("--no-capql", action="store_true", help="skip morl-baselines' CAPQL")
    p.add_argument("--episodes", type=int, default=8, help="episodes per sweep level")
    p.add_argument("--front-samples", type=int, default=64)
    p.add_argument("--eval-seed", type=int, default=1)
    p.add_argument("--out", type=Path, default=ROOT / "runs" / "w-response")
    p.add_argument(
        "--collect",
        type=Path,
        nargs="+",
        default=None,
        metavar="JSON",
        help="train nothing: merge these reports (runs split over processes) into --out and print the table",
    )
    p.add_argument(
        "--measure",
        type=Path,
        nargs="+",
        default=None,
        metavar="RUN",
        help="train nothing: measure these MOPPO run directories (named LEVER-sSEED) with this protocol",
    )
    return p.parse_args(argv)


def measured_runs(runs: Sequence[Path]) -> list[tuple[str, int, Callable[[], Any]]]:
    """Jobs that open existing run directories (``LEVER-sSEED``, as this script names them)
    instead of training; their figures come from the run's last metrics row."""
    import csv

    jobs = []
    for path in runs:
        run = RunDir.open(path)
        lever = path.name.rsplit("-s", 1)[0]

        def job(run: RunDir = run) -> Any:
            with (run.path / "metrics.csv").open() as f:
                last = list(csv.DictReader(f))[-1]
            figures = {
                "env_steps": int(float(last["env_steps"])),
                "iterations": int(float(last["iteration"])),
                "train_survival": float(last.get("episode/survival") or "nan"),
                "run": str(run.path),
            }
            return run.policy(), run.config, figures

        jobs.append((f"moppo:{lever}", run.config.run.seed, job))
    return jobs


def collect(paths: Sequence[Path], out: Path) -> dict[str, Any]:
    """Merge the results of several reports (e.g. one process per seed) into one."""
    reports = [json.loads(p.read_text()) for p in paths]
    envs = {rep["env"] for rep in reports}
    if len(envs) != 1:
        raise SystemExit(f"--collect: the reports are of different testbeds: {sorted(envs)}")
    merged = {**reports[0], "results": [r for rep in reports for r in rep["results"]]}
    merged["commands"] = sorted({rep["command"] for rep in reports})
    merged["machines"] = sorted({rep["machine"] for rep in reports})
    names = tuple(merged["results"][0]["sweeps"]) if merged["results"] else ()
    merged["table"] = summarize(merged["results"], names)
    out.mkdir(parents=True, exist_ok=True)
    (out / "w_response.json").write_text(json.dumps(merged, indent=1))
    print("\n".join(merged["table"]))
    return merged


def main(argv: list[str] | None = None) -> dict[str, Any]:
    a = parse_args(argv)
    if a.collect:
        return collect(a.collect, a.out)
    seeds = [int(s) for s in a.seeds.split(",") if s.strip()]
    levers = {name: LEVERS[name] for name in (a.lever or ["paper"])}
    if a.set:
        levers["set:" + ",".join(f"{k}={v}" for k, v in a.set)] = dict(a.set)
    budget_s = None if a.budget_steps is not None else a.budget_minutes * 60
    a.out.mkdir(parents=True, exist_ok=True)
    report: dict[str, Any] = {
        "env": a.env,
        "budget": {"steps": a.budget_steps} if a.budget_steps is not None else {"minutes": a.budget_minutes},
        "seeds": seeds,
        "commit": git_commit(),
        "machine": machine(),
        "command": "python benchmarks/w_response.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "results": [],
    }
    names: tuple[str, ...] = ()
    jobs: list[tuple[str, int, Callable[[], tuple[Any, TrainConfig, dict[str, Any]]]]] = []
    for seed in seeds:
        for lever, changes in levers.items():

            def run_lever(lever: str = lever, changes: dict[str, Any] = changes, seed: int = seed) -> Any:
                config = override(base_config(a.env, seed), **changes)
                out = a.out / f"{lever.replace(':', '_').replace(',', '_')}-s{seed}"
                figures = train_moppo(config, out, budget_s, a.budget_steps)
                return RunDir(out).policy(), config, figures

            jobs.append((f"moppo:{lever}", seed, run_lever))
        if not a.no_capql and a.env.startswith("gym:"):

            def run_capql(seed: int = seed) -> Any:
                config = base_config(a.env, seed)
                agent, figures = train_capql(a.env.removeprefix("gym:"), seed, budget_s, a.budget_steps)
                from amorctl.envs.factory import make_env

                env = make_env(override(config, env__num_envs=1))
                pol = CAPQLPolicy(agent, env.reward_space.names)
                env.close()
                return pol, config, figures

            jobs.append(("capql", seed, run_capql))
    if a.measure:
        jobs = measured_runs(a.measure)
    for method, seed, job in jobs:
        print(f"== {method} seed {seed}", flush=True)
        policy, config, figures = job()
        began = time.perf_counter()
        testbed = "toy" if config.env.kind == "toy" else f"gym:{config.env.gym_id}"  # --measure: the run's
        report["env"] = testbed
        measured = measure(
            policy, config, testbed, episodes=a.episodes, samples=a.front_samples, seed=a.eval_seed
        )
        names = tuple(policy.objectives)
        row = {"method": method, "seed": seed, **figures, **measured, "eval_s": time.perf_counter() - began}
        report["results"].append(row)
        rhos = " ".join(f"{n} {s['spearman_rho']}" for n, s in measured["sweeps"].items())
        print(
            f"   {figures['env_steps']:,} env steps in {figures.get('wall_s', math.nan):.0f} s; rho {rhos}; "
            f"HV {measured['front']['hypervolume']:.4g}, EUM {measured['front']['eum']:.4g}",
            flush=True,
        )
        (a.out / "w_response.json").write_text(json.dumps(report, indent=1))
    report["table"] = summarize(report["results"], names)
    (a.out / "w_response.json").write_text(json.dumps(report, indent=1))
    print("\n".join(report["table"]))
    return report


if __name__ == "__main__":
    main()
