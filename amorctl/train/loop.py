"""The backend-agnostic training loop.

Reads like rsl_rl's runner: make env → make trainer → (restore) → iterate → record → checkpoint.
The run directory's layout is :mod:`amorctl.train.rundir`'s. ``--resume`` reloads the newest
checkpoint (trainer and, when the env can snapshot itself, env state), drops metric rows after
it, and continues; the next iteration then computes exactly what an uninterrupted run would have.

A new run that fails before its first checkpoint (bad input found late, divergence, a crash)
removes what it wrote, so the same ``--out`` can be used again. Simulator warnings (MuJoCo's C
warning callback) are counted instead of printed; a whole batch that diverges ends the run with
one error line that quotes the first warning.

Under ``torchrun`` (:mod:`amorctl.train.distributed`) every rank runs this loop on its share of
the envs; rank 0 alone writes the run directory, gathers the ranks' states into each checkpoint
and reports; a stop (signal, ``stop_after``) on any rank stops all ranks at the same iteration.
"""

from __future__ import annotations

import contextlib
import csv
import shutil
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from amorctl.core.config import TrainConfig, to_toml
from amorctl.core.contracts import Snapshot, SnapshotEnv, Trainer, trainer_world_size
from amorctl.core.dir_lock import dir_lock
from amorctl.core.errors import AmorError
from amorctl.core.files import StorageError, atomic_write_text, check_writable
from amorctl.core.levers import check_backend_levers
from amorctl.core.vecenv import VectorEnv, close_env, diverged_total, has_fused_rollout
from amorctl.envs.factory import make_env
from amorctl.registry import get_registry
from amorctl.train import distributed
from amorctl.train.callbacks import Callbacks
from amorctl.train.checkpoint import (
    Checkpoint,
    check_against_config,
    check_like,
    checkpoint_paths,
    prune_checkpoints,
    save_checkpoint,
)
from amorctl.train.distill import Taught, load_teachers, record_teachers, student_library
from amorctl.train.episode_stats import EpisodeRecorder
from amorctl.train.init_from import record_init_from, source_networks, start_from
from amorctl.train.metrics import METRICS_FILE, TB_DIR, MetricsLog
from amorctl.train.rundir import (
    CHECKPOINT_DIR,
    CONFIG_FILE,
    RunDir,
    check_compatible,
    record_dataset,
    run_meta,
)
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
    signal: str = ""  # "SIGINT" / "SIGTERM" when a signal stopped the run, else ""


# --- simulator warnings ---------------------------------------------------------------------------
class SimWarnings:
    """MuJoCo warnings raised while training, counted by message instead of printed."""

    def __init__(self) -> None:
        self.counts: Counter[str] = Counter()
        self.first = ""

    def __call__(self, message: str) -> None:  # called from MuJoCo's threads (the GIL is held)
        text = " ".join(str(message).split())
        if not self.first:
            self.first = text
        self.counts[text.split(" Time =")[0]] += 1

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def summary(self) -> str:
        if not self.total:
            return ""
        return f"; the simulator warned {self.total} times, first: {self.first!r}"


@contextlib.contextmanager
def captured_sim_warnings() -> Iterator[SimWarnings]:
    """Route MuJoCo's C warnings (``mju_warning``) into a :class:`SimWarnings` for the block."""
    sink = SimWarnings()
    try:
        import mujoco
    except ImportError:  # a backend without MuJoCo
        yield sink
        return
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(sink)
    try:
        yield sink
    finally:
        mujoco.set_mju_user_warning(previous)


# --- a new run's files ----------------------------------------------------------------------------
def _remove_failed_run(out: Path, created: bool) -> None:
    """Undo a new run that never saved a checkpoint: the directory if this run created it, else
    only the files a run writes (the directory held other things before)."""
    if created:
        shutil.rmtree(out, ignore_errors=True)
        return
    for name in (CONFIG_FILE, METRICS_FILE):
        (out / name).unlink(missing_ok=True)
    for name in (TB_DIR, CHECKPOINT_DIR):
        shutil.rmtree(out / name, ignore_errors=True)


def _restore(
    ckpt: Checkpoint,
    config: TrainConfig,
    config_path: Path,
    env: VectorEnv,
    trainer: Trainer,
    world: distributed.World | None = None,
    on_note: Callable[[str], None] = lambda text: None,
) -> int:
    """Load a checkpoint into the trainer (and env); returns its iteration.

    Raises:
        AmorError: naming the checkpoint, when it was made for another env or its state does not
            fit this run (wrong shapes, types or indices).
    """
    check_compatible(ckpt, config, env)
    check_against_config(ckpt, config, config_path)
    world = world or distributed.World()
    saved_by = distributed.snapshot_world_size(ckpt.trainer)
    same_world = saved_by == world.size
    try:
        # this rank's part; with another world size every rank takes rank 0's networks and RNG
        trainer_state = distributed.rank_snapshot(ckpt.trainer, world.rank if same_world else 0)
        expected = trainer.state_dict()
        if not same_world:  # per-env arrays (leading dimension N) restart with the envs below
            kept = {k: v for k, v in expected.arrays.items() if v.shape[:1] != (env.num_envs,)}
            expected = Snapshot(kept, expected.meta)
        check_like(ckpt.path, "trainer", expected, trainer_state, finite=True)
        trainer.load_state_dict(trainer_state)
        if not same_world:
            on_note(
                f"{ckpt.path.name} was saved by {saved_by} process(es), this run has {world.size}: "
                "networks, optimizer and normalizer continue, the envs restart from fresh episodes"
            )
        if same_world and ckpt.env is not None and isinstance(env, SnapshotEnv):
            env_state = distributed.rank_snapshot(ckpt.env, world.rank)
            check_like(ckpt.path, "env", env.get_state(), env_state)
            env.set_state(env_state)
        else:  # the env cannot snapshot: continue from fresh episodes, deterministically seeded
            trainer.reset_env(config.run.seed + ckpt.iteration)
    except AmorError as err:  # the trainer's or env's own check: name the checkpoint
        if str(ckpt.path) in str(err):
            raise
        raise AmorError(f"{ckpt.path}: {err}") from None
    except (TypeError, ValueError, KeyError, IndexError, RuntimeError, OverflowError) as exc:
        raise AmorError(
            f"{ckpt.path}: checkpoint state does not fit this run ({type(exc).__name__}: {exc})"
        ) from None
    return ckpt.iteration


def _metrics_log(out: Path, config: TrainConfig, resume_from: int | None) -> MetricsLog:
    try:
        return MetricsLog(out, config.run.tensorboard, resume_from)
    except (ValueError, KeyError, TypeError, csv.Error, UnicodeDecodeError) as exc:
        raise AmorError(f"{out / METRICS_FILE}: cannot continue the metrics file: {exc}") from None


# --- the loop -------------------------------------------------------------------------------------
def train_run(
    config: TrainConfig,
    out: Path,
    *,
    resume: bool = False,
    on_start: Callable[[VectorEnv, int, int], None] | None = None,
    on_iteration: Callable[[dict[str, float], int, float], None] | None = None,
    stop_after: int | None = None,
    stop_when: Callable[[dict[str, float]], bool] | None = None,
    on_note: Callable[[str], None] | None = None,
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
        on_note: called with a one-line notice (e.g. a resume with another number of processes).

    Under torchrun (an initialized process group) the callbacks run on rank 0 only.

    Raises:
        AmorError: ``out`` already holds a run (without ``resume``), has none to resume, its
            checkpoint is damaged or made for another env (nothing in ``out`` is changed then), or
            training diverged. A new run that fails before its first checkpoint leaves nothing.
    """
    run = RunDir(out)
    check_backend_levers(config, get_registry().backend(config.run.backend).levers)
    callbacks = Callbacks(on_start, on_iteration, on_note, stop_after, stop_when)
    if not resume:  # stored absolute with its SHA-256: the run works from anywhere (rundir.py)
        config = record_init_from(record_teachers(record_dataset(config)))
    if run.read_only:
        raise AmorError(
            f"{run.label}: pretrained runs are read-only and carry no optimizer state, so they "
            "cannot be trained further; `amorctl runs list --pretrained` shows the command that trained it"
        )
    world = distributed.current()
    if not world.is_main:  # other ranks stay quiet
        callbacks = callbacks.quiet()
    ckpt: Checkpoint | None = None
    created = not out.exists()
    with contextlib.ExitStack() as lock:
        with world.agreeing():  # every rank sees the files rank 0 checks (a shared filesystem on resume)
            if resume and config.env.dataset == run.config.env.dataset:  # (else moved: --data)
                run.config_for_data(None)  # a valid config, and its dataset where it says
            elif resume:
                run.config  # noqa: B018 (a run to resume must have a valid config)
            elif world.is_main and run.exists():
                raise AmorError(
                    f"{out} already holds a run; pass --resume to continue it or choose another --out"
                )
            if world.is_main and out.exists() and not out.is_dir():
                raise AmorError(f"{out}: --out must be a directory, not a file")
            if world.is_main:  # before any work: a read-only run directory, another writer
                check_writable(out, "run directory", _READ_ONLY_REMEDY[resume])
                lock.enter_context(dir_lock(out, "run directory"))
            if resume:  # under the lock: the newest checkpoint cannot change any more
                ckpt = run.checkpoint()
        if ckpt is not None and world.distributed:
            seen = world.all_gather(ckpt.iteration)
            if len(set(seen)) > 1:
                raise distributed.DistributedError(
                    f"--resume: the ranks see different newest checkpoints in {out} (iterations {seen}); "
                    "every rank must see the same run directory (a shared filesystem)"
                )
        saved: list[Path] = []  # checkpoints this call wrote
        try:
            with captured_sim_warnings() as warnings:
                runner = Runner(config, run, world, callbacks, warnings, saved)
                try:
                    with world.agreeing():
                        start = runner.load(ckpt) if ckpt is not None else runner.start_new()
                    return runner.learn(start)
                finally:
                    runner.close()
        except BaseException:
            if world.is_main and ckpt is None and not saved:
                _remove_failed_run(out, created)
            raise


#: what to do about a read-only run directory, new run (False) or resumed (True)
_READ_ONLY_REMEDY = {
    False: "make it writable or choose another --out",
    True: "make it writable (or copy the run to a writable place and resume there)",
}


class Runner:
    """One rank's training run in a run directory: the env (wrapped by the episode recorder), the
    backend's trainer, and the loop. :meth:`load` restores a checkpoint, :meth:`learn` iterates
    (logging, reporting, stopping on a signal or a callback, checking divergence), :meth:`save`
    writes a checkpoint (rank 0 gathers every rank's parts).

    Args:
        config: the resolved config.
        run: the run directory.
        world: this process's place among the ranks (one process: ``World()``).
        callbacks: progress reports and early stops (quiet on ranks other than 0).
        warnings: where the simulator's warnings are counted (quoted if the run diverges).
        saved: the list each saved checkpoint's path is appended to.
    """

    def __init__(
        self,
        config: TrainConfig,
        run: RunDir,
        world: distributed.World,
        callbacks: Callbacks,
        warnings: SimWarnings,
        saved: list[Path],
    ) -> None:
        self.config, self.run, self.world = config, run, world
        self.callbacks, self.warnings, self.saved = callbacks, warnings, saved
        backend = run.backend(config)
        self.local = distributed.local_config(config, world)  # this rank's envs and seed
        with world.agreeing():
            self.env = make_env(self.local, backend)
        # the trainer steps the env through the recorder (per-family survival, weight coverage); a
        # backend whose env rolls out in one fused call is not wrapped (it would lose that path)
        fused = has_fused_rollout(self.env)
        self.recorder = None if fused else EpisodeRecorder(self.env)
        trained_env: Any = self.env if fused else self.recorder
        if config.distill.teachers:  # checked before anything is written
            teacher = load_teachers(config, self.env, student_library(config))
            trained_env = Taught(trained_env, teacher)
        self.trainer: Trainer = backend.make_trainer(trained_env, self.local)
        if trainer_world_size(self.trainer) != world.size:
            raise AmorError(f"backend {config.run.backend!r} cannot train across {world.size} processes")
        self.meta = run_meta(config, self.env)
        self.resumed_from: Path | None = None
        self.last_path: Path | None = None  # the newest complete checkpoint

    def start_new(self) -> int:
        """Start a new run: its networks from ``run.init_from`` if set (checked first), then rank
        0 writes its config. Returns the first iteration, 0."""
        if self.config.run.init_from:
            start_from(self.trainer, source_networks(self.config, self.env))
        return self.write_config()

    def write_config(self) -> int:
        """Rank 0 writes the new run's config. Returns the first iteration, 0."""
        if self.world.is_main:
            self.run.path.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.run.config_path, to_toml(self.config))
        return 0

    def load(self, ckpt: Checkpoint) -> int:
        """Restore ``ckpt`` into the trainer (and the env); returns its iteration."""
        start = _restore(
            ckpt, self.local, self.run.config_path, self.env, self.trainer, self.world, self.callbacks.note
        )
        self.resumed_from = self.last_path = ckpt.path
        return start

    def save(self, iteration: int) -> Path:
        """Checkpoint ``iteration``; its path on every rank. A storage failure says what is safe."""
        try:
            path = _checkpoint(
                self.run, self.config, self.world, iteration, self.meta, self.env, self.trainer
            )
        except StorageError as err:  # disk full, ...: say what is safe and how to go on
            keep = (
                f"the newest complete checkpoint {self.last_path} is intact: {err.fix}, then continue "
                f"with `amorctl train --resume --out {self.run.path}`"
                if self.last_path is not None
                else f"no checkpoint was saved, so the run directory was removed: {err.fix} and run again"
            )
            raise StorageError(
                err.path, err.reason, f"{err.path}: cannot write ({err.reason}); {keep}"
            ) from None
        if self.world.is_main:
            self.saved.append(path)
        self.last_path = path
        return path

    def learn(self, start: int) -> RunResult:
        """Iterate from ``start`` to ``run.iterations``, or until a stop; every rank stops at the
        same iteration, with a checkpoint."""
        config, world, total = self.config, self.world, self.config.run.iterations
        batch = config.env.num_envs * config.ppo.num_steps
        resuming = self.resumed_from is not None
        log = _metrics_log(self.run.path, config, start if resuming else None) if world.is_main else None
        metrics_log = log or distributed.QuietLog()
        self.callbacks.start(self.env, start, total)
        last: dict[str, float] = {}
        interrupted, signal_name, iteration = False, "", start
        began = time.perf_counter()
        try:
            with stop_on_signals() as stop:
                while iteration < total:
                    diverged_before = diverged_total(self.env)
                    last = self.trainer.iteration()
                    iteration = self.trainer.iteration_count
                    last["wall_time_s"] = time.perf_counter() - began
                    if self.recorder is not None:
                        last.update(self.recorder.metrics(world))
                    metrics_log.write(last)
                    self.callbacks.iteration(last, total, time.perf_counter() - began)
                    diverged = diverged_total(self.env) - diverged_before
                    if world.distributed:  # every rank decides on all ranks' counts
                        diverged = int(world.sum(diverged)[0])
                    nothing_saved = resuming and self.last_path == self.resumed_from
                    _check_divergence(
                        last, iteration, self.warnings, diverged, batch, self.last_path, nothing_saved
                    )
                    interrupted = world.any(  # all ranks stop at the same iteration
                        stop.requested or self.callbacks.wants_stop(last, iteration - start)
                    )
                    if interrupted or iteration % config.run.checkpoint_every == 0 or iteration == total:
                        self.save(iteration)
                    if interrupted:
                        signal_name = stop.signal_name
                        break
        finally:
            metrics_log.close()
        return RunResult(self.run.path, start, iteration, interrupted, self.last_path, last, signal_name)

    def close(self) -> None:
        """Close the env (its simulator threads)."""
        close_env(self.env)


def _checkpoint(
    run: RunDir,
    config: TrainConfig,
    world: distributed.World,
    iteration: int,
    meta: dict[str, Any],
    env: VectorEnv,
    trainer: Trainer,
) -> Path:
    """Save iteration ``iteration`` (rank 0 writes every rank's parts); its path on every rank."""
    env_state = env.get_state() if isinstance(env, SnapshotEnv) else None
    trainer_state = distributed.gather_snapshot(trainer.state_dict(), world)  # all ranks' parts
    if env_state is not None:
        env_state = distributed.gather_snapshot(env_state, world)
    if trainer_state is None:  # not rank 0: wait until rank 0 has written it
        return Path(world.broadcast(str(checkpoint_paths(run.checkpoint_dir, iteration)[1])))
    path = save_checkpoint(run.checkpoint_dir, iteration, meta, trainer_state, env_state)
    prune_checkpoints(run.checkpoint_dir, config.run.keep_checkpoints)
    return Path(world.broadcast(str(path)))


def _check_divergence(
    metrics: dict[str, float],
    iteration: int,
    warnings: SimWarnings,
    diverged: int,
    batch: int,
    last_path: Path | None,
    resumed: bool = False,
) -> None:
    """End the run with one line when the whole batch diverged: a non-finite loss, or every env
    step of the iteration blew up in the simulator. ``resumed``: ``last_path`` is the checkpoint
    this call resumed from (no checkpoint since), so it is not called good."""
    losses_bad = not all(np.isfinite(v) for k, v in metrics.items() if k.startswith("loss/"))
    sim_bad = diverged >= batch
    if not (losses_bad or sim_bad):
        return
    what = "non-finite loss" if losses_bad else f"the simulation was unstable on all {batch} env steps"
    if last_path is None:
        where = "no checkpoint was saved, so the run directory was removed"
    elif resumed:
        where = (
            f"it diverged before saving a checkpoint after resuming from {last_path}, which may itself "
            "hold the bad state: resume from an earlier checkpoint (delete the later ones) or start anew"
        )
    else:
        where = f"the last good checkpoint is {last_path}"
    raise AmorError(f"training diverged at iteration {iteration} ({what}{warnings.summary()}); {where}")
