"""The weight-response measurement protocol: does the one AMOR policy obey ``w``? Writes ``docs/science.md``.

On a character's walking clips (``walk``, ``walker/*``: the selection of
``benchmarks/learn_biped20_walk.py``), in this order, each part saving what it measured to
``OUT/science.json`` and re-rendering the report before the next starts (a partial run still
documents what it measured, and names the command for the rest):

- ``train``: MOPPO for ``--budget-minutes`` of wall clock (``OUT/moppo``; every checkpoint kept);
- ``sweeps``: claim (ii), ``evaluate --sweep`` for each objective (5 levels, rest equal): level
  means, monotonicity, Spearman rho, effect size, survival; for ``smooth`` the action rate and
  joint-velocity RMS per level;
- ``front``: claim (i), 1024 Dirichlet weights on ``walk``: non-dominated fraction and hypervolume
  at a fixed reference point, on all episodes and on the survivors;
- ``bar``: the learning bar, survival over 10 s (uniform w) and joint MAE (tracking-heavy vs uniform);
- ``ppo``: PPO = the same trainer with ``[env] fixed_weights = "uniform"`` for MOPPO's iterations
  (equal env steps; ``OUT/ppo-uniform``);
- ``curves``: learning curves of both runs' checkpoints (uniform-w return of MOPPO and PPO, MOPPO
  at random w) in one figure, and the MOPPO / PPO ratio at the last common env-step count;
- ``kfixed``: 7 PPO runs with corner-heavy fixed weights sharing MOPPO's total env steps; the
  hypervolume of their 7 points vs AMOR's at the same weights.

Usage:
  python benchmarks/science.py --budget-minutes 25 --character biped20 --preset science \\
      --out runs/science-biped20 [--only train,sweeps,...] [--skip-train] [--deadline 12:45]
Lever experiments change one preset value per ``--set SECTION.KEY=VALUE`` (TOML value, repeatable;
recorded in the report's rerun commands), e.g. ``--preset science_sc --set ppo.survival_weight=2``.
Tiny smoke test: --budget-minutes 1 --sweep-episodes 2 --front-samples 16 --doc /tmp/s.md
A run trained elsewhere (a shipped one trained on more clips, say) is measured on its walking clips
with ``--run``: ``--run pretrained:biped20-repertoire --only sweeps,front,bar --out OUT --doc DOC``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import shlex
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from learn_biped20_walk import save_subset, walking_subset
from science_args import PARTS, RUN_PARTS, config_setting, parse_args  # noqa: F401 (tests use them here)
from science_figures import plot_curves, plot_sweeps
from science_measure import fixed_points, measure_bar, measure_front, measure_sweeps, scalarized
from science_report import common_iterations, corner_heavy_weights, hv_reference, render_markdown
from science_runs import Clock, git_commit, machine, metrics_rows, run_summary, train

from amorctl.analysis.eval_env import sweep_weights
from amorctl.analysis.front import hypervolume
from amorctl.core.config import TrainConfig, load_preset, override
from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_write_text
from amorctl.core.weights import format_weights
from amorctl.motion.cache import default_dataset
from amorctl.motion.dataset import load_dataset
from amorctl.sim.cpus import available_cpus
from amorctl.train.rundir import RunDir


# ------------------------------------------------------------------------------------ parts
class Science:
    """The state of one protocol run: arguments, the results dict, where to write."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.out: Path = args.out
        self.clock = Clock(args.deadline)
        self.json_path = self.out / "science.json"
        self.results: dict[str, Any] = (
            json.loads(self.json_path.read_text()) if self.json_path.exists() else {}
        )
        self.results.setdefault("skipped", {})
        self.doc: Path = args.doc
        self.img = self.doc.parent / "img"
        self.moppo = self.out / "moppo"
        self.ppo = self.out / "ppo-uniform"
        self.dataset = self.out / "walking.mcap"
        #: the clips sweeps and the bar draw from: None for the protocol's own run (its dataset is
        #: the walking clips); a run measured with ``--run`` rolls out on its walking clips only
        self.motions: list[str] | None = None
        self.run_clips = 0  # clips in a --run's dataset
        if args.run:
            run = RunDir.open(args.run)
            args.character = run.config.env.character  # the run's, whatever --character said
            self.moppo = run.path
            library = load_dataset(run.dataset_path())
            self.run_clips = len(library.clips)
            self.motions = [c.name for c in walking_subset(library).clips]
        # figures: science-<character>-*.png, or the report's own stem when it extends that name
        # (docs/science-biped20-survival.md -> science-biped20-survival-*.png), so reports of
        # other runs of one character do not overwrite each other's figures (the character is the
        # measured run's with --run)
        base = f"science-{args.character}"
        self.figure_stem = self.doc.stem if self.doc.stem.startswith(base) else base

    # -- config and runs
    def base_config(self, **changes: Any) -> TrainConfig:
        a = self.args
        fields: dict[str, Any] = {
            "env__character": a.character,
            "env__dataset": str(self.dataset),
            "env__num_envs": a.num_envs or load_preset(a.preset).env.num_envs,
            "run__seed": a.seed,
            "run__iterations": 1_000_000,
            "run__checkpoint_every": a.checkpoint_every,
            "run__keep_checkpoints": 0,
            "run__threads": available_cpus(),
            **a.set,
        }
        return override(load_preset(a.preset), **{**fields, **changes})

    def moppo_iterations(self) -> int:
        return RunDir.open(self.moppo).checkpoints()[-1][0]

    def save(self) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(self.json_path, json.dumps(self.results, indent=1) + "\n")
        self.doc.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(self.doc, render_markdown(self.results, self.protocol()))

    def rel(self, path: Path) -> str:
        return os.path.relpath(path, self.doc.parent)

    def meta(self) -> None:
        a = self.args
        other = "humanoid36" if a.character == "biped20" else "biped20"
        base = (
            f"python benchmarks/science.py --character {a.character} --preset {a.preset} "
            + (
                f"--budget-steps {a.budget_steps}"
                if a.budget_steps
                else f"--budget-minutes {a.budget_minutes:g}"
            )
            + f" --out {self.out}"
            + "".join(f" --set {shlex.quote(t)}" for t in a.set_text)
        )
        rerun = {
            "train": base + " --only train",
            "sweeps": base + " --skip-train --only sweeps",
            "front": base + " --skip-train --only front",
            "bar": base + " --skip-train --only bar",
            "curves": base + " --only ppo,curves",
            "kfixed": base + " --only kfixed",
            "other_character": base.replace(f"--character {a.character}", f"--character {other}").replace(
                str(self.out), f"runs/science-{other}"
            ),
        }
        if a.run:  # one run measured: its own parts only
            base = f"python benchmarks/science.py --run {a.run} --out {self.out} --doc {self.doc}"
            rerun = {part: f"{base} --only {part}" for part in RUN_PARTS}
        self.results["meta"] = {
            "command": shlex.join([Path(sys.executable).name, *sys.argv]),
            "commit": git_commit(),
            "date_utc": dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "machine": machine(),
            "character": a.character,
            "preset": "the run's own config" if a.run else a.preset,
            "settings": a.set_text,
            "dataset": (
                f"the {len(self.motions)} walking clips (`walk`, `walker/*`) of the measured run's "
                f"{self.run_clips}-clip dataset"
                if self.motions
                else f"the {len(load_dataset(self.dataset).clips)} walking clips of the built-in set "
                f"(`walk`, `walker/*`)"
            ),
            "run": a.run or None,
            "motions": self.motions,
            "budget_minutes": None if a.budget_steps else a.budget_minutes,
            "budget_steps": a.budget_steps,
            "out": str(self.out),
            "other_report": a.other_report,
            "rerun": rerun,
        }

    def protocol(self) -> str:
        a = self.args
        settings = (" with " + ", ".join(f"`{t}`" for t in a.set_text)) if a.set_text else ""
        training = (
            f"""- **The run** (`--run`): `{a.run}`, trained elsewhere (how: its card or run directory),
  not trained here. Its dataset holds {self.run_clips} clips; every rollout below uses its
  walking clips only ({", ".join(f"`{m}`" for m in self.motions or [])}); the bar splits its
  episodes evenly over them."""
            if a.run
            else f"""- **Training** (`train`): `{a.preset}` preset{settings} on the walking clips,
  {a.num_envs or "the preset's"} envs, seed {a.seed}, one CPU thread per allowed core (the run is
  pinned with `taskset`); MOPPO samples `w` per episode as the preset says; checkpoints every
  {a.checkpoint_every} iterations, all kept."""
        )
        return f"""## Protocol

{training}
- **Claim (ii)** (`sweeps`): for each objective k, `amorctl.analysis.level_sweep.weight_sweep` (what
  `amorctl evaluate RUN --sweep k` reports): w_k at 0, .25, .5, .75, 1, the rest share 1 - w_k
  equally; {a.sweep_episodes} episodes of 10 s per level on the walking clips (seed {a.eval_seed}),
  deterministic policy. Level means of the unweighted return of k; monotonic = every level's mean
  above the one before; Spearman ρ between w_k and the return over all episodes (scipy; the
  verdict's), and as a diagnostic over the episodes that survived only ("ρ survivors"); effect
  size = (mean at w_k = 1 − mean at w_k = 0) / std over episodes at w_k = 0; survival per level.
  For `smooth`, the sweep's own episodes also give (as `evaluate --sweep` reports them) the action
  rate = mean `||q*_t − q*_(t−1)||²` of the PD targets sent (`q* = reference + residual action`)
  and the joint-velocity RMS from finite differences of the joint angles; step pairs across a clip
  switch or an episode end are left out.
- **Claim (i)** (`front`): {a.front_samples} weights `w ~ Dirichlet(1)` (seed {a.eval_seed}), one
  10 s episode each on `walk` (`amorctl.analysis.sweeps.pareto_sweep`); non-dominated fraction
  in all 7 objectives on all episodes and on the surviving episodes alone; hypervolume
  (moocore, exact up to 256 front points in 7-D, else Monte Carlo with a 95 % interval) at the
  **fixed reference point** r = T for each tracking objective and r = 0 for `smooth` (T = the
  episode's control steps: an episode that survives with zero tracking reward, and whose
  smoothness penalties cancel the alive bonus), divided by T^7.
- **Learning bar** (`bar`): {a.bar_episodes} episodes of 10 s on the walking clips (seed
  {a.eval_seed}) under uniform w and under the tracking-heavy w (0.3 on up, lo and feet each, 0.1
  shared by the other four), same starts; `amorctl.analysis.tracking_metrics.evaluate_setting`.
- **MOPPO vs PPO** (`ppo`, `curves`): PPO is the same trainer and config with
  `[env] fixed_weights = "uniform"` (docs/train.md, "Fixed weights"), trained for MOPPO's number of
  iterations (same batch, so equal env steps). Up to {a.curve_points} checkpoint iterations common
  to both runs are evaluated with {a.curve_episodes} episodes each: scalarized return `w·J` under
  uniform w (both) and under Dirichlet w (MOPPO; one weight per episode, seed {a.eval_seed}).
  Ratio = MOPPO / PPO uniform-w return at the last common checkpoint.
- **One policy vs K retrained** (`kfixed`): 7 PPO runs, run k with the corner-heavy fixed weight
  w_k = 0.7 (0.05 each other objective), ⌈MOPPO iterations / 7⌉ iterations each (the same total
  env steps as MOPPO); each evaluated under its own weight, AMOR under the same 7 weights,
  {a.kfixed_episodes} episodes each on `walk`; hypervolume of each 7-point set at the claim (i)
  reference point.
"""

    # -- the parts
    def part_train(self) -> None:
        cfg = self.base_config()
        a = self.args
        budget_s = None if a.budget_steps else a.budget_minutes * 60
        stop_at = self.stop_at(0)
        train(cfg, self.moppo, budget_s=budget_s, stop_at=stop_at, label="MOPPO", budget_steps=a.budget_steps)
        self.results["train"] = run_summary(self.moppo, f"MOPPO (preset `{self.args.preset}` sampling)")
        meta = self.results["meta"]
        self.results["train"]["made_by"] = {k: meta[k] for k in ("command", "commit", "date_utc")}

    def part_ppo(self) -> None:
        iters = self.moppo_iterations()
        cfg = self.base_config(env__fixed_weights="uniform", run__iterations=iters)
        stop = self.stop_at(self.args.reserve_minutes * 60)
        train(cfg, self.ppo, budget_s=None, stop_at=stop, label="PPO (uniform w)")
        self.results["ppo"] = run_summary(self.ppo, "fixed uniform (PPO)")

    def stop_at(self, reserve_s: float) -> float:
        return math.inf if self.clock.at is None else self.clock.at - reserve_s

    def policy(self) -> tuple[Any, TrainConfig]:
        run = RunDir.open(self.args.run or self.moppo)  # pretrained:NAME resolves its files itself
        return run.policy(), run.config

    def part_sweeps(self) -> None:
        pol, cfg = self.policy()
        res, raw = measure_sweeps(
            pol, cfg, episodes=self.args.sweep_episodes, seed=self.args.eval_seed, motions=self.motions
        )
        fig = self.img / f"{self.figure_stem}-sweeps.png"
        if plot_sweeps(res, raw, fig):
            res["figure"] = self.rel(fig)
        self.results["sweeps"] = res

    def part_front(self) -> None:
        pol, cfg = self.policy()
        self.results["front"] = measure_front(
            pol, cfg, samples=self.args.front_samples, seed=self.args.eval_seed
        )

    def part_bar(self) -> None:
        pol, cfg = self.policy()
        self.results["bar"] = measure_bar(
            pol, cfg, episodes=self.args.bar_episodes, seed=self.args.eval_seed, motions=self.motions
        )

    def part_curves(self) -> None:
        a = self.args
        mo, pp = RunDir.open(self.moppo), RunDir.open(self.ppo)
        iters = common_iterations(
            [i for i, _ in mo.checkpoints()], [i for i, _ in pp.checkpoints()], a.curve_points
        )
        cfg = mo.config
        m = len(mo.policy().objectives)
        uniform = np.full((a.curve_episodes, m), 1.0 / m)
        random_w, _ = sweep_weights(m, a.curve_episodes, seed=a.eval_seed)
        steps = {int(float(r["iteration"])): int(float(r["env_steps"])) for r in metrics_rows(self.moppo)}
        rows = []
        for it in iters:
            if self.clock.left() < 20:
                break
            pm, pu = mo.policy(it), pp.policy(it)
            row = {
                "iteration": it,
                "env_steps": steps.get(it, it * cfg.env.num_envs * cfg.ppo.num_steps),
                "moppo_uniform": scalarized(pm, cfg, uniform, a.eval_seed),
                "moppo_random": scalarized(pm, cfg, random_w, a.eval_seed),
                "ppo_uniform": scalarized(pu, pp.config, uniform, a.eval_seed),
            }
            rows.append(row)
            print(
                f"  curve @ {row['env_steps']:,} env steps: PPO {row['ppo_uniform']['return']:.1f}, MOPPO "
                f"uniform {row['moppo_uniform']['return']:.1f}, random {row['moppo_random']['return']:.1f}",
                flush=True,
            )
        res: dict[str, Any] = {"episodes": a.curve_episodes, "seed": a.eval_seed, "rows": rows, "ratio": None}
        if rows:
            last = rows[-1]
            ppo_ret = last["ppo_uniform"]["return"]
            res["ratio"] = last["moppo_uniform"]["return"] / ppo_ret if ppo_ret > 0 else None
            res["ratio_env_steps"] = last["env_steps"]
            if pp.checkpoints()[-1][0] < mo.checkpoints()[-1][0]:
                res["note"] = (
                    f"PPO stopped at iteration {pp.checkpoints()[-1][0]} of MOPPO's "
                    f"{mo.checkpoints()[-1][0]} (the deadline), so the ratio is at that env-step count."
                )
            fig = self.img / f"{self.figure_stem}-curves.png"
            if plot_curves(rows, fig, a.character):
                res["figure"] = self.rel(fig)
        self.results["curves"] = res

    def part_kfixed(self, train_runs: bool) -> None:
        a = self.args
        mo = RunDir.open(self.moppo)
        cfg = mo.config
        names = tuple(mo.policy().objectives)
        w = corner_heavy_weights(len(names), 0.7)
        each = math.ceil(self.moppo_iterations() / len(names))
        runs = [self.out / f"fixed-{n}" for n in names]
        for run, row in zip(runs, w, strict=True):
            if train_runs:
                c = self.base_config(env__fixed_weights=format_weights(row, names), run__iterations=each)
                train(c, run, budget_s=None, stop_at=self.stop_at(a.reserve_minutes * 60), label=run.name)
        pols = [RunDir.open(r).policy() for r in runs]
        pts_f, surv_f = fixed_points(
            pols, cfg, w, episodes=a.kfixed_episodes, seed=a.eval_seed, motion="walk"
        )
        pts_a, surv_a = fixed_points(
            [mo.policy()] * len(names), cfg, w, episodes=a.kfixed_episodes, seed=a.eval_seed, motion="walk"
        )
        front = self.results.get("front")
        t = front["hv_scale"] if front else float(round(cfg.env.episode_seconds * 50))
        ref = hv_reference(len(names), int(t), names.index("smooth") if "smooth" in names else None)
        scale = t ** len(names)
        self.results["kfixed"] = {
            "heavy": 0.7,
            "iterations_each": each,
            "env_steps_total": sum(run_summary(r, "")["env_steps"] for r in runs),
            "moppo_env_steps": run_summary(self.moppo, "")["env_steps"],
            "episodes": a.kfixed_episodes,
            "motion": "walk",
            "hv_fixed_7": hypervolume(pts_f, ref).value / scale,
            "hv_amor_7": hypervolume(pts_a, ref).value / scale,
            "hv_amor_front": front["all"]["hypervolume"]["value"] if front else None,
            "points_fixed": pts_f.tolist(),
            "points_amor": pts_a.tolist(),
            "survival_fixed": surv_f.tolist(),
            "survival_amor": surv_a.tolist(),
        }
        k = self.results["kfixed"]
        print(
            f"  kfixed: HV PPO×7 {k['hv_fixed_7']:.4g}, AMOR at the 7 weights {k['hv_amor_7']:.4g}",
            flush=True,
        )


# ------------------------------------------------------------------------------------ main
def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv, __doc__)
    import torch

    torch.set_num_threads(available_cpus())
    try:
        sci = Science(args)
    except AmorError as err:  # --run: not a run, or its dataset is missing
        raise SystemExit(f"error: --run: {err}") from None
    if not args.run and not sci.dataset.exists():
        args.out.mkdir(parents=True, exist_ok=True)
        save_subset(walking_subset(load_dataset(default_dataset(args.character))), sci.dataset)
    sci.meta()
    print(f"science: {args.character}, preset {args.preset}, parts {', '.join(args.parts)}")
    print(f"machine: {sci.results['meta']['machine']}", flush=True)
    if args.skip_train:  # the runs' own numbers, for the report
        for key, run, label in (
            ("train", sci.moppo, f"MOPPO (preset `{args.preset}` sampling)"),
            ("ppo", sci.ppo, "fixed uniform (PPO)"),
        ):
            if RunDir(run).exists():
                made = sci.results.get(key, {}).get("made_by")
                sci.results[key] = run_summary(run, label) | ({"made_by": made} if made else {})
        if args.run:  # the run as the user named it (pretrained:NAME), its own weight sampling
            sci.results["train"] |= {"run": args.run, "weights": "MOPPO (the run's own sampling)"}
    for part in PARTS:
        if part not in args.parts or (part in ("train", "ppo") and args.skip_train):
            continue
        if sci.clock.left() <= 30:
            sci.results["skipped"][part] = "the run's deadline came first"
            print(f"[{part}] skipped: deadline", flush=True)
            sci.save()
            continue
        began = time.perf_counter()
        print(f"[{part}] {dt.datetime.now(dt.UTC):%H:%M:%S} UTC", flush=True)
        try:
            if part == "kfixed":
                sci.part_kfixed(train_runs=not args.skip_train)
            else:
                getattr(sci, f"part_{part}")()
        except Exception as exc:  # a failed part is reported; the others still run
            sci.results["skipped"][part] = f"failed: {type(exc).__name__}: {exc}"
            print(f"[{part}] FAILED: {exc!r}", flush=True)
        else:
            sci.results["skipped"].pop(part, None)
            sci.results.setdefault("seconds", {})[part] = time.perf_counter() - began
            print(f"[{part}] done in {time.perf_counter() - began:.0f} s", flush=True)
        sci.save()
    for part in PARTS:
        if part not in args.parts and part not in sci.results:
            trains = args.run and part not in RUN_PARTS
            why = "a run measured with --run: no training here" if trains else args.skip_reason
            sci.results["skipped"][part] = why
    sci.save()
    print(f"report: {args.doc}; results: {sci.json_path}")


if __name__ == "__main__":
    main()
