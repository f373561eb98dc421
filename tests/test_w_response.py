"""benchmarks/w_response.py's smoke version on the toy env: trains, measures, reports."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "w_response.py"


def _module():
    spec = importlib.util.spec_from_file_location("w_response", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["w_response"] = module
    spec.loader.exec_module(module)
    return module


def test_toy_testbed_trains_measures_and_collects(tmp_path: Path) -> None:
    w_response = _module()
    args = ["--env", "toy", "--budget-steps", "60000", "--seeds", "0", "--no-capql", "--episodes", "4"]
    report = w_response.main([*args, "--front-samples", "16", "--out", str(tmp_path / "a")])
    (row,) = report["results"]
    assert row["method"] == "moppo:paper" and row["env_steps"] >= 60000
    for name in ("right", "left"):
        sweep = row["sweeps"][name]
        assert len(sweep["mean"]) == 11 and sweep["levels"][0] == 0.0 and sweep["levels"][-1] == 1.0
        assert sweep["spearman_rho"] > 0.5, (name, sweep)  # the toy task responds to w within seconds
        assert 0 <= sweep["survivors"] <= 44 and sweep["spearman_rho_per_step"] > 0.5, (name, sweep)
    assert row["front"]["hypervolume"] > 0 and row["front"]["reference_point"] == [-100.0, -100.0]
    assert 0 < row["front"]["non_dominated_fraction"] <= 1
    # two reports (as from two processes) merge into one table with both seeds
    other = json.loads((tmp_path / "a" / "w_response.json").read_text())
    other["results"][0]["seed"] = 1
    (tmp_path / "b.json").write_text(json.dumps(other))
    merged = w_response.main(
        [
            "--collect",
            str(tmp_path / "a" / "w_response.json"),
            str(tmp_path / "b.json"),
            "--out",
            str(tmp_path / "c"),
        ]
    )
    assert [r["seed"] for r in merged["results"]] == [0, 1]
    assert merged["table"][2].startswith("| moppo:paper | 2 |")
    assert merged["table"][6].startswith("| moppo:paper | ") and "per step" in merged["table"][4]

    # measuring the trained run again (no training) gives the same sweeps: rollouts are seeded
    measure = ["--measure", str(tmp_path / "a" / "paper-s0"), "--out", str(tmp_path / "d")]
    again = w_response.main([*measure, "--episodes", "4", "--front-samples", "16"])
    (remeasured,) = again["results"]
    assert remeasured["method"] == "moppo:paper" and remeasured["seed"] == 0
    assert remeasured["env_steps"] == row["env_steps"] and remeasured["sweeps"] == row["sweeps"]
