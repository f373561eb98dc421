"""``preprocess --tempo``: clips played slower keep their poses and scale every speed."""

from __future__ import annotations

import numpy as np
import pytest

from amorctl.cli.main import main
from amorctl.core.errors import AmorError
from amorctl.motion.dataset import load_clip_stats, load_dataset
from amorctl.motion.preprocess import preprocess
from amorctl.motion.tempo import Tempo, parse_tempo


def test_tempo_values_parse_and_bad_ones_are_refused() -> None:
    assert parse_tempo([]) == Tempo(1.0, {})
    assert parse_tempo(["0.5"]) == Tempo(0.5, {})
    assert parse_tempo(["run=0.5", "0.8", "walker/turn_left0=2"]) == Tempo(
        0.8, {"run": 0.5, "walker/turn_left0": 2.0}
    )
    for values, message in (
        (["fast"], "write a factor"),
        (["run=slow"], "write a factor"),
        (["0"], r"within \[0.1, 10\]"),
        (["nan"], r"within \[0.1, 10\]"),
        (["run=11"], r"within \[0.1, 10\]"),
        (["0.5", "0.6"], "already given"),
        (["run=0.5", "run=0.6"], "'run' was already given"),
    ):
        with pytest.raises(AmorError, match=message):
            parse_tempo(values)


def test_named_clips_resolve_against_the_clip_names() -> None:
    names = ["run", "walk", "walker/turn_left0"]
    rates = Tempo(0.8, {"run": 0.5, "turn_left0": 2.0}).resolve(names)
    assert rates == {"run": 0.5, "walk": 0.8, "walker/turn_left0": 2.0}
    with pytest.raises(AmorError, match=r"--tempo jog=0.5: no motion 'jog' in the motions given; clips: run"):
        Tempo(1.0, {"jog": 0.5}).resolve(names)


def test_a_slowed_clip_keeps_its_poses_and_halves_its_speeds(tmp_path, clip_path) -> None:
    files = [clip_path("walk"), clip_path("run")]
    plain, slow = tmp_path / "plain.mcap", tmp_path / "slow.mcap"
    preprocess(files, character="humanoid36", out=plain, vae=None)
    preprocess(files, character="humanoid36", out=slow, vae=None, tempo=Tempo(1.0, {"run": 0.5}))
    a, b = load_dataset(plain), load_dataset(slow)
    (walk_a, run_a), (walk_b, run_b) = a.clips, b.clips

    def clip(library, info, key: str) -> np.ndarray:
        return getattr(library, key)[info.start : info.start + info.num_frames]

    np.testing.assert_array_equal(clip(a, walk_a, "joint_pos"), clip(b, walk_b, "joint_pos"))
    assert b.clip_duration(run_b) == pytest.approx(2 * a.clip_duration(run_a), abs=0.03)
    # humanoid36 copies the source's joint angles: every other slow frame is a frame of the original
    q_a, q_b = clip(a, run_a, "joint_pos"), clip(b, run_b, "joint_pos")[::2]
    n = min(len(q_a), len(q_b))
    np.testing.assert_allclose(q_b[:n], q_a[:n], atol=1e-4)
    speed_a = np.abs(clip(a, run_a, "joint_vel")).mean()
    speed_b = np.abs(clip(b, run_b, "joint_vel")).mean()
    assert speed_b == pytest.approx(0.5 * speed_a, rel=0.02)
    stats = load_clip_stats(slow)
    assert stats["run"]["tempo"] == 0.5 and "tempo" not in stats["walk"]


def test_a_bad_tempo_is_one_error_line_before_anything_is_written(tmp_path, capsys, clip_path) -> None:
    out = tmp_path / "d.mcap"
    for value, message in (("fast", "write a factor"), ("jog=0.5", "no motion 'jog'")):
        code = main(["preprocess", str(clip_path("walk")), "--character", "humanoid36", "--out", str(out),
                     "--no-vae", "--tempo", value])  # fmt: skip
        err = capsys.readouterr().err
        assert code == 2 and message in err and err.count("\n") == 1
        assert not out.exists()
