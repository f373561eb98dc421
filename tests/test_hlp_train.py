"""The HLP end to end: training on the toy env and a tiny tracking run, resume, CLI, trace, Table 2."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from amorctl.cli.main import main
from amorctl.hlp.config import HlpConfig, merge, to_toml
from amorctl.hlp.run import policy_fingerprint, train_hlp
from amorctl.train.rundir import RunDir

TINY = {
    "run": {"iterations": 3, "checkpoint_every": 1, "tensorboard": False, "threads": 1},
    "env": {"num_envs": 4, "episode_seconds": 0.3},
    "policy": {"actor_hidden": [16, 16, 16], "critic_hidden": [16, 16, 16]},
    "ppo": {"num_steps": 6, "num_epochs": 2, "num_minibatches": 2},
    "discriminator": {"window": 4, "hidden": [16], "z_hidden": [8], "batch_size": 32, "replay_size": 64,
                      "steps_per_iteration": 2},
}  # fmt: skip


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def tiny(**sections: dict) -> HlpConfig:
    return merge(merge(HlpConfig(), TINY, "TINY"), sections, "test")


def rows(path: Path) -> list[dict[str, str]]:
    with (path / "metrics.csv").open(newline="") as f:
        return list(csv.DictReader(f))


def tree(directory: Path) -> dict[str, bytes]:
    if not directory.exists():
        return {}
    return {
        str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()
    }


def run_cli(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize(("target", "index"), [("right", 0), ("left", 1)])
def test_toy_hlp_moves_mean_w_toward_the_rewarded_objective(
    toy_run: Path, tmp_path: Path, target, index
) -> None:
    """Rewarded with one toy objective only, the HLP learns to give that objective the weight:
    mean w starts at 0.5 and must end above 0.75 for it."""
    config = tiny(
        run={"iterations": 12, "checkpoint_every": 12},
        env={"num_envs": 32},
        ppo={"num_steps": 16, "learning_rate": 3e-3, "num_epochs": 4},
        discriminator={"reward": f"objective:{target}"},
    )
    trace: list[float] = []
    result = train_hlp(
        toy_run, tmp_path / "h", config, on_iteration=lambda m, *_: trace.append(m[f"w/{target}"])
    )
    assert abs(trace[0] - 0.5) < 0.05
    assert trace[-1] > 0.75, trace
    assert trace[-1] - trace[0] > 0.25
    # the frozen low-level policy is untouched: same parameters before, after, and as on disk
    assert result.llp_fingerprint_before == result.llp_fingerprint_after
    assert result.llp_fingerprint_after == policy_fingerprint(RunDir.open(toy_run).policy())


def test_tracking_hlp_resumes_bit_exactly_and_keeps_llp_frozen(tracking_run: Path, tmp_path: Path) -> None:
    config = tiny()
    full = train_hlp(tracking_run, tmp_path / "full", config)
    assert full.end_iteration == 3
    part = train_hlp(tracking_run, tmp_path / "part", config, stop_after=2)
    assert part.interrupted and part.end_iteration == 2
    resumed = train_hlp(tracking_run, tmp_path / "part", config, resume=True)
    assert (resumed.start_iteration, resumed.end_iteration) == (2, 3)
    a, b = rows(tmp_path / "full"), rows(tmp_path / "part")
    assert len(a) == len(b) == 3
    timing = {"wall_time_s", "env_steps_per_s"}
    for key in a[2]:
        if key not in timing:
            assert a[2][key] == b[2][key], key
    assert float(a[2]["disc/gp"]) > 0 and "w/smooth" in a[2] and 0 < float(a[2]["disc/replay_size"]) <= 64
    before = policy_fingerprint(RunDir.open(tracking_run).policy())
    assert full.llp_fingerprint_before == full.llp_fingerprint_after == before
    meta = json.loads((tmp_path / "full" / "hlp.json").read_text())
    assert meta["character"] == "biped20" and meta["window"] == 4 and len(meta["objectives"]) == 7


def test_bad_input_is_one_error_line_exit_2_and_writes_nothing(
    tracking_run: Path, toy_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(to_toml(tiny()))
    # a run directory without a checkpoint
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(tracking_run / "config.toml", bare / "config.toml")
    out = tmp_path / "out"
    cases = [
        (("hlp", "train", bare, "--out", out, "--config", cfg), "checkpoint"),
        (("hlp", "train", tracking_run, "--out", out, "--config", cfg, "--window", "0"), "--window 0"),
        (("hlp", "train", tracking_run, "--out", out, "--config", cfg, "--motion", "nope"), "'nope'"),
        (("hlp", "train", tmp_path / "missing", "--out", out), "missing"),
    ]
    for args, needle in cases:
        code, _, err = run_cli(capsys, *args)
        assert code == 2, (args, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error:") and needle in lines[0], err
        assert not out.exists()
        assert not (tracking_run / "hlp").exists()
    # an HLP directory of another run (toy: other character, objectives, layout)
    other = tmp_path / "toy-hlp"
    toy_cfg = tiny(discriminator={"reward": "objective:right"}, run={"iterations": 1})
    train_hlp(toy_run, other, toy_cfg)
    before = tree(other)
    code, _, err = run_cli(
        capsys, "hlp", "train", tracking_run, "--out", other, "--resume", "--iterations", "2"
    )
    assert code == 2 and err.count("error:") == 1 and "HLP was trained for" in err, err
    assert tree(other) == before


def test_cli_train_then_trace_plots_and_logs(tracking_run: Path, tmp_path: Path, capsys) -> None:
    from amorctl.outputs.mcap_log import read_rollout_mcap

    cfg = tmp_path / "tiny.toml"
    cfg.write_text(to_toml(tiny(run={"iterations": 2})))
    hlp_dir = tmp_path / "hlp"
    code, out, err = run_cli(
        capsys, "hlp", "train", tracking_run, "--out", hlp_dir, "--config", cfg, "--json"
    )
    assert code == 0, err
    summary = json.loads(out)
    assert summary["end_iteration"] == 2 and (hlp_dir / "checkpoints" / "iter_000002.json").is_file()
    assert (hlp_dir / "llp").is_dir() and (hlp_dir / "hlp.toml").is_file()
    png, mcap = tmp_path / "w.png", tmp_path / "t.mcap"
    code, out, err = run_cli(
        capsys, "hlp", "trace", hlp_dir, "--motion", "sway_a", "--motion", "sway_b",
        "--plot", png, "--out", mcap, "--compare", hlp_dir, "--json",
    )  # fmt: skip
    assert code == 0, err
    data = json.loads(out)
    assert len(data["traces"]) == 2
    segs = data["traces"][0]["segments"]
    if data["traces"][0]["falls"] == 0:
        assert [s["motion"] for s in segs] == ["sway_a", "sway_b"]
    assert segs[0]["motion"] == "sway_a"
    for s in segs:
        assert sum(s["mean_w"].values()) == pytest.approx(1.0, abs=1e-5)
    assert png.stat().st_size > 10_000
    topics = read_rollout_mcap(mcap)
    w = topics["/hlp/weights"]
    assert len(w) == data["traces"][0]["steps"]
    names = [k for k in w[0] if k != "t"]
    assert len(names) == 7
    assert all(abs(sum(msg[n] for n in names) - 1) < 1e-5 for msg in w)
    assert {m["motion"] for m in topics["/motion"]} <= {"sway_a", "sway_b"}
    code, _, err = run_cli(capsys, "hlp", "trace", hlp_dir, "--motion", "nope")
    assert code == 2 and "'nope'" in err


def test_table2_scores_heldout_windows_with_a_fresh_discriminator(tracking_run: Path, tmp_path: Path) -> None:
    from amorctl.hlp.eval_discriminator import SCHEMA, TableOptions, hlp_table
    from amorctl.hlp.run import load_hlp

    train_hlp(tracking_run, tmp_path / "h", tiny(run={"iterations": 1}))
    hlp = load_hlp(tmp_path / "h")
    opts = TableOptions(num_envs=4, seconds=1.0, window=10, stride=5, steps=20, batch_size=32, hidden=(16,))
    table = hlp_table(str(tracking_run), [("uniform", "uniform", np.full(7, 1 / 7)), ("HLP", "h", hlp)], opts)
    data = table.to_json()
    assert data["schema"] == SCHEMA
    assert [r["label"] for r in data["rows"]] == ["uniform", "HLP"]
    per_env = (50 - 10) // 5 + 1  # at most: every 5 steps once 10 real frames exist, over 50 steps
    for r in data["rows"]:
        assert r["episodes"] == 4 and 0 < r["windows_heldout"] <= 2 * per_env
        assert 0 < r["windows_train"] <= 2 * per_env
        assert np.isfinite(r["logit"]) and r["joint_mae_deg"] > 0
    assert data["counts"]["train_windows_policy"] == sum(r["windows_train"] for r in data["rows"])
    assert data["counts"]["heldout_windows_policy"] == sum(r["windows_heldout"] for r in data["rows"])
    np.testing.assert_allclose(data["rows"][0]["mean_w"], 1 / 7, atol=1e-6)
    assert "held-out" in data["caption"] and str(data["counts"]["heldout_windows_policy"]) in data["caption"]


def test_tune_with_hlp_scales_and_renormalizes_its_weights(
    tracking_run: Path, toy_run: Path, tmp_path: Path
) -> None:
    from amorctl.core.errors import AmorError
    from amorctl.hlp.edit import parse_scales
    from amorctl.hlp.run import load_hlp
    from amorctl.hlp.tune import run_hlp_tune
    from amorctl.tune.session import PinnedMotion

    train_hlp(tracking_run, tmp_path / "h", tiny(run={"iterations": 1}))
    hlp = load_hlp(tmp_path / "h")
    tenv = PinnedMotion(tracking_run, "sway_b")
    try:
        scales = parse_scales("smooth=3,vel=0", tenv.names)
        ro, raw = run_hlp_tune(tenv, hlp, scales, seconds=0.2, stop_on_fall=False)
        assert ro.weights.shape == raw.shape == (10, 7)
        want = raw * scales
        want /= want.sum(1, keepdims=True)
        np.testing.assert_allclose(ro.weights, want, atol=1e-6)
        assert (ro.weights[:, tenv.names.index("vel")] == 0).all()
    finally:
        tenv.close()
    toy = PinnedMotion(toy_run)
    try:
        with pytest.raises(AmorError, match="HLP was trained for"):
            run_hlp_tune(toy, hlp, np.ones(2))
    finally:
        toy.close()


def test_live_hlp_session_sliders_multiply_the_hlps_weights(tracking_run: Path, tmp_path: Path) -> None:
    from amorctl.hlp.edit import edit_weights
    from amorctl.hlp.live import HlpLiveSession
    from amorctl.hlp.run import load_hlp
    from amorctl.tune.session import PinnedMotion

    train_hlp(tracking_run, tmp_path / "h", tiny(run={"iterations": 1}))
    tenv = PinnedMotion(tracking_run, "sway_a")
    try:
        session = HlpLiveSession(tenv, load_hlp(tmp_path / "h"))
        np.testing.assert_allclose(session.scales, 1.0)
        np.testing.assert_allclose(session.weights, session.hlp_weights, atol=1e-6)
        session.set_slider("smooth", 1.0)  # the full slider: x2
        session.set_slider("up", 0.0)
        raw = session.hlp_weights
        rec = session.step()
        want = edit_weights(raw[None], np.array([0, 1, 1, 1, 1, 1, 2.0]))[0]
        np.testing.assert_allclose(rec.weights, want, atol=1e-6)
        assert rec.weights[0] == 0 and rec.weights[6] > raw[6]
    finally:
        tenv.close()


def test_decision_interval_holds_w_for_k_control_steps(toy_run: Path, tmp_path: Path) -> None:
    from amorctl.hlp.rewards import ObjectiveReward
    from amorctl.hlp.run import setup
    from amorctl.hlp.trainer import HlpTrainer

    config = tiny(env={"decision_interval": 3}, discriminator={"reward": "objective:right"})
    s = setup(toy_run, config)
    trainer = HlpTrainer(s.env, s.llp, config, ObjectiveReward(0))
    seen: list[np.ndarray] = []
    step = trainer.llp_step
    trainer.llp_step = lambda w: (seen.append(w.copy()), step(w))[1]  # type: ignore[method-assign]
    m = trainer.iteration()
    assert m["env_steps"] == 3 * 6 * 4  # k * num_steps * num_envs
    assert len(seen) == 18
    for block in range(6):
        held = seen[3 * block : 3 * block + 3]
        assert all(np.array_equal(held[0], w) for w in held)
    assert not np.array_equal(seen[0], seen[3])
