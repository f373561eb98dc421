"""`amorctl tune`: schedules on trained policies, the MCAP rollout log, the plot, bad input, the
live session (without a browser) and the live page in headless Chromium (Playwright)."""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import torch

from amorctl.cli.main import main
from amorctl.core.config import TrainConfig, override
from amorctl.core.errors import AmorError
from amorctl.core.schedule import dump_schedule, load_schedule
from amorctl.outputs.mcap_log import (
    TOPIC_ACTIONS,
    TOPIC_JOINTS,
    TOPIC_REF_JOINTS,
    TOPIC_REWARDS,
    TOPIC_SCENE,
    TOPIC_TF,
    TOPIC_WEIGHTS,
    read_rollout_mcap,
    write_rollout_mcap,
)
from amorctl.outputs.plots import plot_rollout
from amorctl.tune.live import SHUTDOWN_BOUND_S
from amorctl.tune.session import PinnedMotion, run_tune

torch.set_num_threads(1)

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
TRACKING7 = ("up", "lo", "feet", "rbs", "root", "vel", "smooth")


# ---------------------------------------------------------------------------- trained runs


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A MOPPO policy on the toy env whose action follows w: ~+1 for w=(1,0), ~-1 for w=(0,1)."""
    from amorctl.train.loop import train_run

    out = tmp_path_factory.mktemp("toy") / "run"
    config = override(
        TrainConfig(),
        run__iterations=30,
        run__checkpoint_every=30,
        run__tensorboard=False,
        run__threads=1,
        env__kind="toy",
        env__num_envs=64,
        env__episode_seconds=0.4,
        network__actor_hidden=[32, 32],
        network__critic_hidden=[32, 32],
        network__init_std=1.0,
        ppo__num_steps=16,
        ppo__num_epochs=4,
        ppo__num_minibatches=2,
        ppo__learning_rate=3e-3,
    )
    train_run(config, out)
    return out


@pytest.fixture(scope="module")
def tracking_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny biped20 run on two synthetic 1 s clips (sway0, sway1): two iterations, seconds."""
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.motion.dataset import write_dataset
    from amorctl.registry import get_registry
    from amorctl.train.loop import train_run

    root = tmp_path_factory.mktemp("tracking")
    dataset = root / "sway.mcap"
    write_dataset(dataset, synthetic_library(get_registry().character("biped20"), num_clips=2, seconds=1.0))
    config = override(
        TrainConfig(),
        run__iterations=2,
        run__checkpoint_every=2,
        run__tensorboard=False,
        run__threads=1,
        env__kind="tracking",
        env__character="biped20",
        env__dataset=str(dataset),
        env__num_envs=8,
        env__episode_seconds=1.0,
        network__actor_hidden=[32],
        network__critic_hidden=[32],
        ppo__num_steps=8,
        ppo__num_epochs=1,
        ppo__num_minibatches=1,
    )
    train_run(config, root / "run")
    return root / "run"


def run_cli(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


# ---------------------------------------------------------------------------- schedules on policies


def test_a_schedule_switch_changes_the_policys_behaviour_after_the_switch(
    toy_run: Path, tmp_path: Path
) -> None:
    # The toy analogue of "raise smooth half-way": raise `right` half-way. Before the switch the
    # policy acts left (a ~ -1 + s), after it right (a ~ +1 + s), and the favoured reward follows.
    sched = tmp_path / "switch.toml"
    sched.write_text(
        'interpolation = "step"\n'
        "[[keyframe]]\nt = 0\nweights = { right = 0.1, left = 0.9 }\n"
        "[[keyframe]]\nt = 0.2\nweights = { right = 0.9, left = 0.1 }\n"
    )
    tenv = PinnedMotion(toy_run)
    rollout = run_tune(tenv, load_schedule(sched, tenv.names), seconds=0.4, stop_on_fall=False)
    assert len(rollout.times) == 20 and not rollout.terminated.any()
    before, after = rollout.times < 0.2 - 1e-9, rollout.times >= 0.2 - 1e-9
    np.testing.assert_allclose(rollout.weights[before], [[0.1, 0.9]] * 10, atol=1e-6)
    np.testing.assert_allclose(rollout.weights[after], [[0.9, 0.1]] * 10, atol=1e-6)
    a = rollout.actions[:, 0]
    assert a[before].mean() < -0.5 and a[after].mean() > 0.5, a
    r_before, r_after = rollout.returns_between(0, 0.2), rollout.returns_between(0.2, 1)
    assert r_before[1] > r_before[0] + 0.5 and r_after[0] > r_after[1] + 0.5


def test_raising_smooth_half_way_uses_the_smooth_weight_after_the_switch(tracking_run: Path) -> None:
    # On a tracking run, the smooth weight reaches the policy exactly from the switch on, and the
    # action-rate measure the smooth objective penalizes is computed per step. (A policy trained
    # for seconds has not learnt to act smoother; the toy-smooth test below checks that effect.)
    tenv = PinnedMotion(tracking_run, "sway1")
    assert tenv.motion == "sway1" and tenv.names == TRACKING7
    from amorctl.core.schedule import parse_schedule

    sched = parse_schedule(
        {
            "interpolation": "step",
            "keyframe": [
                {"t": 0.0, "weights": {n: 1 for n in TRACKING7[:-1]}},
                {"t": 0.4, "weights": {"smooth": 1}},
            ],
        },
        tenv.names,
    )
    rollout = run_tune(tenv, sched, seconds=0.8, stop_on_fall=False)
    assert len(rollout.times) == 40
    np.testing.assert_allclose(rollout.weights[:20, -1], 0.0)
    np.testing.assert_allclose(rollout.weights[20:], [[0, 0, 0, 0, 0, 0, 1]] * 20, atol=1e-6)
    rate = rollout.action_rate()
    expected = ((rollout.actions[1:] - rollout.actions[:-1]) ** 2).sum(axis=1)
    expected[rollout.terminated[:-1]] = 0.0
    np.testing.assert_allclose(rate[1:], expected, rtol=1e-6)
    assert rate[0] == 0.0
    # the rollout starts at the clip's first frame in the reference state
    view = tenv.view
    first = int(np.concatenate([[0], np.cumsum(view.clip_frame_counts)])[tenv.clip_index])
    np.testing.assert_allclose(rollout.ref_joint_pos[0], view.reference_joint_pos([first + 1])[0], atol=1e-6)


def _smooth_switch(tenv: PinnedMotion, tmp_path: Path, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Roll a toy-smooth run out for 1 s (50 steps, one episode) under a step schedule whose
    ``smooth`` weight is ``lo`` before 0.5 s and ``hi`` from then on: the mean action rate
    ``(a_t - a_{t-1})^2`` and the mean rewards [track, smooth], before and after the switch."""
    sched = tmp_path / f"smooth-{lo}-{hi}.toml"
    sched.write_text(
        'interpolation = "step"\n'
        f"[[keyframe]]\nt = 0\nweights = {{ track = {1 - lo}, smooth = {lo} }}\n"
        f"[[keyframe]]\nt = 0.5\nweights = {{ track = {1 - hi}, smooth = {hi} }}\n"
    )
    rollout = run_tune(tenv, load_schedule(sched, tenv.names), seconds=1.0, stop_on_fall=False)
    assert len(rollout.times) == 50 and not rollout.terminated.any()
    before, after = rollout.times < 0.5 - 1e-9, rollout.times >= 0.5 - 1e-9
    np.testing.assert_allclose(rollout.weights[before], [[1 - lo, lo]] * 25, atol=1e-6)
    np.testing.assert_allclose(rollout.weights[after], [[1 - hi, hi]] * 25, atol=1e-6)
    rate = rollout.action_rate()  # rate[0] is 0 (no previous action): left out of "before"
    rates = np.array([rate[1:25].mean(), rate[after].mean()])
    rewards = np.stack([rollout.returns_between(0, 0.5), rollout.returns_between(0.5, 1.0)])
    return rates, rewards


def test_raising_smooth_half_way_lowers_the_action_rate_after_the_switch(
    toy_smooth_run: Path, tmp_path: Path
) -> None:
    # On a trained toy policy (track a jumping target vs the `smooth` action-rate
    # penalty), raising `smooth` half-way makes the policy hold still from the switch on.
    tenv = PinnedMotion(toy_smooth_run)
    assert tenv.names == ("track", "smooth")
    (rate_before, rate_after), rewards = _smooth_switch(tenv, tmp_path, 0.05, 0.95)
    assert rate_before > 0.05 and rate_after < rate_before / 5, (rate_before, rate_after)
    # the smooth reward (minus the action rate, clipped actions) follows; tracking pays for it
    assert rewards[1, 1] > rewards[0, 1] + 0.04 and rewards[1, 0] < rewards[0, 0], rewards
    # and the reverse schedule does the opposite
    (rate_before, rate_after), rewards = _smooth_switch(tenv, tmp_path, 0.95, 0.05)
    assert rate_after > 0.05 and rate_before < rate_after / 5, (rate_before, rate_after)
    assert rewards[1, 1] < rewards[0, 1] - 0.04 and rewards[1, 0] > rewards[0, 0], rewards


def test_toy_smooth_env_follows_the_vector_env_contract_and_resumes_exactly() -> None:
    from amorctl.core.vecenv import VectorEnv
    from amorctl.envs.toy import ToySmoothEnv

    env = ToySmoothEnv(4, max_steps=5, hazard=0.2, seed=1)
    assert isinstance(env, VectorEnv) and env.reward_space.names == ("track", "smooth")
    obs, _ = env.reset(seed=1)
    assert obs.shape == (4, env.obs_dim) and obs.dtype == np.float32
    np.testing.assert_array_equal(obs[:, -2:], env.weights)
    np.testing.assert_allclose(env.weights.sum(axis=1), 1.0, atol=1e-6)
    a = np.array([[0.5], [-0.5], [0.0], [3.0]])
    _, r, _, _, info = env.step(a)
    s0 = info["final_obs"][:, 0]
    assert r.shape == (4, 2) and r.dtype == np.float32
    np.testing.assert_allclose(r[:, 1], -(np.clip(a[:, 0], -2, 2) ** 2), rtol=1e-6)  # a_{-1} = 0
    np.testing.assert_allclose(info["final_obs"][:, 1], np.clip(a[:, 0], -2, 2))  # a_prev observed
    assert ((np.abs(s0) >= 0.25) & (np.abs(s0) <= 1.0)).all()
    snap = env.get_state()
    rng = np.random.default_rng(0)
    acts = rng.normal(size=(12, 4, 1))
    first = [env.step(x) for x in acts]
    env.set_state(snap)
    again = [env.step(x) for x in acts]
    ended = np.zeros(4, dtype=bool)
    for (o1, r1, te1, tr1, i1), (o2, r2, te2, tr2, i2) in zip(first, again, strict=True):
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(te1, te2)
        np.testing.assert_array_equal(tr1, tr2)
        np.testing.assert_array_equal(i1["final_obs"], i2["final_obs"])
        assert not (te1 & tr1).any()
        ended |= te1 | tr1
        # an ended episode restarts with a_prev = 0 and t = 0
        np.testing.assert_array_equal(o1[te1 | tr1, 1:3], 0.0)
    assert ended.all()


# ---------------------------------------------------------------------------- MCAP log and plot


def test_mcap_log_round_trips_with_the_expected_channels_and_counts(
    tracking_run: Path, tmp_path: Path
) -> None:
    tenv = PinnedMotion(tracking_run, "sway0")
    w = np.array([1, 1, 1, 1, 1, 1, 3], dtype=np.float64) / 9
    rollout = run_tune(tenv, w, seconds=0.3, stop_on_fall=False)
    t = len(rollout.times)
    assert t == 15
    path = tmp_path / "rollout.mcap"
    write_rollout_mcap(rollout, path)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp file left
    msgs = read_rollout_mcap(path)
    counts = {k: len(v) for k, v in msgs.items()}
    assert counts == {
        TOPIC_TF: t,
        TOPIC_SCENE: 1,
        TOPIC_JOINTS: t,
        TOPIC_REF_JOINTS: t,
        TOPIC_ACTIONS: t,
        TOPIC_WEIGHTS: t,
        TOPIC_REWARDS: t,
    }
    bodies = len(tenv.body_names)
    tf0 = msgs[TOPIC_TF][0]
    assert len(tf0.transforms) == 2 * bodies  # the character and the reference ghost
    assert tf0.transforms[0].parent_frame_id == "world"
    assert tf0.transforms[0].child_frame_id == tenv.body_names[0]
    assert tf0.transforms[bodies].child_frame_id == "ref/" + tenv.body_names[0]
    last = msgs[TOPIC_TF][-1].transforms[0]
    np.testing.assert_allclose(
        [last.translation.x, last.translation.y, last.translation.z], rollout.body_pos[-1, 0], atol=1e-9
    )
    q = last.rotation
    np.testing.assert_allclose([q.w, q.x, q.y, q.z], rollout.body_quat[-1, 0], atol=1e-9)
    entities = msgs[TOPIC_SCENE][0].entities
    assert len(entities) == 2 * bodies and sum(len(e.cubes) for e in entities) > 0
    weights = msgs[TOPIC_WEIGHTS]
    assert set(weights[0]) == {"t", *TRACKING7}
    np.testing.assert_allclose([weights[3][n] for n in TRACKING7], w, atol=1e-6)
    np.testing.assert_allclose([m["t"] for m in weights], rollout.times)
    np.testing.assert_allclose([msgs[TOPIC_REWARDS][5][n] for n in TRACKING7], rollout.rewards[5], rtol=1e-6)
    np.testing.assert_allclose(msgs[TOPIC_ACTIONS][7]["values"], rollout.actions[7], rtol=1e-6)
    joints = msgs[TOPIC_JOINTS][2]
    assert joints["name"] == list(tenv.view.joint_names)
    np.testing.assert_allclose(joints["position"], rollout.joint_pos[2], atol=1e-9)

    plot = tmp_path / "plot.png"
    plot_rollout(rollout, plot)
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and plot.stat().st_size > 10_000


def test_toy_runs_log_actions_weights_and_rewards_only(toy_run: Path, tmp_path: Path) -> None:
    rollout = run_tune(PinnedMotion(toy_run), np.array([0.25, 0.75]), seconds=0.1, stop_on_fall=False)
    write_rollout_mcap(rollout, tmp_path / "toy.mcap")
    msgs = read_rollout_mcap(tmp_path / "toy.mcap")
    assert {k: len(v) for k, v in msgs.items()} == {TOPIC_ACTIONS: 5, TOPIC_WEIGHTS: 5, TOPIC_REWARDS: 5}
    assert msgs[TOPIC_WEIGHTS][0] == {"t": 0.0, "right": 0.25, "left": 0.75}


# ---------------------------------------------------------------------------- CLI


def test_cli_runs_a_schedule_and_writes_log_plot_and_json(
    tracking_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    import json

    sched = tmp_path / "s.toml"
    dump_schedule([(0.0, {"up": 1}), (0.2, {"smooth": 1})], TRACKING7, sched, interpolation="step")
    out, plot = tmp_path / "r.mcap", tmp_path / "r.png"
    code, stdout, err = run_cli(
        capsys, "tune", str(tracking_run), "--motion", "sway1", "--schedule", str(sched), "--seconds", "0.4",
        "--no-stop-on-fall", "--out", str(out), "--plot", str(plot), "--json",
    )  # fmt: skip
    assert code == 0, err
    result = json.loads(stdout)
    assert result["motion"] == "sway1" and result["steps"] == 20
    assert [s["t0"] for s in result["segments"]] == [0.0, 0.2]
    assert [s["steps"] for s in result["segments"]] == [10, 10]
    assert set(result["returns"]) == set(TRACKING7)
    assert out.is_file() and plot.is_file()
    assert len(read_rollout_mcap(out)[TOPIC_WEIGHTS]) == 20

    code, stdout, err = run_cli(capsys, "tune", str(tracking_run), "--motion", "sway", "--weights", "up=1")
    assert code == 2 and "ambiguous" in err and "sway0, sway1" in err


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("unknown motion", r"no motion 'dance' in the biped20 dataset; clips: sway0, sway1"),
        ("bad schedule", r"schedule .*bad\.toml: keyframe 1 \(t=0\): unknown objective 'upp'"),
        ("schedule motion", r"schedule .*bad\.toml: motion 'dance': unknown motion"),
        ("missing checkpoint", r"checkpoints: no checkpoint"),
        ("no run", r"run directory not found"),
        ("both", r"exactly one of --weights or --schedule"),
        ("bad weights", r"unknown objective"),
    ],
)
def test_cli_bad_input_fails_cleanly_without_partial_files(
    tracking_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture, case: str, message: str
) -> None:
    run = str(tracking_run)
    bad = tmp_path / "bad.toml"
    args = ["--weights", "up=1"]
    if case == "unknown motion":
        args += ["--motion", "dance"]
    elif case == "bad schedule":
        bad.write_text("[[keyframe]]\nt = 0\nweights = { upp = 1 }\n")
        args = ["--schedule", str(bad)]
    elif case == "schedule motion":
        bad.write_text("[motion.dance]\n[[motion.dance.keyframe]]\nt = 0\nweights = { up = 1 }\n")
        args = ["--schedule", str(bad)]
    elif case == "missing checkpoint":
        run_copy = tmp_path / "copy"
        run_copy.mkdir()
        shutil.copy(tracking_run / "config.toml", run_copy / "config.toml")
        run = str(run_copy)
    elif case == "no run":
        run = str(tmp_path / "nope")
    elif case == "both":
        bad.write_text("[[keyframe]]\nt = 0\nweights = { up = 1 }\n")
        args += ["--schedule", str(bad)]
    elif case == "bad weights":
        args = ["--weights", "upp=1"]
    outs = tmp_path / "outs"
    outs.mkdir()
    code, _, err = run_cli(
        capsys, "tune", run, *args, "--out", str(outs / "r.mcap"), "--plot", str(outs / "r.png")
    )
    assert code == 2
    assert re.search(message, err), err
    assert err.startswith("error: ") and "Traceback" not in err
    assert list(outs.iterdir()) == []


# ---------------------------------------------------------------------------- live session (no browser)


def test_live_session_slider_reaches_the_policy_on_the_next_step(tracking_run: Path, tmp_path: Path) -> None:
    from amorctl.tune.live import LiveSession

    session = LiveSession(PinnedMotion(tracking_run, "sway0"), save_to=tmp_path / "rec.toml")
    rec = session.step()
    assert rec is not None
    np.testing.assert_allclose(session.weights_seen_by_policy, np.full(7, 1 / 7), atol=1e-6)
    np.testing.assert_allclose(session.set_slider("smooth", 0.0), [1 / 6] * 6 + [0], atol=1e-12)
    session.step()
    np.testing.assert_allclose(session.weights_seen_by_policy, [1 / 6] * 6 + [0], atol=1e-6)
    session.set_slider("up", 0.5)
    session.step()
    np.testing.assert_allclose(
        session.weights_seen_by_policy, np.array([0.5, 1, 1, 1, 1, 1, 0]) / 5.5, atol=1e-6
    )
    with pytest.raises(AmorError, match="unknown objective 'upp'"):
        session.set_slider("upp", 1)
    with pytest.raises(AmorError, match="outside"):
        session.set_slider("up", 2)

    # pause: no step, no time; resume
    t = session.t
    session.pause()
    assert session.step() is None and session.t == t
    session.resume()

    # keyframes at the current time, saved as a schedule that --schedule reads back
    with pytest.raises(AmorError, match="no keyframes recorded"):
        session.save_schedule()
    session.restart()
    assert session.t == 0.0
    session.record_keyframe()
    for _ in range(10):
        session.step()
    session.set_slider("smooth", 1.0)
    t1, w1 = session.record_keyframe()
    assert t1 == pytest.approx(0.2)
    path = session.save_schedule()
    sched = load_schedule(path, TRACKING7, ["sway0", "sway1"])
    np.testing.assert_allclose(sched.weights_at(0.0), np.array([0.5, 1, 1, 1, 1, 1, 0]) / 5.5, atol=1e-12)
    np.testing.assert_allclose(sched.weights_at(0.2), w1, atol=1e-12)

    # switching motion restarts it; an unknown one is refused and changes nothing
    session.set_motion("sway1")
    assert session.motion == "sway1" and session.t == 0.0
    with pytest.raises(AmorError, match="no motion 'dance'"):
        session.set_motion("dance")
    assert session.motion == "sway1"


# ---------------------------------------------------------------------------- live page in Chromium


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_http(url: str, proc: subprocess.Popen, timeout: float = 90.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"tune --live exited with {proc.returncode}: {proc.stderr.read()}")
        try:
            with urllib.request.urlopen(url, timeout=2) as resp:
                if resp.status == 200:
                    return
        except OSError:
            time.sleep(0.3)
    raise AssertionError(f"{url} did not come up in {timeout} s")


def _policy_sees(page, name: str) -> float:  # type: ignore[no-untyped-def]
    """The 'policy sees' cell of objective ``name`` in the page's weights table."""
    row = page.locator("tr", has=page.locator("td", has_text=re.compile(f"^{name}$")))
    return float(row.locator("td").nth(2).inner_text())


def _resume(page) -> None:  # type: ignore[no-untyped-def]
    """Press 'resume' on the paused live page and wait until it runs."""
    page.get_by_role("button", name="resume").click()
    page.wait_for_function("() => !document.body.innerText.includes('paused')", timeout=30_000)


def _pause_at(page) -> str:  # type: ignore[no-untyped-def]
    """Press 'pause' on the live page; returns the time it then shows ("t = 0.50 s" -> "0.50")."""
    page.get_by_role("button", name="pause").click()
    page.wait_for_function("() => document.body.innerText.includes('paused')", timeout=30_000)
    found = re.search(r"t = ([0-9.]+) s", page.locator("body").inner_text())
    assert found, "the live page shows no time"
    return found.group(1)


@pytest.mark.skipif(
    not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} not installed (CI installs Debian's chromium)"
)
def test_live_page_in_headless_chromium(
    tracking_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright (test extra) not installed")
    port = _free_port()
    saved = tmp_path / "recorded.toml"
    proc = subprocess.Popen(
        [sys.executable, "-X", "faulthandler", "-m", "amorctl.cli.main", "tune", str(tracking_run),
         "--live", "--motion", "sway0", "--port", str(port), "--save-to", str(saved)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        url = f"http://127.0.0.1:{port}/"
        _wait_http(url, proc)
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(
                executable_path=CHROMIUM,
                headless=True,
                args=CHROMIUM_FLAGS,  # Playwright itself gives it a fresh temporary profile
            )
            page = browser.new_page(viewport={"width": 1100, "height": 720})
            page.goto(url)
            sliders = page.get_by_role("slider")
            sliders.first.wait_for(timeout=60_000)
            assert sliders.count() == 7
            page.wait_for_function(
                "() => [...document.querySelectorAll('td')].some(td => td.innerText === '0.143')",
                timeout=30_000,
            )
            assert _policy_sees(page, "smooth") == pytest.approx(1 / 7, abs=1e-3)

            # move the smooth slider to 0 from the keyboard: the policy's weights follow
            sliders.nth(6).focus()
            page.keyboard.press("Home")
            page.wait_for_function(
                "() => [...document.querySelectorAll('tr')].some(tr => tr.innerText.startsWith('smooth')"
                " && tr.innerText.trim().endsWith('0.000'))",
                timeout=30_000,
            )
            assert _policy_sees(page, "smooth") == 0.0
            assert _policy_sees(page, "up") == pytest.approx(1 / 6, abs=1e-3)

            shot = os.environ.get("AMORCTL_TUNE_SCREENSHOT")
            if shot:  # docs/img/tune-live.png is made this way (docs/tune.md)
                close = page.locator(".mantine-Notification-closeButton")  # "software WebGL" notice
                if close.count():
                    close.first.click()
                time.sleep(1.0)
                page.screenshot(path=shot)

            # record a keyframe, move another slider, record again, save the schedule. Each keyframe
            # is recorded paused, at a time shown on the page: the clip loops, and a keyframe at the
            # time of an earlier one replaces it (LiveSession.record_keyframe)
            t_first = _pause_at(page)
            page.get_by_role("button", name="record keyframe").click()
            page.wait_for_function("() => document.body.innerText.includes('keyframes: 1')", timeout=30_000)
            _resume(page)
            sliders.nth(0).focus()
            page.keyboard.press("Home")  # up to 0: the policy sees it once it steps again
            page.wait_for_function(
                "() => [...document.querySelectorAll('tr')].some(tr => tr.innerText.startsWith('up')"
                " && tr.innerText.trim().endsWith('0.000'))",
                timeout=30_000,
            )
            for _ in range(20):
                if _pause_at(page) != t_first:
                    break
                _resume(page)
            else:
                raise AssertionError(f"the page's time stayed at t = {t_first} s across 20 resumes")
            page.get_by_role("button", name="record keyframe").click()
            page.wait_for_function("() => document.body.innerText.includes('keyframes: 2')", timeout=30_000)
            page.get_by_role("button", name="save schedule").click()
            page.wait_for_function("() => document.body.innerText.includes('saved:')", timeout=30_000)
            browser.close()
    finally:
        proc.send_signal(signal.SIGINT)
        try:  # Ctrl-C ends the page within SHUTDOWN_BOUND_S (a watchdog ends a hung shutdown)
            proc.wait(timeout=SHUTDOWN_BOUND_S + 30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, proc.stderr.read()

    # the saved keyframes load as a schedule: smooth 0 in both, up 0 in the second
    sched = load_schedule(saved, TRACKING7, ["sway0", "sway1"])
    rows = sched.track_for().weights  # in time order; the motion may have looped in between
    assert rows.shape == (2, 7) and (rows[:, -1] == 0.0).all()
    first = int(np.argmax(rows[:, 0]))
    np.testing.assert_allclose(rows[first], [1 / 6] * 6 + [0], atol=1e-9)
    np.testing.assert_allclose(rows[1 - first], [0] + [0.2] * 5 + [0], atol=1e-9)
    code, stdout, err = run_cli(
        capsys, "tune", str(tracking_run), "--schedule", str(saved), "--seconds", "0.2"
    )
    assert code == 0, err
    assert "per-objective return" in stdout


def test_live_app_steps_a_toy_run_in_the_background_and_stops(toy_run: Path) -> None:
    # the page for a run without a character (the toy task's scene), served and stepped in-process
    from amorctl.tune.live import LiveApp, LiveSession

    session = LiveSession(PinnedMotion(toy_run), np.array([1.0, 0.0]))
    app = LiveApp(session, host="127.0.0.1", port=_free_port(), realtime=False).start()
    try:
        with urllib.request.urlopen(app.url, timeout=10) as resp:
            assert resp.status == 200
        deadline = time.monotonic() + 30
        while session.steps_total < 5 and time.monotonic() < deadline:
            time.sleep(0.05)
        np.testing.assert_allclose(session.weights_seen_by_policy, [1.0, 0.0])
        session.set_slider("left", 1.0)
        target = session.steps_total + 2
        while session.steps_total < target and time.monotonic() < deadline:
            time.sleep(0.05)
        np.testing.assert_allclose(session.weights_seen_by_policy, [0.5, 0.5])
        x, _, z = app.toy_action.position  # the action ball is posed from the last action
        assert z == pytest.approx(0.1) and -3.0 <= x <= 3.0 and x != 0.0
    finally:
        app.stop()
    assert app.error is None
    with pytest.raises(OSError):
        urllib.request.urlopen(app.url, timeout=2)


def test_live_page_behind_the_token_gate_serves_its_websocket_only_with_the_cookie(toy_run: Path) -> None:
    """The real page (viser) behind :class:`LiveGate`: the page's websocket handshake passes with
    the cookie the token URL gave, and is refused (403) without it."""
    import viser
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    from amorctl.tune.live import LiveApp, LiveSession
    from amorctl.tune.live_gate import LiveGate

    token = "a-live-page-token-0123456789"
    session = LiveSession(PinnedMotion(toy_run), np.array([1.0, 0.0]))
    app = LiveApp(session, host="127.0.0.1", port=0, realtime=False).start()
    gate = LiveGate("127.0.0.1", 0, app.port, token)
    try:
        cookies = urllib.request.HTTPCookieProcessor()
        opener = urllib.request.build_opener(cookies)  # a client that keeps cookies, as browsers do
        with opener.open(gate.url, timeout=10) as resp:  # the token URL -> redirect + cookie -> the page
            assert resp.status == 200 and resp.url == f"http://127.0.0.1:{gate.port}/"
            assert b"<html" in resp.read().lower()
        value = "; ".join(f"{c.name}={c.value}" for c in cookies.cookiejar)
        assert value.startswith("amorctl_live=")
        with pytest.raises(urllib.error.HTTPError, match="403"):  # no token, no cookie: refused
            urllib.request.urlopen(f"http://127.0.0.1:{gate.port}/", timeout=10)
        ws_url = f"ws://127.0.0.1:{gate.port}/"
        protocol = [f"viser-v{viser.__version__}"]
        with connect(ws_url, subprotocols=protocol, additional_headers={"Cookie": value}) as ws:
            assert ws.recv(timeout=10)  # the page's first messages came through the gate
        with pytest.raises(InvalidStatus, match="403"):
            connect(ws_url, subprotocols=protocol)
    finally:
        gate.close()
        app.stop()


def test_live_page_beyond_loopback_without_a_token_is_one_error_line_before_any_work(
    toy_run: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    import amorctl.tune.session as session_mod

    def tripwire(*args: object, **kwargs: object) -> None:
        raise AssertionError("the run was opened")

    monkeypatch.setattr(session_mod, "PinnedMotion", tripwire)
    for extra in ([], ["--hlp", str(toy_run / "no-hlp")]):
        code = main(["tune", str(toy_run), "--live", "--host", "0.0.0.0", *extra])
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1, err
        assert lines[0].startswith("error: --live --host 0.0.0.0 binds 0.0.0.0, beyond loopback")
        assert "AMORCTL_TOKEN=" in lines[0] and "--token" in lines[0]
    monkeypatch.setenv("AMORCTL_TOKEN", "short")
    assert main(["tune", str(toy_run), "--live", "--host", "0.0.0.0"]) == 2
    assert "the token is 5 characters" in capsys.readouterr().err


def test_the_live_page_refreshes_its_text_at_ten_hz_whatever_the_control_rate() -> None:
    from amorctl.tune.live import text_refresh_steps

    assert text_refresh_steps(1 / 50) == 5  # biped20, humanoid36
    assert text_refresh_steps(1 / 30) == 3
    assert text_refresh_steps(1 / 200) == 20
    assert text_refresh_steps(1 / 5) == 1  # slower than 10 Hz: every step
