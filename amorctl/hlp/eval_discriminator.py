"""Table 2: uniform weights vs HLP-chosen weights, by joint MAE and by a separately trained
evaluation discriminator's logits.

Protocol (paper Section 7.3, CPU-sized by default):

1. Each condition (uniform w = 1/m, any fixed ``--weights``, each HLP) rolls out N envs of the
   run for ``seconds`` each (clips are appended as they end, as the paper fills 30-s episodes;
   same env seed for every condition, so all start from the same clips and frames). Joint MAE
   (degrees, |q - q_ref| over joints and steps) is averaged per env stream; the CI is over envs.
2. Every ``stride``-th step each env contributes its last V frames (V = 30) with the z beside them.
   Envs are split: the first ``train_fraction`` of them give training windows, the rest are held
   out. A FRESH discriminator (not the HLP's) is trained on dataset windows (positives) against the
   training windows of every condition pooled (negatives), with the HLP discriminator's loss
   (BCE + GP on dataset samples + logit L2 + weight decay; mismatched-z negatives too).
3. Its mean logit on each condition's held-out windows (never trained on) is the row's "logit";
   the CI is over held-out envs (per-env mean logits). Held-out dataset windows are scored too.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from amorctl.core.errors import AmorError
from amorctl.core.vecenv import close_env
from amorctl.hlp.config import DiscriminatorConfig, HlpConfig
from amorctl.hlp.discriminator import DiscriminatorLearner
from amorctl.hlp.run import HlpSetup, resolve_motions, run_dataset, setup
from amorctl.hlp.windows import DatasetWindows, WindowHistory, WindowSpec, observation_slices
from amorctl.train.rundir import RunDir

SCHEMA = "amorctl.hlp_table/1"


@dataclass(frozen=True)
class TableOptions:
    """Sizes of the Table 2 evaluation (CPU defaults; the paper used 80k episodes, 32M windows)."""

    num_envs: int = 16  # episodes (env streams) per condition
    seconds: float = 10.0  # length of each (paper: 30 s)
    window: int = 30  # V of the evaluation discriminator
    stride: int = 5  # a window every this many steps per env
    train_fraction: float = 0.5  # envs whose windows train the evaluation D
    steps: int = 300  # Adam steps of the evaluation D
    batch_size: int = 256
    hidden: tuple[int, ...] = (256, 128)
    learning_rate: float = 3e-4  # Adam; 3x the HLP D's, as this D trains for a fixed, short budget
    seed: int = 0
    motions: tuple[str, ...] = ()
    data: Path | None = None  # the run's own dataset where it is now (--data, after it moved)

    def check(self) -> None:
        bad = [
            (self.num_envs >= 2, "--hlp-envs must be >= 2 (some train the evaluation D, some are held out)"),
            (self.seconds > 0, "--hlp-seconds must be > 0"),
            (self.window >= 1, "the evaluation window must be >= 1"),
            (self.stride >= 1, "--hlp-stride must be >= 1"),
            (0 < self.train_fraction < 1, "train fraction must be in (0, 1)"),
            (self.steps >= 1, "--disc-steps must be >= 1"),
        ]
        for ok, msg in bad:
            if not ok:
                raise AmorError(msg)


@dataclass
class ConditionData:
    """One condition's rollout: MAE per env [N], windows [K, W], z [K, L], their env [K]."""

    label: str
    weights: str
    mae_per_env: np.ndarray
    windows: np.ndarray
    z: np.ndarray
    env_of: np.ndarray
    falls: int
    mean_w: np.ndarray  # [m]


@dataclass
class Table2:
    """The result: rows (one per condition), the caption, and counts."""

    objective_names: tuple[str, ...]
    rows: list[dict[str, Any]]
    dataset_logit: float
    counts: dict[str, int]
    options: TableOptions
    caption: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        o = self.options
        return {
            "schema": SCHEMA,
            "objectives": list(self.objective_names),
            "rows": self.rows,
            "dataset_logit": self.dataset_logit,
            "counts": self.counts,
            "caption": self.caption,
            "options": {
                "num_envs": o.num_envs,
                "seconds": o.seconds,
                "window": o.window,
                "stride": o.stride,
                "train_fraction": o.train_fraction,
                "steps": o.steps,
                "batch_size": o.batch_size,
                "hidden": list(o.hidden),
                "learning_rate": o.learning_rate,
                "seed": o.seed,
                "motions": list(o.motions),
            },
        }


def _ci95(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=np.float64)
    return float(1.96 * x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")


def roll_condition(
    s: HlpSetup,
    label: str,
    weights_text: str,
    weights_fn: Callable[[np.ndarray], np.ndarray],
    spec: WindowSpec,
    proprio: slice,
    latent: slice,
    opts: TableOptions,
) -> ConditionData:
    """Roll out one condition on a freshly reset env (seed ``opts.seed``)."""
    env, view, llp = s.env, s.view, s.llp
    n, m = env.num_envs, len(s.meta["objectives"])
    steps = max(1, round(opts.seconds / view.dt))
    obs, _ = env.reset(seed=opts.seed)
    hist = WindowHistory(n, spec)
    hist.reset(np.arange(n), spec.features(obs[:, proprio]))
    err = np.zeros(n)
    wins, zs, owners = [], [], []
    falls = 0
    w_sum = np.zeros(m)
    for t in range(steps):
        w = weights_fn(obs)
        env.set_weights(w)
        patched = obs.copy()
        patched[:, -m:] = w
        obs, _, term, trunc, info = env.step(llp(patched))
        final = np.asarray(info["final_obs"], dtype=np.float32)
        hist.push(spec.features(final[:, proprio]))
        w_sum += w.mean(0)
        err += np.degrees(np.abs(view.joint_pos() - view.reference_joint_pos(view.reference_index()))).mean(
            -1
        )
        if (t + 1) % opts.stride == 0:  # full windows only (amorctl.hlp.windows)
            full = hist.full()
            wins.append(hist.windows()[full])
            zs.append(final[full][:, latent].copy())
            owners.append(np.flatnonzero(full))
        done = np.flatnonzero(term | trunc)
        falls += int(term.sum())
        if len(done):
            hist.reset(done, spec.features(obs[done][:, proprio]))
    if sum(len(w) for w in wins) == 0:
        raise AmorError(f"--hlp-seconds {opts.seconds}: too short for one {spec.window}-frame window")
    return ConditionData(
        label,
        weights_text,
        err / steps,
        np.concatenate(wins),
        np.concatenate(zs).astype(np.float32),
        np.concatenate(owners),
        falls,
        w_sum / steps,
    )


def hlp_table(
    run_path: str,
    conditions: list[tuple[str, str, Any]],
    opts: TableOptions,
    progress: Callable[[str], None] | None = None,
) -> Table2:
    """Table 2 for the run at ``run_path``.

    Args:
        conditions: (label, weights text, source) with source a fixed w [m] or a
            :class:`~amorctl.hlp.run.LoadedHlp`.
        opts: sizes.
        progress: called with a line per phase.
    """
    opts.check()
    say = progress or (lambda _: None)
    torch_threads = torch.get_num_threads()
    rolled = _roll_conditions(run_path, conditions, opts, say)
    data, dataset = rolled.data, rolled.dataset
    n_train_envs = max(1, round(opts.num_envs * opts.train_fraction))
    rng = np.random.default_rng(opts.seed + 7)
    held_rows = rng.permutation(len(dataset))
    n_held_ds = max(1, len(dataset) // 4)
    ds_held, ds_train = held_rows[:n_held_ds], held_rows[n_held_ds:]
    neg_w = np.concatenate([d.windows[d.env_of < n_train_envs] for d in data])
    neg_z = np.concatenate([d.z[d.env_of < n_train_envs] for d in data])
    say(f"training the evaluation discriminator ({opts.steps} steps, {len(neg_w)} policy windows)")
    learner = _train_discriminator(dataset, ds_train, neg_w, neg_z, opts, rng)
    torch.set_num_threads(torch_threads)
    ds_logit = float(learner.logits(dataset.windows_at(ds_held), dataset.z[dataset.ends[ds_held] + 1]).mean())
    rows_out = [_row(d, learner, n_train_envs) for d in data]
    counts = {
        "episodes_per_condition": opts.num_envs,
        "train_windows_policy": len(neg_w),
        "train_windows_dataset_pool": len(ds_train),
        "dataset_windows_seen": int(opts.steps * opts.batch_size),
        "heldout_windows_policy": int(sum(r["windows_heldout"] for r in rows_out)),
        "heldout_windows_dataset": len(ds_held),
    }
    caption = (
        f"Table 2 (CPU-sized): {opts.num_envs} episodes x {opts.seconds:g} s per row "
        f"(MAE CI over episodes); evaluation D: fresh, V = {opts.window}, trained {opts.steps} steps on "
        f"{counts['train_windows_policy']} policy windows (all rows' training envs pooled) vs dataset "
        f"windows; logits on {counts['heldout_windows_policy']} held-out policy windows "
        f"(CI over {opts.num_envs - n_train_envs} held-out episodes per row); "
        f"{counts['heldout_windows_dataset']} held-out dataset windows score {ds_logit:.2f}."
    )
    return Table2(rolled.objectives, rows_out, ds_logit, counts, opts, caption)


@dataclass(frozen=True)
class _Rolled:
    """Step 1 of the protocol: every condition's rollout and the run's dataset windows."""

    objectives: tuple[str, ...]
    data: list[ConditionData]
    dataset: DatasetWindows


def _roll_conditions(
    run_path: str, conditions: list[tuple[str, str, Any]], opts: TableOptions, say: Callable[[str], None]
) -> _Rolled:
    """Roll every condition out on the run's env (one env, the same seed for all); an HLP of another
    run, or a run without motion tracking, is refused before any rollout."""
    from amorctl.hlp.run import LoadedHlp

    for _, _, source in conditions:
        if isinstance(source, LoadedHlp):
            source.dir.check_run(RunDir.open(run_path))
    cfg = HlpConfig()
    cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, motions=tuple(opts.motions)))
    s = setup(
        run_path,
        cfg,
        num_envs=opts.num_envs,
        seed=opts.seed,
        episode_seconds=opts.seconds + 1.0,
        data=opts.data,
    )
    try:
        if s.view is None:
            raise AmorError("Table 2 (--hlp) needs a motion-tracking run")
        for _, _, source in conditions:
            if isinstance(source, LoadedHlp):
                source.dir.check_matches(s.meta, f"run {s.run.path}")
        library = run_dataset(s.run)
        ch = s.view.character
        spec = WindowSpec(opts.window, len(ch.joint_names()), len(ch.end_effectors))
        proprio, latent = observation_slices(s.view.observation_layout, library.latent_dim)
        clips = resolve_motions(s.view, opts.motions)
        data: list[ConditionData] = []
        for label, text, source in conditions:
            say(f"rolling out {label} ({opts.num_envs} envs x {opts.seconds:g} s)")
            if isinstance(source, LoadedHlp):
                fn = source.weights
            else:
                w = np.asarray(source, dtype=np.float32)
                fn = lambda obs, w=w: np.tile(w, (len(obs), 1))  # noqa: E731
            data.append(roll_condition(s, label, text, fn, spec, proprio, latent, opts))
    finally:
        close_env(s.env)
    return _Rolled(tuple(s.meta["objectives"]), data, DatasetWindows(library, spec, clips))


def _train_discriminator(
    dataset: DatasetWindows,
    ds_train: np.ndarray,
    neg_w: np.ndarray,
    neg_z: np.ndarray,
    opts: TableOptions,
    rng: np.random.Generator,
) -> DiscriminatorLearner:
    """Step 2: a fresh discriminator, trained on the dataset windows of rows ``ds_train`` against
    the policy windows ``neg_w`` [K, W] with their z ``neg_z`` [K, L] (and mismatched-z negatives)."""
    dcfg = DiscriminatorConfig()
    learner = DiscriminatorLearner(
        dataset.spec.size,
        dataset.z.shape[1],
        opts.hidden,
        dcfg.z_hidden,
        dcfg.grad_penalty,
        dcfg.logit_l2,
        dcfg.weight_decay,
        opts.learning_rate,
        opts.seed + 11,
    )
    b = opts.batch_size
    n_mis = b // 4
    for _ in range(opts.steps):
        rows = ds_train[rng.integers(len(ds_train), size=b)]
        pos = (dataset.windows_at(rows), dataset.z[dataset.ends[rows] + 1])
        pick = rng.integers(len(neg_w), size=b - n_mis)
        mw, mz = dataset.mismatched(rng, n_mis)
        learner.step(pos, (np.concatenate([neg_w[pick], mw]), np.concatenate([neg_z[pick], mz])))
    return learner


def _row(d: ConditionData, learner: DiscriminatorLearner, n_train_envs: int) -> dict[str, Any]:
    """Step 3: one condition's row of the table, its logits on its held-out envs' windows."""
    held = d.env_of >= n_train_envs
    logits = learner.logits(d.windows[held], d.z[held])
    per_env = np.array([logits[d.env_of[held] == e].mean() for e in np.unique(d.env_of[held])])
    return {
        "label": d.label,
        "weights": d.weights,
        "joint_mae_deg": float(d.mae_per_env.mean()),
        "joint_mae_ci95": _ci95(d.mae_per_env),
        "logit": float(logits.mean()),
        "logit_ci95": _ci95(per_env),
        "episodes": len(d.mae_per_env),
        "falls": d.falls,
        "windows_train": int((~held).sum()),
        "windows_heldout": int(held.sum()),
        "mean_w": [float(x) for x in d.mean_w],
    }
