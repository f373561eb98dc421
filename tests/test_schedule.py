"""Weight schedules: interpolation properties, every bad-file class, save -> load round trip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amorctl.core.errors import AmorError
from amorctl.core.schedule import dump_schedule, load_schedule

NAMES = ["up", "lo", "smooth"]

BASIC = """
interpolation = "linear"

[[keyframe]]
t = 0.0
weights = { up = 1, lo = 1, smooth = 2 }

[[keyframe]]
t = 2.0
weights = { smooth = 1 }   # up, lo take the default 0

[[keyframe]]
t = 4
weights = { up = 3, lo = 1 }
"""


def write(tmp_path: Path, text: str, name: str = "s.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


# ---------------------------------------------------------------- interpolation


def test_keyframes_exact_and_normalized(tmp_path: Path) -> None:
    s = load_schedule(write(tmp_path, BASIC), NAMES)
    np.testing.assert_allclose(s.weights_at(0.0), [0.25, 0.25, 0.5])
    np.testing.assert_allclose(s.weights_at(2.0), [0.0, 0.0, 1.0])
    np.testing.assert_allclose(s.weights_at(4.0), [0.75, 0.25, 0.0])


def test_linear_midpoints_and_hold_outside(tmp_path: Path) -> None:
    s = load_schedule(write(tmp_path, BASIC), NAMES)
    np.testing.assert_allclose(s.weights_at(1.0), [0.125, 0.125, 0.75])
    np.testing.assert_allclose(s.weights_at(3.0), [0.375, 0.125, 0.5])
    np.testing.assert_allclose(s.weights_at(0.5), [0.1875, 0.1875, 0.625])
    np.testing.assert_allclose(s.weights_at(-5.0), [0.25, 0.25, 0.5])  # before the first: hold it
    np.testing.assert_allclose(s.weights_at(100.0), [0.75, 0.25, 0.0])  # after the last: hold it


def test_step_holds_until_next_keyframe(tmp_path: Path) -> None:
    s = load_schedule(write(tmp_path, BASIC.replace('"linear"', '"step"')), NAMES)
    ts = np.array([-1.0, 0.0, 1.999, 2.0, 3.9, 4.0, 9.0])
    expected = np.array(
        [
            [0.25, 0.25, 0.5],
            [0.25, 0.25, 0.5],
            [0.25, 0.25, 0.5],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
            [0.75, 0.25, 0.0],
            [0.75, 0.25, 0.0],
        ]
    )
    np.testing.assert_allclose(s.weights_at_times(ts), expected)


def test_always_on_simplex_and_vectorized_matches_scalar(tmp_path: Path) -> None:
    for interp in ("linear", "step"):
        s = load_schedule(write(tmp_path, BASIC.replace('"linear"', f'"{interp}"')), NAMES)
        ts = np.linspace(-1.0, 6.0, 701)
        w = s.weights_at_times(ts)
        assert w.shape == (701, 3)
        assert np.all(w >= 0)
        np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
        for i in (0, 150, 333, 700):
            np.testing.assert_allclose(w[i], s.weights_at(ts[i]))


def test_single_keyframe_is_constant_and_default_key(tmp_path: Path) -> None:
    text = "default = 1\n[[keyframe]]\nt = 3\nweights = { up = 2 }\n"
    s = load_schedule(write(tmp_path, text), NAMES)
    np.testing.assert_allclose(s.weights_at_times(np.array([0.0, 3.0, 10.0])), [[0.5, 0.25, 0.25]] * 3)
    assert s.track is not None and s.track.interpolation == "linear"  # the default interpolation


MOTIONS = (
    BASIC
    + """
[motion.walk]
interpolation = "step"
[[motion.walk.keyframe]]
t = 0
weights = { up = 1 }
[[motion.walk.keyframe]]
t = 1
weights = { lo = 1 }

[motion.spin]
default = 1
[[motion.spin.keyframe]]
t = 0
weights = { smooth = 2 }
"""
)


def test_per_motion_keyframes(tmp_path: Path) -> None:
    s = load_schedule(write(tmp_path, MOTIONS), NAMES, motion_names=["walk", "spin", "jump"])
    np.testing.assert_allclose(s.weights_at(0.5, motion="walk"), [1.0, 0.0, 0.0])  # step
    np.testing.assert_allclose(s.weights_at(1.0, motion="walk"), [0.0, 1.0, 0.0])
    np.testing.assert_allclose(s.weights_at(7.0, motion="spin"), [0.25, 0.25, 0.5])  # own default
    # a motion without its own keyframes (and no motion) uses the top-level ones
    np.testing.assert_allclose(s.weights_at(1.0, motion="jump"), [0.125, 0.125, 0.75])
    np.testing.assert_allclose(s.weights_at(1.0), [0.125, 0.125, 0.75])


def test_motion_only_schedule_needs_a_motion(tmp_path: Path) -> None:
    text = "[motion.walk]\n[[motion.walk.keyframe]]\nt = 0\nweights = { up = 1 }\n"
    s = load_schedule(write(tmp_path, text), NAMES)
    np.testing.assert_allclose(s.weights_at(0.0, motion="walk"), [1.0, 0.0, 0.0])
    with pytest.raises(AmorError, match="no top-level"):
        s.weights_at(0.0, motion="run")


# ---------------------------------------------------------------- bad files


KF = "[[keyframe]]\nt = {t}\nweights = {w}\n"
GOOD = KF.format(t=0, w="{ up = 1 }")

BAD_CASES = {
    "unknown objective": (
        GOOD + KF.format(t=1, w="{ upp = 1 }"),
        r"keyframe 2 \(t=1\): unknown objective 'upp'",
    ),
    "negative weight": (
        KF.format(t=0, w="{ up = -1, lo = 2 }"),
        r"keyframe 1 \(t=0\): weight up = -1 is negative",
    ),
    "infinite weight": (
        KF.format(t=0, w="{ up = inf }"),
        r"keyframe 1 \(t=0\): weight up = inf is not a finite",
    ),
    "nan weight": (KF.format(t=0, w="{ up = nan }"), "is not a finite number"),
    "string weight": (KF.format(t=0, w='{ up = "1" }'), "is not a finite number"),
    "all zero": (KF.format(t=0, w="{ up = 0 }"), r"keyframe 1 \(t=0\): all weights are zero"),
    "empty weights": (KF.format(t=0, w="{}"), "all weights are zero"),
    "times equal": (GOOD + KF.format(t=0, w="{ lo = 1 }"), r"keyframe 2 \(t=0\): .*strictly increasing"),
    "times decreasing": (KF.format(t=2, w="{ up = 1 }") + GOOD, r"keyframe 2 \(t=0\): .*strictly increasing"),
    "non-finite time": (KF.format(t="nan", w="{ up = 1 }"), "t must be a finite number"),
    "missing t": ("[[keyframe]]\nweights = { up = 1 }\n", r"keyframe 1: missing key 't'"),
    "missing weights": ("[[keyframe]]\nt = 0\n", r"keyframe 1: missing key 'weights'"),
    "no keyframes": ('interpolation = "step"\n', r"missing \[\[keyframe\]\]"),
    "unknown keyframe key": ("[[keyframe]]\nt = 0\nweight = { up = 1 }\n", "unknown key"),
    "unknown top-level key": ("interpolate = 'step'\n" + GOOD, "unknown top-level key"),
    "bad interpolation": ('interpolation = "cubic"\n' + GOOD, "interpolation must be"),
    "negative default": ("default = -1\n" + GOOD, "default must be"),
    "weights not a table": (KF.format(t=0, w="[1, 2, 3]"), "weights must be a table"),
    "malformed TOML": ("[[keyframe]\nt = 0\n", "malformed TOML"),
    "motion keyframe error": (
        "[motion.walk]\n[[motion.walk.keyframe]]\nt = 0\nweights = { up = -2 }\n",
        r"motion 'walk': keyframe 1 \(t=0\): weight up = -2 is negative",
    ),
    "unknown motion": (
        "[motion.wlak]\n[[motion.wlak.keyframe]]\nt = 0\nweights = { up = 1 }\n",
        "unknown motion",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_schedules_name_file_and_problem(tmp_path: Path, case: str) -> None:
    text, pattern = BAD_CASES[case]
    path = write(tmp_path, text, "bad.toml")
    with pytest.raises(AmorError, match=pattern) as info:
        load_schedule(path, NAMES, motion_names=["walk"])
    assert str(path) in str(info.value)


def test_unknown_motion_only_checked_when_names_given(tmp_path: Path) -> None:
    path = write(tmp_path, BAD_CASES["unknown motion"][0])
    assert "wlak" in load_schedule(path, NAMES).motions


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(AmorError, match=r"nope\.toml: file not found"):
        load_schedule(tmp_path / "nope.toml", NAMES)


# ---------------------------------------------------------------- save and load


def test_dump_load_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    w = rng.dirichlet(np.ones(3), size=4)
    w[1] = [0.0, 0.0, 1.0]
    keyframes = [(t, row) for t, row in zip([0.0, 0.5, 1.25, 3.0], w, strict=True)]
    path = tmp_path / "out" / "rec.toml"
    dump_schedule(
        keyframes,
        NAMES,
        path,
        interpolation="step",
        motion_keyframes={"walk": [(0.0, {"up": 2, "lo": 2}), (1.0, [0, 1, 3])]},
    )
    s = load_schedule(path, NAMES, motion_names=["walk"])
    assert s.track is not None
    assert s.track.interpolation == "step"
    np.testing.assert_array_equal(s.track.times, [0.0, 0.5, 1.25, 3.0])
    np.testing.assert_allclose(s.track.weights, w, rtol=0, atol=1e-15)
    np.testing.assert_allclose(s.weights_at(0.6), w[1])
    np.testing.assert_allclose(s.motions["walk"].weights, [[0.5, 0.5, 0.0], [0.0, 0.25, 0.75]])
    assert not list(path.parent.glob(".*.tmp"))  # the atomic write left no temporary file


def test_dump_quotes_odd_names(tmp_path: Path) -> None:
    names = ["up", "root vel"]
    path = tmp_path / "q.toml"
    dump_schedule([(0.0, [1.0, 3.0])], names, path, motion_keyframes={"double pirouette": [(0, [1, 0])]})
    s = load_schedule(path, names)
    np.testing.assert_allclose(s.weights_at(0.0), [0.25, 0.75])
    np.testing.assert_allclose(s.weights_at(0.0, motion="double pirouette"), [1.0, 0.0])


def test_dump_validates_before_writing(tmp_path: Path) -> None:
    path = tmp_path / "x.toml"
    with pytest.raises(AmorError, match="strictly increasing"):
        dump_schedule([(1.0, [1, 0, 0]), (1.0, [0, 1, 0])], NAMES, path)
    with pytest.raises(AmorError, match="expected 3"):
        dump_schedule([(0.0, [1, 0])], NAMES, path)
    with pytest.raises(AmorError, match="unknown objective"):
        dump_schedule([(0.0, {"speed": 1})], NAMES, path)
    with pytest.raises(AmorError, match="no keyframes"):
        dump_schedule([], NAMES, path)
    assert not path.exists()


def test_documented_example_schedules_load() -> None:
    names = ("up", "lo", "feet", "rbs", "root", "vel", "smooth")
    examples = sorted(
        p
        for p in (Path(__file__).resolve().parents[1] / "docs" / "examples").glob("*.toml")
        if "randomize" not in p.name  # deploy randomization files, not schedules (tests/test_deploy.py)
    )
    assert len(examples) >= 2
    for path in examples:
        schedule = load_schedule(path, names, motion_names=["walk"])
        w = schedule.weights_at(10.0)
        assert abs(float(w.sum()) - 1.0) < 1e-9
        assert w[names.index("smooth")] > 1.0 / len(names)  # every example ends favouring smooth


def test_dump_writes_tomlkit_toml_with_quoted_names_and_huge_weights(tmp_path) -> None:
    import tomllib

    from amorctl.core.schedule import dump_schedule, load_schedule

    path = tmp_path / "s.toml"
    names = ["up", "a b"]
    dump_schedule(
        [(0.0, [1e308, 1e308]), (1.5, {"a b": 1})],
        names,
        path,
        motion_keyframes={'walker/turn "x"': [(0.0, [1, 3])]},
    )
    doc = tomllib.loads(path.read_text())
    assert doc["keyframe"][0]["weights"] == {"up": 0.5, "a b": 0.5}
    back = load_schedule(path, names)
    assert back.weights_at(0.0).tolist() == [0.5, 0.5]
    assert back.weights_at(0.0, 'walker/turn "x"').tolist() == [0.25, 0.75]


def test_deeply_nested_or_huge_schedule_is_one_error(tmp_path) -> None:
    from amorctl.core.errors import AmorError
    from amorctl.core.schedule import load_schedule

    path = tmp_path / "deep.toml"
    path.write_text("default = " + "[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(AmorError, match=r"deep\.toml"):
        load_schedule(path, ["up"])
    path.write_text("[[keyframe]]\nt = 0\nweights = { up = 1e308, lo = 1e308 }\n")
    assert load_schedule(path, ["up", "lo"]).weights_at(3.0).tolist() == [0.5, 0.5]
