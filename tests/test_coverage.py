"""``amorctl pareto --coverage``: predicted vs achieved scalarized return per simplex region."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from amorctl.analysis.coverage import (
    coverage,
    coverage_to_dict,
    feasible_regions,
    stratified_weights,
    training_episodes,
)
from amorctl.analysis.eval_env import episode_limit, make_eval_env
from amorctl.analysis.schemas import COVERAGE_JSON_SCHEMA
from amorctl.cli.main import main
from amorctl.core.simplex_regions import NUM_BINS, region_index
from amorctl.core.vecenv import close_env
from amorctl.envs.wrappers import FixedWeights
from amorctl.train.rundir import RunDir


def test_feasible_regions() -> None:
    # m = 2: the dominant weight is >= 0.5, so only the two upper bins of each objective
    np.testing.assert_array_equal(feasible_regions(2), [False, False, True, True] * 2)
    assert feasible_regions(7).all()


@pytest.mark.parametrize("m", [2, 3, 7])
def test_stratified_weights_fill_every_feasible_region(m: int) -> None:
    feasible = np.flatnonzero(feasible_regions(m))
    k = 3 * len(feasible) + 1
    w = stratified_weights(m, k, seed=4)
    assert w.shape == (k, m)
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    assert (w >= 0).all()
    counts = np.bincount(region_index(w), minlength=m * NUM_BINS)
    assert counts.sum() == k
    assert set(np.flatnonzero(counts)) == set(feasible)
    assert counts[feasible].min() == 3 and counts[feasible].max() == 4


def test_coverage_on_toy_run(toy_run: Path) -> None:
    run = RunDir(toy_run)
    policy, config = run.policy(), run.config
    w = stratified_weights(2, 12, seed=0)
    cov = coverage(policy, config, w, seed=5, metrics_path=run.metrics_path)
    doc = coverage_to_dict(cov)
    regions = doc["regions"]
    assert sum(r["samples"] for r in regions) == 12  # every sample in exactly one region
    assert [r["samples"] for r in regions if not r["feasible"]] == [0, 0, 0, 0]
    # predicted = w . V(s_0): the critic on the same first observations (same env, same seed)
    env, _ = make_eval_env(config, 12, seed=5)
    obs, _ = FixedWeights(env, w).reset(seed=5)
    first = np.array(obs, dtype=np.float32)
    first[:, -2:] = w
    np.testing.assert_allclose(cov.predicted, (policy.values(first) * w).sum(axis=1), rtol=1e-6)
    # toy rewards are positive: discounting can only lower the return, by at most gamma^T
    t = episode_limit(env)
    close_env(env)
    assert t > 0
    assert (cov.achieved <= cov.achieved_undiscounted + 1e-9).all()
    assert (cov.achieved >= config.ppo.gamma**t * cov.achieved_undiscounted - 1e-9).all()
    # training episodes per region: the run's wcount/ columns, which add up to its episodes
    train = training_episodes(run.metrics_path, policy.objectives)
    assert train is not None and doc["training_logged"]
    last = [ln for ln in run.metrics_path.read_text().splitlines() if ln][-1]
    header = run.metrics_path.read_text().splitlines()[0].split(",")
    assert train.sum() == float(last.split(",")[header.index("episodes")])
    shares = [r["training_share"] for r in regions if r["training_share"] is not None]
    assert sum(shares) == pytest.approx(1.0)


def test_training_episodes_missing_columns(tmp_path: Path) -> None:
    path = tmp_path / "metrics.csv"
    path.write_text("iteration,episodes\n1,4\n")
    assert training_episodes(path, ("a", "b")) is None  # a run logged before wcount/ existed
    assert training_episodes(tmp_path / "none.csv", ("a", "b")) is None


def test_pareto_coverage_cli(toy_run: Path, tmp_path: Path, capsys) -> None:
    code = main(["pareto", str(toy_run), "--coverage", "-k", "8", "--out", str(tmp_path), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads(out)
    jsonschema.validate(doc, COVERAGE_JSON_SCHEMA)
    assert doc["samples"] == 8 and sum(r["samples"] for r in doc["regions"]) == 8
    on_disk = json.loads((tmp_path / "coverage.json").read_text())
    assert on_disk == doc
    assert (tmp_path / "coverage.png").stat().st_size > 1000 and (tmp_path / "coverage.svg").is_file()
    ps = doc["per_sample"]
    for r in doc["regions"]:  # each region's mean is the mean of its samples
        sel = [i for i, g in enumerate(ps["region"]) if doc["regions"][g]["region"] == r["region"]]
        if sel:
            assert r["predicted"] == pytest.approx(np.mean([ps["predicted"][i] for i in sel]))


def test_docs_print_the_coverage_schema() -> None:
    import re

    text = (Path(__file__).parent.parent / "docs" / "pareto.md").read_text(encoding="utf-8")
    blocks = [json.loads(b) for b in re.findall(r"```json\n(.*?)```", text, flags=re.S)]
    assert COVERAGE_JSON_SCHEMA in blocks, "docs/pareto.md does not show the current coverage schema"
