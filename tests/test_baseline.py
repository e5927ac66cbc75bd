"""Is flat PPO an adequate baseline (gsa_jax.analysis.verdicts.baseline)? The references table read and refused in one line,
flat PPO's standing against an entry on the entry's own metric, the still-learning test on learning curves whose
plateau is known, and the answer judging against a reference flat PPO falls below."""

import os

import numpy as np
import pytest

from gsa_jax.analysis.verdicts import answering as A
from gsa_jax.analysis.verdicts import baseline as B
from gsa_jax.analysis.verdicts import trimmed
from gsa_jax.analysis.verdicts import verdict
from gsa_jax.orchestration import answer_loop as L

HEADER = "task,published_task,score,std,seeds,steps,metric,algorithm,source,note\n"


def write(tmp_path, text, name="refs.csv"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def test_the_shipped_table_covers_every_v5_and_dmc_task_at_1m_steps():
    import envs

    refs = B.load_references()
    for task in list(envs.GYM_V5_TASKS) + list(envs.DMC_TASKS):
        at_1m = B.applicable(refs, task, 1_000_000)
        assert at_1m, task
        assert all(r["source"] and r["metric"] in B.METRICS for r in at_1m)
    assert all(r["steps"] <= 1_000_000 for r in B.applicable(refs, "Hopper-v5", 1_000_000))


@pytest.mark.parametrize("text, message", [
    ("task,score,steps\nHopper-v5,1,2\n", "lacks the column(s) metric, source"),
    (HEADER + "Hopper-v5,Hopper-v4,abc,1,3,1000000,deterministic,x,src,\n", "line 2: could not convert string to float"),
    (HEADER + "Hopper-v5,Hopper-v4,100,1,3,1000000,median,x,src,\n", "metric 'median' is not one of"),
    (HEADER + "Hopper-v5,Hopper-v4,100,1,3,,deterministic,x,src,\n", "line 2: missing steps"),
])
def test_a_malformed_table_is_refused_in_one_line(tmp_path, text, message):
    with pytest.raises(B.ReferencesError, match=message.replace("(", r"\(").replace(")", r"\)")) as e:
        B.load_references(write(tmp_path, text))
    assert "\n" not in str(e.value)


def test_a_malformed_table_stops_the_answer_before_anything_compiles(tmp_path, capsys):
    from gsa_jax.answer import main

    bad = write(tmp_path, HEADER + "dmc:cartpole-swingup,x,abc,1,3,1000000,deterministic,x,src,\n")
    assert main(["--env", "dmc:cartpole-swingup", "--references", bad, "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "could not convert" in err and not (tmp_path / "a").exists()


def test_standing_is_judged_on_the_entrys_own_metric():
    training = {"task": "t", "score": 1000.0, "metric": "training_last_100", "std": 0.0, "seeds": 3, "steps": 10}
    values = {"controller_score": [2000.0] * 5, "training_return_last_100_episodes": [850.0] * 5}
    s = B.stand(training, values, trimmed.fixed(0.0), margin=0.1)
    assert s.ours == 850.0 and s.ratio == pytest.approx(0.85) and s.below  # its controllers score higher: not compared
    deterministic = dict(training, metric="deterministic", score=2100.0)
    s2 = B.stand(deterministic, values, trimmed.fixed(0.0), 0.1)
    assert s2.ratio == pytest.approx(2000.0 / 2100.0) and not s2.below
    assert B.binding([s, s2]) is s


def test_a_baseline_a_little_below_an_entry_is_not_switched_by_its_point_estimate():
    """Flat PPO at 0.88 of an entry's gain (the margin's bar at 0.9) with two of ten seeds failing: not shown below,
    so the entry does not bind; ten tight seeds at 0.85 are shown below it."""
    entry = {"task": "t", "score": 1000.0, "metric": "deterministic", "std": 50.0, "seeds": 10, "steps": 10}
    spread = {"controller_score": [1100.0] * 8 + [0.0, 0.0]}  # mean 880
    s = B.stand(entry, spread, trimmed.fixed(0.0), 0.1)
    assert s.ratio == pytest.approx(0.88) and not s.below and s.p_below > 0.05
    tight = B.stand(entry, {"controller_score": list(850.0 + np.linspace(-5, 5, 10))}, trimmed.fixed(0.0), 0.1)
    assert tight.below and tight.p_below < 0.05
    assert B.binding([s, tight]) is tight


def curves_flattening_at(step, seeds=10, total=100_000, every=4000, noise=0.01, rate=1.0):
    """Learning curves (env_steps, eval_return) rising linearly to 1 at `step`, flat after (random policy at 0)."""
    rng = np.random.default_rng(0)
    steps = np.arange(every, total + 1, every, dtype=float)
    return [(steps, np.minimum(steps / step, 1.0) * rate + noise * rng.standard_normal(len(steps))) for _ in range(seeds)]


def test_still_learning_is_reported_and_a_plateau_is_found_where_it_is():
    rising = curves_flattening_at(200_000)  # still climbing at 100k: the last fifth gains 0.1 of the scale and more
    learn = B.learning(rising, 100_000, scale=0.5, margin=0.1)
    assert not learn.stopped and learn.gain > 0.1
    flat = curves_flattening_at(40_000)
    assert B.learning(flat, 100_000, scale=1.0, margin=0.1).stopped
    candidates = np.arange(8000, 100_001, 4000, dtype=float)
    found = B.plateau_step(flat, candidates, scale=1.0, margin=0.1)
    # the first budget whose last fifth gains less than the margin: at 48k its start averages 36k-40k (0.95), its end
    # 44k-48k (1.0), a gain of 0.05
    assert found == pytest.approx(48_000.0)


def synthetic(shape, seeds=8, every=2_000, total=100_000, noise=0.01, seed=0):
    """Learning curves [(env_steps, eval_return)] of `seeds` runs: shape(steps) plus evaluation noise."""
    rng = np.random.default_rng(seed)
    steps = np.arange(every, total + 1, every, dtype=float)
    return [(steps, shape(steps) + noise * rng.standard_normal(len(steps))) for _ in range(seeds)]


def test_a_falling_curve_is_never_stopped_and_a_plateau_is():
    """Gains as a share of scale 1 over the last fifth (80k .. 100k steps), margin 0.1: falling by about 0.2, a
    plateau, a slow rise of 0.2. A curve falling by the margin or more is never 'stopped', however noisy (the rule
    before took any gain shown below +margin, a fall included, as stopped)."""
    falling = B.learning(synthetic(lambda s: 1.0 - np.maximum(s - 80_000, 0) / 100_000), 100_000, 1.0, 0.1)
    assert not falling.stopped and falling.upper < -0.1 and falling.gain < -0.15
    for noise in (0.001, 0.05, 0.3, 1.0):
        for seed in range(5):
            learn = B.learning(synthetic(lambda s: 1.0 - s / 150_000, noise=noise, seed=seed), 100_000, 1.0, 0.1)
            assert not learn.stopped
    plateau = B.learning(synthetic(lambda s: np.minimum(s / 40_000, 1.0)), 100_000, 1.0, 0.1)
    assert plateau.stopped and -0.1 < plateau.lower <= plateau.gain <= plateau.upper < 0.1
    slow = B.learning(synthetic(lambda s: s / 100_000), 100_000, 1.0, 0.1)
    assert not slow.stopped and slow.lower > 0.1


def test_one_noisy_evaluation_does_not_decide_an_end_of_the_last_fifth():
    """Evaluated every 2.5k steps, each end's 5% window holds two evaluations: it averages the MIN_EVALS nearest its
    end instead (95k-100k and 77.5k-82.5k), so one evaluation 0.5 off (at 100k) moves the gain by a third of that."""
    steps = np.arange(2_500, 100_001, 2_500, dtype=float)
    clean = np.ones(len(steps))
    spiked = clean.copy()
    spiked[-1] += 0.5
    gains = B.last_fifth_gains([(steps, spiked)], 100_000)
    assert gains[0] == pytest.approx(0.5 / B.MIN_EVALS)
    assert B.window_steps(steps, 100_000, "end").tolist() == [95_000, 97_500, 100_000]
    assert B.window_steps(steps, 100_000, "start").tolist() == [77_500, 80_000, 82_500]


def test_a_budget_without_evaluations_near_an_end_is_not_shown_stopped():
    """At 61,440 steps evaluated every 20,480 no evaluation lies within a tenth of the budget of 49,152: no gain can
    be read (the rule before compared two single evaluations), so flat PPO is not shown to have stopped."""
    steps = np.array([20_480.0, 40_960.0, 61_440.0])
    curves = [(steps, np.array([0.5, 0.9, 1.0])) for _ in range(6)]
    assert B.last_fifth_gains(curves, 61_440).size == 0 and B.steps_read(61_440, 20_480) == [61_440]
    assert not B.learning(curves, 61_440, 1.0, 0.1).stopped


@pytest.mark.parametrize("at_step, every", [(122_880, 20_480), (245_760, 20_480),
                                             (1_003_520, 20_480), (100_000, 4_000), (100_000, 7_000)])
def test_evaluating_only_the_steps_read_gives_the_same_gains(at_step, every):
    """The answer evaluates flat PPO only where the still-learning test reads (steps_read): the test's gains on those
    evaluations alone equal its gains on an evaluation after every chunk, and fewer are read than run."""
    rng = np.random.default_rng(3)
    steps = np.arange(every, at_step + 1, every, dtype=float)
    curves = [(steps, rng.standard_normal(len(steps)).cumsum()) for _ in range(6)]
    read = B.steps_read(at_step, every)
    sparse = [(s, np.where(np.isin(s, read), r, np.nan)) for s, r in curves]
    np.testing.assert_array_equal(B.last_fifth_gains(sparse, at_step), B.last_fifth_gains(curves, at_step))
    assert len(read) <= len(steps) and set(read) <= set(steps.astype(int).tolist())
    assert len(read) < len(steps) or len(steps) <= 2 * B.MIN_EVALS
    dropped = [np.where(np.isin(s, read[:-1]), r, np.nan) for s, r in curves]  # reading fewer changes the gains
    assert not np.array_equal(B.last_fifth_gains([(steps, r) for r in dropped], at_step), B.last_fifth_gains(curves, at_step))


def test_a_task_not_learned_gets_no_answer_only_where_it_is_shown():
    """The bar: 10% of the way from the random policy's 5 to the maximum 1000 (104.5). Ten seeds near 30 are shown
    below it; a quadruped-like IQM of 194 with an error of about 30 is not (nor is a coin flip from the bar)."""
    rand = trimmed.fixed(5.0)
    ok, why = B.learned(list(30.0 + np.linspace(-3, 3, 10)), rand, 1000.0)
    assert not ok and "does not learn the task" in why and "shown below 104.5" in why
    assert B.learned(list(150.0 + np.linspace(-3, 3, 10)), rand, 1000.0)[0] and B.learned([3.0] * 10, rand, None)[0]
    coin = list(np.random.default_rng(0).normal(100.0, 80.0, 10))
    assert B.learned(coin, rand, 1000.0)[0]


def reference_trainer(truth):
    from tests.test_answer import synthetic_trainer

    return synthetic_trainer(truth)


@pytest.mark.parametrize("mixture_mean, expect", [(1000.0, verdict.INSUFFICIENT), (2000.0, verdict.SUFFICIENT)])
def test_a_baseline_below_its_reference_is_replaced_by_it(tmp_path, mixture_mean, expect):
    """Flat PPO at 1000 against a tuned PPO at 2000 on the same metric: the verdicts judge against the reference, so
    K = 4 at flat PPO's level is insufficient and only K = 4 within the margin of the reference is sufficient."""
    from tests.test_answer import random_policy, synthetic_trainer

    refs = write(tmp_path, HEADER + "task,task,2000,50,10,1000,deterministic,tuned PPO,src,\n")
    spec = {"steps": 1000, "chunk": 1, "eval_every": 0, "hparams": {}, "config": {}}
    setup = A.Setup("task", (4,), 0.1, (10, 20), {"mlp": spec, "mixture": spec}, references=refs)
    run, _ = synthetic_trainer({A.FLAT: (1000.0, 20.0), 4: (mixture_mean, 5.0)})
    state = L.run_answer(str(tmp_path / "a"), setup, 1e9, random_policy(), log=lambda m: None, train=run)
    assert state["baseline"]["entry"]["score"] == 2000.0 and state["baseline"]["binding"]["below"]
    assert state["judged"]["4"]["verdict"] == expect and state["judged"]["4"]["reference_seeds"] == 10


def test_flat_ppo_within_the_random_returns_interval_gives_no_answer(tmp_path):
    """fish-like: flat PPO scores 80 where 128 random episodes average 80 with a wide spread: the answer stops with
    'no answer' after the first look, for every K."""
    from gsa_jax.commands.answer import finish
    from tests.test_answer import random_policy, synthetic_trainer

    spec = {"steps": 1000, "chunk": 1, "eval_every": 0, "hparams": {}, "config": {}}
    setup = A.Setup("task", (1, 2), 0.1, (10, 20), {"mlp": spec, "mixture": spec})
    run, calls = synthetic_trainer({A.FLAT: (80.0, 10.0), 1: (85.0, 10.0), 2: (90.0, 10.0)})
    out = str(tmp_path / "a")
    state = L.run_answer(out, setup, 1e9, random_policy(80.0, 100.0), log=lambda m: None, train=run)
    assert state["stopped"] == "no answer" and len(calls) == 2  # flat PPO, then K = 1, 2 in one sweep
    assert {r["verdict"] for r in state["judged"].values()} == {verdict.NO_SCALE}
    assert "no answer" in finish(out, setup, state, ["--env", "task"])
    assert os.path.exists(os.path.join(out, "report.md"))
