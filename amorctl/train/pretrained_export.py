"""``amorctl runs export-pretrained``: make a pretrained entry (:mod:`amorctl.train.pretrained`) from a run.

The entry holds one checkpoint stripped to what inference needs (no optimizer, RNG, rollout or
env state), the config with ``env.dataset = "dataset.mcap"``, a copy of the run's dataset, the
learning curve (``metrics.csv``), the given figures, ``card.json`` and ``README.md``. It is built in
a temporary folder beside the target and renamed into place only after the stripped policy gave
the same actions and values as the run's own on random observations, so a failed export leaves
nothing behind.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import math
import shutil
import subprocess
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from amorctl.core.config import to_toml
from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_write_text
from amorctl.core.weights import sample_dirichlet
from amorctl.train import pretrained
from amorctl.train.checkpoint import save_checkpoint
from amorctl.train.metrics import total_wall_time
from amorctl.train.rundir import CHECKPOINT_DIR, CONFIG_FILE, RunDir

DATASET_FILE = "dataset.mcap"
METRICS_EVERY = 10  # an entry's metrics.csv keeps every this many iterations (thin_metrics)
#: Trainer arrays / metadata that only resuming training needs (dropped): key prefixes.
_TRAINING_ONLY = ("optimizer", "rng", "episodes.", "obs")
#: Observations compared between the run's policy and the stripped one.
_CHECK_SAMPLES = 64


def strip_trainer_state(state: Snapshot) -> Snapshot:
    """The trainer snapshot without optimizer, RNG, per-env rollout and episode state.

    Args:
        state: a checkpoint's trainer snapshot (arrays + JSON meta).

    Returns:
        A snapshot with the remaining arrays (networks, normalizer) and meta.
    """
    arrays = {k: v for k, v in state.arrays.items() if not k.startswith(_TRAINING_ONLY)}
    meta = {k: v for k, v in state.meta.items() if not k.startswith("optimizer")}
    return Snapshot(arrays, meta)


def copy_dataset(source: Path, target: Path, *, with_encoder: bool) -> None:
    """Copy a motion dataset, byte for byte, or without its motion encoder attachment (same clips,
    frames, latents and clip statistics)."""
    if with_encoder:
        shutil.copyfile(source, target)
        return
    from amorctl.motion.dataset import load_clip_stats, load_dataset, write_dataset

    write_dataset(target, load_dataset(source), clip_stats=load_clip_stats(source), encoder=None)


def wall_time_s(metrics_path: Path) -> float:
    """Training wall time from ``metrics.csv`` (:func:`~amorctl.train.metrics.total_wall_time`;
    NaN without the file or the column)."""
    if not metrics_path.is_file():
        return math.nan
    with metrics_path.open(newline="", encoding="utf-8") as f:
        return total_wall_time([float(r["wall_time_s"]) for r in csv.DictReader(f) if r.get("wall_time_s")])


def thin_metrics(src: Path, dst: Path, every: int = METRICS_EVERY) -> None:
    """Copy ``metrics.csv`` keeping every ``every``-th iteration, the first and last rows and the
    last row of each resumed segment (so :func:`wall_time_s` and the learning curves survive): an
    entry trained in stages would otherwise grow by a full row per iteration per stage."""
    with src.open(newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        fields, rows = reader.fieldnames or [], list(reader)

    def seconds(row: dict[str, str]) -> float:
        return float(row.get("wall_time_s") or "nan")

    keep = [
        row
        for i, row in enumerate(rows)
        if i in (0, len(rows) - 1)
        or float(row.get("iteration") or 0) % every == 0
        or seconds(rows[i + 1]) < seconds(row)  # a resume starts a new segment after this row
    ]
    with dst.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        writer.writerows(keep)


def _last_metrics(metrics_path: Path) -> dict[str, float]:
    if not metrics_path.is_file():
        return {}
    with metrics_path.open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    out: dict[str, float] = {}
    for key, value in (rows[-1] if rows else {}).items():
        try:
            v = float(value)
        except (TypeError, ValueError):
            continue
        if math.isfinite(v) and (key.startswith(("return/", "survival/")) or key.startswith("episode/")):
            out[key] = v
    return out


def git_commit(where: Path) -> str:
    """``git rev-parse HEAD`` of the repository at ``where`` (``+dirty``: local changes), or ``""``."""
    try:
        head = subprocess.run(
            ["git", "-C", str(where), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10
        )
        if head.returncode != 0:
            return ""
        dirty = subprocess.run(
            ["git", "-C", str(where), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return ""


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _check_same_policy(original: Any, copy: Any, obs_dim: int, m: int) -> None:
    """The stripped policy must act and value exactly like the run's on random observations."""
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(_CHECK_SAMPLES, obs_dim)).astype(np.float32)
    w = sample_dirichlet(rng, _CHECK_SAMPLES, m)
    obs[:, obs_dim - m :] = w  # the last m entries are the weights
    for what in ("actions", "values"):
        call = (lambda p: p(obs)) if what == "actions" else (lambda p: p.values(obs))
        a, b = np.asarray(call(original)), np.asarray(call(copy))
        if a.shape != b.shape or not np.array_equal(a, b):
            raise AmorError(f"the stripped checkpoint's {what} differ from the run's; nothing was written")


def export_pretrained(
    run_path: str | Path,
    name: str,
    out: str | Path,
    *,
    iteration: int | None = None,
    command: str = "",
    description: str = "",
    notes: str = "",
    figures: Sequence[str | Path] = (),
    commit: str | None = None,
    replace: bool = False,
    resumable: bool = False,
    stages: Sequence[dict[str, Any]] = (),
    teacher: bool = False,
) -> pretrained.PretrainedEntry:
    """Write the pretrained entry ``out/name`` from checkpoint ``iteration`` (None: newest) of a run.

    Args:
        run_path: the run directory (or another ``pretrained:`` entry).
        name: the entry's name (``pretrained:<name>``): lowercase letters, digits, ``.``, ``_``, ``-``.
        out: the folder that receives ``<name>/`` (``amorctl/pretrained`` to ship it in the package).
        command: the command that trained the run (recorded in the card); empty and ``run_path``
            an entry: that entry's command.
        description: one line on what the policy does.
        notes: free text for the card (e.g. measured figures).
        figures: image files copied into ``figures/`` and listed in the card.
        commit: the code version that trained it; None: an entry's own commit, else
            ``git rev-parse HEAD`` of the current directory.
        replace: replace an existing entry of that name in ``out``.
        resumable: keep the checkpoint's whole training state (optimizer, RNG, rollout and env
            state), so that the entry can be trained further (``benchmarks/stage.py``), at about
            four times the size.
        stages: the training stages so far (``benchmarks/stage.py``'s records), kept in the card;
            none given and ``run_path`` an entry folder: that entry's own stages.
        teacher: an entry only ever read (a kickstarting teacher, ``[distill] teachers``): the
            stripped checkpoint and the dataset without its motion encoder (the clips' frames
            and latents are what a student compares and a policy reads), about 2 MB instead of 11
            for a one-clip humanoid36 run.

    Raises:
        AmorError: a bad name, an existing entry (without ``replace``), a missing run, checkpoint,
            dataset or figure, ``resumable`` with ``teacher``, or a stripped policy that differs
            from the run's.
    """
    if resumable and teacher:
        raise AmorError("--teacher and --resumable: a teacher entry is never trained further; pick one")
    if not pretrained.NAME_RE.match(name):
        raise AmorError(f"--name {name!r}: use lowercase letters, digits, '.', '_' or '-' (at most 64)")
    out = Path(out)
    target = out / name
    if target.exists() and not replace:
        raise AmorError(f"{target}: already exists (pass --replace to overwrite it)")
    figure_paths = [Path(f) for f in figures]
    for fig in figure_paths:
        if not fig.is_file():
            raise AmorError(f"--figure {fig}: file not found")
    run = RunDir.open(run_path)
    ckpt = run.checkpoint(iteration)
    policy = run.policy_of(ckpt)
    dataset = run.dataset_path()  # checked: one error naming the run's config key if it moved
    config = run.config
    kept = ckpt.trainer if resumable else strip_trainer_state(ckpt.trainer)
    kept_env = ckpt.env if resumable else None
    meta = {k: v for k, v in ckpt.meta.items() if k != "iteration"}
    if (run.path / pretrained.CARD_FILE).is_file():  # an entry, by folder or name: keep its record
        source_card = pretrained.read_card(run.path)
        stages = stages or source_card.get("stages") or []
        command = command or source_card.get("command") or ""
        commit = source_card.get("commit") if commit is None else commit

    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", suffix=".tmp", dir=out))
    try:
        if dataset is not None:
            copy_dataset(dataset, tmp / DATASET_FILE, with_encoder=not teacher)
            config = dataclasses.replace(config, env=dataclasses.replace(config.env, dataset=DATASET_FILE))
        atomic_write_text(tmp / CONFIG_FILE, to_toml(config))
        save_checkpoint(tmp / CHECKPOINT_DIR, ckpt.iteration, meta, kept, kept_env)
        if run.metrics_path.is_file():
            thin_metrics(run.metrics_path, tmp / "metrics.csv")
        copied = []
        for fig in figure_paths:
            (tmp / "figures").mkdir(exist_ok=True)
            shutil.copyfile(fig, tmp / "figures" / fig.name)
            copied.append(f"figures/{fig.name}")
        card = _card(run, ckpt, name, description, command, commit, notes, copied, dataset, tmp)
        card["resumable"], card["stages"] = resumable, list(stages)
        atomic_write_text(tmp / pretrained.CARD_FILE, json.dumps(card, indent=2) + "\n")
        atomic_write_text(tmp / "README.md", card_markdown(card))
        check = RunDir(tmp)
        _check_same_policy(policy, check.policy(), int(policy.obs_dim), len(policy.objectives))
        tmp.chmod(0o755)  # mkdtemp makes it private; an installed entry is read by everyone
        if target.exists():
            shutil.rmtree(target)
        tmp.rename(target)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return pretrained.PretrainedEntry(name, target, card)


def _card(
    run: RunDir,
    ckpt: Any,
    name: str,
    description: str,
    command: str,
    commit: str | None,
    notes: str,
    figures: list[str],
    dataset: Path | None,
    folder: Path,
) -> dict[str, Any]:
    """The card's fields (:data:`amorctl.train.pretrained.CARD_KEYS`)."""
    cfg = run.config
    tm = ckpt.trainer.meta
    wall = wall_time_s(run.metrics_path)
    data = None
    if dataset is not None:
        copy = folder / DATASET_FILE
        data = {
            "file": DATASET_FILE,
            "source": str(dataset),
            "bytes": copy.stat().st_size,
            "sha256": _sha256(copy),
        }
    return {
        "format": pretrained.CARD_FORMAT,
        "name": name,
        "description": description,
        "character": cfg.env.character if cfg.env.kind == "tracking" else None,
        "env_kind": cfg.env.kind,
        "backend": cfg.run.backend,
        "objectives": list(ckpt.meta.get("objectives", [])),
        "motions": _motions(cfg, dataset),
        "iteration": ckpt.iteration,
        "env_steps": int(tm.get("env_steps", 0)),
        "episodes": int(tm.get("episodes", 0)),
        "wall_time_s": None if math.isnan(wall) else round(wall, 1),
        "command": command,
        "commit": git_commit(Path.cwd()) if commit is None else commit,
        "source_run": run.label,
        "init_from": cfg.run.init_from or None,
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "dataset": data,
        "summary": _last_metrics(run.metrics_path),
        "figures": figures,
        "notes": notes,
    }


def _motions(config: Any, dataset: Path | None) -> list[str] | None:
    """The clip names a tracking run trained on (None for other envs)."""
    if config.env.kind != "tracking":
        return None
    from amorctl.motion.cache import default_dataset
    from amorctl.motion.dataset import load_dataset

    path = Path(dataset) if dataset else default_dataset(config.env.character)
    return [c.name for c in load_dataset(path).clips]


def card_markdown(card: dict[str, Any]) -> str:
    """``README.md`` of an entry: the card for people."""
    wall = card.get("wall_time_s")
    lines = [
        f"# pretrained:{card['name']}",
        "",
        card.get("description") or "(no description)",
        "",
        f"- character: {card.get('character')} · env {card.get('env_kind')} · backend {card.get('backend')}",
        f"- objectives: {', '.join(card.get('objectives', []))}",
        f"- checkpoint: iteration {card.get('iteration')}, {card.get('env_steps', 0):,} env steps, "
        f"{card.get('episodes', 0):,} episodes",
        f"- wall time: {'unknown' if wall is None else f'{wall / 60:.1f} min'}",
        f"- trained by: `{card.get('command') or 'not recorded'}`",
        f"- code version: {card.get('commit') or 'not recorded'}; source run: {card.get('source_run')}",
        f"- made: {card.get('created_utc')}",
    ]
    if card.get("init_from"):
        lines.append(f"- started from the networks of: `{card['init_from']}` (`amorctl train --init-from`)")
    if card.get("summary"):
        shown = ", ".join(f"{k} {v:.4g}" for k, v in card["summary"].items())
        lines.append(f"- last training iteration: {shown}")
    ref = f"pretrained:{card['name']}"
    lines += ["", "Use it wherever a run directory goes:", "", "```bash"]
    lines += [f"amorctl pareto {ref}", f"amorctl tune {ref}", f"amorctl evaluate {ref}", "```"]
    lines += stage_table(card.get("stages") or [])
    for fig in card.get("figures", []):
        lines += ["", f"![{fig}]({fig})"]
    if card.get("notes"):
        lines += ["", card["notes"]]
    return "\n".join(lines) + "\n"


def stage_table(stages: Sequence[dict[str, Any]]) -> list[str]:
    """Markdown lines of the card's training stages (``benchmarks/stage.py``); none without."""
    if not stages:
        return []
    lines = [
        "",
        "Training stages (resume with `python benchmarks/stage.py --run NAME --minutes M`):",
        "",
        "| stage | commit | machine | precision | wall clock (min) | env steps | iterations | "
        "cumulative env steps | evaluation at its end (uniform w: survival, joint MAE per motion family) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for st in stages:
        evaluation = "; ".join(
            f"{fam} {v['survival']:.0%}, {v['joint_mae_deg']:.1f}°"
            for fam, v in (st.get("evaluation") or {}).items()
        )
        cells = (
            st["stage"],
            str(st["commit"])[:10],
            st["machine"],
            st.get("precision") or "not recorded",
            f"{st['wall_clock_s'] / 60:.1f}" + (" (stopped by hand)" if st.get("interrupted") else ""),
            f"{st['env_steps']:,}",
            f"{st['iterations']:,}",
            f"{st['cumulative']['env_steps']:,}",
            evaluation or "–",
        )
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return lines
