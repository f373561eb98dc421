"""pareto, evaluate, tune and render against a stub backend that implements only the contracts.

The stub (``stub-numpy``, registered through the plugin registry like a third-party plugin) is a
numpy kinematic "tracker": joint angles jump to the action, and each clip's reference holds every
joint at one angle (``wave`` 0.4 rad, ``bend`` 0.2 rad). Its policy acts ``a = w_pose * target``,
so every number the commands report has a closed form: under ``w = (w_pose, w_effort)`` the joint
error is ``(1 - w_pose) * c`` each step, the pose reward ``-(1 - w_pose) * c`` and the effort
reward ``-(w_pose * c)^2``. If analysis reached into the torch-cpu env instead of the contracts,
these commands would fail here.
"""

from __future__ import annotations

import json
import types
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest

from amorctl.api import hookimpl
from amorctl.cli.main import main
from amorctl.core.config import TrainConfig, merge
from amorctl.core.contracts import Backend, Policy, Snapshot, TrackingView, Trainer, tracking_view
from amorctl.core.frame_layout import frame_dim
from amorctl.core.specs import BackendSpec, CharacterSpec
from amorctl.core.vecenv import RewardSpace, VectorEnv
from amorctl.core.weights import sample_dirichlet
from amorctl.registry import get_registry, load_registry, reset_registry

NAME = "stub-numpy"
CLIPS = {"wave": 0.4, "bend": 0.2}  # clip -> the angle every joint holds, rad
CLIP_FRAMES = 30
OBJECTIVES = ("pose", "effort")
EPISODE_STEPS = 10  # 0.2 s at 50 Hz


# ---------------------------------------------------------------------------- the stub backend
def _frame_vectors(q: np.ndarray, num_ee: int) -> np.ndarray:
    """Frame vectors [..., Df] of joint angles q [..., J]: height 0.5, joints, end effector e at
    (q_e, 0, 0) relative to the root; everything else 0."""
    j = q.shape[-1]
    out = np.zeros((*q.shape[:-1], frame_dim(j, num_ee)))
    out[..., 0] = 0.5
    out[..., 13 : 13 + j] = q
    out[..., 13 + 2 * j : 13 + 2 * j + 9 * num_ee : 9] = q[..., :num_ee]
    return out


class StubView:
    """The stub env's :class:`TrackingView`."""

    def __init__(self, env: StubEnv) -> None:
        self._env = env
        self.character = env.character
        self.dt = env.dt
        self.max_episode_steps = env.max_episode_steps
        self.num_envs = env.num_envs
        self.fall_drop = 0.3
        self.future_frames: tuple[int, ...] = ()

    model = property(lambda self: self._env.model)
    clip_names = property(lambda self: tuple(CLIPS))
    clip_seconds = property(lambda self: np.full(len(CLIPS), (CLIP_FRAMES - 1) * self.dt))
    clip_frame_counts = property(lambda self: np.full(len(CLIPS), CLIP_FRAMES))
    joint_names = property(lambda self: self.character.joint_names())
    weights = property(lambda self: self._env.weights)
    observation_layout = property(lambda self: self._env.layout)

    def clip_index(self) -> np.ndarray:
        return self._env.ref_idx // CLIP_FRAMES

    def reference_index(self) -> np.ndarray:
        return self._env.ref_idx.copy()

    def reference_joint_pos(self, frames: np.ndarray) -> np.ndarray:
        return self._env.ref_q[np.asarray(frames, dtype=np.int64)].copy()

    def reference_frames(self, frames: np.ndarray) -> np.ndarray:
        return _frame_vectors(self.reference_joint_pos(frames), len(self.character.end_effectors))

    def reference_qpos(self, frames: np.ndarray) -> np.ndarray:
        return self._env.qpos_of(self.reference_joint_pos(frames))

    def qpos(self) -> np.ndarray:
        return self._env.qpos_of(self._env.q)

    def joint_pos(self) -> np.ndarray:
        return self._env.q.copy()

    def joint_vel(self) -> np.ndarray:
        return (self._env.q - self._env.q_prev) / self.dt

    def end_effector_pos(self) -> np.ndarray:
        e = len(self.character.end_effectors)
        out = np.zeros((self.num_envs, e, 3))
        out[:, :, 0] = self._env.q[:, :e]
        return out

    def select_clips(
        self,
        clips: Sequence[int] | None = None,
        env_clips: np.ndarray | None = None,
        from_start: bool = False,
    ) -> None:
        self._env.clips = np.arange(len(CLIPS)) if clips is None else np.asarray(clips, dtype=np.int64)
        self._env.env_clips = None if env_clips is None else np.asarray(env_clips, dtype=np.int64)
        self._env.from_start = from_start


class StubEnv:
    """A numpy :class:`VectorEnv`: joint angles become the action; reference clips of constant pose."""

    def __init__(self, character: CharacterSpec, num_envs: int, max_episode_steps: int, seed: int) -> None:
        from amorctl.sim.batch_sim import build_model

        self.character, self.num_envs, self.max_episode_steps = character, num_envs, max_episode_steps
        self.dt = 1.0 / character.control_hz
        self.model = build_model(character)
        j, e, m = character.num_joints, len(character.end_effectors), len(OBJECTIVES)
        self.joint_qpos = np.array(
            [self.model.jnt_qposadr[mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, n)]
             for n in character.joint_names()]
        )  # fmt: skip
        self.ref_q = np.repeat(np.array(list(CLIPS.values())), CLIP_FRAMES)[:, None] * np.ones(j)  # [F, J]
        df = frame_dim(j, e)
        self.layout = {"proprio": (0, df), "targets": (df, df + j), "weights": (df + j, df + j + m)}
        self.obs_dim, self.action_dim = df + j + m, j
        self.reward_space = RewardSpace(
            OBJECTIVES, ("joint tracking", "action size"), np.full(m, -np.inf), np.zeros(m)
        )
        self.clips, self.env_clips, self.from_start = np.arange(len(CLIPS)), None, False
        self.rng = np.random.default_rng(seed)
        self.q = np.zeros((num_envs, j))
        self.q_prev = self.q.copy()
        self.ref_idx = np.zeros(num_envs, dtype=np.int64)
        self.steps = np.zeros(num_envs, dtype=np.int64)
        self._weights = np.zeros((num_envs, m), dtype=np.float32)

    weights = property(lambda self: self._weights.copy())

    def tracking_view(self) -> StubView:
        return StubView(self)

    def qpos_of(self, q: np.ndarray) -> np.ndarray:
        out = np.zeros((q.shape[0], self.model.nq))
        out[:, 2], out[:, 3] = 0.5, 1.0  # the root stands at 0.5 m, unrotated
        out[:, self.joint_qpos] = q
        return out

    def _reset(self, ids: np.ndarray) -> None:
        k = len(ids)
        clips = (
            self.env_clips[ids]
            if self.env_clips is not None
            else self.clips[self.rng.integers(len(self.clips), size=k)]
        )
        offset = 0 if self.from_start else self.rng.integers(0, CLIP_FRAMES - 2, size=k)
        self.ref_idx[ids] = clips * CLIP_FRAMES + offset
        self.q[ids] = self.q_prev[ids] = self.ref_q[self.ref_idx[ids]]
        self.steps[ids] = 0
        self._weights[ids] = sample_dirichlet(self.rng, k, len(OBJECTIVES))

    def _obs(self) -> np.ndarray:
        e = len(self.character.end_effectors)
        return np.concatenate(
            [_frame_vectors(self.q, e), self.ref_q[self.ref_idx + 1], self._weights], axis=1, dtype=np.float32
        )

    def reset(self, seed: int | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self._reset(np.arange(self.num_envs))
        return self._obs(), {}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        a = np.asarray(actions, dtype=np.float64)
        target = self.ref_idx + 1
        self.q_prev, self.q = self.q, a.copy()
        rewards = np.stack([-np.abs(a - self.ref_q[target]).mean(axis=1), -(a**2).mean(axis=1)], axis=1)
        self.steps += 1
        # at a clip's last frame the reference restarts the clip (as the real env's pinned clips do)
        self.ref_idx = np.where(target % CLIP_FRAMES == CLIP_FRAMES - 1, target - (CLIP_FRAMES - 1), target)
        truncated = self.steps >= self.max_episode_steps
        obs = self._obs()
        final = obs.copy()
        if truncated.any():
            self._reset(np.flatnonzero(truncated))
            obs = self._obs()
        terminated = np.zeros(self.num_envs, dtype=bool)
        return obs, rewards.astype(np.float32), terminated, truncated, {"final_obs": final}

    def close(self) -> None:
        self.closed = True


class StubPolicy:
    """``a = gain * w_pose * target``: perfect tracking under w = (1, 0), stillness under (0, 1)."""

    def __init__(
        self, gain: float, layout: Mapping[str, tuple[int, int]], obs_dim: int, action_dim: int
    ) -> None:
        self.gain, self.layout = gain, dict(layout)
        self.objectives, self.obs_dim, self.action_dim = OBJECTIVES, obs_dim, action_dim

    @property
    def observation_layout(self) -> Mapping[str, tuple[int, int]]:
        return self.layout

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        t, w = slice(*self.layout["targets"]), slice(*self.layout["weights"])
        return (self.gain * obs[:, w][:, :1] * obs[:, t]).astype(np.float32)

    def values(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((obs.shape[0], len(self.objectives)), dtype=np.float32)

    def export_arrays(self) -> Snapshot:
        return Snapshot({"gain": np.array([self.gain])}, {"layout": self.layout})


class StubTrainer:
    """Steps the env with the policy; its one parameter is the policy's gain (always 1)."""

    def __init__(self, env: StubEnv) -> None:
        self.env, self.iteration_count = env, 0
        self.policy = StubPolicy(1.0, env.layout, env.obs_dim, env.action_dim)
        self.obs, _ = env.reset(seed=0)

    def iteration(self) -> dict[str, float]:
        total = np.zeros(len(OBJECTIVES))
        for _ in range(4):
            self.obs, r, _, _, _ = self.env.step(self.act(self.obs))
            total += r.mean(axis=0)
        self.iteration_count += 1
        return {
            "iteration": float(self.iteration_count),  # the metrics log's row key
            "loss/value": 0.0,
            **{f"return/{n}": float(v) for n, v in zip(OBJECTIVES, total, strict=True)},
        }

    def state_dict(self) -> Snapshot:
        env = self.env
        meta = {"obs_dim": env.obs_dim, "action_dim": env.action_dim, "objectives": list(OBJECTIVES),
                "layout": env.layout, "iteration": self.iteration_count}  # fmt: skip
        return Snapshot({"gain": np.array([self.policy.gain])}, meta)

    def load_state_dict(self, state: Snapshot) -> None:
        self.policy.gain = float(state.arrays["gain"][0])
        self.iteration_count = int(state.meta["iteration"])

    def reset_env(self, seed: int) -> None:
        self.obs, _ = self.env.reset(seed=seed)

    def act(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        return self.policy(obs)


class StubBackend:
    name = NAME

    def make_env(
        self,
        *,
        character: str,
        dataset: str | None = None,
        objective_set: str = "tracking7",
        num_envs: int = 256,
        episode_seconds: float = 10.0,
        seed: int = 0,
        **options: Any,
    ) -> StubEnv:
        spec = get_registry().character(character)
        return StubEnv(spec, num_envs, max(1, round(episode_seconds * spec.control_hz)), seed)

    def make_trainer(self, env: VectorEnv, config: TrainConfig) -> StubTrainer:
        return StubTrainer(env)  # type: ignore[arg-type]

    def load_policy(self, trainer_state: Snapshot, config: TrainConfig) -> StubPolicy:
        meta = trainer_state.meta
        layout = {k: tuple(v) for k, v in meta["layout"].items()}
        return StubPolicy(float(trainer_state.arrays["gain"][0]), layout, meta["obs_dim"], meta["action_dim"])


def _stub_registry() -> Any:
    plugin = types.ModuleType("stub_backend_plugin")
    plugin.amorctl_register_backends = hookimpl(  # type: ignore[attr-defined]
        lambda register: register(BackendSpec(NAME, "numpy stub (tests)", make=StubBackend))
    )
    return load_registry(extra_plugins=[("stub_backend", plugin, "stub-pkg", "0.1")])


@pytest.fixture(scope="module")
def stub_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run directory of the stub backend (config + one checkpoint), written by ``train_run``."""
    import amorctl.registry
    from amorctl.train.loop import train_run

    out = tmp_path_factory.mktemp("stub") / "run"
    amorctl.registry._CACHED = _stub_registry()
    try:
        config = merge(
            TrainConfig(),
            {"run": {"backend": NAME, "iterations": 2, "checkpoint_every": 2, "tensorboard": False},
             "env": {"kind": "tracking", "character": "biped20", "num_envs": 4, "episode_seconds": 0.2}},
            "stub run",
        )  # fmt: skip
        train_run(config, out)
    finally:
        reset_registry()
    return out


@pytest.fixture(autouse=True)
def _with_stub(_fresh_registry: None, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("amorctl.registry._CACHED", _stub_registry())


def _cli(capsys: pytest.CaptureFixture, *argv: str) -> dict[str, Any]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out)


def _pose_error(w_pose: float, c: float) -> float:
    return (1.0 - w_pose) * c


# ---------------------------------------------------------------------------- the tests
def test_the_stub_implements_every_contract(stub_run: Path) -> None:
    backend = get_registry().backend(NAME).make()
    assert isinstance(backend, Backend)
    env = backend.make_env(character="biped20", num_envs=3, episode_seconds=0.2)
    assert isinstance(env, VectorEnv) and isinstance(tracking_view(env), TrackingView)
    assert isinstance(backend.make_trainer(env, TrainConfig()), Trainer)
    from amorctl.train.rundir import RunDir

    policy = RunDir.open(stub_run).policy()
    assert isinstance(policy, Policy) and policy.objectives == OBJECTIVES


def test_evaluate_reports_closed_form_tracking_metrics(stub_run: Path, capsys: pytest.CaptureFixture) -> None:
    import jsonschema

    from amorctl.analysis.schemas import EVALUATE_JSON_SCHEMA

    doc = _cli(capsys, "evaluate", str(stub_run), "--compare", "-w", "pose=1", "-m", "wave", "-m", "bend",
               "-e", "3", "--json")  # fmt: skip
    jsonschema.validate(doc, EVALUATE_JSON_SCHEMA)
    uniform, pose_only = doc["settings"]
    assert (uniform["label"], pose_only["label"]) == ("uniform", "weights")
    for setting, w_pose in ((uniform, 0.5), (pose_only, 1.0)):
        for motion, c in CLIPS.items():
            metrics = setting["per_motion"][motion]
            err = _pose_error(w_pose, c)
            assert metrics["joint_mae_deg"] == pytest.approx(np.degrees(err), abs=1e-4)
            for group in ("up", "lo", "feet"):
                assert metrics[f"joint_mae_deg/{group}"] == pytest.approx(np.degrees(err), abs=1e-4)
            assert metrics["mpjpe_mm"] == pytest.approx(1000 * err, abs=1e-3)
            assert metrics["survival_rate"] == 1.0 and metrics["episodes"] == 3
            assert metrics["episode_length_s"] == pytest.approx(0.2)
            assert metrics["return/pose"] == pytest.approx(-EPISODE_STEPS * err, abs=1e-5)
            assert metrics["return/effort"] == pytest.approx(-EPISODE_STEPS * (w_pose * c) ** 2, abs=1e-5)
    mean_err = np.mean([_pose_error(0.5, c) for c in CLIPS.values()])
    assert uniform["metrics"]["joint_mae_deg"] == pytest.approx(np.degrees(mean_err), abs=1e-4)


def test_pareto_front_is_the_closed_form_trade_off(
    stub_run: Path, capsys: pytest.CaptureFixture, tmp_path: Path
) -> None:
    doc = _cli(capsys, "pareto", str(stub_run), "-m", "bend", "--grid", "4", "--out", str(tmp_path), "--json")
    (group,) = doc["motions"]
    w = np.array(doc["weights"])
    c = CLIPS["bend"]
    want = np.stack([-EPISODE_STEPS * (1 - w[:, 0]) * c, -EPISODE_STEPS * (w[:, 0] * c) ** 2], axis=1)
    np.testing.assert_allclose(group["points"], want, atol=1e-5)
    np.testing.assert_allclose(
        group["equal_weights_point"], [-EPISODE_STEPS * 0.5 * c, -EPISODE_STEPS * 0.25 * c * c], atol=1e-5
    )
    assert group["non_dominated"] == [True] * len(w)  # a strict trade-off: every weight is on the front
    assert group["survival"] == [1.0] * len(w)
    assert doc["episode_seconds"] == pytest.approx(0.2)
    assert (tmp_path / "pareto.csv").read_text().count("\n") == len(w) + 2


def test_tune_rolls_the_pinned_motion_out_with_its_ghost(stub_run: Path) -> None:
    from amorctl.tune.session import PinnedMotion, run_tune

    tenv = PinnedMotion(stub_run, "bend")
    assert tenv.motion == "bend" and tenv.motions == tuple(CLIPS)
    assert tenv.motion_seconds == pytest.approx((CLIP_FRAMES - 1) * 0.02)
    rollout = run_tune(tenv, np.array([1.0, 0.0]), seconds=0.1)
    assert len(rollout.times) == 5 and not rollout.terminated.any()
    np.testing.assert_allclose(rollout.joint_pos, CLIPS["bend"])
    np.testing.assert_allclose(rollout.ref_joint_pos, CLIPS["bend"])
    np.testing.assert_allclose(rollout.returns, [0.0, -5 * CLIPS["bend"] ** 2], atol=1e-6)
    assert rollout.qpos is not None and rollout.ref_qpos is not None
    np.testing.assert_allclose(rollout.ref_qpos, rollout.qpos)  # perfect tracking: the ghost coincides
    np.testing.assert_allclose(rollout.ref_body_pos, rollout.body_pos, atol=1e-12)
    half = run_tune(tenv, np.array([0.5, 0.5]), seconds=0.1)
    np.testing.assert_allclose(half.joint_pos, 0.5 * CLIPS["bend"])
    assert not np.allclose(half.ref_body_pos, half.body_pos)
    tenv.close()


@pytest.mark.parametrize("command", ["tune", "evaluate"])
def test_videos_are_given_the_reference_ghost(
    command: str,
    stub_run: Path,
    capsys: pytest.CaptureFixture,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import amorctl.outputs.video as video

    calls: list[dict[str, Any]] = []

    def fake_render(path: Any, character: str, qpos: np.ndarray, **kw: Any) -> video.VideoInfo:
        calls.append({"character": character, "qpos": qpos, **kw})
        return video.VideoInfo(Path(path), len(qpos), 16, 16, kw["fps"], "fake")

    monkeypatch.setattr(video, "render_video", fake_render)
    length = ["--seconds", "0.1"] if command == "tune" else ["--video-seconds", "0.1"]
    _cli(capsys, command, str(stub_run), "-m", "wave", "-w", "pose=1,effort=1", *length,
         "--video", str(tmp_path / "v.mp4"), "--json")  # fmt: skip
    (call,) = calls
    assert call["character"] == "biped20" and call["fps"] == pytest.approx(50.0)
    joints = StubBackend().make_env(character="biped20", num_envs=1).joint_qpos
    assert call["qpos"].shape == call["ref_qpos"].shape == (5, 27)
    np.testing.assert_allclose(call["ref_qpos"][:, joints], CLIPS["wave"])  # the ghost: the reference
    np.testing.assert_allclose(call["qpos"][:, joints], 0.5 * CLIPS["wave"])  # w = (1/2, 1/2)
    np.testing.assert_allclose(call["weights"], 0.5)


def test_rendered_ghost_shows_in_the_ghost_colour(stub_run: Path, tmp_path: Path) -> None:
    import imageio.v3 as iio

    from amorctl.core.errors import AmorError
    from amorctl.outputs.video import GHOST_RGBA, render_video
    from amorctl.tune.session import PinnedMotion, run_tune

    tenv = PinnedMotion(stub_run, "wave")
    rollout = run_tune(tenv, np.array([0.5, 0.5]), seconds=0.02)
    tenv.close()
    assert rollout.qpos is not None and rollout.ref_qpos is not None
    # one video, two identical frames of the character: the ghost in frame 0, moved out of view
    # (1 km away) in frame 1, so the frames differ exactly where the ghost is drawn
    qpos = np.repeat(rollout.qpos[:1], 2, axis=0)
    ref = np.repeat(rollout.ref_qpos[:1], 2, axis=0)
    ref[1, 0] += 1000.0
    try:
        render_video(
            tmp_path / "g.mp4", "biped20", qpos, ref_qpos=ref, width=160, height=120, ghost_alpha=1.0
        )
    except AmorError as err:
        if "no headless OpenGL" in str(err):
            pytest.skip(f"no GL backend: {err}")
        raise
    frames = iio.imread(tmp_path / "g.mp4").astype(int)  # [2, H, W, 3]
    changed = np.abs(frames[0] - frames[1]).max(axis=-1) > 40  # [H, W]: where the ghost is drawn
    assert changed.sum() > 100, changed.sum()
    mean = frames[0][changed].mean(axis=0)  # [3] the colour there: the ghost's hue (blue > green > red)
    ghost = np.array(GHOST_RGBA)
    assert np.argsort(mean).tolist() == np.argsort(ghost).tolist(), (mean, ghost)
