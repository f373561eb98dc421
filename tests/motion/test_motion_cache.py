"""The cache helper `amorctl train` uses, and (slow) the full built-in preprocessing."""

from __future__ import annotations

import pytest

from amorctl.motion.cache import CACHE_ENV, cache_dir, default_dataset
from amorctl.motion.dataset import load_dataset
from amorctl.motion.vae import VaeConfig


def test_default_dataset_is_built_once(tmp_path, monkeypatch, deepmimic_dir):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    assert cache_dir() == tmp_path
    tiny = VaeConfig(window=2, latent_dim=2, hidden=16, epochs=1)
    path = default_dataset("humanoid36", vae=tiny)
    assert path.parent.parent == tmp_path and path.is_file()
    stamp = path.stat().st_mtime_ns
    assert default_dataset("humanoid36") == path
    assert path.stat().st_mtime_ns == stamp
    lib = load_dataset(path)
    assert len(lib.clips) == 20 and lib.latent_dim == 2


@pytest.mark.slow
@pytest.mark.parametrize("character", ["humanoid36", "biped20"])
def test_full_builtin_preprocess(character, tmp_path, deepmimic_dir):
    from amorctl.motion.preprocess import preprocess

    report = preprocess([], character=character, out=tmp_path / "d.mcap", builtin="deepmimic")
    assert len(report.clips) == 20
    assert report.vae["heldout_recon_mse"] < 0.3 * report.vae["untrained_heldout_recon_mse"]
    assert max(c["retarget_error_m"] for c in report.clips) < 0.1
