"""``--data DATASET`` on evaluate / pareto / tune: held-out clips re-encoded with the
run's own VAE, and a clear refusal when they do not fit the run."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from amorctl.cli.main import main
from amorctl.core.errors import AmorError
from amorctl.envs.synthetic import synthetic_library
from amorctl.motion.dataset import load_dataset, write_dataset
from amorctl.motion.heldout import dataset_for_run
from amorctl.motion.vae import VaeConfig, encoder_from_bytes, encoder_to_bytes, train_vae
from amorctl.registry import get_registry


def _vae_dataset(path: Path, seed: int) -> Path:
    """A biped20 dataset whose latents come from a small trained VAE (stored with it)."""
    lib = synthetic_library(get_registry().character("biped20"), num_clips=3, seconds=1.0, seed=seed)
    starts = np.array([c.start for c in lib.clips])
    lengths = np.array([c.num_frames for c in lib.clips])
    cfg = VaeConfig(window=2, latent_dim=3, hidden=16, epochs=2, batch_size=64)
    vae = train_vae(lib.frames, starts, lengths, cfg)
    blob = encoder_to_bytes(vae, lib.frames.shape[1])
    z = encoder_from_bytes(blob).encode(lib.frames, starts, lengths).astype(np.float32)
    write_dataset(path, dataclasses.replace(lib, z=z), encoder=blob)
    return path


def test_held_out_clips_get_the_run_vae_latents(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("AMORCTL_CACHE_DIR", str(tmp_path / "cache"))
    run_ds = _vae_dataset(tmp_path / "run.mcap", seed=1)
    other = _vae_dataset(tmp_path / "other.mcap", seed=2)  # its own VAE: other latents
    out = dataset_for_run(run_ds, other)
    assert out != other and out.is_relative_to(tmp_path / "cache")
    lib, own = load_dataset(out), load_dataset(other)
    np.testing.assert_array_equal(lib.frames, own.frames)
    starts = np.array([c.start for c in own.clips])
    lengths = np.array([c.num_frames for c in own.clips])
    from amorctl.motion.dataset import load_encoder_bytes

    expected = encoder_from_bytes(load_encoder_bytes(run_ds)).encode(own.frames, starts, lengths)
    np.testing.assert_allclose(lib.z, expected, atol=1e-6)
    assert not np.allclose(lib.z, own.z, atol=1e-3)
    assert dataset_for_run(run_ds, other) == out  # cached
    assert dataset_for_run(run_ds, run_ds) == run_ds


def test_mismatched_datasets_are_refused(tmp_path: Path) -> None:
    run_ds = tmp_path / "run.mcap"
    write_dataset(run_ds, synthetic_library(get_registry().character("biped20"), num_clips=1, seconds=0.5))
    human = tmp_path / "human.mcap"
    write_dataset(human, synthetic_library(get_registry().character("humanoid36"), num_clips=1, seconds=0.5))
    with pytest.raises(
        AmorError, match=r"human\.mcap: does not fit the run's dataset .*run\.mcap: character 'humanoid36'"
    ):
        dataset_for_run(run_ds, human)
    lib = synthetic_library(get_registry().character("biped20"), num_clips=1, seconds=0.5, seed=4)
    wide = tmp_path / "wide.mcap"
    write_dataset(wide, dataclasses.replace(lib, z=np.zeros((lib.num_frames, 5), dtype=np.float32)))
    with pytest.raises(AmorError, match=r"latents have size 5, the run's 2.*no VAE encoder"):
        dataset_for_run(run_ds, wide)
    # Same character, another joint order, frame rate and frame layout: each named.
    other = tmp_path / "other.mcap"
    frames = np.concatenate([lib.frames, np.zeros((lib.num_frames, 1), lib.frames.dtype)], axis=1)
    write_dataset(
        other,
        dataclasses.replace(lib, joint_names=lib.joint_names[::-1], fps=lib.fps / 2, frames=frames),
    )
    with pytest.raises(AmorError) as info:
        dataset_for_run(run_ds, other)
    message = str(info.value)
    assert message.startswith(f"{other}: does not fit the run's dataset {run_ds}: ")
    assert (
        "joint names or order differ" in message
        and f"{lib.fps / 2:g} fps, the run's is {lib.fps:g}" in message
    )
    width = lib.frames.shape[1]
    assert f"frame layout differs ({width + 1} vs {width} features)" in message


def test_evaluate_pareto_and_tune_take_held_out_data(tracking_run: Path, tmp_path: Path, capsys) -> None:
    lib = synthetic_library(get_registry().character("biped20"), num_clips=1, seconds=1.0, seed=11)
    held = tmp_path / "held.mcap"
    write_dataset(
        held, dataclasses.replace(lib, clips=(dataclasses.replace(lib.clips[0], name="held_sway"),))
    )
    args = ["evaluate", str(tracking_run), "--data", str(held), "--episodes", "1"]
    code = main([*args, "--motion", "held_sway", "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads(out)
    assert doc["motions"] == ["held_sway"]
    # a clip of the training data is not in the held-out set
    code = main([*args, "--motion", "sway_a"])
    assert code == 2 and "held_sway" in capsys.readouterr().err
    tune = ["tune", str(tracking_run), "--data", str(held), "--weights", "up=1", "--seconds", "0.2", "--json"]
    code = main(tune)
    out, err = capsys.readouterr()
    assert code == 0, err
    assert json.loads(out)["motion"] == "held_sway"
    pareto = ["pareto", str(tracking_run), "--data", str(held), "-k", "2", "--out", str(tmp_path / "p")]
    code = main([*pareto, "--motion", "held_sway", "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert [g["motion"] for g in json.loads(out)["motions"]] == ["held_sway"]
    human = tmp_path / "human.mcap"
    write_dataset(human, synthetic_library(get_registry().character("humanoid36"), num_clips=1, seconds=0.5))
    for command in (["evaluate"], ["pareto", "--samples", "2"], ["tune", "--weights", "up=1"]):
        code = main([*command, str(tracking_run), "--data", str(human)])
        err = capsys.readouterr().err
        assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, (command, err)
        assert "human.mcap: does not fit the run's dataset" in err and "character 'humanoid36'" in err
