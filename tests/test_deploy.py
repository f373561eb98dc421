"""`amorctl deploy`: ONNX export with w as an input (parity, metadata, bundle), the torch-free
sim2sim runtime (reproduces `tune`, randomization, watchdog), `deploy check`, bad input."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from amorctl.cli.main import main
from amorctl.core.errors import AmorError
from amorctl.deploy.bundle import METADATA_KEYS, ONNX_FILE, compiled_model_hash, read_bundle
from amorctl.deploy.export import export_bundle, parity_observations, split_observation
from amorctl.deploy.randomize import load_randomization
from amorctl.deploy.runtime import Runtime

torch.set_num_threads(1)
TRACKING7 = ("up", "lo", "feet", "rbs", "root", "vel", "smooth")
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def deploy_run(tmp_path_factory: pytest.TempPathFactory, make_tracking_run) -> Path:
    """A one-iteration biped20 residual-action run on two 1 s synthetic clips, 2.5 s episodes (so
    `tune` rolls out 2 s without truncation)."""
    return make_tracking_run(
        tmp_path_factory.mktemp("deploy-run"),
        "deploy_run fixture",
        episode_seconds=2.5,
        action_mode="residual",
    )


@pytest.fixture(scope="module")
def bundle_dir(deploy_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bundle") / "b"
    export_bundle(deploy_run, out)
    return out


def _cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# ---------------------------------------------------------------------------- export


def test_bundle_has_named_inputs_metadata_in_onnx_and_sidecar(bundle_dir: Path, deploy_run: Path) -> None:
    import onnx

    from amorctl.registry import get_registry

    meta = json.loads((bundle_dir / "deploy.json").read_text())
    assert set(meta) == set(METADATA_KEYS)
    model = onnx.load(str(bundle_dir / ONNX_FILE))
    props = {p.key: json.loads(p.value) for p in model.metadata_props}
    assert props == meta  # same content, JSON-encoded values, full precision
    assert [i.name for i in model.graph.input] == ["obs", "ref_frame", "latent", "w"]
    assert [o.name for o in model.graph.output] == ["pd_target", "action"]
    assert model.opset_import[0].version == meta["opset"] == 17
    ch = get_registry().character("biped20")
    assert meta["joint_names"] == list(ch.joint_names())
    assert meta["objectives"] == list(TRACKING7)
    assert meta["model_sha256"] == compiled_model_hash(ch)
    assert meta["pd_gains"]["kp"] == [j.kp for j in ch.joints]
    assert meta["actuator_model"]["kind"] == "servo" and meta["actuator_model"]["latency_steps"] == 2
    assert meta["control_hz"] == 50 and meta["physics_hz"] == 250 and meta["iteration"] == 1
    assert meta["action"]["mode"] == "residual"
    for spec in meta["inputs"].values():  # element names cover every column
        assert len(spec["elements"]) == spec["shape"][1]
    assert meta["inputs"]["w"]["elements"] == [f"w/{o}" for o in TRACKING7]
    assert "obs/proprio/joint_pos/l_knee" not in meta["inputs"]["obs"]["elements"]
    assert "proprio/joint_pos/l_knee" in meta["inputs"]["obs"]["elements"]
    with np.load(bundle_dir / "motions.npz", allow_pickle=False) as npz:
        assert list(npz["clip_names"]) == ["sway_a", "sway_b"]
        assert npz["frames"].shape[1] == meta["inputs"]["ref_frame"]["shape"][1]


def test_onnx_matches_the_torch_policy_and_w_alone_changes_its_output(
    bundle_dir: Path, deploy_run: Path
) -> None:
    from amorctl.core.contracts import Policy
    from amorctl.train.rundir import RunDir

    b = read_bundle(bundle_dir)
    policy = RunDir.open(deploy_run).policy()
    assert isinstance(policy, Policy)  # the whole contract, observation_layout and export_arrays included
    assert policy.observation_layout["weights"] == (policy.obs_dim - 7, policy.obs_dim)
    snap = policy.export_arrays()
    assert snap.meta["format"] == "amorctl-mlp-policy/1" and snap.meta["actor_layers"] == 2
    assert all(a.dtype == np.float32 for a in snap.arrays.values())
    obs = parity_observations(
        snap.arrays["normalizer/mean"], snap.arrays["normalizer/scale"], 7, 1000, seed=5
    )
    groups = {k: [(p, a, c) for p, (a, c) in v["parts"].items()] for k, v in b.meta["inputs"].items()}
    got = b.evaluate(split_observation(obs, groups))  # a batch of 1008 through the dynamic axis
    action = policy(obs).astype(np.float64)
    r0 = b.meta["observation_layout"]["ref_frame"][0] + 13
    ref = obs[:, r0 : r0 + 20].astype(np.float64)
    low, high = np.array(b.meta["joint_ranges"]).T
    assert np.max(np.abs(got["action"] - action)) <= 1e-5
    assert np.max(np.abs(got["pd_target"] - np.clip(ref + action, low, high))) <= 1e-5
    assert b.meta["parity"]["max_abs"] <= 1e-5 and b.meta["parity"]["samples"] >= 1000

    feeds = split_observation(obs[:1].repeat(7, axis=0), groups)
    feeds["w"] = np.eye(7, dtype=np.float32)  # only w differs between the rows
    out = b.evaluate(feeds)["action"]
    assert np.ptp(out, axis=0).max() > 1e-4


def test_a_trained_toy_policy_flips_its_action_with_w_through_onnx(toy_run: Path, tmp_path: Path) -> None:
    res = export_bundle(toy_run, tmp_path / "toy")
    b = read_bundle(tmp_path / "toy")
    assert list(b.meta["inputs"]) == ["obs", "w"] and list(b.meta["outputs"]) == ["action"]
    assert b.meta["character"] is None and res.parity_max_abs <= 1e-5
    obs = np.zeros((2, 3), dtype=np.float32)
    out = b.evaluate({"obs": obs, "w": np.eye(2, dtype=np.float32)})["action"][:, 0]
    assert out[0] > 0.3 and out[1] < -0.3  # w = (1, 0): right; w = (0, 1): left


# ---------------------------------------------------------------------------- runtime


def test_runtime_reproduces_tunes_trajectory_for_two_seconds(
    bundle_dir: Path, deploy_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from amorctl.outputs.mcap_log import TOPIC_JOINTS, TOPIC_REWARDS, read_rollout_mcap

    w = "up=3,lo=1,feet=1,rbs=1,root=1,vel=1,smooth=2"
    log = tmp_path / "tune.mcap"
    code, _, err = _cli(["tune", str(deploy_run), "--motion", "sway_a", "--weights", w, "--seconds", "2",
                         "--no-stop-on-fall", "--out", str(log)], capsys)  # fmt: skip
    assert code == 0, err
    topics = read_rollout_mcap(log)
    tune_q = np.array([m["position"] for m in topics[TOPIC_JOINTS]])
    tune_r = np.array([[m[o] for o in TRACKING7] for m in topics[TOPIC_REWARDS]])
    from amorctl.core.weights import parse_weights

    rt = Runtime(read_bundle(bundle_dir), rewards=True)
    res = rt.run(parse_weights(w, TRACKING7), motion="sway_a", seconds=2.0, stop_on_fall=False, record=True)
    q = np.array([r.joint_pos for r in res.records])
    assert q.shape == tune_q.shape == (100, 20)
    # at a fall both restart the clip; tune logs the restarted state at that step, the runtime the fallen one
    fell = [round(e.t / rt.dt) - 1 for e in res.events if e.kind == "fell"]
    keep = np.setdiff1d(np.arange(100), fell)
    assert len(keep) >= 95
    assert np.max(np.abs(q[keep] - tune_q[keep])) < 1e-5  # stated tolerance: 1e-5 rad over 2 s
    # the runtime's rewards (numpy kernels of the bundle's objective set) are the torch-cpu
    # tracking env's (tune's /rewards, float32) for the same states: stated tolerance 1e-5
    # (measured: 1.5e-7 to 5e-7, float32 rounding)
    r = np.array([rec.rewards for rec in res.records])
    assert r.shape == tune_r.shape == (100, 7)
    assert np.max(np.abs(r[keep] - tune_r[keep])) < 1e-5
    assert res.returns is not None and list(res.returns) == list(TRACKING7)
    assert np.allclose(list(res.returns.values()), r.sum(axis=0))


#: a sitecustomize that makes torch unimportable: a finder first in sys.meta_path refuses it
BLOCK_TORCH = """import sys
class _NoTorch:
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ModuleNotFoundError(f"No module named {name!r} (blocked by the test)", name=name)
        return None
sys.meta_path.insert(0, _NoTorch())
"""


def _no_torch_env(tmp_path: Path) -> dict[str, str]:
    shim = tmp_path / "shim"
    shim.mkdir(exist_ok=True)
    (shim / "sitecustomize.py").write_text(BLOCK_TORCH)
    return {**os.environ, "PYTHONPATH": str(shim)}


def test_amorctl_deploy_run_and_check_work_with_torch_unimportable(bundle_dir: Path, tmp_path: Path) -> None:
    """The plain `amorctl` entry point (console script and `python -m amorctl`) runs `deploy run`
    and `deploy check` without torch; the run's MCAP log carries per-objective rewards."""
    from amorctl.outputs.mcap_log import TOPIC_REWARDS, TOPIC_WEIGHTS, read_rollout_mcap

    env = _no_torch_env(tmp_path)
    blocked = subprocess.run([sys.executable, "-c", "import torch"], env=env, capture_output=True, text=True)
    assert blocked.returncode != 0 and "blocked by the test" in blocked.stderr
    log = tmp_path / "run.mcap"
    script = Path(sys.executable).with_name("amorctl")
    entry = [str(script)] if script.is_file() else [sys.executable, "-m", "amorctl"]
    cmd = [*entry, "deploy", "run", str(bundle_dir), "--motion", "sway_b", "--weights", "up=1,smooth=1",
           "--seconds", "0.5", "--out", str(log), "--json"]  # fmt: skip
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert info["steps"] == 25 and log.is_file()
    topics = read_rollout_mcap(log)
    assert len(topics[TOPIC_WEIGHTS]) == 25
    rewards = topics[TOPIC_REWARDS]
    assert len(rewards) == 25
    r = np.array([[m[o] for o in TRACKING7] for m in rewards])
    assert all(list(m) == ["t", *TRACKING7] for m in rewards)  # one per objective, in order
    assert np.isfinite(r).all()
    assert (r[:, :6] >= 0).all() and (r[:, :6] <= 2.0).all() and (r[:, 6] <= 1.0).all()  # tracking7 bounds
    assert r[:, :6].min() > 1.0  # alive bonus 1 + a tracking term in (0, 1] on every step (no fall)
    assert np.allclose(r.sum(axis=0), [info["returns"][o] for o in TRACKING7])

    check = [sys.executable, "-m", "amorctl", "deploy", "check", str(bundle_dir), "--episodes", "1",
             "--seconds", "0.2", "--weights", "smooth=1", "--json"]  # fmt: skip
    proc = subprocess.run(check, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert [c["label"] for c in json.loads(proc.stdout)["conditions"]] == ["uniform", "weights"]


def test_runtime_imports_only_numpy_mujoco_onnxruntime(bundle_dir: Path, tmp_path: Path) -> None:
    """The runtime library itself (no CLI): only numpy, mujoco and onnxruntime, and with rewards
    also the objective set's plugin (amorctl's plugin API: pluggy, tomlkit), never torch."""
    env = _no_torch_env(tmp_path)
    banned = {"torch", "scipy", "safetensors", "typer", "rich", "foxglove", "mcap", "onnx", "jax"}
    for rewards, also_banned in ((False, {"pluggy", "tomlkit"}), (True, set())):
        probe = (
            "import sys, numpy as np\n"
            "from amorctl.deploy.bundle import read_bundle\n"
            "from amorctl.deploy.runtime import Runtime\n"
            "from amorctl.deploy.check import run_check\n"
            f"rt = Runtime(read_bundle({str(bundle_dir)!r}), rewards={rewards})\n"
            "res = rt.run(np.full(7, 1 / 7), seconds=0.1)\n"
            "assert (res.returns is not None) == (rt.reward_meter is not None)\n"
            "print(sorted({m.split('.')[0] for m in sys.modules if sys.modules[m] is not None}))\n"
        )
        proc = subprocess.run(
            [sys.executable, "-c", probe], env=env, capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 0, proc.stderr
        loaded = set(eval(proc.stdout.strip().splitlines()[-1]))
        assert {"numpy", "mujoco", "onnxruntime"} <= loaded
        assert not loaded & (banned | also_banned), loaded & (banned | also_banned)


def test_perfect_tracking_of_the_reference_gets_the_maximal_reward(bundle_dir: Path) -> None:
    from amorctl.deploy.runtime_rewards import load_reward_meter

    b = read_bundle(bundle_dir)
    meter = load_reward_meter(b)
    assert meter.names == TRACKING7
    f, j = 7, b.spec.num_joints
    q = b.motions.joint_pos[f]
    zeros = np.zeros(j)
    perfect = meter(meter.ref_frames[f], f, np.zeros((b.spec.substeps, j)), q, q, q, zeros, alive=True)
    assert np.allclose(perfect, meter.high) and np.allclose(perfect, [2.0] * 6 + [1.0])
    off = meter.ref_frames[f].copy()
    off[13:16] += 0.2  # three joint angles 0.2 rad off: some joint-position objectives drop
    worse = meter(off, f, np.zeros((b.spec.substeps, j)), q, q, q, zeros, alive=True)
    assert (worse <= perfect + 1e-12).all() and (worse < perfect - 1e-3).any()
    fallen = meter(meter.ref_frames[f], f, np.zeros((b.spec.substeps, j)), q, q, q, zeros, alive=False)
    assert np.allclose(fallen, perfect - 1.0)  # no survival bonus on the step that falls
    assert not meter(off, f, np.zeros((b.spec.substeps, j)), q, q, q, zeros, alive=True, diverged=True).any()


def _live_script(rt: Runtime, port: int, sends: dict[int, list[bytes]], clock: list[float]):
    """A should_stop hook that, at tick k, advances the fake clock and sends ``sends[k]``."""
    import socket

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tick = {"k": 0}

    def hook() -> bool:
        k = tick["k"]
        clock[0] = k * rt.dt
        for data in sends.get(k, []):
            sock.sendto(data, ("127.0.0.1", port))
        tick["k"] += 1
        return False

    return hook, sock


def test_live_weights_over_loopback_validation_counts_and_stale_watchdog(bundle_dir: Path) -> None:
    from amorctl.deploy.runtime_input import UdpWeights

    rt = Runtime(read_bundle(bundle_dir))
    clock = [0.0]
    live = UdpWeights(TRACKING7, np.full(7, 1 / 7), port=0, stale_timeout=0.1, clock=lambda: clock[0])
    assert live.address[0] == "127.0.0.1"
    nan = b'{"weights": [NaN, 1, 1, 1, 1, 1, 1]}'
    sends = {
        1: [b'{"weights": {"up": 1, "smooth": 3}}'],
        3: [b"{not json", nan, b'{"weights": {"up": -1}}', b'{"weights": {"jump": 1}}',
            b'{"weights": [1, 2]}', b'{"weights": {"up": 0}}', b'[1, 2]'],
        5: [b'{"weights": [1, 1, 1, 1, 1, 1, 2]}'],
        # then silence: stale after 0.1 s (5 ticks) -> hold; a valid message at tick 20 restores
        20: [b'{"weights": {"lo": 1}}'],
    }  # fmt: skip
    hook, sock = _live_script(rt, live.address[1], sends, clock)
    try:
        res = rt.run(live, motion="sway_a", seconds=0.5, stop_on_fall=False, record=True, should_stop=hook)
    finally:
        sock.close()
        live.close()
    w = np.array([r.weights for r in res.records])
    held = np.array([r.held for r in res.records])
    np.testing.assert_allclose(w[0], np.full(7, 1 / 7))
    np.testing.assert_allclose(w[1], [0.25, 0, 0, 0, 0, 0, 0.75])  # applied at the tick it arrived before
    np.testing.assert_allclose(w[3], w[1])  # every message of tick 3 rejected: weights unchanged
    np.testing.assert_allclose(w[5], np.array([1, 1, 1, 1, 1, 1, 2]) / 8)
    np.testing.assert_allclose(w[20], np.eye(7)[1])
    stats = res.input
    assert stats["accepted"] == 3 and stats["rejected"] == 7 and stats["received"] == 10
    assert stats["rejected_by_reason"] == {"bad_json": 1, "not_finite": 1, "negative": 1, "unknown_name": 1,
                                           "wrong_count": 1, "all_zero": 1, "bad_shape": 1}  # fmt: skip
    kinds = [(round(e.t / rt.dt), e.kind) for e in res.events if e.kind in ("stale_input", "input_restored")]
    assert kinds == [(11, "stale_input"), (20, "input_restored")]
    assert not held[:11].any() and held[11:20].all() and not held[20:].any()
    targets = np.array([r.pd_target for r in res.records])
    assert np.all(targets[11:20] == targets[10])  # the last safe pose is held
    assert sum(e.kind == "rejected_input" for e in res.events) == 7


TOKEN = "a-test-token-of-32-characters-xx"


def test_any_datagram_is_accepted_or_rejected_by_reason_never_raised() -> None:
    """Arbitrary bytes and arbitrary JSON into the live input's validation (signed and not)."""
    import json as _json

    from hypothesis import given, settings
    from hypothesis import strategies as st

    from amorctl.core.live_auth import mac
    from amorctl.deploy.runtime_input import Rejected, UdpWeights

    live = UdpWeights(TRACKING7, np.full(7, 1 / 7), port=0)
    signed = UdpWeights(TRACKING7, np.full(7, 1 / 7), port=0, token=TOKEN)
    leaf = st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8)
    tree = st.recursive(
        leaf, lambda c: st.lists(c, max_size=8) | st.dictionaries(st.text(max_size=8), c, max_size=8)
    )
    message = st.fixed_dictionaries({"weights": tree}, optional={"seq": tree})
    payloads = (
        st.binary(max_size=200)
        | message.map(lambda m: _json.dumps(m).encode())
        | tree.map(lambda m: _json.dumps(m).encode())
    )

    @settings(max_examples=400, deadline=None, derandomize=True)
    @given(payloads)
    def check(data: bytes) -> None:
        for endpoint, datagram in ((live, data), (signed, mac(TOKEN, data) + b" " + data)):
            try:
                w = endpoint._validate(datagram)
            except Rejected as rej:
                assert rej.reason in ("too_long", "bad_json", "bad_shape", "unknown_name", "wrong_count",
                                      "not_number", "not_finite", "negative", "all_zero", "bad_seq",
                                      "replayed")  # fmt: skip
            else:
                assert w.shape == (7,) and np.isfinite(w).all() and (w >= 0).all()
                assert abs(w.sum() - 1) < 1e-12

    try:
        check()
    finally:
        live.close()
        signed.close()


def test_signed_live_input_counts_and_ignores_wrong_missing_or_replayed_hmacs(bundle_dir: Path) -> None:
    from amorctl.core.live_auth import mac, sign_datagram
    from amorctl.deploy.runtime_input import UdpWeights

    rt = Runtime(read_bundle(bundle_dir))
    clock = [0.0]
    live = UdpWeights(TRACKING7, np.full(7, 1 / 7), port=0, stale_timeout=10, clock=lambda: clock[0],
                      token=TOKEN)  # fmt: skip
    good = sign_datagram({"weights": {"up": 1, "smooth": 3}}, TOKEN, 10)
    no_seq = b'{"weights":{"lo":1}}'
    sends = {
        1: [good],
        3: [b'{"weights": {"lo": 1}}',  # the unsigned (loopback) format
            sign_datagram({"weights": {"lo": 1}}, "another-token-of-16+", 11),  # another token
            good.replace(b'"up":1', b'"up":5'),  # altered after signing
            good,  # replayed: its seq is not above the last accepted
            mac(TOKEN, no_seq) + b" " + no_seq,  # signed, but without a sequence number
            sign_datagram({"weights": [1, 2]}, TOKEN, 12),  # signed, but invalid weights
            b"f" * 64],  # a MAC with nothing after it
        5: [sign_datagram({"weights": {"lo": 1}}, TOKEN, 13)],
    }  # fmt: skip
    hook, sock = _live_script(rt, live.address[1], sends, clock)
    try:
        res = rt.run(live, motion="sway_a", seconds=0.2, stop_on_fall=False, record=True, should_stop=hook)
    finally:
        sock.close()
        live.close()
    w = np.array([r.weights for r in res.records])
    np.testing.assert_allclose(w[0], np.full(7, 1 / 7))
    np.testing.assert_allclose(w[1], [0.25, 0, 0, 0, 0, 0, 0.75])
    np.testing.assert_allclose(w[3], w[1])  # nothing of tick 3 applied
    np.testing.assert_allclose(w[5], np.eye(7)[1])
    stats = res.input
    assert stats["signed"] and stats["accepted"] == 2 and stats["received"] == 9
    assert stats["rejected_by_reason"] == {"unsigned": 2, "bad_mac": 2, "replayed": 1, "bad_seq": 1,
                                           "wrong_count": 1}  # fmt: skip
    assert sum(e.kind == "rejected_input" for e in res.events) == 7


def test_a_backlog_is_read_within_the_poll_budget_and_rejections_are_reported_at_a_bounded_rate() -> None:
    import socket

    from amorctl.deploy.runtime_input import UdpWeights

    reported: list[str] = []
    live = UdpWeights(TRACKING7, np.full(7, 1 / 7), port=0, budget_s=0.0, reports_per_s=5,
                      on_reject=reported.append)  # fmt: skip
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for _ in range(200):
            sock.sendto(b"{not json", live.address)
        sock.sendto(b'{"weights": {"vel": 1}}', live.address)
        time.sleep(0.05)
        assert not live.poll()  # a zero budget: 7 datagrams (the clock is read every 8th), then wait
        assert live.stats.received == 7 and live.stats.deferred_polls == 1
        live.budget_s = 1.0
        assert live.poll()  # the rest, the valid one last
        np.testing.assert_allclose(live.weights, np.eye(7)[5])
    finally:
        sock.close()
    report = live.report()
    live.close()
    assert report["received"] == 201 and report["accepted"] == 1 and report["rejected"] == 200
    assert len(reported) == 5 and report["unreported"] == 195 and report["kernel_drops"] in (0, None)


@pytest.mark.slow
@pytest.mark.parametrize("signed", [False, True], ids=["loopback", "token"])
def test_a_flood_of_live_datagrams_keeps_the_ticks_on_time(bundle_dir: Path, signed: bool) -> None:
    """≥ 10,000 datagrams/s for 3.5 s, valid and malformed mixed (with a token also unsigned, wrongly
    signed, tampered and replayed ones), into a real-time runtime: ≥ 95 % of its 250 ticks on time,
    only valid weights applied, every datagram counted, rejections reported at a bounded rate."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        import deploy_flood
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    token = deploy_flood.TOKEN if signed else None
    flood = deploy_flood.run_flood(bundle_dir, rate=12000, seconds=5.0, flood_seconds=3.5, token=token)
    sent, info = flood["sent"], flood["result"]
    inp = info["input"]
    assert sent["rate"] >= 10000 and sent["seconds"] >= 3.5 and sent["sent"] >= 35000, sent
    assert info["steps"] == 250 and not info["diverged"]  # never crashed, ran to the end
    assert info["on_time"] >= 0.95, info
    assert inp["signed"] is signed and inp["received"] == inp["accepted"] + inp["rejected"]
    assert inp["received"] + (inp["kernel_drops"] or 0) >= 0.9 * sent["sent"], (inp, sent)
    kinds = {k for k in sent["by_kind"] if k not in ("valid", "not_sent")}
    assert set(inp["rejected_by_reason"]) == kinds  # each malformed kind counted under its reason
    share = sent["by_kind"]["valid"] / sent["sent"]
    assert abs(inp["accepted"] / inp["received"] - share) < 0.05, (inp, sent)
    allowed = np.vstack([deploy_flood.expected_weights(), np.full((1, 7), 1 / 7)])
    applied = flood["applied"]
    assert np.isclose(applied[:, None, :], allowed[None], atol=1e-12).all(axis=2).any(axis=1).all()
    flood_rows = np.isclose(applied[:, None, :], allowed[None, :3], atol=1e-12).all(axis=2)
    assert flood_rows.any(axis=0).sum() >= 2  # the flood's valid weights were applied, not one stuck
    reported = sum(e["kind"] == "rejected_input" for e in info["events"])
    assert reported <= 20 * 6 and inp["unreported"] == inp["rejected"] - reported


def test_realtime_deadline_misses_latch_the_hold(bundle_dir: Path) -> None:
    import time

    rt = Runtime(read_bundle(bundle_dir), realtime=True, max_misses=3)
    slow = rt.policy

    def late(feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        time.sleep(0.03)  # longer than the 20 ms control period
        return slow(feeds)

    rt.policy = late
    res = rt.run(np.full(7, 1 / 7), motion="sway_a", seconds=0.2, record=True)
    kinds = [e.kind for e in res.events]
    assert kinds[:4] == ["deadline_miss", "deadline_miss", "deadline_miss", "watchdog_latched"]
    assert res.held_steps == res.steps == 10 and res.to_dict()["policy_ms_median"] >= 25
    targets = np.array([r.pd_target for r in res.records])
    assert np.all(targets == targets[0])  # held from the first tick: the initial pose


def test_randomization_is_seeded_validated_and_changes_the_dynamics(bundle_dir: Path, tmp_path: Path) -> None:
    rand = load_randomization(REPO / "docs/examples/deploy-randomize.toml")
    b = read_bundle(bundle_dir)
    w = np.full(7, 1 / 7)
    nominal = Runtime(b).run(w, seconds=0.6, stop_on_fall=False, record=True)
    rt = Runtime(b, randomization=rand)
    a = rt.run(w, seconds=0.6, seed=4, stop_on_fall=False, record=True)
    again = rt.run(w, seconds=0.6, seed=4, stop_on_fall=False, record=True)
    other = rt.run(w, seconds=0.6, seed=5, stop_on_fall=False, record=True)
    qa = np.array([r.qpos for r in a.records])
    assert np.array_equal(qa, np.array([r.qpos for r in again.records]))
    assert np.abs(qa - np.array([r.qpos for r in nominal.records])).max() > 1e-3
    assert a.dynamics != other.dynamics and a.dynamics["latency_steps"] in (0, 1)

    pushy = tmp_path / "push.toml"
    pushy.write_text("[push]\nforce = [30, 30]\nduration = [0.1, 0.1]\ninterval = [0.2, 0.2]\n")
    res = Runtime(b, randomization=load_randomization(pushy)).run(
        w, seconds=0.6, stop_on_fall=False, record=True
    )
    assert sum(e.kind == "push" for e in res.events) == 2
    qp, qn = np.array([r.qpos for r in res.records]), np.array([r.qpos for r in nominal.records])
    assert np.array_equal(qp[:10], qn[:10])  # identical until the first push at 0.2 s
    assert np.abs(qp[10:15] - qn[10:15]).max() > 1e-3

    late = tmp_path / "late.toml"
    late.write_text("[latency]\nextra_steps = [2, 2]\n")
    res = Runtime(b, randomization=load_randomization(late)).run(
        w, seconds=0.3, stop_on_fall=False, record=True
    )
    qd = np.array([r.qpos for r in res.records])
    assert res.dynamics["latency_steps"] == 2
    assert np.abs(qd - qn[:15]).max() > 1e-4

    for text, msg in (
        ("[gravity]\nscale = [1, 2]\n", "unknown table"),
        ("[mass]\nweight = [1, 2]\n", "unknown key"),
        ("[mass]\nscale = [1.2, 0.8]\n", "above high"),
        ("[mass]\nscale = [-1, 1]\n", ">= 0"),
        ("[mass]\nscale = 1.0\n", "range"),
        ("[latency]\nextra_steps = [0, 1.5]\n", "whole control steps"),
        ("[push]\ninterval = [0, 1]\n", ">= 0.001"),
        ("[push]\nvelocity = [0, 1]\n", "unknown key"),
        ("[mass\n", "TOML"),
    ):
        bad = tmp_path / "bad.toml"
        bad.write_text(text)
        with pytest.raises(AmorError, match=msg):
            load_randomization(bad)


def test_check_compares_uniform_and_given_weights_on_the_same_episodes(
    bundle_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rand = str(REPO / "docs/examples/deploy-randomize.toml")
    argv = ["deploy", "check", str(bundle_dir), "--episodes", "2", "--seconds", "0.4", "--weights",
            "smooth=4,up=1", "--randomize", rand, "--json"]  # fmt: skip
    code, out, err = _cli(argv, capsys)
    assert code == 0, err
    report = json.loads(out)
    assert [c["label"] for c in report["conditions"]] == ["uniform", "weights"]
    for c in report["conditions"]:
        assert c["episodes"] == 2 and 0.0 <= c["survival"] <= 1.0 and c["joint_mae_deg"] > 0
    assert [e["motion"] for e in report["per_episode"]] == ["sway_a", "sway_b"]
    code, out, _ = _cli(argv[:-1], capsys)
    assert code == 0 and "survival" in out and "uniform" in out


# ---------------------------------------------------------------------------- bad input


def _one_error_line(code: int, err: str) -> str:
    assert code == 2
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


def test_a_bundle_exported_before_models_were_copied_still_reads(bundle_dir: Path, tmp_path: Path) -> None:
    """Earlier bundles named the installed plugin package (``plugin_module``) and hashed the MJB."""
    import shutil

    import onnx

    from amorctl.deploy.bundle import mjb_sha256
    from amorctl.registry import get_registry
    from amorctl.sim.model import load_model

    old = tmp_path / "old"
    shutil.copytree(bundle_dir, old)
    shutil.rmtree(old / "model")
    meta = json.loads((old / "deploy.json").read_text())
    cm = meta["character_model"]
    for key in ("mjcf", "model_files", "licence_files", "licence", "model_source"):
        del cm[key]
    cm.update(plugin_module="amorctl.plugins.characters.biped20", mjcf="biped20.xml")
    meta["model_sha256"] = mjb_sha256(load_model(get_registry().character("biped20")))
    (old / "deploy.json").write_text(json.dumps(meta))
    model = onnx.load(str(old / ONNX_FILE))
    for prop in model.metadata_props:
        if prop.key in ("character_model", "model_sha256"):
            prop.value = json.dumps(meta[prop.key])
    onnx.save(model, str(old / ONNX_FILE))
    b = read_bundle(old)
    assert b.spec is not None and b.spec.mjcf_path == get_registry().character("biped20").mjcf_path


def test_bad_inputs_fail_with_one_error_line_and_write_nothing(
    bundle_dir: Path, deploy_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import shutil

    import onnx

    empty_run = tmp_path / "empty_run"
    empty_run.mkdir()
    shutil.copy(deploy_run / "config.toml", empty_run / "config.toml")
    out = tmp_path / "out"
    line = _one_error_line(*_cli(["deploy", "export", str(empty_run), "--out", str(out)], capsys)[::2])
    assert "checkpoint" in line and not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]

    occupied = tmp_path / "occupied"
    occupied.mkdir()
    (occupied / "x").write_text("x")
    line = _one_error_line(*_cli(["deploy", "export", str(deploy_run), "--out", str(occupied)], capsys)[::2])
    assert "already exists" in line

    def broken(name: str, damage) -> Path:
        copy = tmp_path / name
        shutil.copytree(bundle_dir, copy)
        damage(copy)
        return copy

    def other_hash(d: Path) -> None:
        meta = json.loads((d / "deploy.json").read_text())
        meta["model_sha256"] = "0" * 64
        (d / "deploy.json").write_text(json.dumps(meta))
        model = onnx.load(str(d / ONNX_FILE))
        for p in model.metadata_props:
            if p.key == "model_sha256":
                p.value = json.dumps("0" * 64)
        onnx.save(model, str(d / ONNX_FILE))

    def cut_onnx(d: Path) -> None:
        data = (d / ONNX_FILE).read_bytes()
        (d / ONNX_FILE).write_bytes(data[: len(data) // 3])

    def bad_json(d: Path) -> None:
        (d / "deploy.json").write_text('{"format": "amorctl-deploy/1", ')

    def edited_json(d: Path) -> None:
        meta = json.loads((d / "deploy.json").read_text())
        meta["control_hz"] = 100
        (d / "deploy.json").write_text(json.dumps(meta))

    def lost_model(d: Path) -> None:
        (d / "model" / "biped20.xml").unlink()

    def swapped_layout(d: Path) -> None:  # two terms exchanged, in both copies of the metadata
        meta = json.loads((d / "deploy.json").read_text())
        layout = meta["observation_layout"]
        layout["proprio"], layout["ref_frame"] = layout["ref_frame"], layout["proprio"]
        (d / "deploy.json").write_text(json.dumps(meta))
        model = onnx.load(str(d / ONNX_FILE))
        for p in model.metadata_props:
            if p.key == "observation_layout":
                p.value = json.dumps(layout)
        onnx.save(model, str(d / ONNX_FILE))

    for name, damage, expect in (
        ("hash", other_hash, "model_sha256"),
        (
            "model",
            lost_model,
            "biped20.xml: missing from the bundle (1 model file(s)): copy the whole bundle",
        ),
        ("onnx", cut_onnx, "onnxruntime cannot load"),
        ("json", bad_json, "not valid JSON"),
        ("edited", edited_json, "differs from"),
        ("layout", swapped_layout, "is not the layout of this amorctl's tracking envs"),
    ):
        bad = broken(name, damage)
        log = tmp_path / f"{name}.mcap"
        for cmd in (["run", str(bad), "--seconds", "0.2", "--out", str(log)],
                    ["check", str(bad), "--weights", "up=1", "--episodes", "1"]):  # fmt: skip
            line = _one_error_line(*_cli(["deploy", *cmd], capsys)[::2])
            assert expect in line, line
        assert not log.exists()


def test_listen_binds_beyond_loopback_only_with_a_token() -> None:
    from amorctl.cli.deploy import _listen_address
    from amorctl.core.live_auth import is_loopback
    from amorctl.deploy.runtime_input import Rejected, UdpWeights, parse_message

    assert _listen_address("udp://127.0.0.1:9870", None) == ("127.0.0.1", 9870)
    assert _listen_address("udp://localhost:9870", None) == ("127.0.0.1", 9870)
    assert _listen_address("udp://[::1]:9870", None) == ("::1", 9870)
    for listen, host in (("udp://0.0.0.0:9870", None), ("udp://127.0.0.1:9870", "0.0.0.0"),
                         ("udp://192.168.1.20:9870", None), ("udp://robot.local:9870", None)):  # fmt: skip
        with pytest.raises(AmorError, match="beyond loopback") as info:
            _listen_address(listen, host)
        assert "set a shared token (AMORCTL_TOKEN=" in str(info.value) and "or --token" in str(info.value)
    token = "x" * 16
    assert _listen_address("udp://127.0.0.1:9870", "0.0.0.0", token) == ("0.0.0.0", 9870)
    assert _listen_address("udp://0.0.0.0:9870", None, token) == ("0.0.0.0", 9870)
    with pytest.raises(AmorError, match="the token is 15 characters; use at least 16"):
        _listen_address("udp://0.0.0.0:9870", None, "x" * 15)
    with pytest.raises(AmorError, match="beyond loopback"):  # the library refuses it as well
        UdpWeights(TRACKING7, np.full(7, 1 / 7), host="0.0.0.0")
    assert [is_loopback(h) for h in ("127.0.0.1", "127.8.0.1", "::1", "localhost", "0.0.0.0", "", "::")] == [
        True, True, True, True, False, False, False,
    ]  # fmt: skip
    with pytest.raises(AmorError, match="udp://"):
        _listen_address("tcp://127.0.0.1:1", None)
    np.testing.assert_allclose(
        parse_message(b'{"weights": {"up": 2, "lo": 2}}', ["up", "lo", "x"]), [0.5, 0.5, 0]
    )
    with pytest.raises(Rejected, match="not_number"):
        parse_message(b'{"weights": [true, 1, 1]}', ["up", "lo", "x"])


def test_policy_arrays_without_the_backend_neutral_names_are_refused() -> None:
    from amorctl.core.contracts import Snapshot
    from amorctl.deploy.export import policy_arrays

    style = Snapshot({"normalizer.mean": np.zeros(3), "actor.net.0.weight": np.zeros((2, 3))}, {})
    with pytest.raises(AmorError, match="no normalizer/mean, normalizer/scale, actor/0/weight"):
        policy_arrays(style)
    names = ("normalizer/mean", "normalizer/scale", "actor/0/weight")
    ok = Snapshot({name: np.zeros(3) for name in names}, {})
    assert set(policy_arrays(ok)[0]) == set(names)
