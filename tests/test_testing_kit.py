"""The plugin authors' testing kit: the built-in plugins and the stickman fixture pass
its contract suites, and the suites catch broken plugins."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from amorctl.registry import get_registry
from amorctl.testing import check_backend, check_character, check_objective_set, tiny_dataset


def _character(name: str):
    registry = get_registry()
    if name not in registry.names("character"):
        pytest.skip(f"character {name} not installed (pip install ./tests/plugins/amorctl-stickman)")
    return registry.character(name)


@pytest.mark.parametrize("name", ["humanoid36", "biped20"])
def test_builtin_characters_meet_the_contract(name: str) -> None:
    report = check_character(_character(name))
    by_name = {c.name: c for c in report}
    assert by_name["hold"].status == "pass"
    assert by_name["sensors"].values["max_error_m"] < 1e-9


def test_stickman_fixture_meets_the_contract_without_the_hold() -> None:
    # The stickman is a test fixture that is not tuned to balance unaided (its spec says so).
    report = check_character(_character("stickman12"), hold=False)
    assert {c.name for c in report} >= {"model", "actuators", "floor", "sensors", "gains", "standing_height"}


@pytest.mark.parametrize("name", ["humanoid36", "biped20", "stickman12"])
def test_tracking7_meets_the_objective_contract(name: str) -> None:
    check_objective_set(get_registry().objective_set("tracking7"), _character(name))


def test_torch_cpu_backend_meets_the_contract(tmp_path: Path) -> None:
    spec = _character("biped20")
    check_backend(get_registry().backend("torch-cpu"), spec, tiny_dataset(spec, tmp_path / "ds.mcap"))


def test_check_character_names_what_is_broken() -> None:
    spec = _character("biped20")
    bad = dataclasses.replace(spec, standing_height=spec.standing_height + 0.2)
    with pytest.raises(AssertionError, match="standing_height"):
        check_character(bad, hold=False)
    ungrouped = dataclasses.replace(spec, joints=tuple(j for j in spec.joints if j.group != "feet"))
    with pytest.raises(AssertionError, match="no joint in group 'feet'"):
        check_character(ungrouped, hold=False)


def test_check_objective_set_catches_out_of_bounds_rewards() -> None:
    good = get_registry().objective_set("tracking7")

    def make(ch):
        obj = good.make(ch)
        obj.high = np.asarray(obj.high) - 10.0  # claims a bound its rewards exceed
        obj.low = np.minimum(np.asarray(obj.low), obj.high)
        return obj

    with pytest.raises(AssertionError, match="outside"):
        check_objective_set(dataclasses.replace(good, make=make), _character("biped20"), jax=False)


def test_pytest_plugin_fixtures_register_a_character(register_character, amorctl_registry) -> None:
    spec = dataclasses.replace(_character("biped20"), name="biped20-copy")
    register_character(spec)
    assert get_registry().character("biped20-copy") is spec
    assert "biped20-copy" in amorctl_registry.names("character")


@pytest.mark.slow
def test_jax_mjx_backend_meets_the_contract(tmp_path: Path) -> None:
    """About 150 s on 2 CPU cores (XLA compilation): kept out of the default run."""
    registry = get_registry()
    if "jax-mjx" not in registry.names("backend"):
        pytest.skip("jax-mjx backend not installed (pip install amorctl[jax])")
    spec = _character("biped20")
    check_backend(registry.backend("jax-mjx"), spec, tiny_dataset(spec, tmp_path / "ds.mcap"))


def _doc_tables(text: str) -> list[list[list[str]]]:
    """Markdown tables of ``text``: each a list of rows, each a list of cells (header row first)."""
    tables: list[list[list[str]]] = []
    current: list[list[str]] = []
    for line in [*text.splitlines(), ""]:
        if line.startswith("|"):
            cells = [c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
            if not set("".join(cells)) <= {"-", " "}:
                current.append(cells)
        elif current:
            tables.append(current)
            current = []
    return tables


def test_plugins_doc_describes_every_spec_field() -> None:
    """docs/plugins.md's spec reference: one row per dataclass field of every spec type, with a
    type, a unit and a status (character, joint and actuator fields) or a type and a meaning."""
    from amorctl.core import specs

    doc = (Path(__file__).resolve().parents[1] / "docs" / "plugins.md").read_text()
    section = doc[doc.index("## Character spec reference") : doc.index("## Adding a real robot")]
    tables = _doc_tables(section)
    five = [t for t in tables if t[0] == ["field", "type", "unit", "status", "meaning"]]
    assert len(five) == 3
    statuses = re.compile(r"^(enforced|checked|informational)\b")
    for cls, table in zip((specs.CharacterSpec, specs.JointSpec, specs.ActuatorModel), five, strict=True):
        rows = {r[0].strip("`"): r for r in table[1:]}
        assert list(rows) == [f.name for f in dataclasses.fields(cls)], cls.__name__
        for name, (_, type_, unit, status, meaning) in rows.items():
            assert type_ and unit and meaning and statuses.match(status), (cls.__name__, name, status)
    (others,) = [t for t in tables if t[0] == ["spec", "field", "type", "meaning"]]
    documented = [(r[0].strip("`"), r[1].strip("`")) for r in others[1:] if r[2] and r[3]]
    small = (specs.LazyCharacter, specs.ObjectiveSetSpec, specs.BackendSpec, specs.MotionFormatSpec)
    expected = [
        (cls.__name__, f.name) for cls in (*small, specs.ImportOptions) for f in dataclasses.fields(cls)
    ]
    assert sorted(documented) == sorted(expected)


def test_plugins_doc_lists_every_api_name() -> None:
    from amorctl import api

    doc = (Path(__file__).resolve().parents[1] / "docs" / "plugins.md").read_text()
    section = doc[doc.index("## `amorctl.api`") : doc.index("## Writing a plugin package")]
    assert set(api.__all__) <= set(re.findall(r"`(\w+)", section))
