"""The config schema: presets, layering, resolved TOML round trip, unknown keys named."""

from __future__ import annotations

from pathlib import Path

import pytest

from amorctl.core.config import TrainConfig, config_docs, load_config, load_preset, merge, override, to_toml
from amorctl.core.errors import AmorError


def test_presets_have_the_documented_sizes() -> None:
    quick, paper = load_preset("quick"), load_preset("paper")
    assert quick == TrainConfig()  # the schema defaults are the quick preset
    assert quick.network.actor_hidden == (256, 256, 256) and quick.env.num_envs == 256
    assert paper.network.actor_hidden == (1024,) * 4 and paper.network.critic_hidden == (1024,) * 4
    assert paper.env.num_envs == 8192 and paper.run.iterations == 300_000


def test_resolved_toml_round_trips(tmp_path: Path) -> None:
    config = override(load_preset("paper"), env__fixed_weights='up=1,"x"', ppo__learning_rate=3e-4)
    path = tmp_path / "c.toml"
    path.write_text(to_toml(config))
    assert load_config(path) == config


def test_every_field_has_a_one_line_doc() -> None:
    for section, docs in config_docs().items():
        for key, doc in docs.items():
            assert doc and "\n" not in doc, (section, key)


def test_partial_file_overrides_only_its_keys(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text("[ppo]\nlearning_rate = 1\n[network]\nactor_hidden = [8]\n")
    config = load_config(path, load_preset("paper"))
    assert config.ppo.learning_rate == 1.0 and isinstance(config.ppo.learning_rate, float)
    assert config.network.actor_hidden == (8,)
    assert config.env.num_envs == 8192


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[ppo]\nlerning_rate = 1e-3\n", "unknown key 'lerning_rate' in \\[ppo\\]"),
        ("[optimizer]\nlr = 1\n", "unknown section \\[optimizer\\]"),
        ("[env]\nnum_envs = 'many'\n", "num_envs: expected an integer"),
        ("[env]\nnum_envs = 0\n", "num_envs must be >= 1"),
        ("[env]\nkind = 'atari'\n", "kind must be one of"),
        ("[ppo\n", "not valid TOML"),
    ],
)
def test_bad_config_is_rejected_naming_the_problem(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(AmorError, match=message) as info:
        load_config(path)
    assert str(path) in str(info.value)


def test_unknown_preset_and_missing_file() -> None:
    with pytest.raises(AmorError, match="unknown preset 'fast'"):
        load_preset("fast")
    with pytest.raises(AmorError, match="not found"):
        load_config("/nonexistent/x.toml")
    with pytest.raises(AmorError, match="unknown key"):
        merge(TrainConfig(), {"run": {"sed": 1}})
