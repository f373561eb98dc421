"""Unit tests of the HLP's parts: softmax head, GAE, windows, discriminator loss, GP, conditioning."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import frame_dim
from amorctl.core.gae import gae
from amorctl.hlp.config import HlpConfig, load_hlp_preset, merge, to_toml
from amorctl.hlp.discriminator import (
    Discriminator,
    DiscriminatorLearner,
    ReplayBuffer,
    discriminator_loss,
    gradient_penalty,
    reward_from_logits,
)
from amorctl.hlp.policy import HlpActorCritic, hlp_normalizer, softmax_weights
from amorctl.hlp.windows import DatasetWindows, WindowHistory, WindowSpec, observation_slices


@pytest.fixture(autouse=True)
def _one_thread():
    """Small networks: one torch thread is fastest, and the machine's cores are shared."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


# --- the softmax head ------------------------------------------------------------------------------
def _assert_simplex(w: np.ndarray) -> None:
    assert np.isfinite(w).all()
    assert (w >= 0).all()
    np.testing.assert_allclose(w.sum(-1), 1.0, atol=1e-6)


def test_softmax_weights_on_simplex_for_random_and_extreme_logits() -> None:
    rng = np.random.default_rng(0)
    random = torch.as_tensor(rng.normal(0, 5, size=(1000, 7)))
    extreme = torch.tensor(
        [[1e30, -1e30, 0, 0, 0, 0, 0], [-1e30] * 7, [1e4] * 3 + [-1e4] * 4, [88.0, 89.0, 90.0, -200, 0, 0, 0]]
    )
    for logits in (random, extreme):
        w = softmax_weights(logits).numpy()
        _assert_simplex(w)
    w = softmax_weights(torch.tensor([[1e30, -1e30, 0.0]])).numpy()
    np.testing.assert_allclose(w, [[1.0, 0.0, 0.0]])
    np.testing.assert_allclose(softmax_weights(torch.zeros(1, 4)).numpy(), 0.25, atol=1e-7)


def test_actor_samples_lie_on_simplex_even_with_huge_spread() -> None:
    torch.manual_seed(0)
    model = HlpActorCritic(6, 5, (8, 8, 8), (8, 8, 8), init_std=1e3, obs_clip=10.0)
    obs = np.random.default_rng(1).normal(0, 100, size=(512, 6)).astype(np.float32)
    gen = torch.Generator().manual_seed(0)
    w, u, logp, v = model.act(obs, gen)
    _assert_simplex(w)
    assert w.max() > 0.999  # the spread pushes samples into corners, still on the simplex
    assert u.shape == (512, 5) and logp.shape == v.shape == (512,)
    w_det, _, _, _ = model.act(obs, None, deterministic=True)
    _assert_simplex(w_det)
    np.testing.assert_allclose(w_det, 0.2, atol=0.05)  # the small last layer starts near uniform


# --- PPO pieces ------------------------------------------------------------------------------------
def test_gae_matches_hand_computation_and_bootstraps_truncation() -> None:
    g, lam = 0.9, 0.5
    r = np.array([[1.0], [2.0], [3.0]])
    v = np.array([[0.5], [1.0], [1.5]])
    nv = np.array([[1.0], [4.0], [10.0]])  # step 1 ended truncated in a state worth 4
    term = np.zeros((3, 1), dtype=bool)
    truncated = np.array([[False], [True], [False]])
    adv, ret = gae(r, v, nv, term, truncated, g, lam)
    d2 = 3 + g * 10 - 1.5
    d1 = 2 + g * 4 - 1.0
    d0 = 1 + g * 1.0 - 0.5
    want = [d0 + g * lam * d1, d1, d2]
    np.testing.assert_allclose(adv[:, 0], want, rtol=1e-6)
    np.testing.assert_allclose(ret[:, 0], np.array(want) + v[:, 0], rtol=1e-6)
    adv_t, _ = gae(r, v, nv, truncated, term, g, lam)  # terminated instead: no bootstrap
    assert adv_t[1, 0] == pytest.approx(2 - 1.0)


def test_running_norm_matches_numpy_statistics() -> None:
    rng = np.random.default_rng(2)
    x = rng.normal(3.0, 2.0, size=(300, 4))
    norm = hlp_normalizer(4)
    for chunk in np.split(x, [50, 170]):
        norm.update(torch.as_tensor(chunk))
    np.testing.assert_allclose(norm.mean.numpy(), x.mean(0), rtol=1e-10)
    np.testing.assert_allclose(norm.var.numpy(), x.var(0), rtol=1e-10)


# --- windows ---------------------------------------------------------------------------------------
def _tiny_library(j: int = 2, e: int = 1, lengths: tuple[int, ...] = (5, 4), latent: int = 3):
    from amorctl.motion.clips import ClipInfo, MotionLibrary

    f = sum(lengths)
    d = frame_dim(j, e)
    frames = np.arange(f * d, dtype=np.float32).reshape(f, d)
    clips, start = [], 0
    for k, n in enumerate(lengths):
        clips.append(ClipInfo(f"c{k}", "x", "0", "test", start, n, 50.0))
        start += n
    zeros = lambda *s: np.zeros((f, *s), dtype=np.float32)  # noqa: E731
    z = np.repeat(np.arange(f, dtype=np.float32)[:, None], latent, axis=1)
    lib = MotionLibrary(
        "toy", 50.0, tuple(f"j{i}" for i in range(j)), tuple(f"e{i}" for i in range(e)), tuple(clips),
        zeros(3), zeros(4), zeros(3), zeros(3), zeros(j), zeros(j), zeros(e, 3), zeros(e, 4), zeros(e, 3),
        frames, z,
    )  # fmt: skip
    return lib


def test_window_features_take_rot6d_velocities_and_joint_angles() -> None:
    spec = WindowSpec(window=3, num_joints=2, num_ee=1)
    frame = np.arange(frame_dim(2, 1), dtype=np.float32)[None]
    # layout: h [0], rot6d [1:7], lin vel [7:10], ang vel [10:13], q [13:15], qdot [15:17], ...
    np.testing.assert_array_equal(spec.features(frame)[0], np.r_[np.arange(1, 13), 13, 14])
    assert spec.frame_features == 14 and spec.size == 42
    with pytest.raises(AmorError, match="frame vectors have"):
        spec.features(np.zeros((1, 10), dtype=np.float32))


def test_dataset_windows_stay_in_clip_and_pair_z_of_next_frame() -> None:
    lib = _tiny_library()
    spec = WindowSpec(3, 2, 1)
    ds = DatasetWindows(lib, spec)
    # full windows only: end frames 2, 3 of clip 0 (frames 0-4) and 7 of clip 1 (frames 5-8)
    np.testing.assert_array_equal(ds.ends, [2, 3, 7])
    feats = spec.features(lib.frames)
    row = int(np.flatnonzero(ds.ends == 3)[0])
    np.testing.assert_array_equal(ds.windows_at(np.array([row]))[0], feats[1:4].ravel())
    padded = DatasetWindows(lib, WindowSpec(6, 2, 1))  # no clip holds 6 + 1 frames: padded windows
    assert len(padded) == (5 - 1) + (4 - 1)
    row = int(np.flatnonzero(padded.ends == 5)[0])  # the second clip's first frame repeats
    np.testing.assert_array_equal(padded.windows_at(np.array([row]))[0], np.tile(feats[5], 6))
    _, z, rows = ds.sample(np.random.default_rng(0), 64)
    np.testing.assert_array_equal(z[:, 0], ds.ends[rows] + 1)  # z of the frame after the window
    mw, mz = ds.mismatched(np.random.default_rng(1), 64)
    # every mismatched z comes from the other clip: its frame index is not in the window's clip
    own_last = mw.reshape(64, 3, -1)[:, -1, -2]  # joint 0 angle of the last frame identifies it
    frame_of = ((own_last - 13) / frame_dim(2, 1)).astype(int)
    clip_of_window = (frame_of >= 5).astype(int)
    clip_of_z = (mz[:, 0] >= 5).astype(int)
    assert (clip_of_window != clip_of_z).all()


def test_window_history_rolls_and_resets() -> None:
    spec = WindowSpec(3, 1, 0)
    h = WindowHistory(2, spec)
    f = lambda v: np.full((2, spec.frame_features), v, dtype=np.float32)  # noqa: E731
    h.reset(np.arange(2), f(1))
    h.push(f(2))
    h.push(f(3))
    np.testing.assert_array_equal(h.buf[0, :, 0], [1, 2, 3])
    assert h.full().all()
    h.reset(np.array([1]), f(9)[:1])
    np.testing.assert_array_equal(h.buf[1, :, 0], [9, 9, 9])
    np.testing.assert_array_equal(h.buf[0, :, 0], [1, 2, 3])
    np.testing.assert_array_equal(h.full(), [True, False])
    h.push(f(4))
    np.testing.assert_array_equal(h.full(), [True, False])
    h.push(f(5))
    np.testing.assert_array_equal(h.full(), [True, True])


def test_observation_slices_need_proprio_and_matching_latent() -> None:
    layout = {"proprio": (0, 10), "latent": (20, 23), "weights": (23, 25)}
    assert observation_slices(layout, 3) == (slice(0, 10), slice(20, 23))
    assert observation_slices({"proprio": slice(0, 10), "context": (10, 23)}, 3)[1] == slice(20, 23)
    with pytest.raises(AmorError, match="latent"):
        observation_slices(layout, 4)
    with pytest.raises(AmorError, match="proprio"):
        observation_slices({"observation": (0, 5)}, 3)


def test_replay_buffer_wraps_around() -> None:
    buf = ReplayBuffer(4, 2, 1)
    buf.add(np.arange(6, dtype=np.float32).reshape(3, 2), np.zeros((3, 1)))
    buf.add(np.full((3, 2), 7, dtype=np.float32), np.ones((3, 1)))
    assert buf.size == 4 and buf.head == 2
    np.testing.assert_array_equal(buf.windows[:, 0], [7, 7, 4, 7])


# --- the discriminator -----------------------------------------------------------------------------
def test_gradient_penalty_of_linear_d_equals_squared_weight_norm() -> None:
    torch.manual_seed(0)
    disc = Discriminator(window_size=3, latent_dim=2, hidden=(), z_hidden=())
    with torch.no_grad():
        disc.logit.weight.copy_(torch.tensor([[0.5, -1.0, 2.0, 0.25, -3.0]]))
    x = torch.randn(16, 3)
    z = torch.randn(16, 2)
    gp = gradient_penalty(disc, x, z)
    assert gp.item() == pytest.approx(0.25 + 1.0 + 4.0 + 0.0625 + 9.0, rel=1e-6)


def test_gradient_penalty_uses_dataset_samples_only() -> None:
    torch.manual_seed(0)
    disc = Discriminator(4, 2, hidden=(16,), z_hidden=(8,))
    pos = (torch.randn(32, 4) + 2, torch.randn(32, 2))
    neg_a = (torch.randn(32, 4) - 2, torch.randn(32, 2))
    neg_b = (torch.randn(32, 4) * 5, torch.randn(32, 2) * 5)
    a = discriminator_loss(disc, pos, neg_a, 5.0, 0.01, 1e-4)
    b = discriminator_loss(disc, pos, neg_b, 5.0, 0.01, 1e-4)
    assert a.gp.item() == pytest.approx(b.gp.item(), rel=1e-12)  # negatives do not enter the GP
    assert a.gp.item() == pytest.approx(gradient_penalty(disc, *pos).item(), rel=1e-12)
    assert a.gp.item() != pytest.approx(gradient_penalty(disc, *neg_a).item(), rel=1e-3)
    l2 = disc.logit.weight.pow(2).sum().item()
    decay = sum(w.pow(2).sum().item() for w in disc.weights())
    want = a.bce_dataset.item() + a.bce_negative.item() + 5.0 * a.gp.item() + 0.01 * l2 + 1e-4 * decay
    assert a.total.item() == pytest.approx(want, rel=1e-6)


def _learner(latent: int, seed: int = 0) -> DiscriminatorLearner:
    z_hidden = (16,) if latent else ()
    return DiscriminatorLearner(4, latent, (32, 32), z_hidden, 5.0, 0.01, 1e-4, 3e-3, seed)


def test_discriminator_loss_decreases_when_dataset_and_policy_differ() -> None:
    rng = np.random.default_rng(0)
    learner = _learner(2)
    z = lambda n: rng.normal(size=(n, 2)).astype(np.float32)  # noqa: E731
    losses = []
    for _ in range(150):
        pos = (rng.normal(1.0, 1.0, (128, 4)).astype(np.float32), z(128))
        neg = (rng.normal(-1.0, 1.0, (128, 4)).astype(np.float32), z(128))
        losses.append(learner.step(pos, neg)["loss"])
    assert np.mean(losses[-20:]) < np.mean(losses[:5]) - 0.3
    test_pos = learner.logits(rng.normal(1.0, 1.0, (500, 4)).astype(np.float32), z(500))
    test_neg = learner.logits(rng.normal(-1.0, 1.0, (500, 4)).astype(np.float32), z(500))
    assert 0.5 * ((test_pos > 0).mean() + (test_neg < 0).mean()) > 0.85  # Bayes accuracy: 0.977


def test_z_conditioning_beats_no_z_when_the_positive_class_depends_on_z() -> None:
    """Positives: windows around +2·s with z = (s, 0), s = ±1; negatives: windows around -2·s. The
    window marginals of both classes are identical, so only the pairing with z separates them."""
    rng = np.random.default_rng(1)

    def draw(n: int, positive: bool) -> tuple[np.ndarray, np.ndarray]:
        s = rng.choice([-1.0, 1.0], size=n)
        mean = (2.0 if positive else -2.0) * s
        x = (mean[:, None] + rng.normal(0, 0.5, (n, 4))).astype(np.float32)
        return x, np.stack([s, np.zeros(n)], 1).astype(np.float32)

    with_z, without_z = _learner(2, seed=3), _learner(0, seed=3)
    for _ in range(200):
        pos, neg = draw(128, True), draw(128, False)
        with_z.step(pos, neg)
        without_z.step((pos[0], pos[1][:, :0]), (neg[0], neg[1][:, :0]))
    (px, pz), (nx, nz) = draw(1000, True), draw(1000, False)
    acc = lambda lp, ln: 0.5 * ((lp > 0).mean() + (ln < 0).mean())  # noqa: E731
    acc_z = acc(with_z.logits(px, pz), with_z.logits(nx, nz))
    acc_no = acc(without_z.logits(px, pz[:, :0]), without_z.logits(nx, nz[:, :0]))
    assert acc_z > 0.95
    assert acc_no < 0.65
    assert acc_z - acc_no > 0.3


def test_reward_is_minus_log_one_minus_d_clamped() -> None:
    r = reward_from_logits(np.array([0.0, -50.0, 50.0]), clamp=1e-4)
    np.testing.assert_allclose(r, [np.log(2.0), 0.0, -np.log(1e-4)], rtol=1e-5, atol=1e-7)


def test_batch_holds_mismatched_z_negatives_and_replay() -> None:
    from amorctl.hlp.config import DiscriminatorConfig
    from amorctl.hlp.rewards import DiscriminatorReward

    lib = _tiny_library()
    spec = WindowSpec(2, 2, 1)
    cfg = DiscriminatorConfig(window=2, hidden=(8,), z_hidden=(4,), batch_size=40, replay_size=100)
    d = DiscriminatorReward(cfg, spec, DatasetWindows(lib, spec), slice(0, 0), slice(0, 3), 2, 0)
    rng = np.random.default_rng(0)
    pol_w = np.full((10, spec.size), -5.0, dtype=np.float32)
    pol_z = np.zeros((10, 3), dtype=np.float32)
    pos, neg, kind = d.batch(rng, pol_w, pol_z)
    assert pos[0].shape == neg[0].shape == (40, spec.size)
    assert (kind == d.MISMATCHED).sum() == 10 and (kind == d.POLICY).sum() == 30
    assert (kind == d.REPLAY).sum() == 0  # nothing in the replay buffer yet
    mis_w, mis_z = neg[0][kind == d.MISMATCHED], neg[1][kind == d.MISMATCHED]
    last_q = mis_w.reshape(10, 2, -1)[:, -1, -2]
    frame_of = ((last_q - 13) / frame_dim(2, 1)).astype(int)
    assert (mis_z[:, 0] != frame_of + 1).all()  # a dataset window, but not with its own z
    d.replay.add(pol_w, pol_z)
    _, _, kind = d.batch(rng, pol_w, pol_z)
    assert (kind == d.REPLAY).sum() == 15 and (kind == d.POLICY).sum() == 15


# --- config ----------------------------------------------------------------------------------------
def test_presets_differ_in_window_and_round_trip(tmp_path) -> None:
    v30, v2, paper = load_hlp_preset("v30"), load_hlp_preset("v2"), load_hlp_preset("paper")
    assert (v30.discriminator.window, v2.discriminator.window, paper.discriminator.window) == (30, 2, 30)
    assert paper.discriminator.hidden == (1024, 512) and paper.discriminator.replay_size == 200_000
    assert v30.discriminator.grad_penalty == 5.0 and v30.discriminator.logit_l2 == 0.01
    path = tmp_path / "c.toml"
    path.write_text(to_toml(v2))
    from amorctl.hlp.config import load_hlp_config

    assert load_hlp_config(path) == v2
    with pytest.raises(AmorError, match="window"):
        merge(HlpConfig(), {"discriminator": {"window": 0}})
    with pytest.raises(AmorError, match="unknown key 'nope'"):
        merge(HlpConfig(), {"ppo": {"nope": 1}})
    assert dataclasses.replace(v30.env, decision_interval=3).decision_interval == 3


def test_edited_hlp_weights_are_scaled_and_renormalized() -> None:
    from amorctl.hlp.edit import edit_weights, parse_scales

    names = ("up", "smooth", "vel")
    s = parse_scales("smooth=2, vel=0", names)
    np.testing.assert_array_equal(s, [1.0, 2.0, 0.0])
    w = np.array([[0.2, 0.3, 0.5], [0.0, 0.0, 1.0]])
    out = edit_weights(w, s)
    np.testing.assert_allclose(out[0], [0.25, 0.75, 0.0], atol=1e-7)
    np.testing.assert_allclose(out[1], [0.5, 0.5, 0.0], atol=1e-7)  # all weight scaled away: uniform
    _assert_simplex(out)
    np.testing.assert_array_equal(parse_scales(None, names), 1.0)
    for bad, needle in (
        ("nope=2", "unknown objective 'nope'"),
        ("up=-1", "up"),
        ("up=0,smooth=0,vel=0", "zero"),
    ):
        with pytest.raises(AmorError, match=needle):
            parse_scales(bad, names)
