"""Every class of bad input: one clear error naming the file, non-zero exit, no output left."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest

from amorctl.cli.main import main
from amorctl.motion.source import CANONICAL_JOINTS

MAP = "[joints]\n" + "".join(f'{j} = "{j}"\n' for j in CANONICAL_JOINTS)


def _bvh(
    frames: list[str],
    count: int | None = None,
    frame_time: str | None = "Frame Time: 0.033333",
    root: str = "root",
) -> str:
    """A minimal canonical-skeleton BVH (all joints chained under the root: fine for parsing)."""
    lines = [
        "HIERARCHY",
        f"ROOT {root}",
        "{",
        "OFFSET 0 0 0",
        "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",
    ]
    for j in CANONICAL_JOINTS[1:]:
        lines += [f"JOINT {j}", "{", "OFFSET 0 0.1 0", "CHANNELS 3 Zrotation Xrotation Yrotation", "}"]
    lines += ["}", "MOTION", f"Frames: {len(frames) if count is None else count}"]
    if frame_time is not None:
        lines.append(frame_time)
    return "\n".join(lines + frames) + "\n"


GOOD_ROW = " ".join(["0 0.9 0"] + ["0"] * (3 + 3 * 12))
WIDTH = 44


def _bad_channel(value: str, token: int = 6) -> str:
    """GOOD_ROW with one channel replaced (token 6: the chest's Zrotation, after the root's 6)."""
    tokens = GOOD_ROW.split()
    tokens[token] = value
    return " ".join(tokens)


def _npy_bytes() -> bytes:
    """A single .npy array: what ``np.load`` returns as an array, not as an archive."""
    buf = io.BytesIO()
    np.save(buf, np.zeros((5, 20)))
    return buf.getvalue()


def _dm(rows) -> str:
    return json.dumps({"Loop": "wrap", "Frames": rows})


def _row(dt: float = 1 / 30, value: float = 0.0) -> list[float]:
    row = [dt, 0.0, 0.9, 0.0, 1.0, 0.0, 0.0, 0.0]
    for width in (4, 4, 4, 1, 4, 4, 1, 4, 1, 4, 4, 1):
        row += [1.0, 0.0, 0.0, 0.0] if width == 4 else [value]
    return row


def _npz_bytes(tmp_path: Path, **arrays) -> Path:
    p = tmp_path / "robot.npz"
    np.savez(p, **arrays)
    return p


def _good_npz(**override):
    names = [
        "head_pan",
        "head_tilt",
        "l_sho_pitch",
        "l_sho_roll",
        "l_el",
        "r_sho_pitch",
        "r_sho_roll",
        "r_el",
        "l_hip_yaw",
        "l_hip_roll",
        "l_hip_pitch",
        "l_knee",
        "l_ank_pitch",
        "l_ank_roll",
        "r_hip_yaw",
        "r_hip_roll",
        "r_hip_pitch",
        "r_knee",
        "r_ank_pitch",
        "r_ank_roll",
    ]
    quat = np.zeros((5, 1, 4))
    quat[..., 0] = 1
    arrays = {
        "fps": np.array(50.0),
        "joint_pos": np.zeros((5, 20)),
        "joint_vel": np.zeros((5, 20)),
        "body_pos_w": np.full((5, 1, 3), 0.3),
        "body_quat_w": quat,
        "joint_names": np.array(names),
        "body_names": np.array(["torso"]),
    }
    arrays.update(override)
    return {k: v for k, v in arrays.items() if v is not None}


CASES = {
    # name: (file name, content (str | bytes | dict for npz), extra args, expected message part)
    "json_truncated": ("t.txt", _dm([_row()] * 3)[:-40], [], r"not valid JSON \(line"),
    "json_garbage": ("g.txt", "hello, world", [], "not valid JSON"),
    "json_binary": ("b.txt", b"\xff\xfe\x00\x01", [], "cannot decode"),
    "json_short_row": ("s.txt", _dm([_row(), _row()[:40]]), [], "frame 1 has 40 values, expected 44"),
    "json_nan": ("n.txt", _dm([_row(), _row(value=float("nan")), _row()]), [], "NaN or inf"),
    "json_zero_frames": ("z.txt", _dm([]), [], "zero frames"),
    "json_missing_rate": ("m.txt", _dm([_row(), _row(dt=0.0), _row()]), [], "frame 1 has duration 0"),
    "json_inconsistent_rate": (
        "i.txt",
        _dm([_row(), _row(), _row(dt=0.5), _row()]),
        [],
        "inconsistent frame rate",
    ),
    "bvh_garbage": ("g.bvh", "this is not a bvh\n", ["--map", "MAP"], "line 1: expected 'HIERARCHY'"),
    "bvh_truncated": ("t.bvh", _bvh([GOOD_ROW] * 2, count=5), ["--map", "MAP"], "truncated BVH"),
    "bvh_joint_not_in_map": (
        "j.bvh",
        _bvh([GOOD_ROW], root="Hips"),
        ["--map", "MAP"],
        "joint 'root' named in .*map.toml is not in the file's hierarchy",
    ),
    "bvh_inf": ("f.bvh", _bvh([GOOD_ROW.replace("0.9", "inf", 1)]), ["--map", "MAP"], "non-finite"),
    # one plausibility bound for every imported number: rotations like root positions
    "bvh_huge_rotation": (
        "h.bvh",
        _bvh([GOOD_ROW, _bad_channel("1e26"), GOOD_ROW]),
        ["--map", "MAP"],
        r"line 71: value 1e\+26 in joint 'chest' Zrotation at frame 1 is implausibly large "
        r"\(\|x\| > 1e\+06\)",
    ),
    "bvh_large_rotation": (
        "l.bvh",
        _bvh([GOOD_ROW, GOOD_ROW, _bad_channel("-1e7", token=10)]),
        ["--map", "MAP"],
        r"line 72: value -1e\+07 in joint 'neck' Xrotation at frame 2 is implausibly large",
    ),
    "bvh_huge_root": (
        "r.bvh",
        _bvh([GOOD_ROW, _bad_channel("2e6", token=1)]),
        ["--map", "MAP"],
        r"line 71: value 2e\+06 in joint 'root' Yposition at frame 1 is implausibly large",
    ),
    "json_huge_hinge": (
        "h.txt",
        _dm([_row(), _row(value=1e7), _row()]),
        [],
        r"value 1e\+07 in frame values at frame 1 is implausibly large",
    ),
    "bvh_zero_frames": ("z.bvh", _bvh([], count=0), ["--map", "MAP"], "zero frames"),
    "bvh_missing_rate": (
        "m.bvh",
        _bvh([GOOD_ROW], frame_time=None),
        ["--map", "MAP"],
        "expected 'Frame Time",
    ),
    "bvh_bad_rate": (
        "r.bvh",
        _bvh([GOOD_ROW], frame_time="Frame Time: 0"),
        ["--map", "MAP"],
        "not a positive number",
    ),
    "bvh_no_map": ("n.bvh", _bvh([GOOD_ROW]), [], "needs a joint map"),
    "npz_garbage": ("g.npz", b"PK\x03\x04 garbage that is not a zip", ["-c", "biped20"], "not a valid .npz"),
    "npz_text": ("t.npz", "hello, a text file\n", ["-c", "biped20"], r"not an \.npz \(zip\) file"),
    "npz_single_npy": ("s.npz", _npy_bytes(), ["-c", "biped20"], r"not an \.npz \(zip\) file"),
    "npz_empty": ("e.npz", b"", ["-c", "biped20"], r"not an \.npz \(zip\) file"),
    "npz_bool_fps": (
        "b.npz",
        _good_npz(fps=np.array(True)),
        ["-c", "biped20"],
        "'fps' must hold numbers, not bool",
    ),
    "npz_bool_joint_pos": (
        "j.npz",
        _good_npz(joint_pos=np.zeros((5, 20), dtype=bool)),
        ["-c", "biped20"],
        "'joint_pos' must hold numbers, not bool",
    ),
    "npz_huge_joint": (
        "u.npz",
        _good_npz(joint_pos=np.where(np.eye(5, 20) > 0, 3e6, 0.0)),
        ["-c", "biped20"],
        r"value 3e\+06 in joint_pos at frame 0 is implausibly large",
    ),
    "npz_nan": ("n.npz", _good_npz(joint_pos=np.full((5, 20), np.nan)), ["-c", "biped20"], "NaN or inf"),
    "npz_missing_fps": ("f.npz", _good_npz(fps=None), ["-c", "biped20"], "missing frame rate fps"),
    "npz_bad_fps": ("b.npz", _good_npz(fps=np.array(0.0)), ["-c", "biped20"], "'fps' must be one positive"),
    "npz_zero_frames": (
        "z.npz",
        _good_npz(joint_pos=np.zeros((0, 20))),
        ["-c", "biped20"],
        "at least one frame",
    ),
    "npz_inconsistent": (
        "i.npz",
        _good_npz(joint_vel=np.zeros((4, 20))),
        ["-c", "biped20"],
        "does not match",
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input(case, tmp_path, capsys):
    name, content, extra, expect = CASES[case]
    path = tmp_path / name
    if isinstance(content, dict):
        np.savez(path, **content)
    elif isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    if case == "npz_garbage":
        path.write_bytes(content)
    (tmp_path / "map.toml").write_text(MAP)
    extra = [str(tmp_path / "map.toml") if a == "MAP" else a for a in extra]
    if "-c" not in extra:
        extra += ["-c", "humanoid36"]
    out = tmp_path / "out" / "d.mcap"
    rc = main(["preprocess", str(path), "--out", str(out), "--no-vae", *extra])
    err = capsys.readouterr().err
    assert rc != 0
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert str(path) in err
    import re

    assert re.search(expect, err), err
    assert not out.exists()
    assert not out.parent.exists() or list(out.parent.iterdir()) == []


def test_npz_truncated(tmp_path, capsys):
    good = tmp_path / "good.npz"
    np.savez(good, **_good_npz())
    bad = tmp_path / "trunc.npz"
    bad.write_bytes(good.read_bytes()[:300])
    out = tmp_path / "d.mcap"
    assert main(["preprocess", str(bad), "-c", "biped20", "--out", str(out), "--no-vae"]) != 0
    assert str(bad) in capsys.readouterr().err
    assert not out.exists()


def test_unknown_character(tmp_path, capsys, clip_path):
    out = tmp_path / "d.mcap"
    assert main(["preprocess", str(clip_path("walk")), "-c", "robocop", "--out", str(out), "--no-vae"]) != 0
    assert "robocop" in capsys.readouterr().err
    assert not out.exists()


def test_missing_file_and_map_entry(tmp_path, capsys):
    out = tmp_path / "d.mcap"
    assert (
        main(["preprocess", str(tmp_path / "nope.txt"), "-c", "humanoid36", "--out", str(out), "--no-vae"])
        != 0
    )
    assert "nope.txt: motion file not found" in capsys.readouterr().err
    bvh = tmp_path / "a.bvh"
    bvh.write_text(_bvh([GOOD_ROW]))
    partial = tmp_path / "partial.toml"
    partial.write_text("\n".join(MAP.splitlines()[:-1]) + "\n")  # left_elbow has no entry
    assert (
        main(
            ["preprocess", str(bvh), "--map", str(partial), "-c", "humanoid36", "--out", str(out), "--no-vae"]
        )
        != 0
    )
    err = capsys.readouterr().err
    assert "partial.toml" in err and "left_elbow" in err
    assert not out.exists()


@pytest.mark.parametrize(
    ("scale", "shown"), [("true", "True"), ("1e300", "1e+300"), ("0", "0"), ('"1"', "'1'")]
)
def test_joint_map_scale_must_be_a_plausible_number(tmp_path, capsys, scale, shown):
    """``scale = true`` is no unit scale (it was read as 1.0); nor is a scale beyond the bound."""
    bvh, jmap, out = tmp_path / "a.bvh", tmp_path / "map.toml", tmp_path / "d.mcap"
    bvh.write_text(_bvh([GOOD_ROW, GOOD_ROW]))
    jmap.write_text(MAP + f"[options]\nscale = {scale}\n")
    rc = main(["preprocess", str(bvh), "--map", str(jmap), "-c", "humanoid36", "--out", str(out), "--no-vae"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1, err
    assert err == f"error: {jmap}: [options] scale = {shown} must be a positive number (at most 1e+06)\n"
    assert not out.exists()
