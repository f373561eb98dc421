"""Importers on the real DeepMimic clips: frame counts and durations match the source files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from amorctl.core.errors import AmorError
from amorctl.motion.builtin import deepmimic_clips
from amorctl.motion.formats import ImportOptions, get_importer, import_file, importers, infer_format
from amorctl.motion.resample import resample_source
from amorctl.motion.source import keypoint_positions


def test_builtin_set_has_the_20_clips_with_short_names(deepmimic_dir):
    names = [n for n, _ in deepmimic_clips()]
    assert len(names) == 20
    assert {"walk", "backflip", "run", "walker/turn_left0", "walker/0walk_forward"} <= set(names)


def test_every_clip_keeps_frame_count_and_duration(deepmimic_dir):
    for name, path in deepmimic_clips():
        rows = json.loads(path.read_text())["Frames"]
        duration = sum(r[0] for r in rows[:-1])  # dt of row i = time to row i+1
        motion = import_file(path, None, ImportOptions(name=name))
        assert motion.name == name
        assert motion.times.shape == (len(rows),)
        assert motion.root_pos.shape == (len(rows), 3)
        assert motion.local_quat.shape == (len(rows), 13, 4)
        assert motion.times[-1] == pytest.approx(duration, abs=1e-9)
        res = resample_source(motion, 50.0)
        assert res.times.shape[0] == int(np.floor(duration * 50 + 1e-6)) + 1
        assert res.times[-1] == pytest.approx(duration, abs=0.02)


def test_y_up_becomes_z_up(clip_path):
    """Walking: head above root above feet, root height like the source's y."""
    motion = import_file(clip_path("walk"), None, ImportOptions())
    rows = np.array(json.loads(clip_path("walk").read_text())["Frames"])
    np.testing.assert_allclose(motion.root_pos[:, 2], rows[:, 2])  # DeepMimic y -> MuJoCo z
    np.testing.assert_allclose(motion.root_pos[:, 1], -rows[:, 3])  # DeepMimic z -> MuJoCo -y
    kp = keypoint_positions(motion)
    assert (kp["head"][:, 2] > kp["root"][:, 2] + 0.3).all()
    assert (kp["left_foot"][:, 2] < kp["root"][:, 2] - 0.5).all()
    assert (kp["left_foot"][:, 1] > kp["right_foot"][:, 1]).mean() > 0.9  # left is +y when facing +x


def test_registry_and_format_inference(tmp_path):
    assert {"deepmimic", "bvh", "npz"} <= set(importers())
    assert infer_format(tmp_path / "a.bvh") == "bvh"
    assert infer_format(tmp_path / "a.npz") == "npz"
    assert infer_format(tmp_path / "a.txt") == "deepmimic"
    with pytest.raises(AmorError, match="cannot tell the motion format"):
        infer_format(tmp_path / "a.xyz")
    with pytest.raises(AmorError, match="unknown motion format 'fbx'"):
        get_importer("fbx")
