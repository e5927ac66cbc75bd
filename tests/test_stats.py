"""gsa_jax.analysis.sweeps.stats against NumPy / SciPy references, and gsa_jax.plot merging sweeps (fabricated tables:
nothing to compile)."""

import csv
import gzip
import json
import math

import numpy as np
import pytest
from scipy import stats as sps

from gsa_jax.analysis.sweep_report import plot_sweep
from gsa_jax.analysis.sweeps import columns as C
from gsa_jax.analysis.sweeps import stats
from gsa_jax.analysis.sweeps.results import Cell, PlotError
from gsa_jax.plot import main as plot_main

FEW = {"reps": 50, "curve_reps": 20}  # bootstrap resamples: enough for the checks, cheap


def test_final_score_is_the_mean_of_the_last_evaluations():
    ev = [np.nan, 10.0, np.nan, 20.0, 30.0, np.nan, 40.0]
    assert stats.final_score(ev, [1.0] * 7) == (30.0, "deterministic")  # mean of 20, 30, 40
    train = np.arange(1.0, 21.0)
    assert stats.final_score([np.nan] * 20, train) == (19.5, "training")  # last 10%: 19, 20


def test_iqm_point_is_the_trimmed_mean_and_the_interval_covers_it():
    x = np.random.default_rng(0).normal(size=(20, 1)) * 10 + 100
    iqm, lo, hi = stats.iqm_ci({"x": x})["x"]
    assert iqm == pytest.approx(sps.trim_mean(x[:, 0], 0.25))
    assert lo < iqm < hi and hi - lo < 15
    np.random.seed(3)
    assert stats.iqm_ci({"x": x})["x"] == (iqm, lo, hi)  # reproducible ...
    assert np.random.rand() == np.random.RandomState(3).rand()  # ... without touching NumPy's global RNG


def test_curve_score_is_the_mean_over_all_evaluations():
    assert stats.curve_score([np.nan, 10.0, np.nan, 20.0, 60.0]) == 30.0
    assert np.isnan(stats.curve_score([np.nan, np.nan]))


def test_probability_of_improvement_is_mann_whitney():
    x, y = np.array([[3.0], [5.0], [7.0]]), np.array([[1.0], [4.0], [6.0], [8.0]])
    want = np.mean([(a > b) + 0.5 * (a == b) for a in x[:, 0] for b in y[:, 0]])  # 6 of 12 pairs
    p, lo, hi = stats.improvement_probability({"x>y": (x, y)})["x>y"]
    assert p == pytest.approx(want) and lo <= p <= hi
    assert stats.improvement_probability({"x>x": (x, x)})["x>x"][0] == 0.5


def test_critics_compared_cell_by_cell():
    """A sweep listing value_targets: P(Retrace's run beats GAE's) for each retrace cell, nothing for others."""
    from gsa_jax.analysis.sweeps.tables import critic_comparisons

    gae, rt = np.array([1.0, 4.0, 6.0, 8.0]), np.array([3.0, 5.0, 7.0])
    cell = lambda env, target: Cell(env, "mixture", 6, (("value_target", target),))  # noqa: E731
    scores = {cell("hopper", "gae"): (gae, "deterministic"), cell("hopper", "retrace"): (rt, "deterministic"),
              cell("walker2d", "retrace"): (rt, "deterministic")}  # no GAE cell to compare with
    got = critic_comparisons(scores)
    assert list(got) == [cell("hopper", "retrace")] and got[cell("hopper", "retrace")][0] == pytest.approx(0.5)
    assert critic_comparisons({Cell("hopper", "mixture", 6): (rt, "deterministic")}) == {}


def test_normalize_and_profiles():
    np.testing.assert_allclose(stats.normalize([10.0, 55.0, 100.0], 10.0, 100.0), [0.0, 0.5, 1.0])
    frac, lo, hi = stats.performance_profiles({"a": np.array([[0.2], [0.6], [1.2]])}, [0.0, 0.5, 1.0, 2.0])["a"]
    np.testing.assert_allclose(frac, [1.0, 2 / 3, 1 / 3, 0.0])
    assert np.all(lo <= frac) and np.all(frac <= hi)


def test_profile_bands_are_drawn_from_their_seed_and_leave_the_global_rng_alone():
    scores, taus = {"a": np.random.default_rng(1).normal(size=(10, 1))}, np.linspace(-2.0, 2.0, 9)
    before = np.random.get_state()[1].copy()
    a, b, c = (stats.performance_profiles(scores, taus, reps=50, seed=s)["a"] for s in (0, 0, 1))
    assert all(np.array_equal(x, y) for x, y in zip(a, b)) and not all(np.array_equal(x, y) for x, y in zip(a, c))
    assert np.array_equal(np.random.get_state()[1], before)


def write_sweep(d, env, steps=100, final=None, seeds=4, evaluated=True, critic=None):
    """A fabricated sweep directory: tidy metrics.csv (flat PPO and K=2) and its sweep.json; `critic`: the
    one entry of its value_targets (a value_target column), None for a sweep that lists none."""
    d.mkdir(parents=True, exist_ok=True)
    final = final or {"mlp": 100.0, "mixture": 120.0}
    listed = [critic] if critic else []
    with open(d / "metrics.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["env", "policy", *(["value_target"] if critic else []), "K", "seed", "run", "iteration", "env_steps",
                    "episode_return", "eval_return"])
        for policy, value in final.items():
            for seed in range(seeds):
                for it in range(1, 11):
                    ev = value + 3 * seed if evaluated and it % 2 == 0 else ""
                    w.writerow([env, policy, *listed, 2 if policy == "mixture" else 1, seed, 0, it, it * steps // 10,
                                value / 2 + seed, ev])
    spec = {"envs": [env], "policies": list(final), "steps": steps, "hparams": {}, "config": {}}
    if critic:
        spec.update(value_targets=listed, config={"retrace_iterations": 4})
    (d / "sweep.json").write_text(json.dumps({"spec": spec}))
    return d


def test_merged_sweeps_count_together_and_score_the_controllers(tmp_path):
    a = write_sweep(tmp_path / "hopper", "hopper")
    b = write_sweep(tmp_path / "walker", "walker2d", final={"mlp": 50.0, "mixture": 40.0})
    with open(b / "metrics.csv", "rb") as src, gzip.open(b / "metrics-process-0.csv.gz", "wb") as dst:
        dst.write(src.read())  # committed results keep their tidy metrics gzipped
    (b / "metrics.csv").unlink()
    (a / "random_returns.json").write_text(json.dumps({"hopper": 0.0, "walker2d": 0.0}))
    out = tmp_path / "out"
    assert plot_main([str(a), str(b), "--out", str(out), "--reps", "0"]) == 2  # one-line error, nothing drawn
    assert plot_main([str(a), str(b), "--out", str(out), "--reps", "50", "--curve-reps", "20"]) == 0
    with open(out / "final_returns.csv") as f:
        rows = [{k: (float(v) if k not in ("env", "policy", "score") and v != "" else v) for k, v in r.items()}
                for r in csv.DictReader(f)]
    by = {(r["env"], r["policy"]): r for r in rows}
    groups = (C.MEAN_CI, C.IQM_CI, C.P_FLAT_CI, C.TRAINING_CI, C.CURVE_CI)  # the declared columns, in the file's order
    assert [c for c in rows[0] if any(c in g for g in groups)] == [c for g in groups for c in g]
    assert by[("hopper", "mixture")]["score"] == "deterministic" and by[("hopper", "mixture")]["seeds"] == 4
    assert by[("hopper", "mixture")]["final_return_mean"] == pytest.approx(120.0 + 4.5)  # evaluated, not training
    assert by[("hopper", "mixture")]["curve_iqm"] == pytest.approx(124.5)  # IQM of 120, 123, 126, 129: (123 + 126) / 2
    assert by[("hopper", "mixture")]["p_better_than_flat_ppo"] == 1.0 and by[("walker2d", "mixture")]["p_better_than_flat_ppo"] == 0.0
    with open(out / "aggregate.csv") as f:
        agg = {r["config"]: r for r in csv.DictReader(f)}
    assert agg["flat PPO"]["tasks"] == "hopper walker2d" and float(agg["flat PPO"]["normalized_iqm"]) == pytest.approx(1.0, abs=0.05)
    assert float(agg["K = 0.667 d_a"]["normalized_iqm"]) > 1.0 and agg["K = 0.333 d_a"]["tasks"] == "walker2d"
    for name in ("figure.png", "figure_training.png", "return_vs_k.png", "performance_profile.png"):
        assert (out / name).stat().st_size > 10_000, name
    with open(out / "sufficient_k.csv") as f:
        sufficient = {r["env"]: r for r in csv.DictReader(f)}
    assert sufficient["hopper"]["smallest_sufficient_K"] == ""  # 4 seeds: below the design's first look
    assert "too few seeds for a verdict (4 per cell; the first look needs 10)" in sufficient["hopper"]["answer"]
    with open(out / "per_run_scores.csv") as f:
        runs = list(csv.DictReader(f))
    assert len(runs) == 16 and {r["seed"] for r in runs} == {"0", "1", "2", "3"}
    assert runs[0]["training_return_last_100_episodes"] == ""  # a table without episode counts


def test_smallest_sufficient_k_is_the_smallest_k_judged_sufficient():
    """The product's answer per task, sub-policy class and margin, judged as gsa_jax.answer's first look: the smallest
    K shown within the margin, with the smaller K still undecided named; none where no K is shown sufficient."""
    from gsa_jax.analysis.verdicts.grid import sufficient_k_lines, sufficient_k_table, verdict_table

    spread = np.random.default_rng(0).permutation(np.linspace(-1.0, 1.0, 40))  # 40 seeds: looks 10, 20, 40

    def cell(policy, k, sub):
        return Cell("a", policy, k, (("subpolicy", sub),))

    def runs(scores):  # per seed what verdict_table reads: the controller score and the training series
        return {s: {"controller_score": float(v), "episode_return": np.array([v]), "episodes": np.array([1.0]),
                    "env_steps": np.array([1000.0]), "eval_return": np.array([np.nan]), "eval_failures": np.array([np.nan])}
                for s, v in enumerate(scores)}

    data = {cell("mlp", 1, ""): runs(1000.0 + 5 * spread),          # random policy at 0: the scale is 1000
            cell("mixture", 1, "linear"): runs(400.0 + 5 * spread),     # gap -0.6: insufficient
            cell("mixture", 2, "linear"): runs(930.0 + 300 * spread),   # wide: undecided
            cell("mixture", 4, "linear"): runs(990.0 + 5 * spread),     # gap -0.01: sufficient at every margin
            cell("mixture", 1, "constant"): runs(100.0 + 5 * spread)}
    random = {"a": {"returns": 0.0, "episodes": 0, "start_seed": ""}}
    rows = verdict_table(data, random, {"a": 1000}, ["subpolicy"])
    by = {(r["subpolicy"], r["K"], r["margin"]): r["verdict"] for r in rows}
    assert by[("linear", 1, 0.1)] == "insufficient" and by[("linear", 2, 0.1)] == "undecided"
    assert by[("linear", 4, 0.05)] == "sufficient" and {r["margin"] for r in rows} == {0.05, 0.1, 0.2}
    assert {r["role"] for r in rows if r["margin"] == 0.1} == {"answer"}
    table = sufficient_k_table(rows, ["subpolicy"])
    got = {(r["subpolicy"], r["margin"]): (r["smallest_sufficient_K"], r["undecided_below"]) for r in table}
    assert got[("linear", 0.1)] == (4, "2") and got[("constant", 0.1)] == ("", "")
    lines = sorted(sufficient_k_lines(table))
    assert len(lines) == 2 and "all shown insufficient" in lines[0]
    assert "subpolicy=linear: K = 4 linear controllers suffice (shown within 10% of flat PPO); smaller K = 2 undecided" in lines[1]


def test_configs_across_tasks_are_named_by_the_spec_multiplier(tmp_path):
    """Figure 1 sets K = ceil(m d_a): hopper's K = 2 is the 0.5 d_a configuration (not 0.667 d_a), and on a
    one-action task K = 1 is both 0.5 d_a and 1 d_a; K set directly is named K / d_a."""
    from gsa_jax.analysis.sweeps.results import spec_multipliers
    from gsa_jax.analysis.sweeps.tables import config_keys

    d = tmp_path / "fig1"
    d.mkdir()
    spec = {"envs": ["hopper", "inverted_double_pendulum"], "policies": ["mlp", "mixture"], "cluster_multipliers": [0.5, 1, 2]}
    (d / "sweep.json").write_text(json.dumps({"spec": spec}))
    mult = spec_multipliers([str(d)])
    dims = {"hopper": 3, "inverted_double_pendulum": 1}
    assert mult == {"hopper": [0.5, 1, 2], "inverted_double_pendulum": [0.5, 1, 2]}
    assert config_keys(Cell("hopper", "mixture", 2), dims, mult) == [("K = 0.5 d_a",)]
    assert config_keys(Cell("hopper", "mixture", 6, (("subpolicy", "linear"),)), dims, mult) == [("K = 2 d_a", ("subpolicy", "linear"))]
    assert config_keys(Cell("inverted_double_pendulum", "mixture", 1), dims, mult) == [("K = 0.5 d_a",), ("K = 1 d_a",)]
    assert config_keys(Cell("hopper", "mixture", 5), dims, {}) == [("K = 1.67 d_a",)]
    assert config_keys(Cell("hopper", "mlp", 1), dims, mult) == [("flat PPO",)]


def test_sweeps_with_other_settings_are_not_merged(tmp_path):
    a = write_sweep(tmp_path / "a", "hopper", steps=100)
    b = write_sweep(tmp_path / "b", "hopper", steps=200)
    with pytest.raises(PlotError, match=r"both hold hopper/mlp runs \(gae critic\), with different settings \(steps: 100 -> 200\)"):
        plot_sweep([str(a), str(b)], str(tmp_path / "out"), action_dims={"hopper": 3}, random_returns={"hopper": 0.0})
    with pytest.raises(PlotError, match="seed 0 of hopper/mlp K=1 is already in another directory"):
        plot_sweep([str(a), str(a)], str(tmp_path / "out"), action_dims={"hopper": 3}, random_returns={"hopper": 0.0})


def test_a_critic_sweep_merges_with_a_sweep_that_lists_none(tmp_path):
    """A sweep of Retrace runs alone, merged with a sweep that lists no critics (GAE): the latter's cells
    become the GAE cells the Retrace ones are compared with; the same runs with other settings are refused."""
    from gsa_jax.analysis.sweeps.results import final_scores, load_sweeps
    from gsa_jax.analysis.sweeps.tables import critic_comparisons

    gae = write_sweep(tmp_path / "fig1", "hopper")
    rt = write_sweep(tmp_path / "retrace", "hopper", final={"mixture": 130.0}, critic="retrace")
    data = load_sweeps([str(gae), str(rt)])
    cell = lambda policy, k, critic: Cell("hopper", policy, k, (("value_target", critic),))  # noqa: E731
    assert sorted(data) == [cell("mixture", 2, "gae"), cell("mixture", 2, "retrace"), cell("mlp", 1, "gae")]
    assert critic_comparisons(final_scores(data))[cell("mixture", 2, "retrace")][0] == 1.0  # 130..139 vs 120..129
    other = write_sweep(tmp_path / "other", "hopper", steps=200, final={"mixture": 1.0})
    with pytest.raises(PlotError, match=r"hopper/mixture runs \(gae critic\), with different settings"):
        load_sweeps([str(gae), str(other)])


def test_final_score_takes_the_last_scheduled_evaluations_never_skipping_one():
    ev = [1.0, math.nan, 3.0, math.nan, 5.0, 7.0]
    assert stats.final_score(ev, [])[0] == 5.0  # scheduled where finite: 3, 5, 7
    scheduled = [True, False, True, True, True, True]  # iteration 4 was evaluated but has no return
    assert math.isnan(stats.final_score(ev, [], scheduled)[0])
    assert stats.unscored_evaluations(ev, scheduled) == [4]
    assert stats.unscored_evaluations([1.0, 2.0, 3.0, 4.0], [True] * 4) == []


def test_failed_evaluation_episodes_are_counted_and_unreturned_evaluations_reported(tmp_path):
    """A table with eval_failures: the cell's count in final_returns.csv, every run scored. A table written
    before failures were counted, with a scheduled final evaluation left blank in one run: that run is
    listed in unscored_runs and a printed line, and left out of the statistics -- not scored from an
    earlier evaluation."""
    from gsa_jax.analysis.sweeps.results import load_sweep, unscored_lines
    from gsa_jax.analysis.sweeps.tables import final_table

    counted, legacy = tmp_path / "counted", tmp_path / "legacy"
    for d, with_count in ((counted, True), (legacy, False)):
        d.mkdir()
        with open(d / "metrics.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["env", "policy", "K", "seed", "run", "iteration", "env_steps", "episode_return", "eval_return"]
                       + (["eval_failures"] if with_count else []))
            for seed in range(4):
                for it in range(1, 11):
                    evaluated = it % 2 == 0
                    ev = 100.0 + seed if evaluated and not (not with_count and seed == 2 and it == 10) else ""
                    fails = (2 if seed == 1 and it == 10 else 0) if evaluated else ""
                    w.writerow(["hopper", "mlp", 1, seed, 0, it, it * 10, 50.0, ev] + ([fails] if with_count else []))
    rows = final_table(load_sweep(str(counted)), {"hopper": 3}, reps=20)
    assert rows[0]["eval_failures"] == 2 and rows[0]["seeds"] == 4 and rows[0]["unscored_runs"] == ""
    assert rows[0]["final_return_mean"] == pytest.approx(101.5)
    assert unscored_lines(rows) == []
    rows = final_table(load_sweep(str(legacy)), {"hopper": 3}, reps=20)
    assert rows[0]["unscored_runs"] == "2@10" and rows[0]["seeds"] == 3 and rows[0]["eval_failures"] == ""  # unknown
    assert rows[0]["final_return_mean"] == round((100 + 101 + 103) / 3, 3)
    lines = unscored_lines(rows)
    assert "1 run(s) have no return" in lines[0] and lines[1].strip() == "hopper mlp: 2@10"


def test_sweep_summary_names_the_runs_with_failed_evaluation_episodes():
    from gsa_jax.running.sweeps import eval_failure_lines

    counts = np.full((2, 6), np.nan)
    counts[:, [2, 5]] = [[0, 0], [1, 3]]
    runs = [{"env": "hopper", "policy": "mixture", "K": 2, "seed": s} for s in (0, 1)]
    lines = eval_failure_lines([(runs, {"eval_failures": counts}, 6)])
    assert len(lines) == 2 and "in 1 run(s)" in lines[0]
    assert lines[1].strip() == "env=hopper, policy=mixture, K=2, seed=1: 4 episode(s) at iteration(s) 3, 6"
    assert eval_failure_lines([(runs, {"eval_failures": np.where(np.isnan(counts), np.nan, 0)}, 6)]) == []


def test_last_episodes_return_weights_iterations_by_their_episodes():
    """CleanRL's score of a run, the mean of its last 100 episodes, from per-iteration means and counts: the
    latest iterations in full, the one that reaches 100 for the episodes still needed."""
    ret, cnt = [10.0, np.nan, 20.0, 30.0], [50, 0, 60, 70]
    assert stats.last_episodes_return(ret, cnt) == pytest.approx(27.0)  # 70 x 30 + 30 x 20
    assert stats.last_episodes_return(ret, cnt, n=70) == pytest.approx(30.0)
    assert stats.last_episodes_return(ret, cnt, n=1000) == pytest.approx((50 * 10 + 60 * 20 + 70 * 30) / 180)
    assert math.isnan(stats.last_episodes_return([np.nan, np.nan], [0, 0]))


def test_per_run_table_scores_each_run_as_the_cell_table_does(tmp_path):
    """per_run_scores.csv: a run's final score (mean of its last 3 evaluations), not its last evaluation;
    its training returns; the cell table's mean is the mean of these scores."""
    from gsa_jax.analysis.sweeps.results import load_sweep
    from gsa_jax.analysis.sweeps.tables import final_table, run_table

    d = tmp_path / "sweep"
    d.mkdir()
    with open(d / "metrics.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["env", "policy", "K", "seed", "run", "iteration", "env_steps", "episode_return", "episodes",
                    "eval_return", "eval_failures"])
        for seed in range(2):
            for it in range(1, 21):
                ev = 100.0 * seed + it if it % 4 == 0 else ""
                w.writerow(["hopper", "mixture", 2, seed, seed, it, it * 10, it + seed, 30, ev, 0 if ev != "" else ""])
    data = load_sweep(str(d))
    rows = run_table(data)
    assert [(r["seed"], r["K"], r["score_kind"]) for r in rows] == [(0, 2, "deterministic"), (1, 2, "deterministic")]
    assert rows[1]["final_score"] == pytest.approx(100 + (12 + 16 + 20) / 3) and rows[1]["last_eval_return"] == 120.0
    assert rows[0]["training_return"] == pytest.approx(19.5)  # last 10% of 20 iterations: 19, 20
    assert rows[0]["training_return_last_100_episodes"] == pytest.approx((30 * (20 + 19 + 18) + 10 * 17) / 100)
    assert rows[0]["eval_failures"] == 0
    cell = final_table(data, {"hopper": 3}, reps=20)[0]
    assert cell["final_return_mean"] == pytest.approx(np.mean([r["final_score"] for r in rows]), abs=1e-3)
    # other tidy columns on request, in iteration order; one the table lacks is NaN throughout
    asked = load_sweep(str(d), ("iteration", "episodes", "approx_kl"))[Cell("hopper", "mixture", 2)][1]
    assert list(asked["iteration"]) == list(range(1, 21)) and set(asked["episodes"]) == {30.0}
    assert set(asked) == {"iteration", "episodes", "approx_kl"} and np.isnan(asked["approx_kl"]).all()


def test_random_returns_are_read_from_the_output_directory_when_no_sweep_has_them(tmp_path):
    """Tables redrawn from committed results normalize by the random-policy return an earlier invocation
    measured and saved in OUT, not by a new measurement; a sweep's own value takes precedence."""
    from gsa_jax.analysis.sweeps.results import random_returns_of

    a = write_sweep(tmp_path / "a", "hopper")
    out = tmp_path / "out"
    out.mkdir()
    (out / "random_returns.json").write_text(json.dumps({"hopper": 12.5, "walker2d": 3.0}))
    assert random_returns_of([str(a)], ["hopper"], str(out)) == {"hopper": 12.5}
    (a / "random_returns.json").write_text(json.dumps({"hopper": 7.0}))
    assert random_returns_of([str(a)], ["hopper", "walker2d"], str(out)) == {"hopper": 7.0, "walker2d": 3.0}


def test_random_returns_are_measured_with_the_backend_the_sweep_trained_with(tmp_path, monkeypatch):
    """A task MJX cannot step (dmc:fish-swim) trains with backend 'c': its random-policy return is measured
    with 'c' too, with MJX where the sweep names no backend, and with 'c' where two sweeps disagree."""
    from gsa_jax.analysis.sweeps import random_return
    from gsa_jax.analysis.sweeps.results import random_returns_of

    asked = []
    monkeypatch.setattr(random_return, "random_policy_return", lambda task, backend="mjx": asked.append((task.name, backend)) or 1.0)
    a = write_sweep(tmp_path / "a", "dmc:fish-swim")
    meta = json.loads((a / "sweep.json").read_text())
    meta["spec"]["config"] = {"backend": "c"}
    (a / "sweep.json").write_text(json.dumps(meta))
    b = write_sweep(tmp_path / "b", "hopper")
    assert random_returns_of([str(a), str(b)], ["dmc:fish-swim", "hopper"], str(tmp_path), log=lambda _: None) == {
        "dmc:fish-swim": 1.0, "hopper": 1.0}
    assert asked == [("dmc:fish-swim", "c"), ("hopper", "mjx")]
    # two sweeps of one task with different backends: MuJoCo C, which steps every task
    c = write_sweep(tmp_path / "c", "dmc:fish-swim")
    assert random_returns_of([str(c), str(a)], ["dmc:fish-swim"], str(tmp_path / "c"), log=lambda _: None) == {
        "dmc:fish-swim": 1.0}
    assert asked[-1] == ("dmc:fish-swim", "c")
