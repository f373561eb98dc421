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
    config = override(
        load_preset("paper"),
        env__fixed_weights="up=1, lo=2",
        env__dataset='d\\ "quoted" ü.mcap',
        ppo__learning_rate=3e-4,
    )
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
        ("[env]\nnum_envs = 0\n", r"\[env\] num_envs = 0 is out of range \(1..65536\)"),
        ("[ppo]\nnum_steps = 100000000\n", r"\[ppo\] num_steps = 100000000 is out of range \(1..100000\)"),
        ("[env]\nepisode_seconds = 1e308\n", r"episode_seconds = 1e\+308 is out of range \(> 0 and <= 3600"),
        ("[network]\nactor_hidden = [100000000]\n", r"actor_hidden = \[100000000\]: entry 100000000 is out"),
        ("[network]\nactor_hidden = []\n", "expected 1 to 16 entries"),
        ("[env]\nnum_envs = 65536\n[ppo]\nnum_steps = 100000\n", "exceeds the largest rollout batch"),
        ("[env]\nfixed_weights = 'up=1,,lo=1'\n", r"\[env\] fixed_weights: empty item"),
        ("[env]\nfixed_weights = ' '\n", r"\[env\] fixed_weights: empty weights"),
        ("[ppo]\ngamma = -0.5\n", r"gamma = -0.5 is out of range \(0..1\)"),
        ("[run]\nseed = -1\n", r"seed = -1 is out of range"),
        ("a = " + "[" * 5000 + "]" * 5000 + "\n", "not valid TOML"),
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


def test_resolved_toml_is_written_by_tomlkit_with_docs_as_comments() -> None:
    text = to_toml(TrainConfig())
    assert text.startswith("# amorctl training config, fully resolved")
    assert 'kind = "tracking" # environment: tracking' in text
    assert "actor_hidden = [256, 256, 256] # hidden layer widths of the actor" in text


def test_command_line_errors_name_the_flag(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from amorctl.cli.main import main

    out = tmp_path / "run"
    for args, message in [
        (["--num-envs", "0"], "error: --num-envs: [env] num_envs = 0 is out of range (1..65536)"),
        (["--seed", "-3"], "error: --seed: [run] seed = -3 is out of range"),
        (["--fixed-weights", ""], "error: --fixed-weights: empty weights"),
        (["--fixed-weights", "right=1,,left=1"], "error: --fixed-weights: empty item"),
    ]:
        assert main(["train", "--env", "toy", "--out", str(out), *args]) == 2
        err = capsys.readouterr().err
        assert err.startswith(message) and err.count("\n") == 1, err
        assert not out.exists()


def test_bounds_live_in_the_schema_metadata() -> None:
    from dataclasses import fields

    from amorctl.core.config import SECTIONS

    for section, cls in SECTIONS.items():
        for f in fields(cls):
            if f.type in ("int", "float", "tuple[int, ...]"):
                bounds = {"min", "max", "gt"} & set(f.metadata)
                assert bounds, (section, f.name)
