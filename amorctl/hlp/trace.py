"""``amorctl hlp trace``: run HLP + frozen AMOR through a sequence of motions and record w_t (Fig. 7).

One env plays the motions back to back without resets: each motion's clip runs for
``max(1, ceil(seconds / clip length))`` repetitions; before the last repetition ends the env is
told (``TrackingView.select_clips``) to continue with the next motion's clip, so the character
carries its state across the boundary as in the paper's sequence. A fall resets the env (RSI at
the current clip's start) and is marked. The HLP acts deterministically (softmax of its mean logits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_path
from amorctl.core.vecenv import close_env
from amorctl.hlp.run import LoadedHlp, resolve_motions, setup


@dataclass
class HlpTrace:
    """What one traced sequence recorded (T control steps, m objectives, J joints)."""

    label: str
    objective_names: tuple[str, ...]
    dt: float
    motions: tuple[str, ...]
    weights: np.ndarray  # [T, m] w_t the HLP chose
    rewards: np.ndarray  # [T, m] the objectives' rewards of each step
    clip: np.ndarray  # [T] clip index each step tracked
    clip_names: tuple[str, ...]
    joint_names: tuple[str, ...]
    joint_pos: np.ndarray  # [T, J] rad, after each step
    ref_joint_pos: np.ndarray  # [T, J] rad, the reference of that state
    fell: np.ndarray  # [T] bool, the step ended in a fall (env reset)
    segments: list[tuple[int, int, str]] = field(default_factory=list)  # (first step, end step, motion)

    @property
    def times(self) -> np.ndarray:
        """[T] seconds at the end of each step."""
        return (np.arange(len(self.weights)) + 1) * self.dt

    def joint_mae_deg(self) -> float:
        """Mean |q - q_ref| over the trace, degrees."""
        return float(np.degrees(np.abs(self.joint_pos - self.ref_joint_pos).mean()))


def _segments(clip: np.ndarray, names: tuple[str, ...]) -> list[tuple[int, int, str]]:
    out: list[tuple[int, int, str]] = []
    start = 0
    for t in range(1, len(clip) + 1):
        if t == len(clip) or clip[t] != clip[start]:
            out.append((start, t, names[int(clip[start])]))
            start = t
    return out


def trace_hlp(
    hlp: LoadedHlp, motions: list[str], seconds: float | None = None, seed: int = 0, data: Path | None = None
) -> HlpTrace:
    """Trace ``hlp`` on its AMOR run through ``motions`` (clip names), each for ``seconds``
    (default: one pass of the clip); ``data``: the run's own dataset where it is now.

    Raises:
        AmorError: no motion given, an unknown motion, ``seconds`` <= 0, or the HLP's run no
            longer matches it.
    """
    if not motions:
        raise AmorError("--motion: name at least one motion to trace")
    if seconds is not None and seconds <= 0:
        raise AmorError(f"--seconds must be > 0, got {seconds}")
    s = setup(
        hlp.meta["run"],
        hlp.config,
        llp_checkpoint=hlp.dir.llp_checkpoint_path(),
        num_envs=1,
        seed=seed,
        data=data,
    )
    try:
        hlp.dir.check_matches(s.meta, f"run {s.run.path}")
        view = s.view
        if view is None:
            raise AmorError("hlp trace needs a motion-tracking run")
        clips = resolve_motions(view, motions)
        assert clips is not None
        counts = np.asarray(view.clip_frame_counts)
        reps = [
            1 if seconds is None else max(1, math.ceil(seconds / (max(int(counts[c]) - 1, 1) * view.dt)))
            for c in clips
        ]
        per_rep = [int(counts[c]) - 1 for c in clips]
        total = sum(r * p for r, p in zip(reps, per_rep, strict=True))
        if total + 1 > view.max_episode_steps:  # the env was built with the HLP's episode length
            s.env.close()
            s = setup(
                hlp.meta["run"],
                hlp.config,
                llp_checkpoint=hlp.dir.llp_checkpoint_path(),
                num_envs=1,
                seed=seed,
                episode_seconds=(total + 2) * view.dt,
                data=data,
            )
            view = s.view
        env, m = s.env, len(s.meta["objectives"])
        view.select_clips(clips=[clips[0]], from_start=True)
        obs, _ = env.reset(seed=seed)
        rec: dict[str, list[Any]] = {k: [] for k in ("w", "r", "clip", "q", "qref", "fell")}
        for i, (_c, r, p) in enumerate(zip(clips, reps, per_rep, strict=True)):
            for j in range(r * p):
                if j == (r - 1) * p and i + 1 < len(clips):  # the last pass: continue with the next clip
                    view.select_clips(clips=[clips[i + 1]], from_start=True)
                clip_now = int(view.clip_index()[0])
                w = hlp.weights(obs)
                env.set_weights(w)
                patched = obs.copy()
                patched[:, -m:] = w
                obs, rew, term, _trunc, _ = env.step(s.llp(patched))
                rec["w"].append(w[0])
                rec["r"].append(np.asarray(rew)[0])
                rec["clip"].append(clip_now)
                rec["q"].append(view.joint_pos()[0])
                rec["qref"].append(view.reference_joint_pos(view.reference_index())[0])
                rec["fell"].append(bool(term[0]))
        clip_arr = np.asarray(rec["clip"], dtype=np.int64)
        names = tuple(view.clip_names)
        return HlpTrace(
            label=hlp.dir.path.name,
            objective_names=tuple(s.meta["objectives"]),
            dt=float(view.dt),
            motions=tuple(motions),
            weights=np.asarray(rec["w"], dtype=np.float32),
            rewards=np.asarray(rec["r"], dtype=np.float32),
            clip=clip_arr,
            clip_names=names,
            joint_names=tuple(view.joint_names),
            joint_pos=np.asarray(rec["q"]),
            ref_joint_pos=np.asarray(rec["qref"]),
            fell=np.asarray(rec["fell"], dtype=bool),
            segments=_segments(clip_arr, names),
        )
    finally:
        close_env(s.env)


def plot_traces(traces: list[HlpTrace], path: str | Path, title: str = "") -> None:
    """PNG/SVG of w_t per objective on a log scale with the motion segments shaded (Fig. 7);
    a second trace is overlaid dashed (Fig. 8's 2-frame vs 30-frame comparison)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    first = traces[0]
    names = first.objective_names
    colors = plt.get_cmap("tab10")(np.arange(len(names)) % 10)
    fig, ax = plt.subplots(figsize=(10, 4))
    shades = plt.get_cmap("Pastel1")(np.arange(9))
    motion_colour: dict[str, Any] = {}
    for a, b, motion in first.segments:
        colour = motion_colour.setdefault(motion, shades[len(motion_colour) % 9])
        ax.axvspan(a * first.dt, b * first.dt, color=colour, alpha=0.6, lw=0)
        ax.text(
            (a + b) / 2 * first.dt,
            1.02,
            motion,
            ha="center",
            va="bottom",
            fontsize=8,
            transform=ax.get_xaxis_transform(),
        )
    styles = ("-", "--", ":", "-.")
    for k, tr in enumerate(traces):
        for i, name in enumerate(names):
            ax.plot(
                tr.times,
                np.maximum(tr.weights[:, i], 1e-6),
                color=colors[i],
                lw=1.1,
                ls=styles[k % 4],
                label=f"{name}" if len(traces) == 1 else f"{name} ({tr.label})",
            )
        for t in tr.times[tr.fell]:
            ax.axvline(t, color="k", ls=":", lw=1)
    ax.set_yscale("log")
    ax.set_ylabel("w_t (log scale)")
    ax.set_xlabel("time (s)")
    ax.set_xlim(0, first.times[-1])
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=7, frameon=False)
    ax.set_title(title or "HLP weights " + " vs ".join(t.label for t in traces), pad=16)
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".").lower() or "png", dpi=110, bbox_inches="tight")
    plt.close(fig)


#: topics of the trace log (docs/hlp.md)
TOPIC_WEIGHTS = "/hlp/weights"
TOPIC_REWARDS = "/rewards"
TOPIC_JOINTS = "/joint_states"
TOPIC_REF_JOINTS = "/reference/joint_states"
TOPIC_MOTION = "/motion"


def write_trace_mcap(traces: list[HlpTrace], path: str | Path) -> None:
    """An MCAP log (Foxglove-readable JSON channels) of every trace; a second trace's topics are
    prefixed with ``/<label>``. Per step: ``/hlp/weights`` (t, one number per objective),
    ``/rewards`` (same), ``/joint_states`` and ``/reference/joint_states`` (name, position),
    ``/motion`` (t, clip name, fell)."""
    import foxglove

    def named(title: str, names: tuple[str, ...]) -> dict[str, Any]:
        props = {"t": {"type": "number"}, **{n: {"type": "number"} for n in names}}
        return {"title": title, "type": "object", "properties": props}

    joint_schema = {
        "title": "amorctl.JointState",
        "type": "object",
        "properties": {
            "name": {"type": "array", "items": {"type": "string"}},
            "position": {"type": "array", "items": {"type": "number"}},
        },
    }
    motion_schema = {
        "title": "amorctl.Motion",
        "type": "object",
        "properties": {"t": {"type": "number"}, "motion": {"type": "string"}, "fell": {"type": "boolean"}},
    }
    with atomic_path(path) as tmp:
        ctx = foxglove.Context()
        with foxglove.open_mcap(tmp, allow_overwrite=True, context=ctx) as writer:
            for k, tr in enumerate(traces):
                pre = "" if k == 0 else f"/{tr.label}"
                names = tr.objective_names
                writer.write_metadata(
                    f"amorctl.hlp.trace{'' if k == 0 else '.' + str(k)}",
                    {
                        "hlp": tr.label,
                        "objectives": ",".join(names),
                        "motions": ",".join(tr.motions),
                        "dt": repr(tr.dt),
                    },
                )
                w_ch = foxglove.Channel(
                    pre + TOPIC_WEIGHTS, schema=named("amorctl.Weights", names), context=ctx
                )
                r_ch = foxglove.Channel(
                    pre + TOPIC_REWARDS, schema=named("amorctl.Rewards", names), context=ctx
                )
                j_ch = foxglove.Channel(pre + TOPIC_JOINTS, schema=joint_schema, context=ctx)
                rj_ch = foxglove.Channel(pre + TOPIC_REF_JOINTS, schema=joint_schema, context=ctx)
                m_ch = foxglove.Channel(pre + TOPIC_MOTION, schema=motion_schema, context=ctx)
                jn = list(tr.joint_names)
                for i, t in enumerate(tr.times):
                    lt = round(t * 1e9)
                    w_ch.log(
                        {"t": float(t), **dict(zip(names, tr.weights[i].tolist(), strict=True))}, log_time=lt
                    )
                    r_ch.log(
                        {"t": float(t), **dict(zip(names, tr.rewards[i].tolist(), strict=True))}, log_time=lt
                    )
                    j_ch.log({"name": jn, "position": tr.joint_pos[i].tolist()}, log_time=lt)
                    rj_ch.log({"name": jn, "position": tr.ref_joint_pos[i].tolist()}, log_time=lt)
                    m_ch.log(
                        {"t": float(t), "motion": tr.clip_names[int(tr.clip[i])], "fell": bool(tr.fell[i])},
                        log_time=lt,
                    )
