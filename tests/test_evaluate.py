"""Rollouts, `amorctl pareto` and `amorctl evaluate`: fronts, metrics, sweeps, videos, errors."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from amorctl.analysis.front import hypervolume
from amorctl.analysis.level_sweep import sweep_levels_weights, weight_sweep
from amorctl.analysis.rollout import Episodes, Rollout, rollout
from amorctl.analysis.schemas import EVALUATE_JSON_SCHEMA, PARETO_JSON_SCHEMA
from amorctl.analysis.sweeps import parse_reference_point
from amorctl.analysis.tracking_metrics import joint_errors, tracking_metrics
from amorctl.cli.main import main
from amorctl.core.errors import AmorError
from amorctl.core.weights import sample_dirichlet
from amorctl.envs.toy import ToyTradeoffEnv
from amorctl.registry import get_registry
from amorctl.train.rundir import RunDir

torch.set_num_threads(1)
DOCS = Path(__file__).resolve().parents[1] / "docs"


def run_cli(capsys: pytest.CaptureFixture, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def toy_step_rewards(d: np.ndarray) -> np.ndarray:
    """Per-step rewards (right, left) of acting d = a - s to the right of the drifting state s:
    (exp(-(d - 1)^2), exp(-(d + 1)^2)). Returns [..., 2]."""
    d = np.asarray(d, dtype=np.float64)
    return np.stack([np.exp(-((d - 1) ** 2)), np.exp(-((d + 1) ** 2))], axis=-1)


def toy_support(w: np.ndarray) -> np.ndarray:
    """The best per-step utility max_a w . r(a) for weights w [K, 2]: the true front of the toy env
    (episode returns / length reach the convex hull of the curve toy_step_rewards(d)). Returns [K]."""
    return np.max(w @ toy_step_rewards(np.linspace(-3.0, 3.0, 6001)).T, axis=1)


# ---------------------------------------------------------------------------- rollout
class _ConstantPolicy:
    def __init__(self, value: float) -> None:
        self.value = value

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.full((obs.shape[0], 1), self.value, dtype=np.float32)


def test_rollout_counts_episodes_across_auto_resets() -> None:
    env = ToyTradeoffEnv(6, max_steps=7, hazard=0.2, seed=1)
    ro = rollout(_ConstantPolicy(1.0), env, [0.5, 0.5], episodes=3, seed=4)
    eps = ro.episodes
    assert eps.count == 18
    assert np.array_equal(np.bincount(eps.env, minlength=6), [3] * 6)
    for e in range(6):  # each env's episodes are numbered 0, 1, 2 in order
        assert eps.index[eps.env == e].tolist() == [0, 1, 2]
    assert (eps.length >= 1).all() and (eps.length <= 7).all()
    # Survival = reached the limit without a terminal event (the hazard can also strike at step 7).
    assert (eps.length[eps.survived] == 7).all() and not eps.survived[eps.length < 7].any()
    assert not eps.survived.all() and eps.survived.any()
    # Per-step bookkeeping agrees with the per-episode records.
    assert ro.rewards is not None and ro.done is not None
    steps_per_episode = np.bincount(ro.episode_id[ro.episode_id >= 0], minlength=18)
    assert np.array_equal(steps_per_episode, eps.length)
    sums = np.zeros((18, 2))
    np.add.at(sums, ro.episode_id[ro.episode_id >= 0], ro.rewards[ro.episode_id >= 0])
    np.testing.assert_allclose(sums, eps.returns, rtol=1e-5)
    assert ro.done[ro.valid].sum() == 18
    assert ro.batched_steps == ro.num_steps == ro.valid.shape[0]
    # a = 1 with s in [-1, 1]: right = exp(-s^2) >= exp(-1) per step.
    assert (eps.returns[:, 0] >= np.exp(-1.0) * eps.length - 1e-5).all()


def test_rollout_changes_weights_over_time_per_env() -> None:
    env = ToyTradeoffEnv(3, max_steps=10, hazard=0.0)
    seen: list[np.ndarray] = []

    def policy(obs: np.ndarray) -> np.ndarray:
        seen.append(obs[:, -2:].copy())
        return np.zeros((obs.shape[0], 1), dtype=np.float32)

    def weights(t: np.ndarray) -> np.ndarray:  # env i: w_right = min(1, t / (i + 1) s)
        right = np.clip(t / np.arange(1, 4) / 0.2, 0.0, 1.0)
        return np.stack([right, 1 - right], axis=1)

    ro = rollout(policy, env, weights, episodes=1)
    assert ro.weights is not None and ro.num_steps == 10
    t = np.arange(10)[:, None] * 0.02
    expected = np.clip(t / np.arange(1, 4) / 0.2, 0, 1)
    np.testing.assert_allclose(ro.weights[:, :, 0], expected, atol=1e-6)
    np.testing.assert_allclose(np.stack(seen)[:, :, 0], expected, atol=1e-6)  # the policy saw them
    assert ro.episodes.weights.shape == (3, 2)


def test_rollout_rejects_bad_input() -> None:
    env = ToyTradeoffEnv(2, max_steps=3)
    with pytest.raises(AmorError, match="episodes must be >= 1"):
        rollout(_ConstantPolicy(0.0), env, [0.5, 0.5], episodes=0)
    with pytest.raises(AmorError, match="expected"):
        rollout(_ConstantPolicy(0.0), env, np.ones((3, 2)) / 2)
    with pytest.raises(AmorError, match="sum to 1"):
        rollout(_ConstantPolicy(0.0), env, [0.9, 0.9])


def hand_rollout() -> Rollout:
    """2 steps, 2 envs, 3 joints, 1 end effector; env 1's second step is not counted (not valid)."""
    q = np.zeros((2, 2, 3), np.float32)
    q_ref = q.copy()
    q_ref[:, :, 0] = np.radians(3.0)  # joint 0 off by 3 degrees everywhere
    q_ref[0, 0, 2] = np.radians(6.0)  # joint 2 off by 6 degrees once
    ee = np.zeros((2, 2, 1, 3), np.float32)
    ee_ref = ee.copy()
    ee_ref[:, :, 0, 2] = 0.004  # 4 mm
    ee_ref[0, 1, 0, :2] = [0.003, 0.0]  # env 1 step 0: (3, 0, 4) mm -> 5 mm
    eps = Episodes(
        env=np.array([0, 1]), index=np.array([0, 0]), returns=np.array([[2.0, 1.0], [1.0, 0.0]]),
        length=np.array([2, 1]), survived=np.array([True, False]), weights=np.full((2, 2), 0.5, np.float32),
    )  # fmt: skip
    ro = Rollout(
        objective_names=("a", "b"), dt=0.02, episodes=eps,
        valid=np.array([[True, True], [True, False]]), episode_id=np.array([[0, 1], [0, -1]]),
        joint_pos=q, ref_joint_pos=q_ref, ee_pos=ee, ref_ee_pos=ee_ref,
    )  # fmt: skip
    return ro


def test_tracking_metrics_against_hand_computed_values() -> None:
    ro = hand_rollout()
    m = tracking_metrics(ro, {"up": np.array([0]), "lo": np.array([1, 2])})
    # 3 counted steps x 3 joints: errors 3+3+3 (joint 0) and 6 (joint 2, step 0 env 0) -> 15 / 9.
    assert m["joint_mae_deg"] == pytest.approx(15 / 9, rel=1e-5)
    assert m["joint_mae_deg/up"] == pytest.approx(3.0, rel=1e-5)
    assert m["joint_mae_deg/lo"] == pytest.approx(6 / 6, rel=1e-5)
    assert m["mpjpe_mm"] == pytest.approx((4 + 5 + 4) / 3, rel=1e-4)
    assert m["survival_rate"] == 0.5
    assert m["episode_length_s"] == pytest.approx(0.03)
    assert m["return/a"] == 1.5 and m["return_std/b"] == 0.5


def test_joint_errors_against_hand_computed_values() -> None:
    ro = hand_rollout()  # 3 counted steps; q - q_ref: joint 0 -3 deg each, joint 2 -6 deg once
    errors = joint_errors(ro, ("hip", "knee", "ankle"))
    assert list(errors) == ["hip", "knee", "ankle"]
    assert errors["hip"] == pytest.approx({"mae_deg": 3.0, "bias_deg": -3.0, "p95_deg": 3.0}, rel=1e-5)
    assert errors["knee"] == {"mae_deg": 0.0, "bias_deg": 0.0, "p95_deg": 0.0}
    assert errors["ankle"]["mae_deg"] == pytest.approx(2.0, rel=1e-5)  # (6 + 0 + 0) / 3
    assert errors["ankle"]["bias_deg"] == pytest.approx(-2.0, rel=1e-5)
    assert errors["ankle"]["p95_deg"] == pytest.approx(np.percentile([6.0, 0.0, 0.0], 95), rel=1e-5)
    mean_mae = np.mean([e["mae_deg"] for e in errors.values()])
    assert mean_mae == pytest.approx(tracking_metrics(ro)["joint_mae_deg"], rel=1e-5)
    with pytest.raises(AmorError, match="3 joint angles recorded for 2 joint names"):
        joint_errors(ro, ("hip", "knee"))


# ---------------------------------------------------------------------------- trained toy policy
class _OraclePolicy:
    """Acts d = 2 w_right - 1 to the right of the observed state: every w gives a point on the true
    front r(d), d in [-1, 1], the right end for w = (1, 0) and the left end for w = (0, 1)."""

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return (obs[:, 0] + 2.0 * obs[:, -2] - 1.0)[:, None].astype(np.float32)


def test_sampled_front_matches_the_known_toy_front() -> None:
    from amorctl.analysis.front import summarize_front

    k, steps = 64, 15
    w = sample_dirichlet(np.random.default_rng(0), k, 2).astype(np.float64)
    w /= w.sum(axis=1, keepdims=True)
    env = ToyTradeoffEnv(k, max_steps=steps, hazard=0.0, seed=0)
    ro = rollout(_OraclePolicy(), env, w, episodes=2, record_steps=False)
    points = ro.episodes.by_env(k)  # [K, 2] mean returns over the 2 episodes
    expected = steps * toy_step_rewards(2.0 * w[:, 0] - 1.0)
    np.testing.assert_allclose(points, expected, rtol=1e-5)  # on the true front, point by point
    summary = summarize_front(points, w, [0.0, 0.0])
    assert summary.non_dominated_fraction == 1.0  # d in [-1, 1]: every point is Pareto-optimal
    # The sampled front's hypervolume approaches the true front's (a dense sample of the curve).
    true_hv = hypervolume(steps * toy_step_rewards(np.linspace(-1, 1, 4001)), [0.0, 0.0]).value
    assert summary.hypervolume.value == pytest.approx(true_hv, rel=0.05)
    assert summary.hypervolume.value <= true_hv


def test_trained_toy_front_is_near_the_true_front(toy_run: Path) -> None:
    policy = RunDir(toy_run).policy()
    k, steps = 32, 15
    w = np.vstack([sample_dirichlet(np.random.default_rng(0), k, 2), [[1.0, 0.0], [0.0, 1.0]]]).astype(float)
    w /= w.sum(axis=1, keepdims=True)
    env = ToyTradeoffEnv(len(w), max_steps=steps, hazard=0.0, seed=0)
    per_step = rollout(policy, env, w, episodes=2, record_steps=False).episodes.by_env(len(w)) / steps
    # Each weight's utility against the best possible for it (the true front's support function).
    ratio = np.einsum("km,km->k", w, per_step) / toy_support(w)
    assert (ratio <= 1 + 1e-6).all()  # nothing beyond the true front
    assert np.median(ratio) > 0.75 and ratio.min() > 0.5
    # The policy follows w: the one-objective weights reach opposite ends.
    assert per_step[-2, 0] > 0.6 > per_step[-2, 1] and per_step[-1, 1] > 0.6 > per_step[-1, 0]


def test_weight_sweep_yields_positive_rank_correlation(toy_run: Path) -> None:
    policy, config = RunDir(toy_run).policy(), RunDir(toy_run).config
    sweep = weight_sweep(policy, config, "right", levels=(0.0, 0.25, 0.5, 0.75, 1.0), episodes=8)
    assert sweep.returns.shape == (5, 8)
    assert sweep.spearman_rho > 0.5 and sweep.spearman_p < 0.01
    means = np.nanmean(sweep.returns, axis=1)
    assert means[-1] > means[0]
    np.testing.assert_allclose(sweep_levels_weights(0, 2, [0.0, 0.5, 1.0])[:, 1], [1.0, 0.5, 0.0])
    np.testing.assert_allclose(sweep_levels_weights(2, 4, [0.4, 0.1, 1.0])[0], [0.2, 0.2, 0.4, 0.2])


def _validate(doc: dict, schema: dict) -> None:
    import jsonschema

    jsonschema.Draft202012Validator.check_schema(schema)
    jsonschema.validate(doc, schema, cls=jsonschema.Draft202012Validator)


def test_pareto_cli_writes_files_and_json_validates(toy_run: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "front"
    code, stdout, err = run_cli(
        capsys, "pareto", str(toy_run), "--samples", "24", "--episodes", "2", "--out", str(out), "--json"
    )
    assert code == 0, err
    doc = json.loads(stdout)
    _validate(doc, PARETO_JSON_SCHEMA)
    assert doc["samples"] == 24 and doc["objectives"] == ["right", "left"]
    grp = doc["motions"][0]
    assert grp["motion"] == "all" and len(grp["points"]) == 24
    assert grp["hypervolume"]["method"] == "exact" and grp["hypervolume"]["value"] > 0
    assert 0 < grp["non_dominated_fraction"] <= 1
    assert grp["non_dominated_fraction"] == pytest.approx(np.mean(grp["non_dominated"]))
    for suffix in ("json", "csv", "png", "svg"):
        assert (out / f"pareto.{suffix}").stat().st_size > 0
    assert json.loads((out / "pareto.json").read_text()) == doc
    rows = (out / "pareto.csv").read_text().splitlines()
    assert len(rows) == 1 + 24 + 1 and rows[0].startswith("motion,sample,w_right,w_left,J_right")
    assert (out / "pareto.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # A grid and a fixed reference point: the hypervolume uses it.
    code, stdout, err = run_cli(
        capsys, "pareto", str(toy_run), "--grid", "4", "--ref-point", "right=0,left=0",
        "--out", str(tmp_path / "grid"), "--json",
    )  # fmt: skip
    assert code == 0, err
    doc = json.loads(stdout)
    assert doc["samples"] == 5 and doc["motions"][0]["hypervolume"]["reference_point"] == [0.0, 0.0]


def test_docs_print_the_json_schemas() -> None:
    for page, schema in (("pareto.md", PARETO_JSON_SCHEMA), ("evaluate.md", EVALUATE_JSON_SCHEMA)):
        text = (DOCS / page).read_text(encoding="utf-8")
        blocks = [json.loads(b) for b in re.findall(r"```json\n(.*?)```", text, flags=re.S)]
        assert schema in blocks, f"docs/{page} does not show the current schema"


def test_evaluate_cli_compare_and_sweep_on_toy(toy_run: Path, tmp_path: Path, capsys) -> None:
    code, stdout, err = run_cli(
        capsys, "evaluate", str(toy_run), "--weights", "right=1", "--compare", "--episodes", "4",
        "--sweep", "left", "--out", str(tmp_path), "--json",
    )  # fmt: skip
    assert code == 0, err
    doc = json.loads(stdout)
    _validate(doc, EVALUATE_JSON_SCHEMA)
    labels = [s["label"] for s in doc["settings"]]
    assert labels == ["uniform", "weights"]
    by = {s["label"]: s["metrics"] for s in doc["settings"]}
    assert by["weights"]["return/right"] > by["uniform"]["return/right"]
    assert by["weights"]["joint_mae_deg"] is None  # no reference motion in the toy env
    assert doc["sweep"]["spearman_rho"] > 0.5
    assert Path(doc["sweep"]["figure"]).read_bytes()[:4] == b"\x89PNG"
    levels = len(doc["sweep"]["levels"])
    assert doc["sweep"]["joint_vel_rms"] is None  # the toy env has no joints
    assert len(doc["sweep"]["action_rate"]) == levels and all(r > 0 for r in doc["sweep"]["action_rate"])
    assert all(n > 0 for n in doc["sweep"]["step_pairs"])


# ---------------------------------------------------------------------------- tracking run
def test_evaluate_tracking_metrics_per_motion_and_pareto_colours(
    tracking_run: Path, tmp_path, capsys
) -> None:
    code, stdout, err = run_cli(
        capsys, "evaluate", str(tracking_run), "--motion", "sway_a", "--motion", "sway_b",
        "--episodes", "2", "--json",
    )  # fmt: skip
    assert code == 0, err
    doc = json.loads(stdout)
    _validate(doc, EVALUATE_JSON_SCHEMA)
    metrics = doc["settings"][0]["metrics"]
    assert metrics["episodes"] == 4
    for key in ("joint_mae_deg", "joint_mae_deg/up", "joint_mae_deg/lo", "joint_mae_deg/feet", "mpjpe_mm"):
        assert metrics[key] is not None and 0 <= metrics[key] < 90, key
    assert set(doc["settings"][0]["per_motion"]) == {"sway_a", "sway_b"}
    assert doc["settings"][0]["per_joint"] == {}  # only with --per-joint
    code, stdout, err = run_cli(
        capsys, "evaluate", str(tracking_run), "--motion", "sway_a", "--motion", "sway_b",
        "--episodes", "2", "--per-joint", "--json",
    )  # fmt: skip
    assert code == 0, err
    doc = json.loads(stdout)
    _validate(doc, EVALUATE_JSON_SCHEMA)
    per_joint, joint_mae = doc["settings"][0]["per_joint"], doc["settings"][0]["metrics"]["joint_mae_deg"]
    character = get_registry().character(RunDir(tracking_run).config.env.character)
    assert list(per_joint) == list(character.joint_names())  # biped20's 20 joints, in action order
    assert np.mean([e["mae_deg"] for e in per_joint.values()]) == pytest.approx(joint_mae, rel=1e-4)
    assert all(abs(e["bias_deg"]) <= e["mae_deg"] + 1e-9 for e in per_joint.values())
    code, stdout, err = run_cli(capsys, "evaluate", str(tracking_run), "--episodes", "1", "--per-joint")
    assert code == 0, err
    worst = max(per_joint, key=lambda j: per_joint[j]["mae_deg"])
    assert "Error per joint (deg)" in stdout and worst in stdout
    code, stdout, err = run_cli(
        capsys, "pareto", str(tracking_run), "--motion", "sway_a", "--motion", "sway_b", "--samples", "3",
        "--out", str(tmp_path / "p"), "--json",
    )  # fmt: skip
    assert code == 0, err
    doc = json.loads(stdout)
    _validate(doc, PARETO_JSON_SCHEMA)
    assert [g["motion"] for g in doc["motions"]] == ["sway_a", "sway_b"]
    assert len(doc["motions"][0]["pairwise_non_dominated"]) == 21  # 7 objectives: 21 panels


def test_tracking_sweep_reports_action_rate_and_joint_velocity_per_level(tracking_run: Path, capsys) -> None:
    code, stdout, err = run_cli(
        capsys, "evaluate", str(tracking_run), "--sweep", "smooth", "--levels", "0,0.5,1",
        "--episodes", "2", "--json",
    )  # fmt: skip
    assert code == 0, err
    sweep = json.loads(stdout)["sweep"]
    assert len(sweep["action_rate"]) == len(sweep["joint_vel_rms"]) == len(sweep["step_pairs"]) == 3
    assert all(0 < r < 10 for r in sweep["action_rate"])  # rad² per step, summed over 20 joints
    assert all(0 < v < 50 for v in sweep["joint_vel_rms"])  # rad/s
    assert all(n > 0 for n in sweep["step_pairs"])


def test_video_decodes_with_expected_frames_and_is_not_blank(
    tracking_run: Path, tmp_path: Path, capsys
) -> None:
    import imageio.v3 as iio

    video = tmp_path / "clip.mp4"
    code, stdout, err = run_cli(
        capsys, "evaluate", str(tracking_run), "--schedule", str(_schedule(tmp_path)), "--episodes", "1",
        "--video", str(video), "--video-seconds", "0.3", "--json",
    )  # fmt: skip
    if code != 0 and "no headless OpenGL backend" in err:
        pytest.skip(f"no GL backend: {err.strip()}")
    assert code == 0, err
    doc = json.loads(stdout)
    assert doc["video"]["frames"] == 15  # 0.3 s at 50 Hz (the episode lasts 0.4 s)
    frames = iio.imread(video)
    assert frames.shape == (15, 360, 480, 3)
    assert frames.std() > 10  # not blank
    assert np.abs(frames[-1].astype(int) - frames[0].astype(int)).mean() > 0.5  # it moves
    # The weight bars change with the schedule: the up bar (first row) grows.
    bars = frames[:, 10:20, 40:140, :].astype(int)
    assert bars[-1].sum() != bars[0].sum()


def _schedule(tmp_path: Path) -> Path:
    path = tmp_path / "sched.toml"
    path.write_text(
        "[[keyframe]]\nt = 0.0\nweights = { lo = 1 }\n\n[[keyframe]]\nt = 0.3\nweights = { up = 1 }\n",
        encoding="utf-8",
    )
    return path


# ---------------------------------------------------------------------------- bad input
def test_bad_input_gives_clear_errors(toy_run: Path, tracking_run: Path, tmp_path: Path, capsys) -> None:
    empty = tmp_path / "empty-run"
    (empty / "checkpoints").mkdir(parents=True)
    (empty / "config.toml").write_text((toy_run / "config.toml").read_text())
    cases = [
        (("pareto", str(empty)), "no checkpoint"),
        (("evaluate", str(tmp_path / "nowhere")), "not a run directory"),
        (("pareto", str(tracking_run), "--motion", "moonwalk", "--samples", "2"), "no motion 'moonwalk'"),
        (("evaluate", str(toy_run), "--motion", "walk"), "needs a motion-tracking run"),
        (("evaluate", str(toy_run), "--sweep", "smooth"), "unknown objective 'smooth'"),
        (("evaluate", str(toy_run), "--weights", "up=1"), "unknown objective 'up'"),
        (("evaluate", str(toy_run), "--weights", "right"), "not name=value"),
        (("evaluate", str(toy_run), "--weights", "right=x"), "not a number"),
        (("pareto", str(toy_run), "--samples", "0"), "--samples must be >= 1"),
        (("pareto", str(toy_run), "--ref-point", "1,2,3"), "needs 2 numbers"),
        (("evaluate", str(toy_run), "--sweep", "right", "--levels", "0,1"), "at least 3 levels"),
        (("evaluate", str(toy_run), "--video", str(tmp_path / "v.gif")), "must end in .mp4"),
        (("evaluate", str(toy_run), "--per-joint"), "--per-joint needs a motion-tracking run"),
    ]
    for argv, message in cases:
        code, _, err = run_cli(capsys, *argv)
        assert code != 0, argv
        assert message in err, (argv, err)
        assert err.startswith("error: ") and "Traceback" not in err
    assert not (empty / "pareto").exists()  # nothing written on failure


def test_parse_reference_point() -> None:
    np.testing.assert_allclose(parse_reference_point("1, 2", ["a", "b"]), [1.0, 2.0])
    np.testing.assert_allclose(parse_reference_point("b=3,a=-1", ["a", "b"]), [-1.0, 3.0])
    with pytest.raises(AmorError, match="no value for b"):
        parse_reference_point("a=1", ["a", "b"])
