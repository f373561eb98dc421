"""``amorctl deploy``: export a run to an ONNX bundle, run it sim2sim, check it (docs/deploy.md).

Torch-free at import: ``export`` imports torch when it runs; ``run`` and ``check`` never do, so
``amorctl deploy run ...`` (the ``amorctl`` entry point loads only the subcommand it runs) and
``python -m amorctl.cli.deploy run ...`` work on a machine without torch.
"""

from __future__ import annotations

import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
import typer
from rich.table import Table

from amorctl.cli.options import JsonFlag
from amorctl.cli.output import console, err_console, print_json
from amorctl.core.errors import AmorError

if TYPE_CHECKING:  # annotations only: the commands import the runtime when they run
    from amorctl.deploy.runtime import EpisodeResult, Runtime

app = typer.Typer(
    help="Deploy a policy: ONNX bundle with the weights as an input, sim2sim runtime, robustness check.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)

WeightsOpt = Annotated[
    str | None,
    typer.Option("--weights", "-w", help="Constant weights, e.g. up=1,smooth=2 (normalized), or 'uniform'."),
]
ScheduleOpt = Annotated[
    Path | None, typer.Option("--schedule", "-s", help="Weight schedule TOML (docs/schedules.md).")
]
RandomizeOpt = Annotated[
    Path | None, typer.Option("--randomize", help="Dynamics randomization TOML (docs/deploy.md).")
]


@app.command("export")
def export(
    run: Annotated[Path, typer.Argument(help="Run directory (config.toml + checkpoints/).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Bundle directory to create (must not exist).")],
    checkpoint: Annotated[
        int | None, typer.Option("--checkpoint", help="Iteration of the checkpoint (default: the newest).")
    ] = None,
    data: Annotated[
        Path | None,
        typer.Option(
            "--data", help="Where the run's dataset is now, if it moved (same SHA-256 as recorded)."
        ),
    ] = None,
    json_: JsonFlag = False,
) -> None:
    """Write policy.onnx (weights w as an input), deploy.json, motions.npz and the character's model
    (model/: its MJCF, meshes, textures and licence); checks parity."""
    from amorctl.deploy.export import export_bundle

    res = export_bundle(run, out, checkpoint, data=data)
    info = {
        "out": str(res.out),
        "iteration": res.iteration,
        "inputs": res.inputs,
        "outputs": res.outputs,
        "parity_max_abs": res.parity_max_abs,
        "parity_samples": res.parity_samples,
        "onnx_bytes": res.onnx_bytes,
        "model_files": res.model_files,
    }
    if json_:
        print_json(info)
        return
    console.print(f"bundle {res.out} (run {run}, iteration {res.iteration})")
    for name, shape in res.inputs.items():
        console.print(f"  input  {name:10s} {shape}")
    for name, shape in res.outputs.items():
        console.print(f"  output {name:10s} {shape}")
    console.print(
        f"parity onnxruntime vs torch: max |Δ| = {res.parity_max_abs:.3g} "
        f"over {res.parity_samples} observations"
    )
    if res.model_files:  # the character's model, its assets and licence, copied into the bundle
        size = sum(f.stat().st_size for f in (res.out / "model").rglob("*") if f.is_file())
        console.print(f"model: {res.model_files} file(s), {size / 1e6:.1f} MB in {res.out / 'model'}")


def _weights_source(bundle: Any, weights: str | None, schedule: Path | None) -> tuple[Any, str]:
    """Constant weights or a schedule (or uniform when neither is given), and its label."""
    from amorctl.core.schedule import load_schedule
    from amorctl.core.weights import parse_weights

    if weights is not None and schedule is not None:
        raise AmorError("give --weights or --schedule, not both")
    if schedule is not None:
        return load_schedule(
            schedule, bundle.objectives, bundle.motions.names if bundle.motions else None
        ), "schedule"
    if weights is not None:
        return parse_weights(weights, bundle.objectives), "weights"
    return np.full(len(bundle.objectives), 1.0 / len(bundle.objectives)), "uniform"


def _load(bundle_dir: Path, randomize: Path | None) -> tuple[Any, Any]:
    from amorctl.deploy.bundle import read_bundle
    from amorctl.deploy.randomize import load_randomization

    rand = load_randomization(randomize) if randomize is not None else None  # validate before heavy work
    return read_bundle(bundle_dir), rand


def _listen_address(listen: str, host: str | None, token: str | None = None) -> tuple[str, int]:
    """(host, port) to bind for ``--listen`` (``--host`` overrides the URL's host); beyond
    loopback only with a shared token (:func:`amorctl.core.live_auth.check_bind`)."""
    from amorctl.core.live_auth import check_bind
    from amorctl.deploy.runtime_input import parse_listen

    url_host, port = parse_listen(listen)
    address = host if host is not None else url_host
    if address in ("", "localhost"):
        address = "127.0.0.1"
    where = f"--listen {listen}" + (f" --host {host}" if host is not None else "")
    check_bind(address, token, where)
    return address, port


@app.command("run")
def run_cmd(
    bundle_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Bundle directory (deploy export).")],
    motion: Annotated[
        str | None, typer.Option("--motion", "-m", help="Clip to track (default: the first).")
    ] = None,
    weights: WeightsOpt = None,
    schedule: ScheduleOpt = None,
    listen: Annotated[
        str | None, typer.Option("--listen", help="Live weights as JSON over UDP: udp://127.0.0.1:PORT.")
    ] = None,
    host: Annotated[
        str | None, typer.Option("--host", help="Bind the live endpoint to this address (default loopback).")
    ] = None,
    token: Annotated[
        str | None,
        typer.Option(
            "--token",
            envvar="AMORCTL_TOKEN",
            show_envvar=True,
            help="Shared token: live datagrams must carry its HMAC (needed beyond loopback; prefer the "
            "environment variable, a flag shows in `ps`).",
        ),
    ] = None,
    stale_timeout: Annotated[
        float, typer.Option("--stale-timeout", help="Seconds without a valid live message before holding.")
    ] = 1.0,
    randomize: RandomizeOpt = None,
    realtime: Annotated[
        bool, typer.Option("--realtime", help="Pace to the wall clock; enforce deadlines.")
    ] = False,
    max_misses: Annotated[
        int, typer.Option("--max-misses", help="Deadline misses in a row that latch the hold (--realtime).")
    ] = 3,
    seconds: Annotated[float | None, typer.Option("--seconds", help="Length (default: the clip's).")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the randomized dynamics and pushes.")] = 0,
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Write an MCAP log (Foxglove schemas).")
    ] = None,
    stop_on_fall: Annotated[
        bool, typer.Option("--stop-on-fall/--no-stop-on-fall", help="End at a fall, or restart the clip.")
    ] = True,
    json_: JsonFlag = False,
) -> None:
    """Drive the character in MuJoCo with the ONNX policy at the control rate (no torch needed)."""
    from amorctl.deploy.runtime import Runtime
    from amorctl.deploy.runtime_input import UdpWeights

    if listen is not None and schedule is not None:
        raise AmorError("--listen takes initial --weights, not a --schedule")
    if host is not None and listen is None:
        raise AmorError("--host needs --listen")
    if out is not None and (out.is_dir() or not out.parent.is_dir()):
        raise AmorError(f"{out}: not a writable file path (is a directory, or its directory is missing)")
    address = _listen_address(listen, host, token) if listen is not None else None  # before any work
    bundle, rand = _load(bundle_dir, randomize)
    source, _ = _weights_source(bundle, weights, schedule)
    runtime = Runtime(bundle, randomization=rand, realtime=realtime, max_misses=max_misses)
    if out is not None and bundle.meta.get("objective_set") is not None:
        from amorctl.deploy.runtime_rewards import load_reward_meter

        try:  # the log gets /rewards when the objective set's plugin is installed
            runtime.reward_meter = load_reward_meter(bundle)
        except AmorError as exc:
            err_console.print(f"warning: rewards not logged: {exc}")
    live = None
    if address is not None:
        live = UdpWeights(bundle.objectives, source, *address, stale_timeout=stale_timeout, token=token)
        signed = " (signed datagrams only)" if live.token else ""
        err_console.print(f"listening for weights on udp://{live.address[0]}:{live.address[1]}{signed}")
        source = live
    try:
        result, interrupted = _run_until_interrupt(
            runtime, source, out, motion=motion, seconds=seconds, seed=seed, stop_on_fall=stop_on_fall
        )
    finally:
        if live is not None:
            live.close()
    info = result.to_dict()
    info["interrupted"] = interrupted
    info["log"] = str(out) if out is not None else None
    if json_:
        print_json(info)
        return
    _print_run(bundle_dir, info, out)


def _run_until_interrupt(
    runtime: Runtime, source: Any, out: Path | None, *, seed: int, **run_args: Any
) -> tuple[EpisodeResult, bool]:
    """``runtime.run(source, seed=seed, **run_args)``, logged to ``out`` (MCAP) when given; Ctrl-C
    ends the run after the current step. Returns the run's result and whether Ctrl-C ended it."""
    stop = {"flag": False}

    def _interrupt(signum: int, frame: Any) -> None:
        stop["flag"] = True

    previous = signal.signal(signal.SIGINT, _interrupt)
    try:
        if out is not None:
            from amorctl.deploy.runtime_log import McapLogger

            with McapLogger(out, runtime, {"seed": str(seed)}) as log:
                runtime.logger = log
                result = runtime.run(source, seed=seed, should_stop=lambda: stop["flag"], **run_args)
        else:
            result = runtime.run(source, seed=seed, should_stop=lambda: stop["flag"], **run_args)
    finally:
        signal.signal(signal.SIGINT, previous)
    return result, stop["flag"]


def _print_run(bundle_dir: Path, info: dict[str, Any], out: Path | None) -> None:
    """The human-readable report of ``deploy run``: length, fall, tracking error, timing, returns,
    live input, events and the log written."""
    head = f"{bundle_dir}  motion={info['motion']}  {info['steps']} steps ({info['seconds']:.2f} s)"
    if info["fell_at"] is not None:
        head += f"  fell at {info['fell_at']:.2f} s"
    if info["diverged"]:
        head += "  simulation diverged"
    console.print(head)
    console.print(
        f"joint MAE {info['joint_mae_deg']:.2f} deg, action rate {info['action_rate']:.4g} rad², "
        f"policy {info['policy_ms_median']:.3f} ms median / {info['policy_ms_p99']:.3f} ms p99, "
        f"held {info['held_steps']} steps"
    )
    if info["returns"] is not None:
        console.print("returns " + ", ".join(f"{k}={v:.2f}" for k, v in info["returns"].items()))
    if info["input"] is not None:
        i = info["input"]
        console.print(
            f"live input: {i['accepted']} accepted, {i['rejected']} rejected {i['rejected_by_reason']}"
            + (f", {i['kernel_drops']} dropped by the kernel (buffer full)" if i["kernel_drops"] else "")
        )
    if info["late_ticks"] is not None:
        console.print(f"on time: {info['on_time']:.1%} of ticks ({info['late_ticks']} late)")
    for e in info["events"]:
        console.print(f"  {e['t']:7.2f} s  {e['kind']}  {e['detail']}")
    if out is not None:
        console.print(f"log: {out}")


@app.command("check")
def check_cmd(
    bundle_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Bundle directory (deploy export).")],
    episodes: Annotated[int, typer.Option("--episodes", "-n", help="Episodes per condition.")] = 8,
    randomize: RandomizeOpt = None,
    weights: WeightsOpt = None,
    schedule: ScheduleOpt = None,
    motion: Annotated[
        str | None, typer.Option("--motion", "-m", help="Only this clip (default: cycle through all).")
    ] = None,
    seconds: Annotated[float, typer.Option("--seconds", help="Episode length in seconds.")] = 10.0,
    seed: Annotated[int, typer.Option("--seed", help="Seed of episode i is seed + i.")] = 0,
    json_: JsonFlag = False,
) -> None:
    """Sim2sim robustness: uniform weights vs --weights/--schedule under the same randomized episodes."""
    from amorctl.deploy.check import run_check
    from amorctl.deploy.runtime import Runtime

    if weights is None and schedule is None:
        raise AmorError("give --weights or --schedule to compare with uniform weights")
    bundle, rand = _load(bundle_dir, randomize)
    source, label = _weights_source(bundle, weights, schedule)
    report = run_check(
        Runtime(bundle, randomization=rand),
        source,
        label=label,
        episodes=episodes,
        seconds=seconds,
        motion=motion,
        seed=seed,
    )
    if json_:
        print_json(report)
        return
    title = (
        f"sim2sim check of {bundle_dir} ({report['seconds']:g} s episodes, "
        f"randomization: {report['randomization_file']})"
    )
    columns = ("weights", "episodes", "survival", "joint MAE (deg)", "action rate (rad²)", "mean s", "falls")
    table = Table(*columns, title=title)
    for c in report["conditions"]:
        table.add_row(
            c["label"],
            str(c["episodes"]),
            f"{c['survival']:.0%}",
            f"{c['joint_mae_deg']:.2f}",
            f"{c['action_rate']:.4g}",
            f"{c['mean_seconds']:.2f}",
            str(c["falls"]),
        )
    console.print(table)


def main(argv: list[str] | None = None) -> int:
    """``python -m amorctl.cli.deploy``: the deploy commands alone (no torch needed for run and
    check), with the same error convention as ``amorctl`` (one ``error:`` line, exit 2)."""
    from amorctl.cli.main import run_app  # the lazy root loads this module: import it at call time

    return run_app(app, "amorctl deploy", argv)


if __name__ == "__main__":
    sys.exit(main())
