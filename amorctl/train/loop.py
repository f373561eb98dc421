"""The backend-agnostic training loop and the run directory.

``runs/<name>/`` holds:

- ``config.toml``: the fully resolved config (written once, at the start);
- ``checkpoints/iter_NNNNNN.{safetensors,json}``: every ``checkpoint_every`` iterations, at the
  end, and when SIGINT/SIGTERM stops the run (after the iteration in progress finishes);
- ``metrics.csv``: one row per iteration; ``tb/``: the same as TensorBoard scalars.

``--resume`` reloads the newest checkpoint (trainer and, when the env can snapshot itself, env
state), drops metric rows after it, and continues; the next iteration then computes exactly what
an uninterrupted run would have. The loop reads like rsl_rl's runner: make env → make trainer →
(restore) → iterate → record → checkpoint.
"""

from __future__ import annotations

import contextlib
import csv
import io
import math
import signal
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from amorctl import __version__
from amorctl.core.config import TrainConfig, load_config, to_toml
from amorctl.core.contracts import SnapshotEnv, Trainer
from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_write_text
from amorctl.core.vecenv import VectorEnv
from amorctl.core.weights import parse_weights
from amorctl.registry import get_registry
from amorctl.train.checkpoint import (
    Checkpoint,
    list_checkpoints,
    load_checkpoint,
    prune_checkpoints,
    save_checkpoint,
)

CONFIG_FILE = "config.toml"
METRICS_FILE = "metrics.csv"
CHECKPOINT_DIR = "checkpoints"
TB_DIR = "tb"
TOY_CONTROL_HZ = 50  # the toy env's nominal control rate (episode_seconds -> steps)


@dataclass
class RunResult:
    """What a call to :func:`train_run` did."""

    out: Path
    start_iteration: int
    end_iteration: int
    interrupted: bool
    checkpoint: Path | None
    last_metrics: dict[str, float] = field(default_factory=dict)


# ---------------------------------------------------------------------------- environments
def make_env(config: TrainConfig, backend: Any | None = None) -> VectorEnv:
    """Build the configured env, seeded with ``run.seed``, wrapped for fixed weights if asked.

    ``kind="tracking"`` asks the backend (its ``make_env``) for the motion-tracking env;
    ``toy``, ``toy-smooth`` and ``gym`` are backend-independent numpy envs.
    """
    e, seed = config.env, config.run.seed
    env: Any
    if e.kind == "toy":
        from amorctl.envs.toy import ToyTradeoffEnv

        env = ToyTradeoffEnv(
            e.num_envs, max_steps=max(1, round(e.episode_seconds * TOY_CONTROL_HZ)), seed=seed
        )
    elif e.kind == "toy-smooth":
        from amorctl.envs.toy import ToySmoothEnv

        env = ToySmoothEnv(e.num_envs, max_steps=max(1, round(e.episode_seconds * TOY_CONTROL_HZ)), seed=seed)
    elif e.kind == "gym":
        from amorctl.envs.mo_gym import make_gym_env

        env = make_gym_env(e.gym_id, e.num_envs, seed=seed)
    else:
        if backend is None:
            backend = get_registry().backend(config.run.backend).make()
        env = backend.make_env(
            character=e.character,
            dataset=e.dataset or None,
            objective_set=e.objective_set,
            num_envs=e.num_envs,
            episode_seconds=e.episode_seconds,
            seed=seed,
            action_mode=e.action_mode,
        )
    if e.fixed_weights:
        from amorctl.envs.wrappers import FixedWeights

        env = FixedWeights(env, parse_weights(e.fixed_weights, env.reward_space.names))
    return env


# ---------------------------------------------------------------------------- run directory
def load_run_config(out: Path) -> TrainConfig:
    """The resolved config of an existing run. Raises AmorError if ``out`` holds no run."""
    path = out / CONFIG_FILE
    if not path.is_file():
        raise AmorError(f"{out}: no run to resume ({CONFIG_FILE} not found)")
    return load_config(path)


def latest_checkpoint(out: Path) -> Checkpoint:
    """Load the newest checkpoint of a run. Raises AmorError if there is none or it is damaged."""
    found = list_checkpoints(out / CHECKPOINT_DIR)
    if not found:
        raise AmorError(f"{out / CHECKPOINT_DIR}: no checkpoint to resume from")
    path = found[-1][1]
    try:
        return load_checkpoint(path)
    except AmorError as err:
        older = (
            f"; an older checkpoint exists (iteration {found[-2][0]}): delete {path.name} and its "
            ".safetensors to resume from it"
            if len(found) > 1
            else ""
        )
        raise AmorError(f"{err}{older}") from None


def load_policy(out: Path) -> tuple[Any, TrainConfig, Checkpoint]:
    """The newest checkpoint's policy of the run in ``out``, for inference, with the run's config.

    Returns ``(policy, config, checkpoint)``; ``policy(obs [N, D]) -> actions [N, A]`` and
    ``policy.values(obs) -> [N, m]``, built by the run's backend from arrays and JSON only.
    """
    config = load_run_config(out)
    ckpt = latest_checkpoint(out)
    backend = get_registry().backend(config.run.backend).make()
    return backend.load_policy(ckpt.trainer, config), config, ckpt


def _run_meta(config: TrainConfig, env: VectorEnv) -> dict[str, Any]:
    e = config.env
    return {
        "amorctl_version": __version__,
        "backend": config.run.backend,
        "env_kind": e.kind,
        "character": e.character if e.kind == "tracking" else None,
        "gym_id": e.gym_id if e.kind == "gym" else None,
        "objectives": list(env.reward_space.names),
        "obs_dim": env.obs_dim,
        "action_dim": env.action_dim,
        "fixed_weights": e.fixed_weights,
    }


def check_compatible(ckpt: Checkpoint, config: TrainConfig, env: VectorEnv) -> None:
    """Raise AmorError if a checkpoint was made for another env, character or objective set."""
    expected = _run_meta(config, env)
    for key in ("env_kind", "character", "gym_id", "objectives", "obs_dim", "action_dim", "backend"):
        if ckpt.meta.get(key) != expected[key]:
            what = key.replace("_", " ")
            raise AmorError(
                f"{ckpt.path}: checkpoint was made for {what} {ckpt.meta.get(key)!r}, "
                f"this run has {expected[key]!r}"
            )


class _Metrics:
    """metrics.csv (one row per iteration) plus optional TensorBoard scalars."""

    def __init__(self, out: Path, tensorboard: bool, resume_from: int | None) -> None:
        self.path = out / METRICS_FILE
        self.columns: list[str] | None = None
        if resume_from is not None and self.path.is_file():  # forget iterations after the checkpoint
            rows = list(csv.DictReader(self.path.open(newline="", encoding="utf-8")))
            if rows:
                self.columns = list(rows[0])
                kept = [r for r in rows if float(r["iteration"]) <= resume_from]
                buf = io.StringIO()
                writer = csv.DictWriter(buf, self.columns)
                writer.writeheader()
                writer.writerows(kept)
                atomic_write_text(self.path, buf.getvalue())
        elif self.path.exists():
            self.path.unlink()
        self.tb: Any = None
        if tensorboard:
            from tensorboardX import SummaryWriter

            purge = None if resume_from is None else resume_from + 1
            self.tb = SummaryWriter(str(out / TB_DIR), purge_step=purge)

    def write(self, metrics: dict[str, float]) -> None:
        step = int(metrics["iteration"])
        if self.columns is None:
            self.columns = list(metrics)
        new = not self.path.exists()
        with self.path.open("a", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, self.columns, extrasaction="ignore")
            if new:
                writer.writeheader()
            writer.writerow({k: repr(float(metrics.get(k, math.nan))) for k in self.columns})
        if self.tb is not None:
            for key, value in metrics.items():
                if key != "iteration" and math.isfinite(value):
                    self.tb.add_scalar(key, value, step)

    def close(self) -> None:
        if self.tb is not None:
            self.tb.close()


class _StopFlag:
    """Set by SIGINT/SIGTERM; a second signal interrupts at once."""

    def __init__(self) -> None:
        self.requested = False
        self.signal_name = ""


@contextlib.contextmanager
def _stop_on_signals() -> Iterator[_StopFlag]:
    flag = _StopFlag()
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def handler(signum: int, frame: Any) -> None:
        if flag.requested:
            raise KeyboardInterrupt
        flag.requested = True
        flag.signal_name = signal.Signals(signum).name

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield flag
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


# ---------------------------------------------------------------------------- the loop
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
    ckpt_dir = out / CHECKPOINT_DIR
    ckpt: Checkpoint | None = None
    if resume:
        load_run_config(out)
        ckpt = latest_checkpoint(out)
    elif (out / CONFIG_FILE).exists() or list_checkpoints(ckpt_dir):
        raise AmorError(f"{out} already holds a run; pass --resume to continue it or choose another --out")

    backend = get_registry().backend(config.run.backend).make()
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
        atomic_write_text(out / CONFIG_FILE, to_toml(config))

    total = config.run.iterations
    meta = _run_meta(config, env)
    snapshot = isinstance(env, SnapshotEnv)

    def checkpoint(iteration: int) -> Path:
        env_state = env.get_state() if snapshot else None  # type: ignore[union-attr]
        path = save_checkpoint(ckpt_dir, iteration, meta, trainer.state_dict(), env_state)
        prune_checkpoints(ckpt_dir, config.run.keep_checkpoints)
        return path

    metrics_log = _Metrics(out, config.run.tensorboard, start if resume else None)
    if on_start is not None:
        on_start(env, start, total)
    last_path: Path | None = ckpt.path if ckpt is not None else None
    last: dict[str, float] = {}
    interrupted = False
    iteration = start
    began = time.perf_counter()
    try:
        with _stop_on_signals() as stop:
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
