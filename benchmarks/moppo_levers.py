"""The weight-response training levers (docs/moppo.md, "Levers"), measured cheaply by fine-tuning.

Protocol: every variant continues the same trained run (``--base``, e.g. the quick-preset biped20
walking run ``runs/b20walk``) from its newest checkpoint for the same number of iterations, with
only the lever changed, and is then evaluated with ``evaluate --sweep`` for each objective
(:func:`amorctl.analysis.level_sweep.weight_sweep`: levels 0, .25, .5, .75, 1, the other objectives
sharing the rest, deterministic policy, 10 s episodes from the clips' first frames). The
``paper`` variant (no lever) continues the run the same way, so the comparison isolates the lever
from the extra training. A lever whose state the base checkpoint lacks (the return scale, the
adaptive sampler's per-env bookkeeping) starts from a fresh trainer's values; every variant
starts from fresh episodes (the base's env state is not carried over).

Usage (each step is a separate command so the shared lock is held briefly):
  python benchmarks/moppo_levers.py prepare --base runs/b20walk --variant mix --iterations 100
  amorctl train --resume --out runs/levers-mix --iterations <printed>
  python benchmarks/moppo_levers.py eval runs/levers-mix [--episodes 8]
  python benchmarks/moppo_levers.py table runs/levers-*     (a markdown table of the results)
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from amorctl.analysis.level_sweep import weight_sweep
from amorctl.core.config import merge, to_toml
from amorctl.core.contracts import Snapshot
from amorctl.core.files import atomic_write_text
from amorctl.envs.factory import make_env
from amorctl.registry import get_registry
from amorctl.train.checkpoint import save_checkpoint
from amorctl.train.rundir import RunDir

#: The lever settings compared (partial TOML data on top of the base run's config).
VARIANTS: dict[str, dict[str, dict[str, Any]]] = {
    "paper": {},
    "mix": {"weights": {"corner_fraction": 0.1, "axis_fraction": 0.3}},
    "adaptive": {"weights": {"adaptive_fraction": 0.3}},
    "alpha05": {"weights": {"alpha": 0.5}},
    "value": {"ppo": {"return_norm": "value"}},
    "value-adv": {"ppo": {"return_norm": "value+advantage"}},
    "science": {"weights": {"corner_fraction": 0.1, "axis_fraction": 0.3}, "ppo": {"return_norm": "value"}},
}


def _fill_missing(have: Snapshot, fresh: Snapshot) -> Snapshot:
    """``have`` with the arrays and metadata keys only ``fresh`` has (a lever's initial state)."""
    arrays = {**{k: v for k, v in fresh.arrays.items() if k not in have.arrays}, **have.arrays}
    meta = {**{k: v for k, v in fresh.meta.items() if k not in have.meta}, **have.meta}
    return Snapshot(arrays, meta)


def prepare(base: Path, variant: str, iterations: int, out: Path) -> int:
    """Copy ``base``'s config (with the variant's levers) and newest checkpoint (with the levers'
    initial state filled in) into ``out``; returns the iteration count to resume to."""
    run = RunDir.open(base)
    ckpt = run.checkpoint()
    config = merge(run.config, {**VARIANTS[variant], "run": {"iterations": ckpt.iteration + iterations}})
    if out.exists():
        shutil.rmtree(out)
    (out / "checkpoints").mkdir(parents=True)
    atomic_write_text(out / "config.toml", to_toml(config))
    shutil.copy(base / "metrics.csv", out / "metrics.csv")
    backend = get_registry().backend(config.run.backend).make()
    env = make_env(config, backend)
    try:
        trainer = backend.make_trainer(env, config)
        trainer_state = _fill_missing(ckpt.trainer, trainer.state_dict())
    finally:
        env.close()
    # without the env state the run continues from fresh episodes (seeded with seed + iteration),
    # so every variant starts alike, with its own sampler's draws, and a base run made before a
    # change of the simulator's state layout can still be continued
    save_checkpoint(out / "checkpoints", ckpt.iteration, dict(ckpt.meta), trainer_state, None)
    return ckpt.iteration + iterations


def evaluate(path: Path, episodes: int, seed: int) -> dict[str, Any]:
    """Every objective's sweep of the run's newest checkpoint; saved as ``path/levers.json``."""
    run = RunDir.open(path)
    policy, config = run.policy(), run.config
    began = time.perf_counter()
    result: dict[str, Any] = {"run": str(path), "iteration": run.checkpoint().iteration, "sweeps": {}}
    for name in policy.objectives:
        ws = weight_sweep(policy, config, name, episodes=episodes, seed=seed)
        means = ws.returns.mean(axis=1)
        result["sweeps"][name] = {
            "levels": [float(v) for v in ws.levels],
            "mean": [float(v) for v in means],
            "survival": [float(v) for v in np.asarray(ws.survival).reshape(len(ws.levels), -1).mean(1)],
            "rho": float(ws.spearman_rho),
            "monotonic": bool(np.all(np.diff(means) > 0)),
        }
        s = result["sweeps"][name]
        print(
            f"{path.name:>18} {name:>6}: rho {s['rho']:+.2f} means "
            + " ".join(f"{v:.1f}" for v in s["mean"])
            + " survival "
            + " ".join(f"{v:.2f}" for v in s["survival"]),
            flush=True,
        )
    result["seconds"] = time.perf_counter() - began
    atomic_write_text(path / "levers.json", json.dumps(result, indent=1))
    return result


def table(paths: list[Path]) -> str:
    """Markdown: per variant, rho per objective, min survival over levels, and the mean over objectives."""
    rows = []
    names: list[str] = []
    for path in paths:
        file = path / "levers.json"
        if not file.is_file():
            continue
        r = json.loads(file.read_text())
        names = list(r["sweeps"])
        rhos = [r["sweeps"][n]["rho"] for n in names]
        surv = [r["sweeps"][n]["survival"] for n in names]
        rows.append(
            f"| {path.name} | "
            + " | ".join(f"{v:+.2f}" for v in rhos)
            + f" | {np.mean(rhos):+.2f} | {np.min(surv):.2f} | {np.mean(surv):.2f} |"
        )
    head = "| run | " + " | ".join(f"ρ {n}" for n in names) + " | mean ρ | min survival | mean survival |"
    return "\n".join([head, "|" + "---|" * (len(names) + 4), *rows])


def main(argv: list[str]) -> None:
    formatter = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=formatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("prepare")
    p.add_argument("--base", type=Path, default=Path("runs/b20walk"))
    p.add_argument("--variant", choices=sorted(VARIANTS), required=True)
    p.add_argument("--iterations", type=int, default=100)
    p.add_argument("--out", type=Path, default=None)
    e = sub.add_parser("eval")
    e.add_argument("run", type=Path)
    e.add_argument("--episodes", type=int, default=8)
    e.add_argument("--seed", type=int, default=0)
    t = sub.add_parser("table")
    t.add_argument("runs", type=Path, nargs="+")
    args = parser.parse_args(argv)
    if args.command == "prepare":
        out = args.out or Path("runs") / f"levers-{args.variant}"
        total = prepare(args.base, args.variant, args.iterations, out)
        print(f"amorctl train --resume --out {out} --iterations {total}")
    elif args.command == "eval":
        evaluate(args.run, args.episodes, args.seed)
    else:
        print(table(args.runs))


if __name__ == "__main__":
    main(sys.argv[1:])
