"""The MCAP dataset: round trip through the reader, end-to-end preprocess, `amorctl data show`."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
from mcap.reader import make_reader

from amorctl.cli.main import main
from amorctl.motion.clips import ClipInfo, MotionLibrary
from amorctl.motion.dataset import (
    CHANNEL,
    SCHEMA_NAME,
    load_clip_stats,
    load_dataset,
    load_encoder_bytes,
    write_dataset,
)
from amorctl.motion.formats.deepmimic import DEEPMIMIC_LICENCE
from amorctl.motion.preprocess import preprocess
from amorctl.motion.vae import VaeConfig, encoder_from_bytes


def _library(rng: np.random.Generator) -> MotionLibrary:
    lengths = [7, 4]
    f = sum(lengths)
    clips = (
        ClipInfo("a", "a.txt", "00", "MIT", 0, 7, 30.0, 0.01),
        ClipInfo("walker/b", "b.txt", "11", "MIT", 7, 4, 60.0, 0.0),
    )
    arr = lambda *shape: rng.normal(size=(f, *shape)).astype(np.float32)  # noqa: E731
    return MotionLibrary(
        character="humanoid36",
        fps=50.0,
        joint_names=("j0", "j1"),
        end_effectors=("lh", "rh", "lf", "rf"),
        clips=clips,
        root_pos=arr(3),
        root_quat=arr(4),
        root_lin_vel=arr(3),
        root_ang_vel=arr(3),
        joint_pos=arr(2),
        joint_vel=arr(2),
        ee_pos=arr(4, 3),
        ee_quat=arr(4, 4),
        ee_lin_vel=arr(4, 3),
        frames=arr(1 + 6 + 6 + 4 + 36 + 12),
        z=arr(5),
        metadata={"vae": {"window": 3}},
    )


def test_round_trip_through_the_mcap_reader(tmp_path):
    lib = _library(np.random.default_rng(0))
    path = tmp_path / "d.mcap"
    write_dataset(path, lib, clip_stats={"a": {"method": "direct"}})
    back = load_dataset(path)
    assert back.clips == lib.clips
    assert (back.character, back.fps, back.joint_names, back.end_effectors) == (
        lib.character,
        lib.fps,
        lib.joint_names,
        lib.end_effectors,
    )
    for name in ("root_pos", "root_quat", "joint_pos", "ee_pos", "ee_quat", "frames", "z"):
        np.testing.assert_array_equal(getattr(back, name), getattr(lib, name))
    assert back.metadata["vae"] == {"window": 3}
    assert load_clip_stats(path)["a"] == {"method": "direct"}
    assert [p.name for p in tmp_path.iterdir()] == ["d.mcap"]  # no temp file left
    # any MCAP reader sees the schema, channel and metadata records
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert {s.name for s in summary.schemas.values()} == {SCHEMA_NAME}
        assert {c.topic for c in summary.channels.values()} == {CHANNEL}
        assert summary.statistics.message_count == 2
        names = [m.name for m in reader.iter_metadata()]
        assert names.count("amorctl.clip") == 2 and "amorctl.dataset" in names


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory, clip_path):
    out = tmp_path_factory.mktemp("ds") / "h36.mcap"
    files = [clip_path("walk"), clip_path("walker/turn_left0")]
    report = preprocess(
        files,
        character="humanoid36",
        out=out,
        vae=VaeConfig(window=3, latent_dim=4, hidden=32, epochs=3, holdout=("walk",)),
    )
    return out, files, report


def test_preprocess_end_to_end(small_dataset):
    out, files, report = small_dataset
    lib = load_dataset(out)
    assert [c.name for c in lib.clips] == ["walk", "turn_left0"]
    for clip, f in zip(lib.clips, files, strict=True):
        rows = json.loads(f.read_text())["Frames"]
        assert clip.num_frames == int(np.floor(sum(r[0] for r in rows[:-1]) * 50 + 1e-6)) + 1
        assert clip.sha256 == hashlib.sha256(f.read_bytes()).hexdigest()
        assert clip.licence == DEEPMIMIC_LICENCE
        assert clip.source.startswith("pybullet_data/data/motions/")
    assert lib.frames.shape == (lib.num_frames, 1 + 6 + 6 + 2 * 30 + 4 * 9 + 4 * 3)
    assert lib.z.shape == (lib.num_frames, 4)
    assert lib.metadata["vae"]["heldout_clips"] == ["walk"]
    assert lib.metadata["frame_layout"]["ee_vel"][1] == lib.frame_dim
    enc = encoder_from_bytes(load_encoder_bytes(out))
    z = enc.encode(lib.frames.astype(np.float64), lib.starts, lib.lengths)
    np.testing.assert_allclose(z, lib.z, atol=1e-4)
    assert report.num_frames == lib.num_frames


def test_data_show(small_dataset, capsys):
    out, _, _ = small_dataset
    assert main(["data", "show", str(out), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert [c["name"] for c in shown["clips"]] == ["walk", "turn_left0"]
    assert shown["clips"][0]["duration_s"] == pytest.approx((shown["clips"][0]["frames"] - 1) / 50)
    assert main(["data", "show", str(out)]) == 0
    assert "turn_left0" in capsys.readouterr().out


def test_cli_preprocess_without_vae(tmp_path, clip_path, capsys):
    out = tmp_path / "b20.mcap"
    rc = main(
        [
            "preprocess",
            str(clip_path("run")),
            "--character",
            "biped20",
            "--out",
            str(out),
            "--no-vae",
            "--json",
        ]
    )
    assert rc == 0
    report = json.loads(capsys.readouterr().out)
    assert report["vae"] is None and report["clips"][0]["name"] == "run"
    assert load_dataset(out).latent_dim == 0


def test_frame_windows_stay_inside_clips():
    from amorctl.motion.dataset import clip_of_frame, frame_windows

    lib = _library(np.random.default_rng(1))  # clips of 7 and 4 frames
    np.testing.assert_array_equal(clip_of_frame(lib, np.array([0, 6, 7, 10])), [0, 0, 1, 1])
    w = frame_windows(lib, np.array([0, 7, 10]), window=2)
    assert w.shape == (3, 5, lib.frame_dim)
    np.testing.assert_array_equal(w[0], lib.frames[[0, 0, 0, 1, 2]])
    np.testing.assert_array_equal(w[1], lib.frames[[7, 7, 7, 8, 9]])
    np.testing.assert_array_equal(w[2], lib.frames[[8, 9, 10, 10, 10]])
