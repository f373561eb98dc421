"""The command line of ``benchmarks/science.py``: its parts, ``--set SECTION.KEY=VALUE`` values and
the argument parser (the protocol itself is in science.py)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from science_runs import ROOT

PARTS = ("train", "sweeps", "front", "bar", "ppo", "curves", "kfixed")
RUN_PARTS = ("sweeps", "front", "bar")  # what --run measures: the parts that need one run only


def config_setting(text: str) -> tuple[str, Any, str]:
    """``--set section.key=value`` -> (``section__key``, the TOML value, ``text``): the key and
    value as ``override`` takes them, and the text for the rerun commands."""
    import tomllib

    name, sep, value = text.partition("=")
    section, dot, key = name.strip().partition(".")
    if not sep or not dot or not section or not key:
        raise argparse.ArgumentTypeError(f"expected SECTION.KEY=VALUE, got {text!r}")
    try:
        parsed = tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: the value is not TOML ({exc})") from None
    return f"{section}__{key}", parsed, text


def parse_args(argv: list[str] | None = None, description: str = "") -> argparse.Namespace:
    """science.py's arguments (``description``: its help text)."""
    p = argparse.ArgumentParser(
        description=description or __doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--budget-minutes", type=float, default=25.0, help="MOPPO training wall clock")
    p.add_argument(
        "--budget-steps",
        type=int,
        default=None,
        help="MOPPO training budget in env steps instead of --budget-minutes (comparable across machines)",
    )
    p.add_argument("--character", choices=("biped20", "humanoid36"), default="biped20")
    p.add_argument("--preset", default="science")
    p.add_argument(
        "--set",
        action="append",
        type=config_setting,
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="change one config value of the preset (TOML value), e.g. ppo.survival_weight=2; repeatable",
    )
    p.add_argument("--out", type=Path, default=None, help="default runs/science-<character>")
    p.add_argument(
        "--doc", type=Path, default=ROOT / "docs" / "science.md", help="report (figures in its img/)"
    )
    p.add_argument("--skip-train", action="store_true", help="measure existing runs; train nothing")
    p.add_argument(
        "--run",
        default="",
        help="measure this trained run (a run directory or pretrained:NAME) instead of OUT/moppo: "
        f"parts {', '.join(RUN_PARTS)} only, on the walking clips of the run's own dataset",
    )
    p.add_argument("--only", default=",".join(PARTS), help=f"comma-separated parts of {', '.join(PARTS)}")
    p.add_argument("--deadline", default=None, metavar="HH:MM", help="UTC; stop training / skip parts then")
    p.add_argument(
        "--reserve-minutes", type=float, default=4.0, help="PPO training ends this long before --deadline"
    )
    p.add_argument(
        "--skip-reason",
        default="not selected with --only",
        help="reported for parts not run and not measured",
    )
    p.add_argument("--seed", type=int, default=0, help="training seed")
    p.add_argument("--eval-seed", type=int, default=1)
    p.add_argument("--num-envs", type=int, default=0, help="training envs (0: the preset's)")
    p.add_argument("--checkpoint-every", type=int, default=25)
    p.add_argument("--sweep-episodes", type=int, default=32)
    p.add_argument("--front-samples", type=int, default=1024)
    p.add_argument("--bar-episodes", type=int, default=64)
    p.add_argument("--curve-points", type=int, default=8)
    p.add_argument("--curve-episodes", type=int, default=32)
    p.add_argument("--kfixed-episodes", type=int, default=8)
    p.add_argument("--other-report", default="", help="markdown naming the other character's report")
    args = p.parse_args(argv)
    if args.budget_steps is not None and args.budget_steps < 1:
        p.error(f"--budget-steps must be >= 1, got {args.budget_steps}")
    args.out = args.out or Path(f"runs/science-{args.character}")
    parts = [s.strip() for s in args.only.split(",") if s.strip()]
    bad = [s for s in parts if s not in PARTS]
    if bad:
        p.error(f"--only: unknown part(s) {', '.join(bad)}; parts: {', '.join(PARTS)}")
    args.parts = parts
    if args.run:
        other = [s for s in parts if s not in RUN_PARTS]
        if other:
            p.error(f"--run measures one trained run: parts {', '.join(RUN_PARTS)}, not {', '.join(other)}")
        args.skip_train = True
    args.set_text = [text for _, _, text in args.set]
    args.set = {key: value for key, value, _ in args.set}
    return args
