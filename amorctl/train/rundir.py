"""A run directory as one object: resolved config, checkpoints, metrics, the trained policy.

``runs/<name>/`` holds:

- ``config.toml``: the fully resolved config (written once, at the start);
- ``checkpoints/iter_NNNNNN.{safetensors,json}``: see :mod:`amorctl.train.checkpoint`;
- ``metrics.csv``: one row per iteration; ``tb/``: the same as TensorBoard scalars.

Every command that opens a run (train --resume, pareto, evaluate, tune, hlp, deploy) does it
through :class:`RunDir`, so a missing, half-written or mismatched run is reported in one place;
the run's motion dataset is resolved in one place too (:meth:`RunDir.dataset_path`): ``train``
stores it absolute with its SHA-256 (:func:`record_dataset`), so a run works from any directory,
and a moved dataset is found again with ``--data NEWPATH`` (:meth:`RunDir.config_for_data`).
``pretrained:<name>`` in place of a path opens a read-only run shipped with the package
(:mod:`amorctl.train.pretrained`); commands write its outputs to :meth:`RunDir.output_dir`.
"""

from __future__ import annotations

import dataclasses
from functools import cached_property
from pathlib import Path
from typing import Any

from amorctl import __version__
from amorctl.core.config import TrainConfig, load_config
from amorctl.core.contracts import Backend, Policy
from amorctl.core.errors import AmorError
from amorctl.core.files import file_sha256
from amorctl.core.levers import TRAINING_ONLY_ENV
from amorctl.core.vecenv import VectorEnv
from amorctl.envs.factory import make_env
from amorctl.registry import get_registry
from amorctl.train import pretrained
from amorctl.train.checkpoint import (
    Checkpoint,
    check_against_config,
    check_policy_sizes,
    list_checkpoints,
    load_checkpoint,
)
from amorctl.train.metrics import METRICS_FILE

CONFIG_FILE = "config.toml"
CHECKPOINT_DIR = "checkpoints"

#: checkpoint metadata that must match the run it is loaded into
COMPATIBILITY_KEYS = ("env_kind", "character", "gym_id", "objectives", "obs_dim", "action_dim", "backend")


class RunDir:
    """One training run's directory.

    Args:
        path: the directory (it need not exist yet for a new run), or ``pretrained:<name>``.

    Raises:
        AmorError: a ``pretrained:`` name that is not installed.
    """

    def __init__(self, path: str | Path) -> None:
        #: the pretrained entry's name, or None for an ordinary run directory
        self.pretrained: str | None = None
        if pretrained.is_reference(path):
            entry = pretrained.resolve(path)
            self.pretrained, path = entry.name, entry.path
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunDir({self.label!r})"

    @property
    def label(self) -> str:
        """How to name the run to a user: ``pretrained:<name>`` or the directory."""
        return f"{pretrained.PREFIX}{self.pretrained}" if self.pretrained else str(self.path)

    @property
    def read_only(self) -> bool:
        """Pretrained runs are read-only: nothing may be written into them."""
        return self.pretrained is not None

    def output_dir(self, sub: str) -> Path:
        """Default folder for a command's outputs: ``<run>/<sub>``, or ``./<name>/<sub>`` for a
        read-only pretrained run."""
        return pretrained.output_folder(self.pretrained, sub) if self.pretrained else self.path / sub

    # --- files --------------------------------------------------------------------------------
    @property
    def config_path(self) -> Path:
        return self.path / CONFIG_FILE

    @property
    def checkpoint_dir(self) -> Path:
        return self.path / CHECKPOINT_DIR

    @property
    def metrics_path(self) -> Path:
        return self.path / METRICS_FILE

    def exists(self) -> bool:
        """Whether the directory holds a run (a config or a checkpoint)."""
        return self.config_path.exists() or bool(self.checkpoints())

    # --- opening ------------------------------------------------------------------------------
    @classmethod
    def open(cls, path: str | Path, *, need_checkpoint: bool = True) -> RunDir:
        """An existing run; checks it has a config (and a checkpoint unless told otherwise).

        Raises:
            AmorError: ``path`` is not a directory, has no ``config.toml``, or no checkpoint.
        """
        run = cls(path)
        if not run.path.is_dir():
            raise AmorError(f"{run.path}: not a run directory (run directory not found)")
        if not run.config_path.is_file():
            raise AmorError(f"{run.path}: not a run directory ({CONFIG_FILE} not found)")
        if need_checkpoint and not run.checkpoints():
            raise AmorError(f"{run.checkpoint_dir}: no checkpoint yet (the run has not saved one)")
        return run

    @cached_property
    def config(self) -> TrainConfig:
        """The run's resolved config. Raises AmorError if there is none or it is invalid."""
        if not self.config_path.is_file():
            raise AmorError(f"{self.path}: no run to resume or open ({CONFIG_FILE} not found)")
        cfg = load_config(self.config_path)
        dataset = Path(cfg.env.dataset) if cfg.env.dataset else None
        if dataset is not None and not dataset.is_absolute():
            # a pretrained entry carries its dataset: relative to the entry, wherever it is installed
            # (also when opened by its folder's path, e.g. a copy made by ``runs export-pretrained``);
            # any other relative path is read from the directory amorctl runs in
            carried = self.path / dataset
            if self.pretrained or (not dataset.is_file() and carried.is_file()):
                cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, dataset=str(carried)))
        return cfg

    # --- the motion dataset -------------------------------------------------------------------
    def dataset_path(self) -> Path | None:
        """The motion dataset the run trains on, checked to be there: its config's ``env.dataset``
        (a pretrained entry's own copy; the character's built-in clips, preprocessed into the cache
        on first use, when empty); None for runs without motions. Every command that reads a run's
        dataset (train --resume, evaluate, pareto, tune, hlp, deploy export) gets it here.

        Raises:
            AmorError: the file is not there: names the run's config key and how to point at it.
        """
        env = self.config.env
        if env.kind != "tracking":
            return None
        if not env.dataset:
            from amorctl.motion.cache import default_dataset

            return default_dataset(env.character)
        path = Path(env.dataset)
        if path.is_file():
            return path
        relative = "" if path.is_absolute() else " (a relative path, read from the directory amorctl runs in)"
        same = f" with SHA-256 {env.dataset_sha256[:12]}…" if env.dataset_sha256 else ""
        raise AmorError(
            f"{self.config_path}: env.dataset = {str(path)!r}{relative}: the run's motion dataset is "
            f"not there (moved or deleted): pass --data NEWPATH (the same file{same}), or set "
            f"env.dataset in {self.config_path} to where it is now"
        )

    def config_for_data(self, data: str | Path | None) -> TrainConfig:
        """The config to roll the run out on with ``--data DATA`` (evaluate, pareto, tune, deploy
        export): DATA with the SHA-256 the run recorded is the run's own dataset, moved (the run's
        config points at it from now on: ``self.config`` too); any other file is held-out clips,
        re-encoded with the run dataset's VAE (:func:`amorctl.motion.heldout.dataset_for_run`).
        Without DATA, the run's own (checked: :meth:`dataset_path`).

        Raises:
            AmorError: the run is not a motion-tracking run, a file is missing, or DATA does not fit.
        """
        from amorctl.motion.heldout import dataset_for_run

        config = self.config
        if data is None:
            if config.env.kind == "tracking" and config.env.dataset:
                self.dataset_path()
            return config
        if self.relocate_dataset(data):
            return self.config
        held_out = dataset_for_run(self.dataset_path(), Path(data))
        return dataclasses.replace(config, env=dataclasses.replace(config.env, dataset=str(held_out)))

    def relocate_dataset(self, data: str | Path, *, required: str = "") -> bool:
        """Whether ``data`` is the run's own dataset, moved: the SHA-256 the run recorded
        (``env.dataset_sha256``) matches; then ``self.config`` points at it (nothing is written).
        ``required``: why only the run's own dataset will do (a refusal otherwise, saying so).

        Raises:
            AmorError: the run is not a motion-tracking run, ``data`` is missing, or (``required``)
                ``data`` is not the run's dataset.
        """
        data, config = Path(data), self.config
        if config.env.kind != "tracking":
            raise AmorError(
                f"--data {data}: needs a motion-tracking run; this run's env is {config.env.kind!r}"
            )
        if not data.is_file():
            raise AmorError(f"{data}: motion dataset not found (--data)")
        recorded = config.env.dataset_sha256
        if not recorded or file_sha256(data) != recorded:
            if required:
                why = (
                    f"its SHA-256 is not the {recorded[:12]}… recorded in {self.config_path}"
                    if recorded
                    else f"the run recorded no SHA-256 to compare with: set env.dataset in {self.config_path}"
                )
                raise AmorError(f"--data {data}: not the run's dataset ({why}): {required}")
            return False
        env = dataclasses.replace(config.env, dataset=str(data.resolve()))
        self.__dict__["config"] = dataclasses.replace(config, env=env)  # the cached property
        return True

    # --- checkpoints --------------------------------------------------------------------------
    def checkpoints(self) -> list[tuple[int, Path]]:
        """(iteration, JSON path) of every checkpoint, oldest first."""
        return list_checkpoints(self.checkpoint_dir)

    def checkpoint(self, iteration: int | None = None) -> Checkpoint:
        """Load the checkpoint of ``iteration`` (None: the newest), verified.

        Raises:
            AmorError: there is none, that iteration has none, or it is damaged (the message names
                an older one to fall back to when there is one).
        """
        found = self.checkpoints()
        if not found:
            raise AmorError(f"{self.checkpoint_dir}: no checkpoint to resume from or load")
        if iteration is not None:
            paths = dict(found)
            if iteration not in paths:
                have = ", ".join(str(i) for i, _ in found)
                raise AmorError(f"{self.path}: no checkpoint of iteration {iteration} (have: {have})")
            return load_checkpoint(paths[iteration])
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

    # --- what a run makes ---------------------------------------------------------------------
    def backend(self, config: TrainConfig | None = None) -> Backend:
        """The run's backend (``run.backend`` of its config), from the registry."""
        cfg = config or self.config
        return get_registry().backend(cfg.run.backend).make()

    def env(self, *, num_envs: int | None = None, seed: int | None = None, **env_overrides: Any) -> VectorEnv:
        """The run's env rebuilt from its config, optionally resized / reseeded / changed
        (``env_overrides`` are fields of the config's ``[env]`` table)."""
        if "dataset" not in env_overrides:
            self.config_for_data(None)  # the run's dataset is there, or one error naming the key
        return make_env(self.env_config(num_envs=num_envs, seed=seed, **env_overrides), self.backend())

    def env_config(
        self, *, num_envs: int | None = None, seed: int | None = None, **env_overrides: Any
    ) -> TrainConfig:
        """The run's config with ``[env]`` fields and the seed replaced; the training-only episode
        levers are off (``TRAINING_ONLY_ENV``: whoever rebuilds a run's env uses it, not trains it)."""
        cfg = self.config
        env_fields = {**TRAINING_ONLY_ENV, **env_overrides}
        if num_envs is not None:
            env_fields["num_envs"] = int(num_envs)
        run = cfg.run if seed is None else dataclasses.replace(cfg.run, seed=int(seed))
        return dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, **env_fields), run=run)

    def policy(self, iteration: int | None = None) -> Policy:
        """The :class:`~amorctl.core.contracts.Policy` of a checkpoint (None: the newest), checked
        against the run's config (objectives, sizes)."""
        ckpt = self.checkpoint(iteration)
        return self.policy_of(ckpt)

    def policy_of(self, ckpt: Checkpoint) -> Policy:
        """The policy of an already loaded checkpoint of this run."""
        config = self.config
        check_against_config(ckpt, config, self.config_path)
        policy = self.backend().load_policy(ckpt.trainer, config)
        check_policy_sizes(ckpt, policy.obs_dim, policy.action_dim, policy.objectives)
        return policy


def record_dataset(config: TrainConfig) -> TrainConfig:
    """A new run's config with its dataset stored absolute (so the run works from any directory)
    and that file's SHA-256 next to it (so ``--data`` recognizes the file if it moves); unchanged
    without an explicit dataset. A missing file is left to the env's own error."""
    env = config.env
    if env.kind != "tracking" or not env.dataset or not Path(env.dataset).is_file():
        return config
    path = Path(env.dataset).resolve()
    return dataclasses.replace(
        config, env=dataclasses.replace(env, dataset=str(path), dataset_sha256=file_sha256(path))
    )


def run_meta(config: TrainConfig, env: VectorEnv) -> dict[str, Any]:
    """The metadata every checkpoint of a run carries (checked on resume and on load)."""
    e = config.env
    return {
        "amorctl_version": __version__,
        "backend": config.run.backend,
        "env_kind": e.kind,
        "character": e.character if e.kind == "tracking" else None,
        "gym_id": e.gym_id if e.kind == "gym" else None,
        "objective_set": e.objective_set if e.kind == "tracking" else None,
        "objectives": list(env.reward_space.names),
        "obs_dim": env.obs_dim,
        "action_dim": env.action_dim,
        "fixed_weights": e.fixed_weights,
    }


def check_compatible(ckpt: Checkpoint, config: TrainConfig, env: VectorEnv) -> None:
    """Raise AmorError if a checkpoint was made for another env, character or objective set."""
    expected = run_meta(config, env)
    for key in COMPATIBILITY_KEYS:
        if ckpt.meta.get(key) != expected[key]:
            what = key.replace("_", " ")
            raise AmorError(
                f"{ckpt.path}: checkpoint was made for {what} {ckpt.meta.get(key)!r}, "
                f"this run has {expected[key]!r}"
            )
