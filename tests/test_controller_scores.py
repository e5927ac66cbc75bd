"""A run's score is its committed controller's score: gsa_jax.score's controller_score equals gsa_jax.deploy's return
from the same start states, is kept while the file is unchanged, and is what gsa_jax.plot's tables use."""

import csv
import json
import os
import shutil

import pytest

from gsa_jax.analysis.sweeps import controller_scores as cs

COMMITTED = os.path.join(os.path.dirname(__file__), "..", "experiments", "fig1_v5", "results",
                         "fig1_v5_InvertedDoublePendulum-v5", "controllers")


@pytest.fixture
def one_controller(tmp_path):
    d = tmp_path / "results"
    (d / "controllers").mkdir(parents=True)
    for name in ("InvertedDoublePendulum-v5-mixture-K2-s3.npz", "InvertedDoublePendulum-v5-mlp-s1.npz"):
        shutil.copy(os.path.join(COMMITTED, name), d / "controllers" / name)
    return d


def test_controller_score_is_deploys_return_from_the_same_starts(one_controller, tmp_path):
    """gsa score and gsa deploy without seed options score the same starts (the selection starts,
    gsa_jax.deployment.starts): the same number."""
    from gsa_jax.deploy import main as deploy
    from gsa_jax.deployment import starts
    from gsa_jax.score import main as score

    assert score([str(one_controller)]) == 0
    rows = cs.read_scores(str(one_controller / cs.FILE))
    assert set(rows) == {"InvertedDoublePendulum-v5-mixture-K2-s3", "InvertedDoublePendulum-v5-mlp-s1"}
    for label, row in rows.items():
        out = tmp_path / f"{label}.json"
        assert deploy([str(one_controller / "controllers" / f"{label}.npz"), "--out", str(out)]) == 0
        assert float(row["controller_score"]) == pytest.approx(json.loads(out.read_text())["mujoco_c"]["return_mean"], abs=1e-4)
        assert row["episodes"] == str(starts.SELECTION_EPISODES) and row["start_seed"] == str(starts.SELECTION_SEED)
    assert rows["InvertedDoublePendulum-v5-mixture-K2-s3"]["K"] == "2" and rows["InvertedDoublePendulum-v5-mixture-K2-s3"]["seed"] == "3"


def test_scores_are_kept_while_the_file_is_unchanged(one_controller, monkeypatch):
    first = cs.score_directory(str(one_controller), episodes=2, log=None)
    calls = []
    monkeypatch.setattr(cs, "score_controller", lambda path, *a: calls.append(path) or {})
    assert cs.score_directory(str(one_controller), episodes=2, log=None) == first and calls == []
    monkeypatch.undo()
    ctrl = one_controller / "controllers" / "InvertedDoublePendulum-v5-mlp-s1.npz"
    shutil.copy(one_controller / "controllers" / "InvertedDoublePendulum-v5-mixture-K2-s3.npz", ctrl)
    again = cs.score_directory(str(one_controller), episodes=2, log=None)  # another file under the same name: scored again
    row = again["InvertedDoublePendulum-v5-mlp-s1"]
    assert row["sha256"] == cs.file_sha256(str(ctrl)) and row["policy"] == "mixture"
    assert row["controller_score"] == again["InvertedDoublePendulum-v5-mixture-K2-s3"]["controller_score"]
    assert cs.score_directory(str(one_controller), episodes=3, log=None)["InvertedDoublePendulum-v5-mlp-s1"]["episodes"] == "3"


def test_plot_tables_use_the_controller_scores(tmp_path):
    """The committed IDP-v5 sweep with its controllers scored: per_run_scores.csv carries controller_score, and
    final_returns.csv's IQM is the controller scores' (score kind 'controller')."""
    from gsa_jax.analysis.sweeps.stats import iqm
    from gsa_jax.plot import main as plot

    src = os.path.join(COMMITTED, "..")
    d = tmp_path / "idp"
    shutil.copytree(src, d, ignore=shutil.ignore_patterns("*.png", "controllers"))
    (d / "controllers").mkdir()
    labels = [f"InvertedDoublePendulum-v5-mlp-s{s}" for s in range(10)]
    rows = {lb: {"label": lb, "env": "InvertedDoublePendulum-v5", "policy": "mlp", "seed": i, "controller_score": 100.0 + i}
            for i, lb in enumerate(labels)}
    cs.write_scores(str(d / cs.FILE), rows)
    assert plot([str(d), "--reps", "20", "--curve-reps", "5"]) == 0
    with open(d / "per_run_scores.csv") as f:
        runs = [r for r in csv.DictReader(f) if r["policy"] == "mlp"]
    assert [float(r["controller_score"]) for r in runs] == [100.0 + i for i in range(10)]
    assert {r["score_kind"] for r in runs} == {"controller"}
    with open(d / "final_returns.csv") as f:
        flat = next(r for r in csv.DictReader(f) if r["policy"] == "mlp")
    assert flat["score"] == "controller" and float(flat["iqm"]) == pytest.approx(iqm([100.0 + i for i in range(10)]), abs=1e-3)
    assert (d / "verdicts.csv").exists() and (d / "sufficient_k.csv").exists()


def test_scores_from_several_processes_equal_one_process(one_controller, tmp_path):
    """score_directory with jobs=2 (each controller in a spawned process) writes the rows jobs=1 writes."""
    other = tmp_path / "again"
    shutil.copytree(one_controller, other)
    alone = cs.score_directory(str(one_controller), episodes=2, log=None, jobs=1)
    lines = []
    both = cs.score_directory(str(other), episodes=2, log=lines.append, jobs=2)
    assert both == alone and len(lines) == 2
    assert (other / cs.FILE).read_text() == (one_controller / cs.FILE).read_text()
