"""The HLP's run directory and its training loop (``amorctl hlp train``).

``RUN/hlp/<name>/`` holds ``hlp.toml`` (the resolved HLP config), ``hlp.json`` (which AMOR run
and checkpoint it sits on, character, objectives, observation layout, window), ``llp/`` (a copy
of the frozen AMOR checkpoint, so the HLP stays usable when the run prunes its checkpoints),
``checkpoints/iter_NNNNNN.{safetensors,json}`` (:mod:`amorctl.train.checkpoint`), ``metrics.csv``
and ``tb/``. Everything is validated before the first file is written.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from amorctl.core.contracts import Policy, tracking_view
from amorctl.core.dir_lock import writing_into
from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_path, atomic_write_text, file_sha256
from amorctl.core.vecenv import close_env
from amorctl.envs.wrappers import FixedWeights
from amorctl.hlp.config import HlpConfig, load_hlp_config, to_toml
from amorctl.hlp.rewards import DiscriminatorReward, ObjectiveReward, RewardSource
from amorctl.hlp.trainer import HlpTrainer
from amorctl.hlp.windows import DatasetWindows, WindowSpec, observation_slices
from amorctl.train.callbacks import Callbacks
from amorctl.train.checkpoint import (
    Checkpoint,
    checkpoint_paths,
    list_checkpoints,
    load_checkpoint,
    prune_checkpoints,
    save_checkpoint,
)
from amorctl.train.metrics import MetricsLog
from amorctl.train.rundir import RunDir
from amorctl.train.signals import stop_on_signals

FORMAT = "amorctl-hlp/1"
CONFIG_FILE = "hlp.toml"
META_FILE = "hlp.json"
#: what must agree between an HLP directory and the run it is used with
MATCH_KEYS = ("character", "objectives", "obs_dim", "observation_layout")
#: run metadata every HLP checkpoint carries (the checkpoint format requires the first ones)
CHECKPOINT_KEYS = ("backend", "env_kind", "action_dim", *MATCH_KEYS)
#: why ``--data`` must be the run's own dataset for HLP commands
OWN_DATA = "an HLP runs on its AMOR run's own dataset (the one it was trained on), moved or not"


def policy_fingerprint(policy: Policy) -> str:
    """SHA-256 over the frozen policy's parameters (``export_arrays``; else its torch modules)."""
    digest = hashlib.sha256()
    export = getattr(policy, "export_arrays", None)
    if callable(export):
        arrays = export().arrays
    else:
        arrays = {}
        for name, value in sorted(vars(policy).items()):
            if isinstance(value, torch.nn.Module):
                arrays.update({f"{name}/{k}": v.detach().numpy() for k, v in value.state_dict().items()})
    for key in sorted(arrays):
        digest.update(key.encode())
        digest.update(np.ascontiguousarray(arrays[key]).tobytes())
    return digest.hexdigest()


def run_dataset(run: RunDir) -> Any:
    """The run's motion library (:meth:`RunDir.dataset_path`: its ``env.dataset``, or the
    character's built-in cache)."""
    from amorctl.motion.dataset import load_dataset

    return load_dataset(run.dataset_path())


def resolve_motions(view: Any, motions: tuple[str, ...] | list[str]) -> list[int] | None:
    """Clip indices of ``motions`` in the env's library (None for all); AmorError naming an unknown one."""
    if not motions:
        return None
    names = list(view.clip_names)
    out = []
    for name in motions:
        if name not in names:
            shown = ", ".join(names[:12]) + (" ..." if len(names) > 12 else "")
            raise AmorError(f"--motion {name!r}: no such clip in the run's dataset (clips: {shown})")
        out.append(names.index(name))
    return out


@dataclass
class HlpSetup:
    """A frozen AMOR policy, its env wrapped for HLP weights, and what identifies them."""

    run: RunDir
    env: Any
    llp: Policy
    llp_checkpoint: Checkpoint
    view: Any
    clips: list[int] | None
    meta: dict[str, Any] = field(default_factory=dict)


def setup(
    run_path: str | Path,
    config: HlpConfig,
    *,
    llp_checkpoint: Path | None = None,
    num_envs: int | None = None,
    seed: int | None = None,
    episode_seconds: float | None = None,
    data: Path | None = None,
) -> HlpSetup:
    """Open the AMOR run, load its frozen policy, build its env with HLP-settable weights.
    ``data``: the run's own dataset where it is now (``--data``, after the file moved).

    Raises:
        AmorError: no run or checkpoint, a missing checkpoint iteration, an unknown motion, bad ``data``.
    """
    run = RunDir.open(run_path)
    if data is not None:
        run.relocate_dataset(data, required=OWN_DATA)
    if llp_checkpoint is not None:
        ckpt = load_checkpoint(llp_checkpoint)
    else:
        it = config.run.llp_iteration
        ckpt = run.checkpoint(None if it < 0 else it)
    llp = run.policy_of(ckpt)
    base = run.env(
        num_envs=num_envs or config.env.num_envs,
        seed=config.run.seed if seed is None else seed,
        fixed_weights="",
        episode_seconds=episode_seconds or config.env.episode_seconds,
    )
    m = len(base.reward_space.names)
    env = FixedWeights(base, np.full(m, 1.0 / m))
    view = tracking_view(env)
    clips = None
    if config.env.motions:
        if view is None:
            raise AmorError("--motion needs a motion-tracking run")
        clips = resolve_motions(view, config.env.motions)
        view.select_clips(clips=clips)
    layout = dict(view.observation_layout) if view is not None else dict(llp.observation_layout)
    meta = {
        "character": run.config.env.character if run.config.env.kind == "tracking" else None,
        "env_kind": run.config.env.kind,
        "backend": run.config.run.backend,
        "action_dim": int(env.action_dim),
        "objectives": list(env.reward_space.names),
        "obs_dim": int(env.obs_dim),
        "observation_layout": {
            k: [int(v[0]), int(v[1])] if not isinstance(v, slice) else [v.start, v.stop]
            for k, v in layout.items()
        },
    }
    return HlpSetup(run, env, llp, ckpt, view, clips, meta)


def make_reward(s: HlpSetup, config: HlpConfig) -> RewardSource:
    """The configured reward source for the set-up env."""
    d = config.discriminator
    names = list(s.env.reward_space.names)
    if d.reward.startswith("objective:"):
        name = d.reward.split(":", 1)[1]
        if name not in names:
            raise AmorError(
                f"[discriminator] reward {d.reward!r}: no objective {name!r} (have {', '.join(names)})"
            )
        return ObjectiveReward(names.index(name))
    if s.view is None:
        raise AmorError(
            "the discriminator reward needs a motion-tracking run (the run's env has no motions); "
            'use [discriminator] reward = "objective:<name>" on toy envs'
        )
    library = run_dataset(s.run)
    if tuple(c.name for c in library.clips) != tuple(s.view.clip_names):
        raise AmorError("the run's dataset file changed since training (its clips differ from the env's)")
    ch = s.view.character
    spec = WindowSpec(d.window, len(ch.joint_names()), len(ch.end_effectors))
    proprio, latent = observation_slices(s.view.observation_layout, library.latent_dim)
    dataset = DatasetWindows(library, spec, s.clips)
    return DiscriminatorReward(d, spec, dataset, proprio, latent, s.env.num_envs, config.run.seed + 2)


class HlpDir:
    """An HLP directory (see the module docstring)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    @property
    def config_path(self) -> Path:
        return self.path / CONFIG_FILE

    @property
    def meta_path(self) -> Path:
        return self.path / META_FILE

    @property
    def checkpoint_dir(self) -> Path:
        return self.path / "checkpoints"

    @property
    def llp_dir(self) -> Path:
        return self.path / "llp"

    def exists(self) -> bool:
        return (
            self.config_path.exists()
            or self.meta_path.exists()
            or bool(list_checkpoints(self.checkpoint_dir))
        )

    @classmethod
    def open(cls, path: str | Path) -> HlpDir:
        """An existing HLP directory with config, metadata and a checkpoint; AmorError otherwise."""
        d = cls(path)
        if not d.path.is_dir():
            raise AmorError(f"{d.path}: not an HLP directory (not found)")
        for p in (d.config_path, d.meta_path):
            if not p.is_file():
                raise AmorError(f"{d.path}: not an HLP directory ({p.name} not found)")
        if not list_checkpoints(d.checkpoint_dir):
            raise AmorError(f"{d.checkpoint_dir}: no HLP checkpoint yet")
        return d

    @property
    def config(self) -> HlpConfig:
        return load_hlp_config(self.config_path)

    @property
    def meta(self) -> dict[str, Any]:
        try:
            meta = json.loads(self.meta_path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise AmorError(f"{self.meta_path}: unreadable HLP metadata: {exc}") from None
        if meta.get("format") != FORMAT:
            raise AmorError(f"{self.meta_path}: not HLP metadata (format {FORMAT!r} expected)")
        return meta

    def llp_checkpoint_path(self) -> Path:
        """The JSON of the copied frozen AMOR checkpoint."""
        found = list_checkpoints(self.llp_dir)
        if not found:
            raise AmorError(f"{self.llp_dir}: the HLP's copy of the AMOR checkpoint is missing")
        return found[-1][1]

    def checkpoint(self) -> Checkpoint:
        return load_checkpoint(list_checkpoints(self.checkpoint_dir)[-1][1])

    def check_run(self, run: RunDir) -> None:
        """AmorError unless ``run``'s newest checkpoint has this HLP's character, objectives and
        observation size (checked before anything of the run is loaded)."""
        ckpt = run.checkpoint()
        meta = {
            "character": ckpt.meta.get("character"),
            "objectives": ckpt.meta.get("objectives"),
            "obs_dim": ckpt.meta.get("obs_dim"),
        }
        self.check_matches(meta, f"run {run.path}", keys=("character", "objectives", "obs_dim"))

    def check_matches(self, meta: dict[str, Any], what: str, keys: tuple[str, ...] = MATCH_KEYS) -> None:
        """AmorError unless this HLP was trained for an env like ``meta`` (character, objectives,
        observation layout)."""
        mine = self.meta
        for key in keys:
            if mine.get(key) != meta.get(key):
                raise AmorError(
                    f"{self.path}: HLP was trained for {key.replace('_', ' ')} {mine.get(key)!r}, "
                    f"{what} has {meta.get(key)!r}"
                )


def copy_llp_checkpoint(ckpt: Checkpoint, dest: Path) -> Path:
    """Copy a checkpoint's JSON + safetensors into ``dest`` (atomically); returns the JSON path."""
    tensors, _ = checkpoint_paths(ckpt.path.parent, ckpt.iteration)
    dest.mkdir(parents=True, exist_ok=True)
    for src in (tensors, ckpt.path):  # JSON last: the copy exists only once both are complete
        with atomic_path(dest / src.name) as tmp:
            shutil.copyfile(src, tmp)
    return dest / ckpt.path.name


@dataclass
class HlpResult:
    out: Path
    start_iteration: int
    end_iteration: int
    interrupted: bool
    checkpoint: Path | None
    llp_fingerprint_before: str
    llp_fingerprint_after: str
    last_metrics: dict[str, float] = field(default_factory=dict)


def train_hlp(
    run_path: str | Path,
    out: str | Path,
    config: HlpConfig,
    *,
    resume: bool = False,
    on_start: Callable[[HlpSetup, int, int], None] | None = None,
    on_iteration: Callable[[dict[str, float], int, float], None] | None = None,
    stop_after: int | None = None,
    stop_when: Callable[[dict[str, float]], bool] | None = None,
    data: Path | None = None,
) -> HlpResult:
    """Train (or resume) an HLP on the run ``run_path`` into ``out``; ``data``: the run's own
    dataset where it is now (see :func:`setup`).

    Raises:
        AmorError: the run has no checkpoint; ``out`` holds an HLP already (without ``resume``),
            holds none (with it), or belongs to a run of another character / objective set /
            observation layout; an unknown motion; ``out`` is read-only or another process
            trains into it (its lock, :mod:`amorctl.core.dir_lock`). Nothing is written then.
    """
    out = Path(out)
    if resume:
        HlpDir.open(out)  # a missing HLP is named before a lock file is made for it
    with writing_into(out, "HLP directory", "make it writable or choose another --out"):
        hd, config, ckpt, llp_copy = _open_out(run_path, out, config, resume)
        if config.run.threads > 0:
            torch.set_num_threads(config.run.threads)
        s = setup(run_path, config, llp_checkpoint=llp_copy, data=data)
        if resume:
            hd.check_matches(s.meta, f"run {s.run.path}")
        reward = make_reward(s, config)
        trainer = HlpTrainer(s.env, s.llp, config, reward)
        before = policy_fingerprint(s.llp)
        start = 0
        meta = _hlp_meta(s, config, before)
        if ckpt is not None:
            trainer.load_state_dict(ckpt.trainer)
            if ckpt.env is not None:
                s.env.set_state(ckpt.env)
            start = ckpt.iteration
        else:
            hd.path.mkdir(parents=True, exist_ok=True)
            copy_llp_checkpoint(s.llp_checkpoint, hd.llp_dir)
            atomic_write_text(hd.config_path, to_toml(config))
            atomic_write_text(hd.meta_path, json.dumps(meta, indent=1, sort_keys=True) + "\n")

        total = config.run.iterations
        snapshot = callable(getattr(s.env, "get_state", None))

        def checkpoint(iteration: int) -> Path:
            env_state = s.env.get_state() if snapshot else None
            path = save_checkpoint(
                hd.checkpoint_dir,
                iteration,
                {k: meta[k] for k in CHECKPOINT_KEYS},
                trainer.state_dict(),
                env_state,
            )
            prune_checkpoints(hd.checkpoint_dir, config.run.keep_checkpoints)
            return path

        log = MetricsLog(hd.path, config.run.tensorboard, start if resume else None)
        callbacks = Callbacks(on_start, on_iteration, None, stop_after, stop_when)
        callbacks.start(s, start, total)
        last_good = ckpt.path if ckpt is not None else None
        try:
            span = range(start, total)
            result = _iterate(
                trainer, log, checkpoint, span, config.run.checkpoint_every, last_good, callbacks
            )
            iteration, last, interrupted, last_path = result
        finally:
            log.close()
            close_env(s.env)
        after = policy_fingerprint(s.llp)
        if after != before:  # the LLP must stay frozen; this would be a bug, not a user error
            raise RuntimeError("the frozen low-level policy's parameters changed during HLP training")
        return HlpResult(hd.path, start, iteration, interrupted, last_path, before, after, last)


def _open_out(
    run_path: str | Path, out: str | Path, config: HlpConfig, resume: bool
) -> tuple[HlpDir, HlpConfig, Checkpoint | None, Path | None]:
    """The HLP directory ``out``, the config to train with, and with ``resume`` its newest
    checkpoint and its copy of the AMOR checkpoint; AmorError for an HLP that is there without
    ``resume``, or missing or of another run with it."""
    hd = HlpDir(out)
    if not resume:
        if hd.exists():
            raise AmorError(
                f"{out} already holds an HLP; pass --resume to continue it or choose another --out"
            )
        return hd, config, None, None
    hd = HlpDir.open(out)
    hd.check_run(RunDir.open(run_path))
    return hd, _resume_config(hd, config), hd.checkpoint(), hd.llp_checkpoint_path()


def _hlp_meta(s: HlpSetup, config: HlpConfig, llp_fingerprint: str) -> dict[str, Any]:
    """``hlp.json``: the run's metadata, the AMOR checkpoint the HLP sits on (iteration, hash of
    its tensors, fingerprint of the frozen policy), window, reward and motions."""
    llp = s.llp_checkpoint
    return {
        "format": FORMAT,
        **s.meta,
        "run": str(s.run.path.resolve()),
        "llp_iteration": llp.iteration,
        "llp_sha256": file_sha256(checkpoint_paths(llp.path.parent, llp.iteration)[0]),
        "window": config.discriminator.window,
        "reward": config.discriminator.reward,
        "motions": list(config.env.motions),
        "llp_fingerprint": llp_fingerprint,
    }


def _iterate(
    trainer: HlpTrainer,
    log: MetricsLog,
    checkpoint: Callable[[int], Path],
    iterations: range,
    checkpoint_every: int,
    last_path: Path | None,
    callbacks: Callbacks,
) -> tuple[int, dict[str, float], bool, Path | None]:
    """HLP iterations ``iterations`` (from its start up to its stop), or until a signal or a
    callback's stop: each logged, a checkpoint every ``checkpoint_every``, at the end and at a stop.

    Returns:
        (last iteration, its metrics, whether it stopped early, the newest checkpoint).
    """
    start, total = iterations.start, iterations.stop
    last: dict[str, float] = {}
    interrupted = False
    iteration = start
    began = time.perf_counter()
    with stop_on_signals() as stop:
        while iteration < total:
            last = trainer.iteration()
            iteration = trainer.iteration_count
            last["wall_time_s"] = time.perf_counter() - began
            log.write(last)
            callbacks.iteration(last, total, time.perf_counter() - began)
            if not all(np.isfinite(v) for k, v in last.items() if k.startswith("loss/")):
                raise AmorError(
                    f"HLP training diverged at iteration {iteration}; last good checkpoint {last_path}"
                )
            interrupted = stop.requested or callbacks.wants_stop(last, iteration - start)
            if interrupted or iteration % checkpoint_every == 0 or iteration == total:
                last_path = checkpoint(iteration)
            if interrupted:
                break
    return iteration, last, interrupted, last_path


def _resume_config(hd: HlpDir, requested: HlpConfig) -> HlpConfig:
    """The HLP's own config, with only ``run.iterations`` taken from ``requested``."""
    import dataclasses

    own = hd.config
    return dataclasses.replace(own, run=dataclasses.replace(own.run, iterations=requested.run.iterations))


@dataclass
class LoadedHlp:
    """A trained HLP for inference: its config, metadata and actor-critic."""

    dir: HlpDir
    config: HlpConfig
    meta: dict[str, Any]
    model: Any  # HlpActorCritic

    def weights(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic w_t [N, m] = softmax(mean logits) for AMOR observations [N, D]."""
        m = len(self.meta["objectives"])
        w, _, _, _ = self.model.act(obs[:, :-m], None, deterministic=True)
        return w


def load_hlp(path: str | Path) -> LoadedHlp:
    """Open an HLP directory and rebuild its actor from the newest checkpoint."""
    from amorctl.hlp.policy import HlpActorCritic
    from amorctl.hlp.state import load_module

    hd = HlpDir.open(path)
    config, meta = hd.config, hd.meta
    ckpt = hd.checkpoint()
    m = len(meta["objectives"])
    p = config.policy
    model = HlpActorCritic(
        int(meta["obs_dim"]) - m, m, p.actor_hidden, p.critic_hidden, p.init_std, p.obs_clip
    )
    load_module("hlp", model, ckpt.trainer.arrays)
    model.eval()
    return LoadedHlp(hd, config, meta, model)
