"""The non-inferiority verdict (gsa_jax.analysis.verdict) on score sets whose truth is known, and the error rate of
its sequential design by simulation."""

import numpy as np
import pytest

from gsa_jax.analysis import verdict as V


def noisy(center, spread, n, seed):
    return center + spread * np.random.default_rng(seed).standard_normal(n)


def test_iqm_is_rliables():
    from rliable import metrics

    x = np.random.default_rng(0).standard_normal((7, 1)) * 100
    for n in (1, 2, 3, 4, 5, 7):
        assert V.iqm(x[:n, 0]) == pytest.approx(metrics.aggregate_iqm(x[:n]), abs=1e-9)


def test_clear_win_and_clear_loss():
    flat = noisy(1000.0, 50.0, 10, 1)  # random policy scores 0: the scale is ~1000
    win = V.judge(noisy(1200.0, 50.0, 10, 2), flat, 0.0)
    loss = V.judge(noisy(500.0, 50.0, 10, 3), flat, 0.0)
    assert win.verdict == V.SUFFICIENT and win.low > 0.0
    assert loss.verdict == V.INSUFFICIENT and loss.high < -V.DEFAULT_MARGIN
    assert -0.6 < loss.point < -0.4 and win.seeds_to_decide == 10


def test_gap_exactly_minus_margin_is_undecided():
    flat = np.linspace(990.0, 1010.0, 20)  # IQM 1000, random 0: gap -0.1 is 100 points
    g = V.judge(flat - 100.0, flat, 0.0, margin=0.1)
    assert g.point == pytest.approx(-0.1)
    assert g.verdict == V.UNDECIDED and g.low < -0.1 < g.high
    assert g.seeds_to_decide is None  # the point sits on the margin: no number of seeds is likely to decide it


def test_near_deterministic_scores_a_fraction_of_the_margin_apart_are_sufficient():
    """Balance-like: every mixture seed 1 point below flat PPO's 500, a random policy at 100 (scale 400):
    gap -0.0025, far inside a margin of 0.05 although every seed of the mixture loses."""
    flat = 500.0 + np.random.default_rng(4).uniform(0.0, 0.01, 10)
    g = V.judge(flat - 1.0, flat, 100.0, margin=0.05)
    assert g.verdict == V.SUFFICIENT and g.point == pytest.approx(-1.0 / 400.0, rel=1e-3)


def test_too_few_seeds_are_undecided_with_an_estimate():
    flat, mix = noisy(1000.0, 300.0, 3, 5), noisy(950.0, 300.0, 3, 6)
    g = V.judge(mix, flat, 0.0)
    assert g.verdict == V.UNDECIDED and g.n == 3
    assert g.seeds_to_decide is None or g.seeds_to_decide > 3


def test_target_instead_of_flat_ppo():
    mix = noisy(800.0, 10.0, 10, 7)
    assert V.judge(mix, None, 0.0, target=700.0).verdict == V.SUFFICIENT
    assert V.judge(mix, None, 0.0, target=1000.0).verdict == V.INSUFFICIENT


def test_no_scale_where_flat_ppo_learned_nothing():
    g = V.judge(noisy(5.0, 1.0, 10, 8), noisy(3.0, 1.0, 10, 9), 10.0)
    assert g.verdict == V.NO_SCALE


def test_margin_outside_zero_one_is_refused():
    with pytest.raises(ValueError, match="margin"):
        V.judge([1.0, 2.0], [1.0, 2.0], 0.0, margin=1.5)


def test_smallest_sufficient_and_sentence():
    verdicts = {1: V.UNDECIDED, 2: V.SUFFICIENT, 4: V.SUFFICIENT}
    assert V.smallest_sufficient(verdicts) == (2, [1])
    assert "K = 2" in V.sentence("task", verdicts, 0.1, "flat PPO") and "K = 1 undecided" in V.sentence(
        "task", verdicts, 0.1, "flat PPO")
    assert V.smallest_sufficient({1: V.INSUFFICIENT, 2: V.UNDECIDED}) == (None, [2])


def false_sufficient_rate(looks, trials, margin=0.1, seed=11):
    """The share of synthetic cells whose true gap is exactly -margin that the sequential design (a look at
    each seed count of `looks`, stopping when decided) calls sufficient."""
    rng = np.random.default_rng(seed)
    called = 0
    for t in range(trials):
        flat = 1.0 + 0.3 * rng.standard_normal(looks[-1])  # IQM 1, random policy 0: the gap's scale is 1
        mix = 1.0 - margin + 0.3 * rng.standard_normal(looks[-1])
        for i, n in enumerate(looks):
            v = V.judge(mix[:n], flat[:n], 0.0, margin, looks=len(looks), reps=1000, seed=100 * t + i).verdict
            if v != V.UNDECIDED:
                called += v == V.SUFFICIENT
                break
    return called / trials


def test_optional_stopping_keeps_the_error_rate():
    """Adding seeds until decided (looks at 5, 10, 20, 40 seeds per cell) calls a cell whose true gap is exactly
    -delta sufficient in at most 5% of trials; judged at every look with an unadjusted 95% interval it would
    call it more often."""
    rate = false_sufficient_rate((5, 10, 20, 40), trials=300)
    assert rate <= 0.05
    assert V.look_level(4) == pytest.approx(0.9875)
