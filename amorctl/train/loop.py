"""The backend-agnostic training loop.

Reads like rsl_rl's runner: make env → make trainer → (restore) → iterate → record → checkpoint.
The run directory's layout is :mod:`amorctl.train.rundir`'s. ``--resume`` reloads the newest
checkpoint (trainer and, when the env can snapshot itself, env state), drops metric rows after
it, and continues; the next iteration then computes exactly what an uninterrupted run would have.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from amorctl.core.config import TrainConfig, to_toml
from amorctl.core.contracts import SnapshotEnv, Trainer
from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_write_text
from amorctl.core.vecenv import VectorEnv
from amorctl.envs.factory import make_env
from amorctl.train.checkpoint import Checkpoint, prune_checkpoints, save_checkpoint
from amorctl.train.metrics import MetricsLog
from amorctl.train.rundir import RunDir, check_compatible, run_meta
from amorctl.train.signals import stop_on_signals


@dataclass
class RunResult:
    """What a call to :func:`train_run` did."""

    out: Path
    start_iteration: int
    end_iteration: int
    interrupted: bool
    checkpoint: Path | None
    last_metrics: dict[str, float] = field(default_factory=dict)


def train_run(
    config: TrainConfig,
    out: Path,
    *,
    resume: bool = False,
    on_start: Callable[[VectorEnv, int, int], None] | None = None,
    on_iteration: Callable[[dict[str, float], int, float], None] | None = None,
    stop_after: int | None = None,
    stop_when: Callable[[dict[str, float]], bool] | None = None,
) -> RunResult:
    """Train into the run directory ``out`` (new, or resumed from its newest checkpoint).

    Args:
        config: the resolved config (on resume: the run's own, with ``run.iterations`` possibly raised).
        out: the run directory.
        resume: continue the run in ``out`` instead of starting a new one.
        on_start: called with (env, start iteration, total iterations) before the first iteration.
        on_iteration: called after every iteration with (metrics, total iterations, seconds elapsed).
        stop_after: stop (with a checkpoint, as on SIGINT) after this many iterations of this call;
            used by tests to simulate an interruption.
        stop_when: stop the same way once it returns True for an iteration's metrics (e.g. a
            wall-time budget in a benchmark).

    Raises:
        AmorError: ``out`` already holds a run (without ``resume``), has none to resume, or its
            checkpoint is damaged or made for another env; nothing in ``out`` is changed then.
    """
    run = RunDir(out)
    ckpt_dir = run.checkpoint_dir
    ckpt: Checkpoint | None = None
    if resume:
        run.config  # noqa: B018 (a run to resume must have a valid config)
        ckpt = run.checkpoint()
    elif run.exists():
        raise AmorError(f"{out} already holds a run; pass --resume to continue it or choose another --out")

    backend = run.backend(config)
    env = make_env(config, backend)
    trainer: Trainer = backend.make_trainer(env, config)
    start = 0
    if ckpt is not None:
        check_compatible(ckpt, config, env)
        trainer.load_state_dict(ckpt.trainer)
        if ckpt.env is not None and isinstance(env, SnapshotEnv):
            env.set_state(ckpt.env)
        else:  # the env cannot snapshot: continue from fresh episodes, deterministically seeded
            trainer.reset_env(config.run.seed + ckpt.iteration)
        start = ckpt.iteration
    else:
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(run.config_path, to_toml(config))

    total = config.run.iterations
    meta = run_meta(config, env)
    snapshot = isinstance(env, SnapshotEnv)

    def checkpoint(iteration: int) -> Path:
        env_state = env.get_state() if snapshot else None  # type: ignore[union-attr]
        path = save_checkpoint(ckpt_dir, iteration, meta, trainer.state_dict(), env_state)
        prune_checkpoints(ckpt_dir, config.run.keep_checkpoints)
        return path

    metrics_log = MetricsLog(out, config.run.tensorboard, start if resume else None)
    if on_start is not None:
        on_start(env, start, total)
    last_path: Path | None = ckpt.path if ckpt is not None else None
    last: dict[str, float] = {}
    interrupted = False
    iteration = start
    began = time.perf_counter()
    try:
        with stop_on_signals() as stop:
            while iteration < total:
                last = trainer.iteration()
                iteration = trainer.iteration_count
                last["wall_time_s"] = time.perf_counter() - began
                metrics_log.write(last)
                if on_iteration is not None:
                    on_iteration(last, total, time.perf_counter() - began)
                if not all(np.isfinite(v) for k, v in last.items() if k.startswith("loss/")):
                    raise AmorError(
                        f"training diverged at iteration {iteration} (non-finite loss); "
                        f"the last good checkpoint is {last_path}"
                    )
                done_here = iteration - start
                interrupted = (
                    stop.requested
                    or (stop_after is not None and done_here >= stop_after)
                    or (stop_when is not None and stop_when(last))
                )
                if interrupted or iteration % config.run.checkpoint_every == 0 or iteration == total:
                    last_path = checkpoint(iteration)
                if interrupted:
                    break
    finally:
        metrics_log.close()
        close = getattr(env, "close", None)
        if callable(close):
            close()
    return RunResult(out, start, iteration, interrupted, last_path, last)
