"""Table 2 of the paper on a CPU: uniform weights vs HLP (V = 30) vs HLP (V = 2).

Trains two HLPs on the run's frozen AMOR policy (same config and seed, only the discriminator
window differs), each for a wall-clock budget, then evaluates the run with uniform weights and
with each HLP's weights (``amorctl.hlp.eval_discriminator``: joint MAE over long episodes with clips
appended, and the mean logit of a separately trained evaluation discriminator on held-out
windows, both with 95% CIs), traces both HLPs through the run's motions (Fig. 7/8 style plot),
and prints every figure plus the wall times. A benchmark, not a test: nothing is asserted; the
paper's target is -4.7% MAE and +2.5 logits for the HLP over uniform weights.

Usage: flock /tmp/amorctl-heavy.lock python benchmarks/hlp_table2.py [--run runs/b20walk]
       [--minutes 10 | --budget-steps N] [--out RUN/hlp] [--envs 32] [--eval-envs 32] [--eval-seconds 20]
       [--disc-steps 600] [--json table.json] [--plot docs/img/hlp-trace.png] [--skip-train]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from amorctl.hlp.config import load_hlp_preset, merge
from amorctl.hlp.eval_discriminator import TableOptions, hlp_table
from amorctl.hlp.run import HlpDir, load_hlp, run_dataset, train_hlp
from amorctl.hlp.trace import plot_traces, trace_hlp
from amorctl.train.rundir import RunDir


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", default="runs/b20walk")
    ap.add_argument("--minutes", type=float, default=10.0, help="training budget per HLP")
    ap.add_argument(
        "--budget-steps", type=int, default=None, help="training budget per HLP in env steps instead"
    )
    ap.add_argument("--out", default=None, help="where the HLP directories go (default RUN/hlp)")
    ap.add_argument("--envs", type=int, default=32)
    ap.add_argument("--eval-envs", type=int, default=32)
    ap.add_argument("--eval-seconds", type=float, default=20.0)
    ap.add_argument("--disc-steps", type=int, default=600)
    ap.add_argument("--json", default=None, help="write the table's JSON here")
    ap.add_argument("--plot", default=None, help="Fig. 7/8-style trace of both HLPs")
    ap.add_argument("--skip-train", action="store_true", help="evaluate existing bench-v30/bench-v2")
    args = ap.parse_args()
    if args.budget_steps is not None and args.budget_steps < 1:
        ap.error(f"--budget-steps must be >= 1, got {args.budget_steps}")
    torch.set_num_threads(1)
    root = Path(args.out) if args.out else Path(args.run) / "hlp"
    dirs = {30: root / "bench-v30", 2: root / "bench-v2"}
    wall: dict[int, float] = {}
    iters: dict[int, int] = {}
    if not args.skip_train:
        for v, out in dirs.items():
            preset = load_hlp_preset("v30" if v == 30 else "v2")
            config = merge(
                preset,
                {"run": {"iterations": 100000, "checkpoint_every": 50, "keep_checkpoints": 1,
                         "tensorboard": False, "threads": 1},
                 "env": {"num_envs": args.envs}},
                "benchmark",
            )  # fmt: skip
            budget = args.minutes * 60.0
            began = time.perf_counter()
            resume = HlpDir(out).exists()
            result = train_hlp(
                args.run, out, config, resume=resume,
                stop_when=lambda m, b=began, s=budget: (
                    m.get("env_steps", 0) >= args.budget_steps
                    if args.budget_steps
                    else time.perf_counter() - b > s
                ),
            )  # fmt: skip
            wall[v] = time.perf_counter() - began
            iters[v] = result.end_iteration
            m = result.last_metrics
            print(
                f"HLP V={v}: {result.end_iteration} iterations, {int(m.get('env_steps', 0)):,} env steps in "
                f"{wall[v]:.0f} s; last r^D {m.get('reward/mean', float('nan')):.3f}, D acc dataset "
                f"{m.get('disc/accuracy_dataset', float('nan')):.2f} / policy "
                f"{m.get('disc/accuracy_policy_rollout', float('nan')):.2f}, w entropy "
                f"{m.get('w/entropy', float('nan')):.3f}",
                flush=True,
            )
    hlps = {v: load_hlp(d) for v, d in dirs.items()}
    m = len(hlps[30].meta["objectives"])
    conditions = [("uniform", "uniform", [1.0 / m] * m)]
    conditions += [(f"HLP (V = {v})", str(d), hlps[v]) for v, d in dirs.items()]
    opts = TableOptions(num_envs=args.eval_envs, seconds=args.eval_seconds, steps=args.disc_steps)
    began = time.perf_counter()
    table = hlp_table(args.run, conditions, opts, lambda line: print(line, flush=True))
    eval_s = time.perf_counter() - began
    print("\n| weights | MAE (deg) | logit | falls | mean w |")
    print("| --- | --- | --- | --- | --- |")
    for r in table.rows:
        mean_w = ", ".join(f"{x:.3f}" for x in r["mean_w"])
        print(
            f"| {r['label']} | {r['joint_mae_deg']:.2f} ± {r['joint_mae_ci95']:.2f} | "
            f"{r['logit']:.2f} ± {r['logit_ci95']:.2f} | {r['falls']} | {mean_w} |"
        )
    print(f"\n{table.caption}")
    base = table.rows[0]
    for r in table.rows[1:]:
        rel = 100 * (r["joint_mae_deg"] - base["joint_mae_deg"]) / base["joint_mae_deg"]
        print(f"{r['label']}: MAE {rel:+.1f}% vs uniform, logit {r['logit'] - base['logit']:+.2f} vs uniform")
    print(f"evaluation wall time {eval_s:.0f} s; training wall time {wall} s, iterations {iters}")
    print(f"objectives: {', '.join(table.objective_names)}; LLP iteration {hlps[30].meta['llp_iteration']}")
    if args.json:
        data = table.to_json()
        data["benchmark"] = {"train_wall_s": wall, "iterations": iters, "eval_wall_s": eval_s}
        Path(args.json).write_text(json.dumps(data, indent=1) + "\n")
    if args.plot:
        clips = list(hlps[30].config.env.motions)
        names = clips or [c.name for c in run_dataset(RunDir.open(args.run)).clips][:4]
        traces = [trace_hlp(hlps[v], names, seconds=None) for v in (30, 2)]
        for tr in traces:
            tr.label = f"V={30 if tr is traces[0] else 2}"
        plot_traces(
            traces, args.plot, title="HLP weights on the run's clips: V = 30 (solid) vs V = 2 (dashed)"
        )
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
