"""``amorctl tune RUN --hlp HLPDIR``: the pinned motion with the HLP choosing w_t every step, edited
by per-objective multipliers (:mod:`amorctl.hlp.edit`), recorded as a
:class:`~amorctl.tune.session.TuneRollout` (so tune's MCAP log and plot work unchanged)."""

from __future__ import annotations

import math

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.hlp.edit import edit_weights
from amorctl.hlp.run import LoadedHlp
from amorctl.train.rundir import RunDir
from amorctl.tune.session import PinnedMotion, TuneRollout, geom_table


def check_hlp_for(tenv: PinnedMotion, hlp: LoadedHlp) -> None:
    """AmorError unless ``hlp`` was trained on a run like ``tenv``'s (character, objectives, obs)."""
    hlp.dir.check_run(RunDir.open(tenv.run_dir))
    if int(hlp.meta["obs_dim"]) != int(tenv.base.obs_dim):
        raise AmorError(
            f"{hlp.dir.path}: HLP was trained for obs_dim {hlp.meta['obs_dim']}, "
            f"the run has {tenv.base.obs_dim}"
        )


def hlp_weights(tenv: PinnedMotion, hlp: LoadedHlp, scales: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the HLP's w_t [m] for the pinned env's current observation, the edited w_t [m])."""
    raw = hlp.weights(tenv.obs)
    return raw[0], edit_weights(raw, scales)[0]


def run_hlp_tune(
    tenv: PinnedMotion,
    hlp: LoadedHlp,
    scales: np.ndarray,
    seconds: float | None = None,
    stop_on_fall: bool = True,
) -> tuple[TuneRollout, np.ndarray]:
    """Roll the pinned motion out from its start with the HLP's edited weights.

    Returns:
        (the rollout, the HLP's unedited weights [T, m]).
    """
    check_hlp_for(tenv, hlp)
    seconds = tenv.motion_seconds if seconds is None else float(seconds)
    if not math.isfinite(seconds) or seconds <= 0:
        raise AmorError(f"--seconds must be a positive number, got {seconds}")
    steps = max(1, math.ceil(seconds / tenv.dt - 1e-9))
    tenv.restart()
    records, raw_w, episode_t, qpos, ref_qpos = [], [], [], [], []
    view = tenv.view
    for _ in range(steps):
        raw, w = hlp_weights(tenv, hlp, scales)
        episode_t.append(tenv.t)
        rec = tenv.step(w)
        records.append(rec)
        raw_w.append(raw)
        if view is not None:  # simulator and reference poses, for videos
            qpos.append(view.qpos()[0])
            ref_qpos.append(view.reference_qpos(view.reference_index()[:1])[0])
        if rec.terminated and stop_on_fall:
            break
    stack = lambda name: np.stack([getattr(r, name) for r in records])  # noqa: E731
    model = tenv.model
    rollout = TuneRollout(
        objective_names=tenv.names,
        motion=tenv.motion,
        dt=tenv.dt,
        times=np.arange(len(records)) * tenv.dt,
        weights=stack("weights"),
        actions=stack("action"),
        rewards=stack("rewards"),
        terminated=np.array([r.terminated for r in records]),
        joint_pos=stack("joint_pos"),
        joint_vel=stack("joint_vel"),
        ref_joint_pos=stack("ref_joint_pos"),
        body_pos=stack("body_pos"),
        body_quat=stack("body_quat"),
        ref_body_pos=stack("ref_body_pos"),
        ref_body_quat=stack("ref_body_quat"),
        body_names=tenv.body_names,
        joint_names=tuple(tenv.view.joint_names) if tenv.view is not None else (),
        geoms=geom_table(model) if model is not None else [],
        episode_times=np.asarray(episode_t),
        qpos=np.stack(qpos) if qpos else None,
        ref_qpos=np.stack(ref_qpos) if ref_qpos else None,
    )
    return rollout, np.stack(raw_w)
