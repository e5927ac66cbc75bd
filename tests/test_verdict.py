"""The non-inferiority verdict (gsa_jax.analysis.verdicts.verdict, .trimmed, .sequential, .ladder) on score sets whose truth is
known: Yuen's test against SciPy's, the group-sequential boundaries against a simulated Brownian motion, and the whole
answer's error rate by simulation of gsa_jax.answer's own decisions."""

import numpy as np
import pytest

from gsa_jax.analysis.sweeps.stats import iqm
from gsa_jax.analysis.verdicts import ladder, sequential, trimmed
from gsa_jax.analysis.verdicts import verdict as V


def noisy(center, spread, n, seed):
    return center + spread * np.random.default_rng(seed).standard_normal(n)


def test_the_verdicts_trimmed_mean_is_the_one_iqm_rliables_to_the_bit():
    from rliable import metrics

    x = np.random.default_rng(0).standard_normal((41, 1)) * 100
    for n in (1, 2, 3, 4, 5, 7, 10, 17, 40, 41):
        assert iqm(x[:n]) == metrics.aggregate_iqm(x[:n]) == iqm(x[:n, 0])
        assert trimmed.trimmed(x[:n, 0]).mean == iqm(x[:n, 0])
    assert iqm([1.0, 2.0, 3.0, 4.0, 100.0, -50.0, 5.0, 6.0]) == 3.5  # sorted: -50 1 | 2 3 4 5 | 6 100


@pytest.mark.parametrize("n1, n2", [(10, 10), (7, 13), (40, 20), (5, 9)])
def test_two_group_contrast_is_scipys_yuen_welch_test(n1, n2):
    from scipy import stats

    rng = np.random.default_rng(n1 * 100 + n2)
    a, b = rng.normal(size=n1), rng.normal(size=n2) + 0.3
    c = trimmed.contrast([(1.0, trimmed.trimmed(a)), (-1.0, trimmed.trimmed(b))])
    ref = stats.ttest_ind(a, b, trim=0.25, equal_var=False)
    assert c.estimate / c.se == pytest.approx(ref.statistic, rel=1e-12)
    assert c.df == pytest.approx(ref.df, rel=1e-12)
    assert 2 * min(trimmed.p_above(c), trimmed.p_below(c)) == pytest.approx(ref.pvalue, rel=1e-9)


def test_plain_mean_and_a_published_score_as_groups():
    x = np.arange(10.0)
    s = trimmed.plain(x)
    assert s.mean == 4.5 and s.var == pytest.approx(x.var(ddof=1) / 10) and s.df == 9
    ref = trimmed.fixed(100.0, std=10.0, seeds=5)  # a std with ddof 0 over 5 seeds: squared error 100 / 4
    assert ref.var == pytest.approx(25.0) and ref.df == 4
    assert trimmed.fixed(100.0).var == 0.0 and trimmed.fixed(100.0, std=3.0, seeds=1).var == 0.0


def test_clear_win_and_clear_loss():
    flat, rand = noisy(1000.0, 50.0, 40, 1), noisy(0.0, 5.0, 128, 0)
    win = V.judge(noisy(1200.0, 50.0, 40, 2), flat, rand, level=0.005)
    loss = V.judge(noisy(500.0, 50.0, 40, 3), flat, rand, level=0.005)
    assert win.verdict == V.SUFFICIENT and win.low > 0.0 and win.p_share < 0.005
    assert loss.verdict == V.INSUFFICIENT and loss.high < -V.DEFAULT_MARGIN
    assert -0.6 < loss.point < -0.4


def test_the_interval_is_the_inverted_test():
    """At the interval's ends the one-sided tests sit exactly at the level; the margin's test rejects exactly when
    the margin lies outside the interval."""
    flat, mix, rand = noisy(1000.0, 80.0, 20, 4), noisy(960.0, 80.0, 20, 5), noisy(10.0, 5.0, 128, 6)
    g = V.judge(mix, flat, rand, level=0.01)
    parts = trimmed.trimmed(mix), trimmed.trimmed(flat), trimmed.plain(rand)
    assert trimmed.p_above(V.margin_contrast(*parts, g.low)) == pytest.approx(0.01, abs=1e-6)
    assert trimmed.p_below(V.margin_contrast(*parts, g.high)) == pytest.approx(0.01, abs=1e-6)
    assert (g.verdict == V.SUFFICIENT) == (g.low > -V.DEFAULT_MARGIN)


def test_gap_exactly_minus_margin_is_undecided_and_needs_no_finite_seeds():
    flat = np.linspace(990.0, 1010.0, 20)  # IQM 1000, random 0: gap -0.1 is 100 points
    g = V.judge(flat - 100.0, flat, 0.0, margin=0.1)
    assert g.point == pytest.approx(-0.1)
    assert g.verdict == V.UNDECIDED and g.low < -0.1 < g.high
    assert g.seeds_observed is None and g.seeds_parity is not None and g.seeds_parity >= 20


@pytest.mark.parametrize("estimate, fixed_var", [(0.0, 0.0), (0.6, 0.0), (-0.9, 0.0), (1.4, 0.0), (0.6, 0.004),
                                                 (-0.9, 0.01)])
def test_the_chance_to_be_decided_by_the_cap_is_a_simulated_continuation(estimate, fixed_var):
    """chance_to_decide against a NumPy simulation of what it claims: the seeds now have a mean `estimate` (unit spread
    per seed, 10 seeds) plus a part of variance fixed_var that more seeds do not change (the random policy's
    episodes); 30 more seeds drawn with that true mean, the estimate of all 40 tested both ways at the level."""
    n, cap, level, trials = 10, 40, 0.003, 400_000
    c = trimmed.Contrast(estimate, np.sqrt(1.0 / n + fixed_var), 9.0)
    rng = np.random.default_rng(7)
    final = (n * estimate + rng.normal(estimate * (cap - n), np.sqrt(cap - n), trials)) / cap
    edge = 2.7477813854449926 * np.sqrt(1.0 / cap + fixed_var)  # scipy.stats.norm.isf(0.003) x the error at the cap
    simulated = np.mean(np.abs(final) > edge)
    assert V.chance_to_decide(c, n, cap, level, fixed_var) == pytest.approx(simulated, abs=3e-3)
    assert V.chance_to_decide(c, cap, cap, level) is None  # nothing left to add


def test_a_cell_whose_reference_alone_is_too_uncertain_has_no_chance():
    """Against a published score of three seeds (its own error does not shrink with the mixture's seeds), a mixture at
    parity cannot be shown within the margin however many seeds it gets: its chance is ~0, where taking the whole
    error as shrinking would give it one."""
    mix = np.linspace(995.0, 1005.0, 10)
    published = trimmed.fixed(1000.0, std=200.0, seeds=3)
    g = V.judge(mix, published, 0.0, margin=0.1, level=0.003, final_level=0.003, final_seeds=40)
    assert g.verdict == V.UNDECIDED and g.chance_by_cap < 1e-3
    c = V.margin_contrast(trimmed.trimmed(mix), published, V.summarize_random(0.0), -0.1)
    assert V.chance_to_decide(c, 10, 40, 0.003) > 0.05  # the whole error taken as shrinking


def test_seeds_for_power_reach_it_with_a_part_of_the_error_fixed():
    """seeds_for_power against a NumPy simulation: 10 seeds with unit spread each plus a fixed part of variance 0.02
    (the random policy's episodes); at the seeds it returns, a true distance of 1 is rejected at the level in at least
    80% of draws, and at one seed fewer in less. Where the fixed part alone is too large, no number would do (None)."""
    n, level, fixed, trials = 10, 0.003, 0.02, 400_000
    c = trimmed.Contrast(0.0, np.sqrt(1.0 / n + fixed), 9.0)
    need = V.seeds_for_power(c, n, 1.0, level, fixed)
    rng = np.random.default_rng(11)

    def power(seeds):
        sd = np.sqrt(1.0 / seeds + fixed)
        return np.mean(rng.normal(1.0, sd, trials) > 2.7477813854449926 * sd)  # scipy.stats.norm.isf(0.003)

    assert need > n and power(need) >= V.POWER > power(need - 1)
    assert V.seeds_for_power(c, n, 1.0, level) < need  # the whole error taken as shrinking: too few
    assert V.seeds_for_power(c, n, 0.4, level, fixed) is None  # (0.4 / 3.59)^2 < 0.02: no seed count reaches it
    mix = np.linspace(995.0, 1005.0, 10)  # against a published score of three seeds, at parity: none either
    g = V.judge(mix, trimmed.fixed(1000.0, std=200.0, seeds=3), 0.0, margin=0.1, level=0.003)
    assert g.verdict == V.UNDECIDED and g.seeds_parity is None


def test_an_undecided_cell_carries_its_chance_and_a_decided_one_none():
    flat = np.linspace(990.0, 1010.0, 20)
    at_margin = V.judge(flat - 100.0, flat, 0.0, margin=0.1, final_level=0.003, final_seeds=40)
    assert at_margin.verdict == V.UNDECIDED and 0.0 <= at_margin.chance_by_cap < V.FUTILITY
    clear = V.judge(flat, flat, 0.0, margin=0.1, final_level=0.003, final_seeds=40)
    assert clear.verdict == V.SUFFICIENT and clear.chance_by_cap is None


def test_ten_seeds_cannot_show_that_a_mixture_fails_no_more_often():
    """A clear IQM win at 10 seeds is not 'sufficient': had the mixture failed on 29% of its seeds, all 10 would
    succeed 3% of the time, so 10 of 10 cannot show its failure share within SHARE_MARGIN of flat PPO's."""
    flat, rand = noisy(1000.0, 50.0, 10, 1), noisy(0.0, 5.0, 128, 0)
    win = V.judge(noisy(1200.0, 50.0, 10, 2), flat, rand, level=0.005)
    assert win.p_sufficient < 1e-4 and win.p_share > 0.1 and win.verdict == V.UNDECIDED


def test_a_mixture_whose_seeds_fail_is_not_sufficient_whatever_its_iqm():
    """Tied at the ceiling but failing on 10 of 40 seeds: Yuen's error collapses (the IQM ignores them), the
    failure share does not."""
    flat = np.full(40, 1000.0)
    mix = np.r_[np.full(30, 1000.0), np.full(10, 5.0)]
    g = V.judge(mix, flat, np.zeros(128), level=0.01)
    assert g.p_sufficient == 0.0 and g.p_share > 0.5 and g.verdict == V.UNDECIDED
    assert V.judge(mix, trimmed.fixed(1000.0), np.zeros(128), level=0.01).verdict == V.SUFFICIENT  # no shares there


def test_near_deterministic_scores_a_fraction_of_the_margin_apart_are_sufficient():
    """Balance-like: every mixture seed 1 point below flat PPO's 500, a random policy at 100 (scale 400):
    gap -0.0025, far inside a margin of 0.05 although every seed of the mixture loses (40 seeds: the last look)."""
    flat = 500.0 + np.random.default_rng(4).uniform(0.0, 0.01, 40)
    g = V.judge(flat - 1.0, flat, 100.0, margin=0.05, level=0.001)
    assert g.verdict == V.SUFFICIENT and g.point == pytest.approx(-1.0 / 400.0, rel=1e-3)


def test_against_a_fixed_score():
    mix, rand = noisy(800.0, 10.0, 10, 7), noisy(0.0, 1.0, 128, 8)
    assert V.judge(mix, trimmed.fixed(700.0), rand).verdict == V.SUFFICIENT
    assert V.judge(mix, trimmed.fixed(1000.0), rand).verdict == V.INSUFFICIENT
    uncertain = V.judge(mix, trimmed.fixed(870.0, std=100.0, seeds=3), rand)  # a published score known from 3 seeds
    assert uncertain.verdict == V.UNDECIDED and uncertain.n_ref == 3


def test_no_answer_where_flat_ppo_is_within_the_random_returns_interval():
    """fish-like: flat PPO's IQM 78 beside a random policy at 80 +- 10 over 128 episodes: no scale, no answer."""
    rand = noisy(80.0, 10.0 * np.sqrt(128), 128, 9)
    g = V.judge(noisy(90.0, 10.0, 10, 10), noisy(78.0, 10.0, 10, 11), rand)
    assert g.verdict == V.NO_SCALE


def test_the_verdict_uses_no_random_stream():
    """50 draws of NumPy's global generator around the same boundary case give one verdict, bit for bit the same
    numbers: the test is analytic, there is no resampling whose seed could move it."""
    flat, mix, rand = noisy(1000.0, 100.0, 20, 12), noisy(905.0, 100.0, 20, 13), noisy(0.0, 20.0, 128, 14)
    first = V.judge(mix, flat, rand, level=0.01)
    for seed in range(50):
        np.random.seed(seed)
        assert V.judge(mix, flat, rand, level=0.01) == first


def test_margin_outside_zero_one_is_refused():
    with pytest.raises(ValueError, match="margin"):
        V.judge([1.0, 2.0], [1.0, 2.0], 0.0, margin=1.5)


def test_smallest_sufficient_and_sentence():
    verdicts = {1: V.UNDECIDED, 2: V.SUFFICIENT, 4: V.SUFFICIENT}
    assert V.smallest_sufficient(verdicts) == (2, [1])
    assert "K = 2" in V.sentence("task", verdicts, 0.1, "flat PPO") and "K = 1 undecided" in V.sentence(
        "task", verdicts, 0.1, "flat PPO")
    assert V.smallest_sufficient({1: V.INSUFFICIENT, 2: V.UNDECIDED}) == (None, [2])


@pytest.mark.parametrize("spending", sequential.SPENDING)
def test_boundaries_spend_exactly_alpha_on_a_brownian_motion(spending):
    """The per-look levels of looks at 10, 20, 40 seeds: a Brownian motion in the information fraction crosses them
    with probability alpha (Bonferroni: at most alpha, its looks being correlated), within the simulation's error."""
    from scipy import stats

    design = sequential.Design((10, 20, 40), 0.025, spending)
    levels = sequential.look_levels(design, 0.025)
    t = np.array([0.25, 0.5, 1.0])
    steps = np.random.default_rng(0).standard_normal((1_000_000, 3)) * np.sqrt(np.diff(np.r_[0.0, t]))
    crossed = float((np.cumsum(steps, axis=1) / np.sqrt(t) >= stats.norm.isf(np.array(levels))).any(axis=1).mean())
    se = np.sqrt(0.025 * 0.975 / 1_000_000)
    if spending == "bonferroni":
        assert crossed <= 0.025 + 3 * se and levels == pytest.approx((0.025 / 3,) * 3)
    else:
        assert crossed == pytest.approx(0.025, abs=4 * se + 2e-4)


def test_designs_refuse_too_few_seeds_and_unknown_rules():
    with pytest.raises(ValueError, match="at least 10 seeds"):
        sequential.check_design(sequential.Design((5, 10, 20)))
    with pytest.raises(ValueError, match="unknown spending"):
        sequential.check_design(sequential.Design((10, 20), spending="linear"))
    assert sequential.look_index(sequential.Design((10, 20, 40)), 15) == 0
    assert sequential.look_index(sequential.Design((10, 20, 40)), 9) is None


def test_holm_passes_a_sufficient_ks_share_on():
    """K = 4 clearly sufficient frees its share: K = 2, just short of the alpha / 3 level, passes at alpha / 2."""
    design = sequential.Design((40,), 0.025, "obf")
    rand = np.zeros(128)
    flat = noisy(1000.0, 60.0, 40, 20)
    scores = {1: dict(enumerate(noisy(400.0, 60.0, 40, 21))), 4: dict(enumerate(noisy(1100.0, 30.0, 40, 22)))}
    base2 = noisy(0.0, 60.0, 40, 23)
    for shift in np.linspace(900.0, 1100.0, 401):  # find a K = 2 whose p lies between alpha / 3 and alpha / 2
        scores[2] = dict(enumerate(base2 + shift))
        p = V.judge(list(scores[2].values()), flat, rand).p_sufficient
        if 0.025 / 3 < p < 0.025 / 2:
            break
    records = ladder.judge_ladder((1, 2, 4), scores, flat, rand, 0.1, design)
    assert records["4"]["verdict"] == V.SUFFICIENT and records["2"]["verdict"] == V.SUFFICIENT
    assert records["2"]["share"] == pytest.approx(0.025 / 2)
    fixed = ladder.judge_ladder((1, 2, 4), scores, flat, rand, 0.1, design._replace(multiplicity="bonferroni"))
    assert fixed["2"]["verdict"] == V.UNDECIDED  # Bonferroni keeps alpha / 3 whatever K = 4 shows
