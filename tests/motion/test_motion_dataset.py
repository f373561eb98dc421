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


def _flip_frames_byte(monkeypatch, path, lib) -> None:
    """Write ``lib`` with one byte of clip 0's ``frames`` flipped after its hashes were taken:
    a hand-made dataset whose MCAP records are all intact but whose array is not."""
    import base64

    from amorctl.motion import dataset

    encode = dataset._encode_array
    done = []

    def flipping(a):
        d = encode(a)
        if not done and a.shape[1:] == lib.frames.shape[1:]:
            raw = bytearray(base64.b64decode(d["data"]))
            raw[5] ^= 0x10
            d["data"] = base64.b64encode(bytes(raw)).decode("ascii")
            done.append(True)
        return d

    monkeypatch.setattr(dataset, "_encode_array", flipping)
    write_dataset(path, lib)
    monkeypatch.undo()
    assert done


def test_one_flipped_byte_in_frames_is_refused_by_data_show_and_train(tmp_path, capsys, monkeypatch):
    import dataclasses

    from amorctl.envs.synthetic import synthetic_library
    from amorctl.registry import get_registry

    lib = synthetic_library(get_registry().character("biped20"), num_clips=2, seconds=0.4, seed=3)
    lib = dataclasses.replace(
        lib, clips=tuple(dataclasses.replace(c, name=f"c{i}") for i, c in enumerate(lib.clips))
    )
    good, bad = tmp_path / "good.mcap", tmp_path / "bad.mcap"
    write_dataset(good, lib)
    _flip_frames_byte(monkeypatch, bad, lib)

    assert main(["data", "show", str(good), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["integrity"]["verified"] is True
    assert (
        shown["integrity"]["sha256"]["frames"]
        == hashlib.sha256(lib.frames.astype("<f4").tobytes()).hexdigest()
    )

    expected = f"error: {bad}: array 'frames' does not match its recorded SHA-256"
    assert main(["data", "show", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(expected) and err.count("\n") == 1, err
    out = tmp_path / "run"
    code = main(["train", "-c", "biped20", "--data", str(bad), "--num-envs", "2", "--iterations", "1",
                 "--out", str(out), "--json"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(expected) and err.count("\n") == 1, err
    assert not out.exists()


def test_the_library_rules_are_checked_before_writing(tmp_path):
    import dataclasses

    from amorctl.core.errors import AmorError

    lib = _library(np.random.default_rng(0))
    twice = dataclasses.replace(lib, clips=(lib.clips[0], dataclasses.replace(lib.clips[1], name="a")))
    with pytest.raises(AmorError, match="clip name 'a' is used twice"):
        write_dataset(tmp_path / "d.mcap", twice)
    nan = dataclasses.replace(lib, z=np.where(np.arange(11)[:, None] == 8, np.nan, lib.z).astype(np.float32))
    with pytest.raises(AmorError, match=r"array 'z' holds NaN or inf \(clip 'walker/b', frame 1\)"):
        write_dataset(tmp_path / "d.mcap", nan)
    short = dataclasses.replace(
        lib,
        clips=(
            dataclasses.replace(lib.clips[0], num_frames=10),
            dataclasses.replace(lib.clips[1], start=10, num_frames=1),
        ),
    )
    with pytest.raises(AmorError, match="has 1 frame"):
        write_dataset(tmp_path / "d.mcap", short)
    assert not (tmp_path / "d.mcap").exists()


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("fps", "0", "'fps' = '0' must be a number"),
        ("fps", "x", "'fps' = 'x' is not a number"),
        ("version", "x", "'version' = 'x' is not an integer"),
        ("joint_names", "[", "'joint_names' = '\\[' is not a JSON list"),
        ("sha256", None, "lacks the content hashes"),
    ],
)
def test_bad_dataset_metadata_is_one_error_naming_file_and_key(tmp_path, key, value, message):
    from amorctl.core.errors import AmorError
    from amorctl.motion import dataset

    write = dataset.Writer.add_metadata

    def patched(self, name, data):
        if name == "amorctl.dataset":
            data = dict(data)
            if value is None:
                data.pop(key)
            else:
                data[key] = value
        return write(self, name, data)

    path = tmp_path / "d.mcap"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dataset.Writer, "add_metadata", patched)
        write_dataset(path, _library(np.random.default_rng(0)))
    with pytest.raises(AmorError, match=message) as info:
        load_dataset(path)
    assert str(path) in str(info.value)


def _write_with_record(path, lib: MotionLibrary, change) -> None:
    """Write ``lib`` with its ``amorctl.dataset`` record changed by ``change(record) -> record``
    after every hash was taken: a hand-edited (or older) dataset."""
    from amorctl.motion import dataset

    write = dataset.Writer.add_metadata

    def patched(self, name, data):
        return write(self, name, change(dict(data)) if name == "amorctl.dataset" else data)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dataset.Writer, "add_metadata", patched)
        write_dataset(path, lib)


def _as_v1(record: dict) -> dict:
    return {k: v for k, v in record.items() if k != "sha256"} | {"version": "1"}


def _as_v2(record: dict) -> dict:
    """A version-2 record: the arrays' hashes, none over the metadata."""
    hashes = {k: v for k, v in json.loads(record["sha256"]).items() if k != "metadata"}
    return record | {"version": "2", "sha256": json.dumps(hashes)}


def test_version_1_datasets_without_hashes_load_unverified_with_a_warning(tmp_path, capsys):
    from amorctl.core.errors import AmorWarning

    path = tmp_path / "old.mcap"
    _write_with_record(path, _library(np.random.default_rng(0)), _as_v1)
    with pytest.warns(AmorWarning, match="version 1 dataset without content hashes"):
        integrity = load_dataset(path).metadata["integrity"]
    assert integrity["verified"] is False and integrity["metadata_verified"] is False
    assert main(["data", "show", str(path)]) == 0
    out, err = capsys.readouterr()
    assert "integrity: not verified (version 1 dataset" in out
    assert err == (
        f"warning: {path}: version 1 dataset without content hashes: its arrays and metadata cannot be "
        "verified; re-run `amorctl preprocess` (or delete a cached copy) to add them\n"
    )


def test_train_on_a_version_1_dataset_prints_one_warning_line(tmp_path, capsys):
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.registry import get_registry

    lib = synthetic_library(get_registry().character("biped20"), num_clips=1, seconds=0.4, seed=3)
    path, out = tmp_path / "old.mcap", tmp_path / "run"
    _write_with_record(path, lib, _as_v1)
    code = main(["train", "-c", "biped20", "--data", str(path), "--num-envs", "2", "--iterations", "0",
                 "--out", str(out), "--json"])  # fmt: skip
    stdout, err = capsys.readouterr()
    assert code == 0 and json.loads(stdout)["end_iteration"] == 0
    assert err.count("\n") == 1 and err.startswith(
        f"warning: {path}: version 1 dataset without content hashes"
    )


def test_version_2_datasets_load_with_their_metadata_unverified(tmp_path, capsys):
    path = tmp_path / "v2.mcap"
    _write_with_record(path, _library(np.random.default_rng(0)), _as_v2)
    integrity = load_dataset(path).metadata["integrity"]
    assert integrity["verified"] is True and integrity["metadata_verified"] is False
    assert main(["data", "show", str(path)]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    assert (
        "metadata: not verified (version 2 dataset: its metadata (character, fps, clip info, ...) "
        "has no hash)" in out
    )


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("character", "biped20"),
        ("fps", "25.0"),
        ("joint_names", '["j1", "j0"]'),
        ("vae", '{"window": 9}'),
        ("note", "an added key"),
    ],
)
def test_edited_metadata_fails_the_metadata_hash_in_data_show(tmp_path, capsys, key, value):
    """Every key of the dataset record is covered: `data show` refuses an edit (before, only
    `train` noticed a changed character)."""
    path = tmp_path / "d.mcap"
    lib = _library(np.random.default_rng(0))
    write_dataset(tmp_path / "good.mcap", lib)
    assert main(["data", "show", str(tmp_path / "good.mcap")]) == 0
    capsys.readouterr()
    _write_with_record(path, lib, lambda r: r | {key: value})
    assert main(["data", "show", str(path), "--json"]) == 2
    assert capsys.readouterr().err == (
        f"error: {path}: the dataset's metadata (character, fps, joint names, clip info, ...) does not "
        "match its recorded SHA-256 (edited or corrupt; re-run preprocess)\n"
    )


def test_edited_clip_info_fails_the_metadata_hash(tmp_path):
    from amorctl.core.errors import AmorError
    from amorctl.motion import dataset

    add = dataset.Writer.add_message

    def renamed(self, channel, log_time, data, publish_time, sequence=0):
        msg = json.loads(data)
        if msg["name"] == "walker/b":
            data = json.dumps(msg | {"name": "walker/c", "licence": "proprietary"}).encode()
        return add(self, channel, log_time, data, publish_time, sequence)

    path = tmp_path / "d.mcap"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dataset.Writer, "add_message", renamed)
        write_dataset(path, _library(np.random.default_rng(0)))
    with pytest.raises(AmorError, match=r"metadata .* does not match its recorded SHA-256"):
        load_dataset(path)


def test_a_version_3_dataset_without_its_metadata_hash_is_refused(tmp_path):
    from amorctl.core.errors import AmorError

    path = tmp_path / "d.mcap"
    _write_with_record(path, _library(np.random.default_rng(0)), lambda r: _as_v2(r) | {"version": "3"})
    with pytest.raises(
        AmorError, match=r"'sha256' = .* lacks the SHA-256 of the metadata \('metadata'\) of version 3"
    ):
        load_dataset(path)


def test_values_beyond_the_plausibility_bound_are_refused_like_nan(tmp_path):
    import dataclasses

    from amorctl.core.errors import AmorError

    lib = _library(np.random.default_rng(0))
    huge = dataclasses.replace(lib, root_pos=np.where(np.arange(11)[:, None] == 9, 1e30, lib.root_pos))
    with pytest.raises(
        AmorError, match=r"array 'root_pos' holds 1e\+30 \(\|x\| > 1e\+06\) \(clip 'walker/b', frame 2\)"
    ):
        write_dataset(
            tmp_path / "d.mcap", dataclasses.replace(huge, root_pos=huge.root_pos.astype(np.float32))
        )
    assert not (tmp_path / "d.mcap").exists()
