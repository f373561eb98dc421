"""Training throughput when the machine is not idle: quiet vs beside a CPU-bound competitor.

For each *lever* (a way of running training), the script runs a short training measurement in a
fresh process twice, side by side in one run: once on a quiet machine and once while a competitor
process busy-loops (a pure-Python ``while True`` pinned to one core of this process's affinity,
like a browser tab pegging a core). Each measurement builds the env and MOPPO trainer exactly as
``amorctl train`` does (``--preset``, default ``quick``: biped20, 256 envs, 24 steps), runs one
warm-up iteration and then ``--iterations`` timed ones, and reports the median env steps/s. One
line per lever, ending in ``ratio: X.XX`` (contended ÷ quiet; target >= 0.35, a fair share of
two cores with one taken is ~0.5).

Levers (``--levers``; a fresh process each, so environment variables take effect before torch
loads):

- ``default``: what ``amorctl train`` does now: threads = the cores in the affinity mask, the
  servo inside MuJoCo's step, ``OMP_WAIT_POLICY=PASSIVE`` (set by ``import amorctl``);
- ``before``: the state this benchmark was written against: numpy servo between single physics
  steps (5 pool dispatches per control step instead of 1) and libgomp's default wait (spin about
  3 ms after each parallel region, ``GOMP_SPINCOUNT=300000``, which ``import amorctl`` respects);
- ``omp-spin``: ``default`` with libgomp's default spinning (the OpenMP lever alone);
- ``python-servo``: ``default`` with the numpy servo (the servo lever alone);
- ``free-cores``: threads = cores found idle when the process starts (``/proc/stat`` sampled
  for 0.3 s, see :func:`amorctl.sim.cpus.idle_cpus`), for MuJoCo's pool and torch;
- ``one-thread``: one MuJoCo thread and one torch thread, whatever the machine.

Run it under the shared lock; pin it with ``taskset`` to measure on fewer cores (the competitor
then shares one of those).

    python benchmarks/contention.py [--levers default before ...] [--iterations 2]
        [--preset quick] [--num-envs N]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

LEVERS = ("default", "before", "omp-spin", "python-servo", "free-cores", "one-thread")
#: libgomp's spin count when OMP_WAIT_POLICY is unset (about 3 ms; libgomp's env.c)
GOMP_DEFAULT_SPINCOUNT = "300000"


def child(args: argparse.Namespace) -> None:
    """Measure one lever in this process and print ``{"env_steps_per_s": ..., ...}`` as JSON."""
    import torch

    from amorctl.core.config import load_preset, override
    from amorctl.envs.factory import make_env
    from amorctl.plugins.backends.torch_cpu import TorchCpuBackend
    from amorctl.sim.cpus import available_cpus, idle_cpus

    threads = {"free-cores": idle_cpus(), "one-thread": 1}.get(args.lever, available_cpus())
    config = load_preset(args.preset)
    if args.num_envs:
        config = override(config, env__num_envs=args.num_envs)
    config = override(config, run__threads=threads)
    if args.lever in ("python-servo", "before"):  # the env builds its BatchSim with the reference servo
        import functools

        import amorctl.envs.tracking_env as tracking_env
        from amorctl.sim.batch_sim import BatchSim

        tracking_env.BatchSim = functools.partial(BatchSim, servo_model="python")  # type: ignore[misc]
    backend = TorchCpuBackend()
    if args.lever in ("free-cores", "one-thread"):
        orig = backend.make_env
        backend.make_env = lambda **kw: orig(nthread=threads, **kw)  # type: ignore[method-assign]
    env = make_env(config, backend)
    trainer = backend.make_trainer(env, config)
    trainer.iteration()
    rates = [trainer.iteration()["env_steps_per_s"] for _ in range(args.iterations)]
    env.close()
    omp = os.environ.get("OMP_WAIT_POLICY") or f"spin {os.environ.get('GOMP_SPINCOUNT')}"
    result = {
        "env_steps_per_s": statistics.median(rates),
        "threads": threads,
        "torch_threads": torch.get_num_threads(),
        "omp": omp,
    }
    print(json.dumps(result))


def run_child(lever: str, args: argparse.Namespace) -> dict[str, float]:
    """One measurement of ``lever`` in a fresh interpreter (same affinity as this one)."""
    env = dict(os.environ)
    env.pop("OMP_WAIT_POLICY", None)
    env.pop("GOMP_SPINCOUNT", None)
    if lever in ("omp-spin", "before"):  # libgomp's default: amorctl leaves a set spin count alone
        env["GOMP_SPINCOUNT"] = GOMP_DEFAULT_SPINCOUNT
    cmd = [
        sys.executable,
        __file__,
        "--child",
        lever,
        "--iterations",
        str(args.iterations),
        "--preset",
        args.preset,
    ]
    if args.num_envs:
        cmd += ["--num-envs", str(args.num_envs)]
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if out.returncode != 0:
        raise SystemExit(f"lever {lever}: measurement failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def start_competitor() -> subprocess.Popen[bytes]:
    """A busy-looping Python process pinned to the last core of this process's affinity."""
    core = max(os.sched_getaffinity(0))
    code = f"import os; os.sched_setaffinity(0, {{{core}}})\nwhile True:\n    pass\n"
    proc = subprocess.Popen([sys.executable, "-c", code])
    time.sleep(0.5)  # let it reach the loop
    return proc


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--levers", nargs="+", choices=LEVERS, default=list(LEVERS))
    parser.add_argument("--iterations", type=int, default=2, help="timed iterations per measurement")
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--num-envs", type=int, default=None)
    parser.add_argument("--child", choices=LEVERS, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        args.lever = args.child
        child(args)
        return
    cores = sorted(os.sched_getaffinity(0))
    print(
        f"affinity: cores {cores}; competitor: busy loop on core {cores[-1]}; preset {args.preset}",
        flush=True,
    )
    for lever in args.levers:
        quiet = run_child(lever, args)
        competitor = start_competitor()
        try:
            busy = run_child(lever, args)
        finally:
            competitor.kill()
            competitor.wait()
        q, c = quiet["env_steps_per_s"], busy["env_steps_per_s"]
        print(
            f"{lever:<13} threads quiet/contended: {quiet['threads']}/{busy['threads']}  "
            f"omp: {busy['omp']:<12} "
            f"quiet: {q:7,.0f} env steps/s  contended: {c:7,.0f} env steps/s  ratio: {c / q:.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
