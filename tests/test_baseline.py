"""Is flat PPO an adequate baseline (gsa_jax.analysis.verdicts.baseline)? The references table read and refused in one line,
flat PPO's standing against an entry on the entry's own metric, the still-learning test on learning curves whose
plateau is known, and the answer judging against a reference flat PPO falls below."""

import os

import numpy as np
import pytest

from gsa_jax.analysis.verdicts import answering as A
from gsa_jax.analysis.verdicts import baseline as B
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
    s = B.stand(training, values, random_mean=0.0, margin=0.1)
    assert s.ours == 850.0 and s.ratio == pytest.approx(0.85) and s.below  # its controllers score higher: not compared
    deterministic = dict(training, metric="deterministic", score=2100.0)
    s2 = B.stand(deterministic, values, 0.0, 0.1)
    assert s2.ratio == pytest.approx(2000.0 / 2100.0) and not s2.below
    assert B.binding([s, s2]) is s


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
    assert found == pytest.approx(52_000.0)  # the first budget whose last fifth (41.6k .. 52k) lies past the knee at 40k


@pytest.mark.parametrize("at_step, every", [(61_440, 20_480), (122_880, 20_480), (245_760, 20_480),
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
    assert len(read) < len(steps) and set(read) <= set(steps.astype(int).tolist())
    dropped = [np.where(np.isin(s, read[:-1]), r, np.nan) for s, r in curves]  # reading fewer changes the gains
    assert not np.array_equal(B.last_fifth_gains([(steps, r) for r in dropped], at_step), B.last_fifth_gains(curves, at_step))


def test_a_task_not_learned_gets_no_answer():
    ok, why = B.learned(30.0, 5.0, 1000.0)
    assert not ok and "does not learn the task" in why
    assert B.learned(150.0, 5.0, 1000.0)[0] and B.learned(3.0, 5.0, None)[0]


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
