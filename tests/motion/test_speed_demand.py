"""Joint-speed demand of reference clips against the servos' no-load speed (``amorctl data speeds``)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from amorctl.analysis.speed_demand import clip_speed_demand, speed_demand
from amorctl.cli.main import main
from amorctl.envs.synthetic import synthetic_library
from amorctl.motion.dataset import write_dataset
from amorctl.registry import get_registry
from amorctl.train import pretrained


def test_one_clip_counts_samples_frames_and_the_joint_most_above() -> None:
    joint_vel = np.array([[1.0, -6.0], [2.0, 7.0], [3.0, 0.0], [-10.0, 0.0]])  # [F=4, J=2]
    d = clip_speed_demand("c", joint_vel, ("a", "b"), no_load_speed=5.0)
    speed = np.abs(joint_vel)
    assert d.p50_rad_s == pytest.approx(np.percentile(speed, 50))
    assert d.p95_ratio == pytest.approx(np.percentile(speed, 95) / 5.0)
    assert (d.share_above, d.frames_above, d.fastest_joint, d.max_rad_s) == (3 / 8, 3 / 4, "b", 10.0)
    free = clip_speed_demand("c", joint_vel, ("a", "b"), no_load_speed=None)
    assert free.p95_rad_s == d.p95_rad_s and free.share_above is None and free.fastest_joint is None
    slow = clip_speed_demand("c", joint_vel / 100, ("a", "b"), no_load_speed=5.0)
    assert slow.share_above == 0.0 and slow.fastest_joint is None


def test_a_non_positive_no_load_speed_is_refused() -> None:
    lib = synthetic_library(get_registry().character("biped20"), num_clips=1, seconds=0.5)
    with pytest.raises(ValueError, match="no_load_speed"):
        speed_demand(lib, 0.0)


def test_the_shipped_repertoire_dataset_asks_run_for_more_than_the_servo_has(capsys) -> None:
    """The real clips: walking stays under biped20's no-load speed at p95, run far above it."""
    data = pretrained.package_folder() / "biped20-repertoire" / "dataset.mcap"
    assert main(["data", "speeds", str(data), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["no_load_speed_rad_s"] == pytest.approx(46 * 2 * np.pi / 60)
    clips = {c["clip"]: c for c in shown["clips"]}
    assert len(clips) == 20
    assert all(clips[n]["p95_ratio"] < 1.0 and clips[n]["share_above"] < 0.05 for n in clips if "walk" in n)
    assert clips["run"]["p95_ratio"] > 3.0 and clips["run"]["share_above"] > 0.3
    assert main(["data", "speeds", str(data)]) == 0
    assert "backflip" in capsys.readouterr().out


def test_a_character_without_a_speed_limit_gets_speeds_only(tmp_path, capsys) -> None:
    lib = synthetic_library(get_registry().character("humanoid36"), num_clips=2, seconds=1.0)
    path = tmp_path / "h.mcap"
    write_dataset(path, lib)
    assert main(["data", "speeds", str(path), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["no_load_speed_rad_s"] is None
    first = lib.joint_vel[: lib.clips[0].num_frames]
    assert shown["clips"][0]["p95_rad_s"] == pytest.approx(np.percentile(np.abs(first), 95))
    assert shown["clips"][0]["share_above"] is None


def test_a_dataset_for_a_character_not_installed_is_one_error_line(tmp_path, capsys) -> None:
    lib = synthetic_library(get_registry().character("biped20"), num_clips=1, seconds=0.5)
    path = tmp_path / "x.mcap"
    write_dataset(path, dataclasses.replace(lib, character="no_such_robot"))
    assert main(["data", "speeds", str(path)]) == 2
    err = capsys.readouterr().err
    assert "no_such_robot" in err and err.count("\n") == 1, err
