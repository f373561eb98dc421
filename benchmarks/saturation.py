"""Where a servo robot's motors run out: torque saturation per clip while a policy tracks it.

Rolls the run's policy out under uniform ``w`` on every clip of its dataset (``--episodes`` per
clip, seed ``--seed``, one batched rollout, the same starts as ``benchmarks/stage.py``'s
evaluation) and reads the simulator's joint torques (every physics substep) and joint speeds
after every control step. Per clip it prints survival, joint MAE and the share of joint-steps at
a motor limit (:mod:`amorctl.analysis.saturation`: current limit, ``|tau| >= 95 %`` of stall;
speed limit, ``|q̇| >= 90 %`` of no-load), over all counted steps and over the last
``--window`` steps before each fall, with the joint most often at a limit.

    python benchmarks/saturation.py --run pretrained:biped20-repertoire
    python benchmarks/saturation.py --run runs/stages/biped20-repertoire --clips walk run --json

Results and protocol: docs/repertoire.md ("Where the motors run out").
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np

from amorctl.analysis.eval_env import close_env, make_eval_env
from amorctl.analysis.rollout import rollout
from amorctl.analysis.saturation import before_falls, saturation
from amorctl.analysis.tracking_metrics import tracking_metrics
from amorctl.core.contracts import tracking_view
from amorctl.plugins.backends.host import load_library
from amorctl.train.rundir import RunDir


def base_env(env: Any) -> Any:
    """The tracking env under any wrappers (the one that owns the simulator, ``sim``)."""
    while not hasattr(env, "sim"):
        if not hasattr(env, "env"):
            raise SystemExit("saturation.py: the run's env has no MuJoCo simulator (torch-cpu runs only)")
        env = env.env
    return env


def measure(run: RunDir, clips: list[str], episodes: int, seed: int, window_s: float) -> dict[str, Any]:
    """Per clip: survival, joint MAE, saturation over all counted steps and over the last
    ``window_s`` seconds before each fall."""
    config, policy = run.config, run.policy()
    env_motion = np.repeat(np.arange(len(clips)), episodes)
    env, resolved = make_eval_env(config, len(env_motion), motions=clips, env_motion=env_motion, seed=seed)
    try:
        character = tracking_view(env).character
        sim = base_env(env).sim
        torques: list[np.ndarray] = []
        speeds: list[np.ndarray] = []

        def record(step: int, cap: int) -> None:
            torques.append(sim.torque.copy())
            speeds.append(sim.joint_vel().copy())

        uniform = np.full(len(policy.objectives), 1.0 / len(policy.objectives))
        ro = rollout(policy, env, uniform, episodes=1, seed=seed, on_step=record)
    finally:
        close_env(env)
    torque, joint_vel = np.stack(torques), np.stack(speeds)  # [T, N, S, J], [T, N, J]
    limits = np.array([j.torque_limit for j in character.joints])
    no_load = character.actuator.no_load_speed
    falling = before_falls(ro.terminated, ro.episode_id, max(1, round(window_s / ro.dt)))
    names = character.joint_names()
    out: dict[str, Any] = {}
    for gi, clip in enumerate(resolved):
        envs = env_motion == gi
        track = tracking_metrics(ro, None, envs)
        whole = saturation(torque, joint_vel, ro.valid & envs, limits, no_load)
        fall = saturation(torque, joint_vel, falling & envs, limits, no_load)
        worst = int(np.nanargmax(whole.either))
        out[clip] = {
            "survival": float(track["survival_rate"]),
            "joint_mae_deg": float(track["joint_mae_deg"]),
            "any_joint": whole.any_joint,
            "current": float(np.mean(whole.current)),
            "speed": float(np.mean(whole.speed)),
            "worst_joint": names[worst],
            "worst_joint_share": float(whole.either[worst]),
            "any_joint_before_falls": fall.any_joint,
            "falls": int((ro.terminated & (ro.episode_id >= 0) & envs[None, :]).sum()),
        }
    return out


def markdown(rows: dict[str, dict[str, Any]], window_s: float) -> str:
    """One line per clip."""
    lines = [
        "| clip | survival / MAE | steps with a joint at a limit | joint-steps at current / speed limit "
        f"| joint most at a limit | steps with a joint at a limit, last {window_s:.1f} s before a fall |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for clip, r in rows.items():
        before = "no fall" if r["falls"] == 0 else f"{r['any_joint_before_falls']:.0%} ({r['falls']} falls)"
        lines.append(
            f"| {clip} | {r['survival']:.0%} / {r['joint_mae_deg']:.1f}° | {r['any_joint']:.0%} | "
            f"{r['current']:.1%} / {r['speed']:.1%} | {r['worst_joint']} ({r['worst_joint_share']:.0%}) | "
            f"{before} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--run", required=True, help="run directory or pretrained:NAME")
    parser.add_argument("--clips", nargs="*", default=[], help="clips to measure (default: all)")
    parser.add_argument("--episodes", type=int, default=8, help="episodes per clip")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--window", type=float, default=0.5, help="seconds before a fall to look at")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    args = parser.parse_args(argv)
    run = RunDir.open(args.run)
    if run.config.env.kind != "tracking":
        parser.error(f"--run {args.run}: not a motion-tracking run")
    clips = args.clips or [c.name for c in load_library(run.config.env.character, run.dataset_path()).clips]
    rows = measure(run, clips, args.episodes, args.seed, args.window)
    print(json.dumps(rows, indent=1) if args.json else markdown(rows, args.window))


if __name__ == "__main__":
    main()
