"""Pure helpers of ``benchmarks/science.py``: the statistics of the weight-response targets and the report.

Nothing here trains or steps a simulator: every function takes arrays or the results dict that
``science.py`` accumulates in ``OUT/science.json`` and returns numbers or text, so a partial run
(some parts measured, others not) still renders. Shapes: L = sweep levels, E = episodes per level,
T = recorded steps, N = envs, J = actuated joints, m = objectives.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

#: Claim (ii) targets: Spearman rho, survival at every level.
RHO_TARGET = 0.9
SURVIVAL_TARGET = 0.9
#: Claim (i) target: fraction of Dirichlet weights whose point is non-dominated.
NON_DOMINATED_TARGET = 0.9
#: MOPPO vs PPO target: MOPPO's uniform-w return over PPO's at equal env steps.
PPO_RATIO_TARGET = 0.9


# ------------------------------------------------------------------------------------ statistics
def level_stats(levels: Sequence[float], returns: np.ndarray, survival: Sequence[float]) -> dict[str, Any]:
    """Claim (ii) numbers of one objective's sweep.

    Args:
        levels: [L] the swept weight per level, increasing.
        returns: [L, E] the objective's unweighted return per episode (NaN: episode missing).
        survival: [L] survival rate per level.

    Returns:
        mean, std [L]; ``monotonic`` (every level mean above the one before); ``effect_size``
        ``(mean[-1] - mean[0]) / std[0]`` (None when the low level has no spread); ``min_survival``.
    """
    r = np.asarray(returns, dtype=np.float64)
    mean = np.nanmean(r, axis=1)
    std = np.nanstd(r, axis=1)
    effect = float((mean[-1] - mean[0]) / std[0]) if std[0] > 0 else None
    return {
        "levels": [float(v) for v in levels],
        "mean": [float(v) for v in mean],
        "std": [float(v) for v in std],
        "survival": [float(v) for v in survival],
        "monotonic": bool(np.all(np.diff(mean) > 0)),
        "effect_size": effect,
        "min_survival": float(np.min(survival)),
    }


def sweep_passes(stats: dict[str, Any]) -> bool:
    """Claim (ii) for one objective: monotonic, rho >= 0.9, survival >= 90 % at every level."""
    rho = stats.get("spearman_rho")
    return bool(
        stats["monotonic"]
        and rho is not None
        and rho >= RHO_TARGET
        and stats["min_survival"] >= SURVIVAL_TARGET
    )


def corner_heavy_weights(m: int, heavy: float = 0.7) -> np.ndarray:
    """[m, m]: row k puts ``heavy`` on objective k and shares ``1 - heavy`` equally among the rest."""
    w = np.full((m, m), (1.0 - heavy) / (m - 1))
    np.fill_diagonal(w, heavy)
    return w


def hv_reference(m: int, steps: int, smooth_index: int | None) -> np.ndarray:
    """The fixed hypervolume reference point [m] in return units: ``steps`` (an episode that
    survives all ``steps`` with zero tracking reward: the alive bonus alone) for each tracking
    objective and 0 for ``smooth`` (its penalties cancel the alive bonus)."""
    ref = np.full(m, float(steps))
    if smooth_index is not None:
        ref[smooth_index] = 0.0
    return ref


def common_iterations(a: Sequence[int], b: Sequence[int], points: int) -> list[int]:
    """Up to ``points`` iterations present in both lists, evenly spread, always with the largest."""
    both = sorted(set(a) & set(b))
    if len(both) <= points:
        return both
    idx = np.unique(np.round(np.linspace(0, len(both) - 1, points)).astype(int))
    return [both[i] for i in idx]


def spread(items: Sequence[int], points: int) -> list[int]:
    """Up to ``points`` of ``items`` (sorted), evenly spread, always with the last."""
    return common_iterations(items, items, points)


# ------------------------------------------------------------------------------------ report
def _budget(meta: dict[str, Any]) -> str:
    """The MOPPO budget as the run stated it: env steps (comparable across machines) or minutes."""
    if meta.get("budget_steps"):
        return f"{meta['budget_steps']:,} env steps (the wall clock it took is in the training table)"
    return f"{_f(meta.get('budget_minutes'))} min of training wall clock"


def _f(x: Any, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return f"{x:,}"
    return f"{x:.{digits}g}" if abs(x) < 1e3 else f"{x:,.0f}"


def _verdict(ok: bool | None) -> str:
    return "–" if ok is None else ("**pass**" if ok else "**miss**")


def _missing(part: str, results: dict[str, Any]) -> str:
    cmd = results.get("meta", {}).get("rerun", {}).get(part, "")
    why = results.get("skipped", {}).get(part, "not run")
    return f"_Not measured ({why})._" + (f" To measure it: `{cmd}`" if cmd else "") + "\n"


def render_markdown(results: dict[str, Any], protocol: str) -> str:
    """docs/science.md from the accumulated results (parts not measured say so and how to run them)."""
    meta = results.get("meta", {})
    lines = [
        "# Science: does the one policy obey `w`?",
        "",
        "Written by `benchmarks/science.py`; every number below comes from the run it names. "
        "Targets and their verdicts are the project's weight-response targets; a miss is reported as "
        "a miss. The same question on a task that trains in minutes (MO-Gymnasium's hopper, side "
        "by side with CAPQL): [w-response.md](w-response.md).",
        "",
        "## Run",
        "",
        f"- command: `{meta.get('command', '?')}`",
        f"- commit: `{meta.get('commit', '?')}`; measured {meta.get('date_utc', '?')}",
        f"- machine: {meta.get('machine', '?')}",
        f"- character: {meta.get('character', '?')}, preset `{meta.get('preset', '?')}`, "
        f"dataset: {meta.get('dataset', '?')}",
        (
            f"- measured run: `{meta['run']}`, trained elsewhere (how: its card); results in "
            f"`{meta.get('out', '?')}` (not in the repository)"
            if meta.get("run")
            else f"- MOPPO budget: {_budget(meta)}; run directory `{meta.get('out', '?')}` "
            "(not in the repository)"
        ),
        "",
        "## Summary",
        "",
        "| target | measured | verdict |",
        "| --- | --- | --- |",
        *summary_rows(results),
        "",
        protocol.strip(),
        "",
    ]
    lines += _training_section(results)
    lines += _sweeps_section(results)
    lines += _front_section(results)
    lines += _ppo_section(results)
    lines += _kfixed_section(results)
    lines += _bar_section(results)
    other = meta.get("rerun", {}).get("other_character")
    if meta.get("other_report"):
        lines += ["## Other characters", "", f"Measured in a run of its own: {meta['other_report']}", ""]
    elif other:
        lines += ["## Other characters", "", f"Not measured in this run. The same protocol: `{other}`", ""]
    return "\n".join(lines).rstrip() + "\n"


def summary_rows(results: dict[str, Any]) -> list[str]:
    """One table row per issue-13 target."""
    rows = []
    sw = results.get("sweeps")
    if sw:
        for name, s in sw["objectives"].items():
            rows.append(
                f"| claim (ii) `{name}`: monotonic, ρ ≥ 0.9, survival ≥ 90 % | "
                f"ρ {_f(s.get('spearman_rho'))}, "
                f"monotonic {_f(s['monotonic'])}, min survival {_f(s['min_survival'])}, "
                f"effect {_f(s['effect_size'])} | {_verdict(sweep_passes(s))} |"
            )
        sm = sw.get("smooth_motion")
        if sm:
            ok = sm["action_rate_falls"] and sm["joint_vel_rms_falls"]
            rows.append(
                f"| `smooth` sweep: action rate and joint-velocity RMS fall monotonically | "
                f"rate falls {_f(sm['action_rate_falls'])}, RMS falls {_f(sm['joint_vel_rms_falls'])} | "
                f"{_verdict(ok)} |"
            )
    else:
        rows.append("| claim (ii), every objective | not measured | – |")
    fr = results.get("front")
    if fr:
        rows.append(
            f"| claim (i): ≥ 90 % of {fr['samples']} Dirichlet weights non-dominated (walk) | "
            f"all {_f(fr['all']['non_dominated_fraction'])}, survivors "
            f"{_f(fr['survivors']['non_dominated_fraction'])} | "
            f"{_verdict(fr['all']['non_dominated_fraction'] >= NON_DOMINATED_TARGET)} |"
        )
    else:
        rows.append("| claim (i) | not measured | – |")
    cv = results.get("curves")
    if cv and cv.get("ratio") is not None:
        rows.append(
            f"| MOPPO uniform-w return ≥ 90 % of PPO's at equal env steps | ratio {_f(cv['ratio'])} at "
            f"{_f(cv['ratio_env_steps'])} env steps | {_verdict(cv['ratio'] >= PPO_RATIO_TARGET)} |"
        )
    else:
        rows.append("| MOPPO vs PPO at equal env steps | not measured | – |")
    kf = results.get("kfixed")
    if kf:
        rows.append(
            f"| one policy vs 7 fixed-w PPO policies (report) | HV AMOR {_f(kf['hv_amor_7'])} vs "
            f"PPO×7 {_f(kf['hv_fixed_7'])} (normalized) | reported |"
        )
    else:
        rows.append("| one policy vs 7 retrained policies | not measured | – |")
    bar = results.get("bar")
    if bar:
        rows.append(
            f"| learning bar: survival over 10 s ≥ 90 % (uniform w) | "
            f"{_f(bar['uniform']['survival_rate'])} | "
            f"{_verdict(bar['uniform']['survival_rate'] >= SURVIVAL_TARGET)} |"
        )
        mu, mh = bar["uniform"]["joint_mae_deg"], bar["tracking_heavy"]["joint_mae_deg"]
        ok = None if mu is None or mh is None else mh < mu
        rows.append(
            f"| learning bar: joint MAE tracking-heavy w < uniform | {_f(mh)}° vs {_f(mu)}° | "
            f"{_verdict(ok)} |"
        )
    else:
        rows.append("| learning bar | not measured | – |")
    return rows


def _training_section(results: dict[str, Any]) -> list[str]:
    out = ["## Training", ""]
    runs = [(k, results[k]) for k in ("train", "ppo") if results.get(k)]
    if not runs:
        return [*out, _missing("train", results)]
    out += [
        "| run | weights | iterations | env steps | wall clock (min) | env steps/s | training survival |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for _key, t in runs:
        out.append(
            f"| `{t['run']}` | {t['weights']} | {_f(t['iterations'])} | {_f(t['env_steps'])} | "
            f"{_f(t['wall_s'] / 60)} | {_f(t['env_steps'] / max(t['wall_s'], 1e-9))} | "
            f"{_f(t.get('train_survival'))} |"
        )
    made = results.get("train", {}).get("made_by")
    if made and made["command"] != results.get("meta", {}).get("command"):  # trained by an earlier command
        out += ["", f"The MOPPO run was trained by `{made['command']}` (commit `{made['commit']}`, "
                f"{made['date_utc']}){made.get('note', '')}."]  # fmt: skip
    return [*out, ""]


def _sweeps_section(results: dict[str, Any]) -> list[str]:
    out = ["## Claim (ii): sweeping one weight", ""]
    sw = results.get("sweeps")
    if not sw:
        return [*out, _missing("sweeps", results)]
    out += [
        f"{sw['episodes']} episodes per level on the walking clips, seed {sw['seed']}, deterministic "
        f"policy, {sw['seconds']:.0f} s of evaluation. Level means of the swept objective's "
        "unweighted return (± std over episodes), survival per level:",
        "",
        "| objective | " + " | ".join(f"w = {v:g}" for v in sw["levels"]) + " | ρ (p) | ρ survivors | "
        "monotonic | effect size | verdict |",
        "| --- | " + " | ".join("---" for _ in sw["levels"]) + " | --- | --- | --- | --- | --- |",
    ]
    for name, s in sw["objectives"].items():
        cells = [
            f"{m:.1f} ± {d:.1f} ({100 * v:.0f} %)"
            for m, d, v in zip(s["mean"], s["std"], s["survival"], strict=True)
        ]
        out.append(
            f"| `{name}` | "
            + " | ".join(cells)
            + f" | {_f(s.get('spearman_rho'))} ({_f(s.get('spearman_p'), 2)}) "
            f"| {_f(s.get('spearman_rho_survivors'))} "
            f"| {_f(s['monotonic'])} | {_f(s['effect_size'])} | {_verdict(sweep_passes(s))} |"
        )
    sm = sw.get("smooth_motion")
    if sm:
        out += [
            "",
            "`smooth` sweep, the motion itself (same episodes, recorded): mean action rate "
            "`||q*_t - q*_{t-1}||²` of the PD targets sent (rad², summed over joints, per step) and "
            "joint-velocity RMS (rad/s):",
            "",
            "| | " + " | ".join(f"w_smooth = {v:g}" for v in sw["levels"]) + " | falls monotonically |",
            "| --- | " + " | ".join("---" for _ in sw["levels"]) + " | --- |",
            "| action rate | "
            + " | ".join(_f(v, 4) for v in sm["action_rate"])
            + f" | {_f(sm['action_rate_falls'])} |",
            "| joint-velocity RMS | "
            + " | ".join(_f(v, 4) for v in sm["joint_vel_rms"])
            + f" | {_f(sm['joint_vel_rms_falls'])} |",
        ]
    if sw.get("figure"):
        out += ["", f"![level means per objective]({sw['figure']})"]
    return [*out, ""]


def _front_section(results: dict[str, Any]) -> list[str]:
    out = ["## Claim (i): the front over Dirichlet weights", ""]
    fr = results.get("front")
    if not fr:
        return [*out, _missing("front", results)]
    ref = ", ".join(f"{n}={v:g}" for n, v in zip(fr["objectives"], fr["reference_point"], strict=True))
    out += [
        f"{fr['samples']} weights `w ~ Dirichlet(1)` (seed {fr['seed']}), one 10 s episode each on "
        f"`{fr['motion']}`, {fr['seconds']:.0f} s. Fixed reference point (returns): {ref}; "
        f"hypervolumes are divided by {fr['hv_scale']:g}^{len(fr['objectives'])} (per-step units, so a "
        "policy that tracks perfectly without any smoothness penalty scores 1).",
        "",
        "| points | count | non-dominated fraction | hypervolume (normalized) | method |",
        "| --- | --- | --- | --- | --- |",
    ]
    for key, label in (("all", "all episodes"), ("survivors", "survivors only")):
        g = fr[key]
        hv = g["hypervolume"]
        ci = f" [{_f(hv['ci_low'])}, {_f(hv['ci_high'])}]" if hv["method"] == "monte_carlo" else ""
        out.append(
            f"| {label} | {g['count']} | {_f(g['non_dominated_fraction'])} | {_f(hv['value'])}{ci} "
            f"| {hv['method']} |"
        )
    out += ["", f"Survival over the {fr['samples']} weights: {_f(fr['survival_rate'])}."]
    return [*out, ""]


def _ppo_section(results: dict[str, Any]) -> list[str]:
    out = ["## MOPPO vs PPO at equal env steps", ""]
    cv = results.get("curves")
    if not cv:
        return [*out, _missing("curves", results)]
    out += [
        f"Each checkpoint evaluated with {cv['episodes']} episodes on the walking clips (seed "
        f"{cv['seed']}): scalarized return `w·J` under uniform `w` (PPO, MOPPO) and under Dirichlet "
        "`w` (MOPPO, one weight per episode); survival in brackets.",
        "",
        "| env steps | PPO, uniform w | MOPPO, uniform w | MOPPO, random w |",
        "| --- | --- | --- | --- |",
    ]
    for row in cv["rows"]:
        cells = [
            f"{c['return']:.1f} ({100 * c['survival']:.0f} %)" if c else "–"
            for c in (row.get("ppo_uniform"), row.get("moppo_uniform"), row.get("moppo_random"))
        ]
        out.append(f"| {_f(row['env_steps'])} | " + " | ".join(cells) + " |")
    if cv.get("ratio") is not None:
        out += [
            "",
            f"Ratio MOPPO / PPO (uniform w) at {_f(cv['ratio_env_steps'])} env steps: **{_f(cv['ratio'])}**.",
        ]
    if cv.get("note"):
        out += ["", cv["note"]]
    if cv.get("figure"):
        out += ["", f"![learning curves]({cv['figure']})"]
    return [*out, ""]


def _kfixed_section(results: dict[str, Any]) -> list[str]:
    out = ["## One policy vs 7 retrained fixed-weight policies", ""]
    kf = results.get("kfixed")
    if not kf:
        return [*out, _missing("kfixed", results)]
    out += [
        f"7 PPO runs, one per corner-heavy weight (w_k = {kf['heavy']:g}, the rest equal), "
        f"{_f(kf['iterations_each'])} iterations each ({_f(kf['env_steps_total'])} env steps in all, "
        f"MOPPO: {_f(kf['moppo_env_steps'])}); each evaluated under its own weight, AMOR under the same "
        f"7 weights, {kf['episodes']} episodes on `{kf['motion']}`. Hypervolume at the claim (i) "
        "reference point, normalized:",
        "",
        f"- 7 fixed-weight PPO policies: {_f(kf['hv_fixed_7'])}",
        f"- AMOR at the same 7 weights: {_f(kf['hv_amor_7'])}",
        f"- AMOR's Dirichlet front (claim (i), all episodes): {_f(kf.get('hv_amor_front'))}",
        f"- survival: PPO×7 {', '.join(_f(v) for v in kf['survival_fixed'])}; AMOR "
        f"{', '.join(_f(v) for v in kf['survival_amor'])}",
    ]
    return [*out, *_kfixed_reading(kf, results.get("curves")), ""]


def _kfixed_reading(kf: dict[str, Any], curves: dict[str, Any] | None) -> list[str]:
    """What the numbers say when most fixed-weight policies fell: each had 1/7 of the samples."""
    if float(np.mean(kf["survival_fixed"])) >= 0.5:
        return []
    each = kf["env_steps_total"] / len(kf["survival_fixed"])
    walked = [r["env_steps"] for r in (curves or {}).get("rows", []) if r["ppo_uniform"]["survival"] >= 0.8]
    first = (
        f"; the uniform-w PPO run of the curves above first survived ≥ 80 % at {_f(walked[0])} env steps"
        if walked
        else ""
    )
    return [
        "",
        f"Most fixed-weight policies fell: with the env steps split 7 ways, each trained on "
        f"{_f(each)} env steps{first}. At this budget the comparison measures what sharing the "
        "samples across weights buys (one policy that walks under every weight against seven that "
        "have not learned to walk yet), not the shape of the trade-off; with 7× the budget each "
        "fixed-weight policy would be trained as long as AMOR.",
    ]


def _bar_section(results: dict[str, Any]) -> list[str]:
    out = ["## Learning bar", ""]
    bar = results.get("bar")
    if not bar:
        return [*out, _missing("bar", results)]
    out += [
        f"{bar['episodes']} episodes of 10 s on the walking clips, seed {bar['seed']}, same starts for "
        "both weights:",
        "",
        "| weights | survival | joint MAE (deg) | MPJPE (mm) | episode length (s) |",
        "| --- | --- | --- | --- | --- |",
    ]
    for key in ("uniform", "tracking_heavy"):
        b = bar[key]
        out.append(
            f"| {key.replace('_', '-')}: `{b['weights']}` | {_f(b['survival_rate'])} | "
            f"{_f(b['joint_mae_deg'])} | {_f(b['mpjpe_mm'])} | {_f(b['episode_length_s'])} |"
        )
    return [*out, ""]
