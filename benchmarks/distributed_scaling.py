"""Data-parallel training throughput: 1 process × T threads against P processes × T/P threads
(and, as a control, 1 process × T/P threads).

Runs ``amorctl train`` (biped20, the ``quick`` preset: 256 envs, 3 x 256 nets, 24 steps) for a few
iterations once in one process with ``--threads`` torch and MuJoCo threads, and once under
torchrun (``amorctl train --nproc P``) with ``threads / P`` threads per rank, and reads the
run's ``metrics.csv``: env steps per second (all ranks' steps over the iteration's wall time) and,
for the distributed run, ``time/comm_frac``, the share of rank 0's iteration spent inside
collectives (gradient, statistics and normalizer all-reduces, including the wait for the slower
rank). The first iteration (warm-up: allocation, first forward passes) is left out.

    python benchmarks/distributed_scaling.py [--iterations 5] [--threads 2] [--nproc 2]
        [--num-envs 256] [--data DATASET.mcap]

Prints one line per configuration and the speed-up. Run it alone (``flock`` on shared machines):
the figures are wall-clock throughputs. docs/distributed.md records the figures of this machine.
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def run(nproc: int, threads: int, args: argparse.Namespace, root: Path) -> dict[str, float]:
    """Train ``args.iterations`` iterations; mean metrics over iterations 2..end."""
    tag = f"p{nproc}t{threads}"
    config = root / f"{tag}.toml"
    config.write_text(
        f"[run]\niterations = {args.iterations}\ncheckpoint_every = 100000\ntensorboard = false\n"
        f"threads = {threads}\n[env]\nnum_envs = {args.num_envs}\n"
    )
    out = root / tag
    command = [sys.executable, "-m", "amorctl", "train", "--preset", "quick", "--config", str(config)]
    command += ["--out", str(out), "--json"] + (["--data", args.data] if args.data else [])
    if nproc > 1:
        command += ["--nproc", str(nproc)]
    began = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - began
    if done.returncode != 0:
        sys.exit(f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr[-3000:]}")
    rows = list(csv.DictReader((out / "metrics.csv").open()))[1:]
    mean = {k: sum(float(r[k]) for r in rows) / len(rows) for k in rows[0]}
    mean["launch_to_exit_s"] = wall
    return mean


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2, help="threads of the 1-process run (cores)")
    parser.add_argument("--nproc", type=int, default=2)
    parser.add_argument("--num-envs", type=int, default=256)
    parser.add_argument("--data", default="", help="motion dataset (default: the built-in clips)")
    args = parser.parse_args()
    if args.iterations < 2:
        parser.error("--iterations must be >= 2 (the first is warm-up)")
    per_rank = max(1, args.threads // args.nproc)
    with tempfile.TemporaryDirectory(prefix="amorctl-dist-bench-") as tmp:
        results = {}
        # the middle one is the control: 1 process with one rank's threads
        for nproc, threads in ((1, args.threads), (1, per_rank), (args.nproc, per_rank)):
            if (nproc, threads) in results:
                continue
            m = run(nproc, threads, args, Path(tmp))
            results[nproc, threads] = m
            comm = m.get("time/comm_frac")
            print(
                f"{nproc} process(es) x {threads} thread(s): {m['env_steps_per_s']:,.0f} env steps/s, "
                f"iteration {m['time/iteration_s']:.2f} s (env {m['time/env_frac']:.0%}, "
                f"network {m['time/network_frac']:.0%}"
                + (f", communication {comm:.1%}" if comm is not None else "")
                + f"), launch to exit {m['launch_to_exit_s']:.0f} s",
                flush=True,
            )
    multi = results[args.nproc, per_rank]["env_steps_per_s"]
    print(
        f"speed-up of {args.nproc} processes x {per_rank} thread(s) over 1 process x {args.threads} "
        f"thread(s): {multi / results[1, args.threads]['env_steps_per_s']:.2f}x; over 1 process x "
        f"{per_rank} thread(s): {multi / results[1, per_rank]['env_steps_per_s']:.2f}x"
    )


if __name__ == "__main__":
    main()
