"""`amorctl deploy` end to end through the CLI: export of an absolute-action run (parity printed,
metadata), a failed parity check writes nothing, and live weights over real loopback UDP to the
`amorctl` console script with torch unimportable (validation counts, stale watchdog, MCAP log,
loopback bind unless --host)."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from amorctl import __version__
from amorctl.cli.main import main
from amorctl.deploy.bundle import METADATA_KEYS, ONNX_FILE, read_bundle

TRACKING7 = ("up", "lo", "feet", "rbs", "root", "vel", "smooth")


@pytest.fixture(scope="module")
def absolute_run(tmp_path_factory: pytest.TempPathFactory, make_tracking_run) -> Path:
    """A one-iteration biped20 run with absolute actions on two 1 s synthetic clips."""
    return make_tracking_run(
        tmp_path_factory.mktemp("deploy-abs-run"),
        "absolute_run fixture",
        episode_seconds=1.0,
        action_mode="absolute",
    )


@pytest.fixture(scope="module")
def abs_bundle(absolute_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    from amorctl.deploy.export import export_bundle

    out = tmp_path_factory.mktemp("abs-bundle") / "b"
    export_bundle(absolute_run, out)
    return out


def _cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_cli_export_prints_parity_and_writes_every_metadata_key(
    absolute_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import onnx

    from amorctl.registry import get_registry

    out = tmp_path / "bundle"
    code, text, err = _cli(["deploy", "export", str(absolute_run), "--out", str(out)], capsys)
    assert code == 0, err
    meta = json.loads((out / "deploy.json").read_text())
    found = re.search(r"parity onnxruntime vs torch: max \|Δ\| = (\S+) over (\d+) observations", text)
    assert found, text
    assert float(found.group(1)) <= 1e-5 and int(found.group(2)) == meta["parity"]["samples"] >= 1000
    assert float(found.group(1)) == pytest.approx(meta["parity"]["max_abs"], rel=1e-2)

    assert list(meta) == list(METADATA_KEYS)
    props = {p.key: json.loads(p.value) for p in onnx.load(str(out / ONNX_FILE)).metadata_props}
    assert props == meta
    ch = get_registry().character("biped20")
    assert meta["amorctl_version"] == __version__ and meta["iteration"] == 1
    assert Path(meta["run"]) == absolute_run
    assert meta["torque_limits"] == [j.torque_limit for j in ch.joints]
    assert meta["pd_gains"]["kd"] == [j.kd for j in ch.joints]
    assert meta["default_pose"] == [ch.standing_pose.get(j, 0.0) for j in ch.joint_names()]
    assert meta["joint_ranges"] == [list(j.range) for j in ch.joints]
    assert meta["character"] == "biped20" and meta["objectives"] == list(TRACKING7)
    assert meta["action"]["mode"] == "absolute" and meta["action"]["reference_columns"] is None
    assert meta["objective_set"] == {"name": "tracking7", "plugin": meta["objective_set"]["plugin"]}

    # absolute actions: pd_target = clamp(action, joint_ranges), the reference is not added
    b = read_bundle(out)
    rng = np.random.default_rng(0)
    feeds = {n: rng.normal(0, 3, (64, s["shape"][1])).astype(np.float32) for n, s in meta["inputs"].items()}
    feeds["w"] = np.full((64, 7), 1 / 7, dtype=np.float32)
    got = b.evaluate(feeds)
    low, high = np.array(meta["joint_ranges"]).T
    np.testing.assert_allclose(got["pd_target"], np.clip(got["action"], low, high), atol=1e-6)

    code, text, err = _cli(
        ["deploy", "export", str(absolute_run), "--out", str(tmp_path / "j"), "--json"], capsys
    )
    assert code == 0, err
    info = json.loads(text)
    assert info["parity_max_abs"] <= 1e-5 and info["parity_samples"] >= 1000
    latent = meta["inputs"]["latent"]["shape"][1]
    want = {
        "obs": ["batch", 141],
        "ref_frame": ["batch", 101],
        "latent": ["batch", latent],
        "w": ["batch", 7],
    }
    assert info["inputs"] == want


def test_failed_parity_check_is_one_error_line_and_writes_nothing(
    absolute_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import amorctl.deploy.export as export_mod

    real = export_mod.open_session

    class Off:  # onnxruntime answers 1e-4 off: the export must refuse it
        def __init__(self, path: Path, threads: int = 1) -> None:
            self.session = real(path, threads)

        def run(self, names: list[str], feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
            return [o + np.float32(1e-4) for o in self.session.run(names, feeds)]

    monkeypatch.setattr(export_mod, "open_session", Off)
    out = tmp_path / "bundle"
    code, _, err = _cli(["deploy", "export", str(absolute_run), "--out", str(out)], capsys)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: export parity check failed"), err
    assert "1e-05" in lines[0] and not out.exists() and list(tmp_path.iterdir()) == []


#: a sitecustomize that makes torch unimportable: a finder first in sys.meta_path refuses it
BLOCK_TORCH = """import sys
class _NoTorch:
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ModuleNotFoundError(f"No module named {name!r} (blocked by the test)", name=name)
        return None
sys.meta_path.insert(0, _NoTorch())
"""


def _amorctl(tmp_path: Path) -> tuple[list[str], dict[str, str]]:
    """The `amorctl` console script (or `python -m amorctl`) and an environment without torch."""
    shim = tmp_path / "shim"
    shim.mkdir(exist_ok=True)
    (shim / "sitecustomize.py").write_text(BLOCK_TORCH)
    script = Path(sys.executable).with_name("amorctl")
    entry = [str(script)] if script.is_file() else [sys.executable, "-m", "amorctl"]
    return entry, {**os.environ, "PYTHONPATH": str(shim)}


def test_live_weights_over_udp_to_the_cli_without_torch(abs_bundle: Path, tmp_path: Path) -> None:
    """`amorctl deploy run --listen` (real clock, real socket): a valid message, five malformed
    ones, silence past --stale-timeout (hold), a valid message (restored), silence (hold); counts,
    events, log."""
    from amorctl.deploy.runtime_log import TOPIC_TARGETS, TOPIC_WATCHDOG
    from amorctl.outputs.mcap_log import TOPIC_JOINTS, TOPIC_WEIGHTS, read_rollout_mcap

    entry, env = _amorctl(tmp_path)
    log = tmp_path / "live.mcap"
    cmd = [*entry, "deploy", "run", str(abs_bundle), "--motion", "sway_a", "--listen", "udp://127.0.0.1:0",
           "--realtime", "--max-misses", "100000", "--seconds", "5", "--stale-timeout", "0.3",
           "--no-stop-on-fall", "--out", str(log), "--json"]  # fmt: skip
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline().strip()
        found = re.fullmatch(r"listening for weights on udp://127\.0\.0\.1:(\d+)", line)
        assert found, line + proc.stderr.read()
        port = int(found.group(1))
        for data in (
            b'{"weights": {"up": 1, "smooth": 3}}',
            b"{not json",
            b'{"weights": [NaN, 1, 1, 1, 1, 1, 1]}',
            b'{"weights": {"up": -1}}',
            b'{"weights": {"jump": 1}}',
            b'{"weights": [1, 2]}',
        ):
            sock.sendto(data, ("127.0.0.1", port))
        time.sleep(2.5)  # > --stale-timeout: the runtime holds
        sock.sendto(b'{"weights": {"lo": 1}}', ("127.0.0.1", port))
        out, err = proc.communicate(timeout=120)
    finally:
        sock.close()
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    info = json.loads(out)
    assert info["input"]["accepted"] == 2 and info["input"]["received"] == 7
    assert info["input"]["rejected_by_reason"] == {"bad_json": 1, "not_finite": 1, "negative": 1,
                                                   "unknown_name": 1, "wrong_count": 1}  # fmt: skip
    kinds = [e["kind"] for e in info["events"] if e["kind"] in ("stale_input", "input_restored")]
    # silence after each valid message: stale, restored by the second, stale again until the end
    assert kinds == ["stale_input", "input_restored", "stale_input"] and info["held_steps"] > 0
    topics = read_rollout_mcap(log)
    w = np.array([[m[o] for o in TRACKING7] for m in topics[TOPIC_WEIGHTS]])
    assert len(w) == len(topics[TOPIC_JOINTS]) == len(topics[TOPIC_TARGETS]) == info["steps"] == 250
    first = np.array([0.25, 0, 0, 0, 0, 0, 0.75])
    assert np.isclose(w, first).all(axis=1).any()  # the first valid message applied
    np.testing.assert_allclose(w[-1], np.eye(7)[1])
    dog = [m["kind"] for m in topics[TOPIC_WATCHDOG]]
    assert dog.count("rejected_input") == 5 and "stale_input" in dog and "input_restored" in dog


def test_listen_beyond_loopback_needs_a_token_through_the_cli(abs_bundle: Path, tmp_path: Path) -> None:
    entry, env = _amorctl(tmp_path)
    base = [*entry, "deploy", "run", str(abs_bundle), "--seconds", "0.1"]
    for extra in (["--listen", "udp://0.0.0.0:0"], ["--listen", "udp://127.0.0.1:0", "--host", "0.0.0.0"]):
        proc = subprocess.run([*base, *extra], env=env, capture_output=True, text=True)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: --listen "), (
            proc.stderr
        )
        assert "beyond loopback" in lines[0] and "AMORCTL_TOKEN=" in lines[0] and "--token" in lines[0]
    short = {**env, "AMORCTL_TOKEN": "short"}
    proc = subprocess.run([*base, "--listen", "udp://0.0.0.0:0"], env=short, capture_output=True, text=True)
    assert proc.returncode == 2 and "the token is 5 characters; use at least 16" in proc.stderr
    proc = subprocess.run([*base, "--listen", "udp://0.0.0.0:0", "--host", "127.0.0.1"], env=env,
                          capture_output=True, text=True)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert re.search(r"listening for weights on udp://127\.0\.0\.1:\d+\n", proc.stderr)
    signed = {**env, "AMORCTL_TOKEN": "t" * 24}  # a token set: even loopback takes signed datagrams only
    proc = subprocess.run([*base, "--listen", "udp://127.0.0.1:0", "--json"], env=signed, capture_output=True,
                          text=True)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert re.search(
        r"listening for weights on udp://127\.0\.0\.1:\d+ \(signed datagrams only\)", proc.stderr
    )
    assert json.loads(proc.stdout)["input"]["signed"] is True


def test_the_deploy_module_entry_runs_without_torch(abs_bundle: Path, tmp_path: Path) -> None:
    """`python -m amorctl.cli.deploy` (the deploy commands alone) runs and reports errors in one line."""
    _, env = _amorctl(tmp_path)
    base = [sys.executable, "-m", "amorctl.cli.deploy", "run", str(abs_bundle)]
    proc = subprocess.run([*base, "--seconds", "0.1", "--json"], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["steps"] == 5
    proc = subprocess.run([*base, "--weights", "jump=1"], env=env, capture_output=True, text=True)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
