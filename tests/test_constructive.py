"""The constructive answer (gsa_jax.analysis.verdicts.constructive) and exact shares (shares): the exhibited controller,
the paired fresh-start test, the exact share test and its level under the laws training produces (failing seeds, ties
at the ceiling)."""

import itertools
import json
import math
import os
import shutil

import numpy as np
import pytest
from scipy import stats

from gsa_jax.analysis.verdicts import constructive as C
from gsa_jax.analysis.verdicts import shares as S
from gsa_jax.analysis.verdicts import trimmed
from gsa_jax.deployment import starts


def cands(selection, fresh):
    """Candidates with seeds 0.. from selection scores [n] and fresh returns [n, episodes]."""
    return [C.Candidate(i, float(s), np.asarray(f, np.float64)) for i, (s, f) in enumerate(zip(selection, fresh))]


def test_the_exhibit_is_the_best_selection_score_ties_to_the_lower_seed():
    runs = cands([3.0, 5.0, 5.0, 1.0], np.zeros((4, 3)))
    assert C.exhibit(runs).seed == 1
    with pytest.raises(ValueError, match="at least one run"):
        C.exhibit([])


def test_selection_and_fresh_starts_are_disjoint():
    selection = set(range(starts.SELECTION_SEED, starts.SELECTION_SEED + starts.SELECTION_EPISODES))
    fresh = set(range(starts.FRESH_SEED, starts.FRESH_SEED + starts.FRESH_EPISODES))
    assert not selection & fresh and starts.FRESH_EPISODES >= 100


def test_share_interval_is_clopper_pearson():
    for x, n in [(0, 10), (3, 10), (10, 10), (17, 40)]:
        s = S.share_of(np.r_[np.ones(x), np.zeros(n - x)], 0.5, 0.025)
        ci = stats.binomtest(x, n).proportion_ci(confidence_level=0.95, method="exact")
        assert (s.reached, s.seeds) == (x, n)
        assert s.low == pytest.approx(ci.low, abs=1e-12) and s.high == pytest.approx(ci.high, abs=1e-12)


def brute_share_p(x, n, y, m, margin, grid):
    """share_p by loops: sup over the boundary of the chance of an outcome at least as extreme."""
    zs = {(a, b): S.share_statistic(np.float64(a), n, np.float64(b), m, margin) for a in range(n + 1) for b in range(m + 1)}
    best = 0.0
    for q in grid:
        total = 0.0
        for a, b in itertools.product(range(n + 1), range(m + 1)):
            if zs[(a, b)] >= zs[(x, y)] - 1e-12:
                total += stats.binom.pmf(a, n, max(q - margin, 0.0)) * stats.binom.pmf(b, m, q)
        best = max(best, total)
    return best


def test_share_p_equals_enumeration():
    grid = np.linspace(0.1, 1.0, S.NUISANCE_GRID)
    for x, y in [(3, 3), (2, 3), (4, 2), (0, 0)]:
        assert S.share_p(x, 4, y, 3, 0.1) == pytest.approx(brute_share_p(x, 4, y, 3, 0.1, grid), rel=1e-9, abs=1e-12)


def rejection_chance(n, m, p_mix, p_flat, margin=0.1, alpha=C.ALPHA):
    """The exact chance that 'as often' is shown (share_p < alpha) when the shares truly are p_mix and p_flat."""
    pv = np.array([[S.share_p(a, n, b, m, margin) for b in range(m + 1)] for a in range(n + 1)])
    pa, pb = stats.binom.pmf(np.arange(n + 1), n, p_mix), stats.binom.pmf(np.arange(m + 1), m, p_flat)
    return float(pa @ (pv < alpha).astype(float) @ pb)


@pytest.mark.parametrize("n", [10, 20])
def test_share_test_keeps_its_level_on_the_boundary(n):
    """Every pair of true shares at the margin's boundary (0.0/0.1 .. 0.9/1.0, ties at the ceiling included)."""
    for q in np.linspace(0.1, 1.0, 10):
        assert rejection_chance(n, n, q - 0.1, q) <= C.ALPHA + 1e-12


@pytest.mark.parametrize("n", [10, 20, 40])
def test_failing_mixture_is_not_called_as_often(n):
    """The mixture fails on 29% of seeds, flat PPO on none: 'as often' at most ALPHA of the time, computed exactly."""
    assert rejection_chance(n, n, 0.71, 1.0) <= C.ALPHA


def test_share_test_shows_as_often_with_enough_seeds_and_no_failures():
    assert S.share_p(40, 40, 40, 40, 0.1) < C.ALPHA  # 40 of 40 each
    assert S.share_p(10, 10, 10, 10, 0.1) > C.ALPHA  # 10 seeds cannot show it


def test_holm_steps_down():
    assert S.holm({"a": 0.001, "b": 0.02, "c": 0.06}, 0.05) == {"a", "b"}  # 0.001 < 0.05 / 3, 0.02 < 0.05 / 2, 0.06 > 0.05
    assert S.holm({"a": 0.02, "b": 0.001}, 0.025) == {"a", "b"}  # b < 0.025 / 2, then a < 0.025 / 1
    assert S.holm({"a": 0.03, "b": 0.001}, 0.025) == {"b"}
    assert S.holm({"a": 0.001, "b": 0.02}, 0.025) == {"a", "b"} and S.holm({"a": 0.013, "b": 0.014}, 0.025) == set()


def test_paired_contrast_is_the_mean_of_the_differences():
    rng = np.random.default_rng(0)
    flat = rng.normal(100.0, 30.0, 100)
    mix = flat - 1.0 + rng.normal(0.0, 0.5, 100)  # one point below flat on every start: noise the pairing removes
    bar = C.Bar("b", trimmed.plain(flat), flat)
    rand = trimmed.fixed(0.0)
    c = C.gap_contrast(mix, bar, rand, -0.1)
    d = mix - 0.9 * flat
    assert c.estimate == pytest.approx(d.mean()) and c.se == pytest.approx(d.std(ddof=1) / 10.0)
    e = C.judge_exhibit(C.Candidate(0, 0.0, mix), bar, rand, 0.1, C.ALPHA)
    assert e.verdict == C.FOUND and e.gap == pytest.approx((mix.mean() - flat.mean()) / flat.mean())
    assert e.low < e.gap < e.high < 0.0  # the pairing shows it a little below flat PPO's controller
    unpaired = C.Bar("b", trimmed.plain(flat), None)
    assert C.gap_contrast(mix, unpaired, rand, -0.1).se > 10 * c.se


def test_judge_names_the_smallest_found_and_the_shares():
    rng = np.random.default_rng(1)
    flat = [rng.normal(100.0, 2.0, 100) for _ in range(10)]
    k1 = [rng.normal(40.0, 2.0, 100) for _ in range(10)]  # far below: not found
    k2 = [rng.normal(99.0, 2.0, 100) for _ in range(10)]  # at flat's level on every seed
    classes = {"flat": cands([f.mean() for f in flat], flat), 1: cands([f.mean() for f in k1], k1),
               2: cands([f.mean() for f in k2], k2)}
    a = C.judge(classes, rng.normal(0.0, 1.0, 128), 0.1, share_episodes=20)
    assert a.smallest == 2 and a.exhibits[1].verdict == C.NOT_FOUND and a.exhibits[2].verdict == C.FOUND
    assert a.shares[2].reached == 10 and a.shares[1].reached == 0
    assert a.share_verdicts == {1: C.NOT_SHOWN, 2: C.NOT_SHOWN}  # 10 seeds do not show 'as often'
    text = C.sentence("t", a, "10 seeds x 1,000 steps")
    assert "K = 2 suffices by construction" in text and "10 of 10 seeds" in text


def test_judge_against_a_higher_published_bar_and_no_scale():
    rng = np.random.default_rng(2)
    flat = [rng.normal(50.0, 1.0, 100) for _ in range(3)]
    k1 = [rng.normal(95.0, 1.0, 100) for _ in range(3)]
    classes = {"flat": cands([f.mean() for f in flat], flat), 1: cands([f.mean() for f in k1], k1)}
    a = C.judge(classes, 0.0, 0.1, reference=C.Bar("PPO paper", trimmed.fixed(100.0, 5.0, 10), None))
    assert a.bar.name == "PPO paper" and a.bar.episodes is None and a.smallest == 1
    assert math.isclose(a.threshold, 90.0)
    same = {"flat": cands([0.0] * 3, [np.zeros(100)] * 3), 1: classes[1]}
    b = C.judge(same, np.zeros(128) + rng.normal(0, 1e-3, 128), 0.1)
    assert b.exhibits[1].verdict == C.NO_SCALE and b.smallest is None and "no constructive answer" in C.sentence("t", b, "s")


def test_the_answers_fresh_scores_equal_deploy_and_are_not_run_twice(tmp_path, monkeypatch):
    """gsa answer's constructive part on four committed cartpole-balance controllers (flat PPO and K = 1, seeds 0 and
    1; 3 fresh starts for each class's best, 2 for the others): the exhibit's fresh episodes are `gsa deploy`'s on
    the same seeds, the report's record says so, and a second call runs nothing (the episodes are kept)."""
    from gsa_jax.analysis.sweeps import controller_scores
    from gsa_jax.analysis.verdicts.answer_report import constructive_text
    from gsa_jax.analysis.verdicts import answering as A
    from gsa_jax.deployment.evaluation import load_controller, run_mujoco_c
    from gsa_jax.orchestration import constructive_answer as CA

    src = "experiments/atlas_dmc/results/cartpole-balance"
    dst = tmp_path / "runs" / "controllers"
    dst.mkdir(parents=True)
    names = {("flat", s): f"{src}/flat_ppo/controllers/dmc.cartpole-balance-mlp-s{s}.npz" for s in (0, 1)}
    names.update({(1, s): f"{src}/mixture/controllers/dmc.cartpole-balance-mixture-K1-s{s}.npz" for s in (0, 1)})
    for path in names.values():
        shutil.copy(path, dst)
    monkeypatch.setattr(CA, "EXHIBIT", 3)
    monkeypatch.setattr(CA, "SHARE", 2)
    setup = A.Setup("dmc:cartpole-balance", (1,), 0.1, (2,), {}, start_from=(str(tmp_path / "runs"),))
    evidence = A.Evidence({"flat": {0: 900.0, 1: 990.0}, 1: {0: 500.0, 1: 400.0}}, {}, {})
    state = {"random": {"returns": [1.0, 2.0, 3.0]}, "steps": {"budget": 1_000_000}}
    out = str(tmp_path / "answer")
    os.makedirs(out)
    answer, shown = CA.judge_constructive(out, setup, state, evidence, log=lambda m: None)
    assert answer.exhibits["flat"].seed == 1 and answer.exhibits[1].seed == 0
    for cls in ("flat", 1):
        ctrl, task, config = load_controller(shown[cls])
        deployed = run_mujoco_c(ctrl, task, config, 3, seed=starts.FRESH_SEED)
        assert answer.exhibits[cls].fresh == pytest.approx(deployed["return_mean"], abs=1e-3)
        assert answer.exhibits[cls].episodes == 3
    assert answer.shares["flat"].seeds == 2 and answer.shares[1].seeds == 2
    monkeypatch.setattr(controller_scores, "parallel_map", lambda *a: pytest.fail("ran a controller again"))
    again, _ = CA.judge_constructive(out, setup, state, evidence, log=lambda m: None)
    assert again.exhibits == answer.exhibits
    rec = CA.record(again, C.sentence("dmc:cartpole-balance", again, "2 seeds"), "2 seeds")
    assert rec["classes"]["1"]["episodes"] == 3 and rec["fresh_start_seed"] == starts.FRESH_SEED
    assert json.loads(json.dumps(rec)) == rec  # answer.json keeps it as it is
    text = "\n".join(constructive_text(rec))
    assert "## The constructive answer" in text and "| K = 1 | 0 | 500.0 |" in text


def test_no_constructive_answer_against_a_bar_that_has_not_learned_the_task():
    """A task whose maximum is 1000 (random at 0): a best flat PPO controller at 30 is shown below a tenth of the way
    to it, so a mixture at 60 is not 'found'; the same bar on a task without a declared maximum lets it be."""
    flat = [np.full(100, 30.0) + np.linspace(-1, 1, 100)]
    mix = [np.full(100, 60.0) + np.linspace(-1, 1, 100)]
    classes = {"flat": cands([30.0], flat), 1: cands([60.0], mix)}
    a = C.judge(classes, np.linspace(-1, 1, 128), 0.1, max_return=1000.0)
    assert a.smallest is None and a.exhibits[1].verdict == C.NOT_LEARNED
    assert "has not learned the task" in C.sentence("t", a, "1 seed")
    assert C.judge(classes, np.linspace(-1, 1, 128), 0.1).smallest == 1
