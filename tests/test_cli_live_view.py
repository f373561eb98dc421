"""The progress views of ``train`` and ``hlp train`` (amorctl/cli/live_view.py): header, the
throttled plain lines, the live panel's text."""

from __future__ import annotations

import io
import math
from pathlib import Path
from types import SimpleNamespace

from rich.console import Console

from amorctl.cli import hlp as cli_hlp
from amorctl.cli import train as cli_train
from amorctl.cli.live_view import fmt, fmt_time
from amorctl.core.config import load_preset

NAMES = ("pos", "vel")


def _text(renderable: object) -> str:
    c = Console(width=240, record=True, file=io.StringIO())
    c.print(renderable)
    return c.export_text()


def test_formatters() -> None:
    assert fmt(0.123456) == "0.123"
    assert fmt(math.nan) == fmt(math.inf) == "–"
    assert fmt(2.0, ".2f") == "2.00"
    assert fmt_time(3725.9) == "1:02:05"
    assert fmt_time(math.inf) == "?"


def _train_metrics(it: int) -> dict[str, float]:
    m = {
        "iteration": it, "env_steps": 1000 * it, "env_steps_per_s": 2500.0, "loss/total": 0.5,
        "loss/policy": 0.1, "loss/value": 0.4, "loss/entropy": -0.01, "kl": 0.02, "clip_fraction": 0.1,
        "learning_rate": 3e-4, "action_std": 0.8, "episodes": 7, "episode/length": 100.0,
        "episode/survival": 0.75, "return/scalarized": 1.5,
    }  # fmt: skip
    for i, n in enumerate(NAMES):
        m |= {f"return/{n}": 1.0 + i, f"reward/{n}": 0.01 * (i + 1), f"explained_variance/{n}": 0.5}
    m["return/vel"] = math.nan
    return m


def test_train_view_prints_header_and_throttled_lines(capsys, tmp_path: Path) -> None:
    config = load_preset("quick")
    view = cli_train._Display(tmp_path, config, live=False)
    env = SimpleNamespace(reward_space=SimpleNamespace(names=NAMES), obs_dim=12, action_dim=3)
    view.on_start(env, 0, 10)
    for it in (1, 2, 3, 10):
        view.on_iteration(_train_metrics(it), 10, float(it))
    view.stop()
    out = capsys.readouterr().out
    header = " ".join(out.split("\nit ")[0].split())  # the header wraps at the console's width
    assert "obs 12 · actions 3 · 2 objectives" in header and f"run directory: {tmp_path}" in header
    lines = [ln for ln in out.splitlines() if ln.startswith("it ")]
    # the first iteration and the last; 2 and 3 come within 10 s of the first
    assert [ln.split()[1] for ln in lines] == ["1/10", "10/10"]
    assert lines[0].endswith("returns pos=1 vel=–")
    assert "survival 0.75" in lines[0] and "steps/s (fp32)" in lines[0]  # the precision chosen


def test_train_view_panel(tmp_path: Path) -> None:
    view = cli_train._Display(tmp_path, load_preset("quick"), live=False)
    view.names, view.start = NAMES, 0
    text = _text(view.render(_train_metrics(5), 10, 10.0))
    assert "iteration 5/10" in text and "left 0:00:10" in text and "survival 75%" in text
    assert "(2.00 s)" in text  # 100 control steps at 50 Hz
    assert "fp32" in text and "bf16" in _text(view.render({**_train_metrics(5), "bf16": 1.0}, 10, 10.0))
    row = next(ln for ln in text.splitlines() if ln.strip().startswith("pos"))
    assert row.split() == ["pos", "1", "0.01", "0.50"]


def _hlp_metrics(it: int) -> dict[str, float]:
    return {
        "iteration": it, "env_steps": 64 * it, "env_steps_per_s": 800.0, "reward/mean": 0.25,
        "episode/return": 3.0, "episode/length": 40.0, "w/entropy": 0.6, "loss/total": 0.1,
        "loss/value": 0.05, "kl": 0.01, "logit_std": 0.3, "w/pos": 0.25, "w/vel": 0.75,
        "disc/accuracy_dataset": 0.9,
    }  # fmt: skip


def test_hlp_view_lines_and_panel(capsys, tmp_path: Path) -> None:
    view = cli_hlp._Display(tmp_path, live=False)
    setup = SimpleNamespace(
        meta={"objectives": list(NAMES)},
        run=SimpleNamespace(path=Path("runs/x")),
        llp_checkpoint=SimpleNamespace(iteration=847),
        env=SimpleNamespace(num_envs=16),
    )
    view.on_start(setup, 2, 6)
    view.on_iteration(_hlp_metrics(3), 6, 1.0)
    out = capsys.readouterr().out
    header = " ".join(out.split("\nit ")[0].split())
    assert "(AMOR iteration 847, frozen) · 16 envs · 2 objectives" in header
    assert header.endswith("(resuming at iteration 2)")
    assert "it 3/6  r^D 0.25  D acc 0.90/–  w pos=0.250 vel=0.750" in out
    text = _text(view.render(_hlp_metrics(4), 6, 8.0))
    assert "iteration 4/6" in text and "left 8 s" in text and "acc policy –" in text
    assert any(ln.split() == ["vel", "0.750"] for ln in text.splitlines())
