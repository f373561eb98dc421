"""The contract suites: plain functions that raise ``AssertionError`` naming what broke."""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from amorctl.core.config import TrainConfig, merge
from amorctl.core.frame_layout import FrameParts, TrackingInputs, frame_features, split_frame
from amorctl.core.specs import JOINT_GROUPS, KEYPOINTS, BackendSpec, CharacterSpec, ObjectiveSetSpec
from amorctl.registry import Provided, get_registry


# ------------------------------------------------------------------------------------ characters
def check_character(spec: CharacterSpec, *, hold: bool = True) -> list[Any]:
    """Assert that a character meets amorctl's contract; returns the ``characters check`` report.

    Static: unique joint names, every joint in a group and every group used, ranges ordered,
    positive gains and limits, four end effectors, every key point named, standing pose on known
    joints, ``min_standing_height < standing_height``, ``physics_hz`` a multiple of ``control_hz``.
    Against the model (``amorctl characters check``): nu/nv counts, actuators, floor, sensors at
    their own addresses, standing height by forward kinematics, and (``hold=True``) a 5 s PD hold.
    Warnings are allowed; a failed check is not.
    """
    from amorctl.sim.check import check_character as run_checks
    from amorctl.sim.model import load_model

    names = spec.joint_names()
    problems: list[str] = []
    if len(set(names)) != len(names):
        problems.append("joint names repeat")
    for group in JOINT_GROUPS:
        if not spec.group_indices(group):
            problems.append(f"no joint in group {group!r}")
    for j in spec.joints:
        if j.group not in JOINT_GROUPS:
            problems.append(f"joint {j.name!r}: group {j.group!r} unknown")
        if not j.range[0] < j.range[1]:
            problems.append(f"joint {j.name!r}: range {j.range} is not (lower, upper)")
        if not (j.kp > 0 and j.kd >= 0 and j.torque_limit > 0):
            problems.append(f"joint {j.name!r}: kp > 0, kd >= 0, torque_limit > 0 required")
    if len(spec.end_effectors) != 4:
        problems.append(f"end_effectors must be 4 bodies (hands then feet), got {len(spec.end_effectors)}")
    missing = [k for k in KEYPOINTS if k not in spec.keypoints]
    if missing:
        problems.append(f"keypoints lack {', '.join(missing)}")
    unknown = [k for k in spec.standing_pose if k not in names]
    if unknown:
        problems.append(f"standing_pose names unknown joints {', '.join(unknown)}")
    if not 0 < spec.min_standing_height < spec.standing_height:
        problems.append("need 0 < min_standing_height < standing_height")
    if spec.control_hz <= 0 or spec.physics_hz % spec.control_hz:
        problems.append(f"physics_hz {spec.physics_hz} must be a multiple of control_hz {spec.control_hz}")
    assert not problems, f"character {spec.name!r}: " + "; ".join(problems)

    model = load_model(spec)
    hinges = int((model.jnt_type == 3).sum())  # mjJNT_HINGE
    assert model.nu >= spec.num_joints, (
        f"{spec.name}: model has {model.nu} actuators < {spec.num_joints} joints"
    )
    assert model.nv == 6 + hinges, f"{spec.name}: nv {model.nv} is not 6 (free root) + {hinges} hinges"
    report = run_checks(spec, hold=hold)
    failed = [f"{c.name}: {c.detail}" for c in report if c.status == "fail"]
    assert not failed, f"character {spec.name!r} fails: " + " | ".join(failed)
    return report


# ------------------------------------------------------------------------------------ objectives
def _random_inputs(n: int, j: int, e: int, seed: int, substeps: int = 5) -> TrackingInputs:
    """Plausible transition inputs: random frames, a reference near them, small actions."""
    rng = np.random.default_rng(seed)

    def frame() -> np.ndarray:
        quat = rng.standard_normal((n, 4))
        ee_quat = rng.standard_normal((n, e, 4))
        return frame_features(
            rng.standard_normal((n, 3)),
            quat / np.linalg.norm(quat, axis=-1, keepdims=True),
            rng.standard_normal((n, 3)),
            rng.standard_normal((n, 3)),
            rng.standard_normal((n, j)),
            rng.standard_normal((n, j)),
            rng.standard_normal((n, e, 3)),
            ee_quat / np.linalg.norm(ee_quat, axis=-1, keepdims=True),
            rng.standard_normal((n, e, 3)),
        )

    sim = frame()
    ref = sim + 0.1 * rng.standard_normal(sim.shape)
    a = 0.1 * rng.standard_normal((3, n, j))
    return TrackingInputs(
        sim=split_frame(sim, j, e),
        ref=split_frame(ref, j, e),
        torque=rng.standard_normal((n, substeps, j)),
        pd_target=a[0],
        pd_target_prev=a[1],
        pd_target_prev2=a[2],
        joint_acc=rng.standard_normal((n, j)),
    )


def _to_xp(x: TrackingInputs, xp: Any) -> TrackingInputs:
    def parts(p: FrameParts) -> FrameParts:
        return FrameParts(**{f.name: xp.asarray(getattr(p, f.name)) for f in dataclasses.fields(FrameParts)})

    return TrackingInputs(
        sim=parts(x.sim),
        ref=parts(x.ref),
        torque=xp.asarray(x.torque),
        pd_target=xp.asarray(x.pd_target),
        pd_target_prev=xp.asarray(x.pd_target_prev),
        pd_target_prev2=xp.asarray(x.pd_target_prev2),
        joint_acc=xp.asarray(x.joint_acc),
    )


def check_objective_set(spec: ObjectiveSetSpec, character: CharacterSpec, *, jax: bool = True) -> None:
    """Assert an objective set's contract for one character.

    ``make(character)`` has ``names == spec.objectives``, ``low``/``high`` of shape [m] with
    low <= high; on random transitions the rewards are finite, [N, m], inside [low, high] for alive
    and terminated envs; under ``jax.numpy`` (when installed and ``jax``) they equal numpy's.
    """
    obj = spec.make(character)
    m = len(spec.objectives)
    assert tuple(obj.names) == tuple(spec.objectives), f"{spec.name}: names {obj.names} != {spec.objectives}"
    assert len(obj.descriptions) == m, f"{spec.name}: {len(obj.descriptions)} descriptions for {m} objectives"
    low, high = np.asarray(obj.low, dtype=np.float64), np.asarray(obj.high, dtype=np.float64)
    assert low.shape == high.shape == (m,), (
        f"{spec.name}: low/high shapes {low.shape}/{high.shape}, want ({m},)"
    )
    assert (low <= high).all(), f"{spec.name}: low > high somewhere"
    n, j, e = 8, character.num_joints, len(character.end_effectors)
    x = _random_inputs(n, j, e, seed=0, substeps=character.substeps)
    for alive in (np.ones(n), np.zeros(n)):
        r = np.asarray(obj(x, alive))
        assert r.shape == (n, m), f"{spec.name}: rewards have shape {r.shape}, want {(n, m)}"
        assert np.isfinite(r).all(), f"{spec.name}: non-finite rewards"
        assert (r >= low - 1e-9).all() and (r <= high + 1e-9).all(), (
            f"{spec.name}: rewards outside [low, high]"
        )
    if jax:
        try:
            import jax.numpy as jnp
        except ImportError:
            return
        rj = np.asarray(obj(_to_xp(x, jnp), jnp.ones(n), xp=jnp))
        np.testing.assert_allclose(rj, np.asarray(obj(x, np.ones(n))), rtol=1e-5, atol=1e-6)


# ------------------------------------------------------------------------------------ backends
def tiny_dataset(character: CharacterSpec, path: Path, seconds: float = 1.0) -> Path:
    """Write two short synthetic clips for ``character`` (swaying about its standing pose) to ``path``."""
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.motion.dataset import write_dataset

    write_dataset(path, synthetic_library(character, num_clips=2, seconds=seconds, seed=3))
    return Path(path)


def _tiny_config(character: str, dataset: Path, backend: str) -> TrainConfig:
    return merge(
        TrainConfig(),
        {
            "run": {
                "iterations": 2,
                "checkpoint_every": 1,
                "tensorboard": False,
                "threads": 1,
                "backend": backend,
                "seed": 0,
            },
            "env": {
                "kind": "tracking",
                "character": character,
                "dataset": str(dataset),
                "num_envs": 4,
                "episode_seconds": 0.4,
            },
            "network": {"actor_hidden": [16], "critic_hidden": [16]},
            # fp32: the parity check below compares the loaded (always fp32) policy with the trainer
            "ppo": {"num_steps": 4, "num_epochs": 1, "num_minibatches": 1, "precision": "fp32"},
        },
        "amorctl.testing",
    )


def _arrays_equal(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> list[str]:
    diff = sorted(set(a) ^ set(b))
    for k in sorted(set(a) & set(b)):
        x, y = np.asarray(a[k]), np.asarray(b[k])
        nan = x.dtype.kind in "fc" and y.dtype.kind in "fc"  # never-filled statistics are NaN
        if not np.array_equal(x, y, equal_nan=nan):
            diff.append(k)
    return diff


def check_backend(spec: BackendSpec, character: CharacterSpec, dataset: Path) -> None:
    """Assert a backend's contract on a tiny tracking run of ``character`` on ``dataset``.

    Resume is bit-exact: a trainer restored from a snapshot (and its env, when it can snapshot
    itself) computes the same next iteration as the one that went on. Policy parity: the
    :class:`Policy` loaded from the snapshot gives the trainer's deterministic actions.
    """
    from amorctl.core.contracts import Policy, SnapshotEnv, Trainer

    config = _tiny_config(character.name, dataset, spec.name)
    e = config.env

    def fresh() -> tuple[Any, Any, Any]:
        backend = spec.make()
        env = backend.make_env(
            character=e.character,
            dataset=e.dataset,
            objective_set=e.objective_set,
            num_envs=e.num_envs,
            episode_seconds=e.episode_seconds,
            seed=config.run.seed,
        )
        trainer = backend.make_trainer(env, config)
        assert isinstance(trainer, Trainer), f"backend {spec.name}: make_trainer does not give a Trainer"
        return backend, env, trainer

    backend, env, trainer = fresh()
    trainer.iteration()
    snap = trainer.state_dict()
    env_snap = env.get_state() if isinstance(env, SnapshotEnv) else None
    trainer.iteration()
    after = trainer.state_dict()

    _, env2, trainer2 = fresh()
    trainer2.load_state_dict(snap)
    if env_snap is not None:
        env2.set_state(env_snap)
    else:
        trainer2.reset_env(config.run.seed + 1)
    trainer2.iteration()
    differ = _arrays_equal(after.arrays, trainer2.state_dict().arrays)
    assert not differ, f"backend {spec.name}: resumed run differs from the uninterrupted one in {differ[:5]}"

    policy = backend.load_policy(after, config)
    assert isinstance(policy, Policy), f"backend {spec.name}: load_policy does not give a Policy"
    obs = np.asarray(env.reset(seed=0)[0])
    np.testing.assert_allclose(
        np.asarray(policy(obs.astype(np.float32))),
        np.asarray(trainer.act(obs, deterministic=True)),
        rtol=1e-5,
        atol=1e-6,
        err_msg=f"backend {spec.name}: loaded policy and trainer disagree",
    )
    for closer in (env, env2):
        with contextlib.suppress(Exception):
            closer.close()


# ------------------------------------------------------------------------------------ registry
@contextlib.contextmanager
def with_characters(*specs: CharacterSpec, package: str = "test") -> Iterator[None]:
    """Make ``specs`` resolvable by name through the registry for the block (as if installed)."""
    from amorctl.registry import reset_registry

    registry = get_registry()
    for spec in specs:
        registry.items["character"][spec.name] = spec
        registry.provided.append(Provided(spec.name, "character", package, "0", spec.name))
    try:
        yield
    finally:
        reset_registry()
