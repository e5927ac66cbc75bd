"""The step budget of an answer (gsa_jax.analysis.verdicts.step_budget): on synthetic learning curves that flatten at
a known step, the rule picks the first candidate budget whose last fifth lies past it; the answer loop trains flat
PPO's first seeds at doubling budgets until then, trains every class to that budget, and keeps the chosen budget's
runs as flat PPO's first look."""

import json
import os

import numpy as np
import pytest

from gsa_jax.analysis.sweeps import controller_scores
from gsa_jax.analysis.verdicts import answering as A
from gsa_jax.analysis.verdicts import step_budget, verdict
from gsa_jax.orchestration import answer_loop as L
from tests.test_answer import random_policy

KNEE = 100_000  # flat PPO's return rises linearly to its plateau at this step, whatever the budget it trains to


def curve(budget: int, seed: int, points: int = 12, noise: float = 0.01, knee: int = KNEE) -> tuple:
    """(env_steps [points], eval_return [points]) of a run trained to `budget`: return min(step / knee, 1) * 1000."""
    steps = np.linspace(budget / points, budget, points)
    rng = np.random.default_rng(seed)
    return steps, 1000.0 * np.minimum(steps / knee, 1.0) + noise * 1000.0 * rng.standard_normal(points)


def test_candidates_halve_the_cap_and_respect_the_floor():
    assert step_budget.candidates(1_000_000) == [62_500, 125_000, 250_000, 500_000, 1_000_000]
    assert step_budget.candidates(1_000_000, floor=200_000) == [250_000, 500_000, 1_000_000]
    assert step_budget.candidates(50_000, floor=60_000) == [50_000]


def test_candidates_are_whole_chunks_nearest_the_halvings():
    """With quantum = one chunk of flat PPO's program (10 iterations x 2048 env steps), every budget is whole chunks,
    so a run trains exactly the budget judged: 62,500 would train 4 chunks (81,920 steps) rounded up, its nearest
    whole number is 3 chunks."""
    q = 20_480
    assert step_budget.candidates(1_000_000, quantum=q) == [61_440, 122_880, 245_760, 491_520, 1_003_520]
    assert all(b % q == 0 for b in step_budget.candidates(1_000_000, floor=24_576, quantum=q))
    assert step_budget.candidates(30_000, quantum=q) == [20_480, 40_960]  # at least one chunk; the cap rounded up
    assert step_budget.candidates(19_000, floor=19_000, quantum=2048) == [20_480]  # never below the floor


def test_the_rule_picks_the_first_budget_past_the_knee():
    budgets = step_budget.candidates(1_000_000)
    judged, chosen = [], None
    while chosen is None:
        chosen, nxt = step_budget.next_budget(judged, budgets)
        if chosen is None:
            runs = [curve(nxt, s) for s in range(10)]
            judged.append(step_budget.judge_budget(nxt, [r[1][-1] for r in runs], runs, [0.0] * 128 + [1.0], 0.1, None,
                                                   (judged or [None])[-1]))
    # 62.5k: still rising over its last fifth (50k .. 62.5k), not falling, and the controllers trained to 125k are
    # shown better by more than the margin; 125k: its last fifth (100k .. 125k) is past the knee, and the controllers
    # trained to 250k confirm it (no better by the margin)
    assert chosen == 125_000 and [j["stopped"] for j in judged] == [False, True, True]
    assert judged[0]["candidate"] and not judged[1]["confirms"]["confirmed"] and judged[2]["confirms"]["confirmed"]


def judged_at(steps: int, level: float) -> tuple:
    """A candidate whose runs' curves are flat at `level` over their whole budget (stopped learning there), judged
    after the previous record (the confirmation)."""
    runs = [(np.linspace(steps / 12, steps, 12), np.full(12, level) + 1.0 * s) for s in range(10)]
    return [r[1][-1] for r in runs], runs


def test_a_curve_flat_for_a_while_is_not_chosen_where_longer_training_is_shown_better():
    """A plateau that the next budget leaves (a second rise the first budget's curves never show): the curve's test
    says stopped at both budgets, the controllers at the next budget refuse the first, and the rule goes on."""
    budgets, rand = step_budget.candidates(1_000_000), [0.0] * 128 + [1.0]
    judged = []
    for steps, level in ((62_500, 500.0), (125_000, 1000.0)):
        scores, runs = judged_at(steps, level)
        judged.append(step_budget.judge_budget(steps, scores, runs, rand, 0.1, None, (judged or [None])[-1]))
    assert all(j["enough"] for j in judged)
    assert not judged[1]["confirms"]["confirmed"] and judged[1]["confirms"]["gain"] > 0.9
    assert step_budget.next_budget(judged, budgets) == (None, 250_000)  # 125k itself awaits its confirmation
    scores, runs = judged_at(250_000, 1000.0)
    judged.append(step_budget.judge_budget(250_000, scores, runs, rand, 0.1, None, judged[-1]))
    assert step_budget.next_budget(judged, budgets) == (125_000, None)


def rising_then(steps: int, end: float, rise: float, later: float) -> tuple:
    """Two judged budgets: runs trained to `steps` whose last fifth rose by `rise` x (1 .. 1.9) from seed to seed (the
    curve's upper bound far above the margin) to `end`, then runs trained to twice as long ending at `later`."""
    rand = [0.0] * 128 + [1.0]
    runs = [(np.linspace(steps / 12, steps, 12), np.r_[np.full(10, end - rise * (1 + 0.1 * s)), end - 0.1 * s, end])
            for s in range(10)]
    first = step_budget.judge_budget(steps, [end - 0.1 * s for s in range(10)], runs, rand, 0.1, None)
    flat = [(np.linspace(steps / 6, 2 * steps, 12), np.full(12, later) - 0.1 * s) for s in range(10)]
    second = step_budget.judge_budget(2 * steps, [later - 0.1 * s for s in range(10)], flat, rand, 0.1, None, first)
    return first, second


def test_a_last_fifth_that_rose_is_chosen_where_the_next_budget_is_shown_no_better():
    """An annealed run refines to its end (the last fifth rose 15-20% of the gain: the curve's test says still
    learning), but the controllers trained twice as long are shown within the margin above it: that budget is chosen;
    where they are shown better by more than the margin, it is not."""
    budgets = step_budget.candidates(1_000_000, floor=200_000)  # 250k, 500k, 1M
    first, second = rising_then(250_000, 995.0, 120.0, 999.0)
    assert first["learning"]["upper"] > 0.1 and not first["stopped"] and not first["enough"] and first["candidate"]
    assert second["confirms"]["shown_within"] and second["confirms"]["confirmed"]
    assert step_budget.next_budget([first, second], budgets) == (250_000, None)
    first, second = rising_then(250_000, 995.0, 120.0, 995.0 * 1.2)
    assert not second["confirms"]["shown_within"] and not second["confirms"]["confirmed"]
    assert step_budget.next_budget([first, second], budgets) == (None, 1_000_000)


def test_a_falling_curve_is_never_stopped_whatever_the_next_budget_gives():
    """A last fifth that fell by 30-43% of the gain is neither stopped nor a candidate, even where the controllers
    trained twice as long score exactly as these."""
    budgets = step_budget.candidates(1_000_000, floor=200_000)  # 250k, 500k, 1M
    first, second = rising_then(250_000, 995.0, -250.0, 995.0)
    assert first["learning"]["upper"] < -0.1 and not first["stopped"] and not first["candidate"]
    assert second["confirms"] is None and step_budget.next_budget([first, second], budgets) == (None, 1_000_000)


def test_a_noisy_next_budget_confirms_a_stopped_curve_but_does_not_choose_a_rising_one():
    """The next budget's controllers spread widely (seed to seed over 60% of the gain) and score as these on average:
    not shown above (so they confirm a budget whose curve stopped) and not shown within the margin (so a budget whose
    last fifth still rose is not chosen by them)."""
    rand, budgets = [0.0] * 128 + [1.0], step_budget.candidates(1_000_000, floor=200_000)
    noisy = [995.0 + 300.0 * x for x in np.linspace(-1.0, 1.0, 10)]
    rising, _ = rising_then(250_000, 995.0, 120.0, 995.0)
    scores, runs = judged_at(250_000, 995.0)
    stopped = step_budget.judge_budget(250_000, scores, runs, rand, 0.1, None)
    for first, chosen in ((rising, None), (stopped, 250_000)):
        later = step_budget.judge_budget(500_000, noisy, runs, rand, 0.1, None, first)
        assert later["confirms"]["confirmed"] and not later["confirms"]["shown_within"]
        assert step_budget.next_budget([first, later], budgets)[0] == chosen


def test_the_cap_needs_no_confirmation_and_a_small_gain_confirms():
    rand = [0.0] * 128 + [1.0]
    scores, runs = judged_at(1_000_000, 1000.0)
    at_cap = step_budget.judge_budget(1_000_000, scores, runs, rand, 0.1, None)
    assert step_budget.next_budget([at_cap], [1_000_000]) == (1_000_000, None)
    later = [x + 20.0 for x in scores]  # 2% of the gain better: not shown above by the 10% margin
    assert step_budget.confirm(scores, later, rand, 0.1)["confirmed"]
    assert not step_budget.confirm(scores, [x + 300.0 for x in scores], rand, 0.1)["confirmed"]


def test_a_task_not_learned_is_not_stopped_at_a_flat_curve():
    flat = [(np.linspace(1, 62_500, 12), np.zeros(12) + 0.01 * s) for s in range(10)]
    judged = step_budget.judge_budget(62_500, [0.0] * 10, flat, list(np.random.default_rng(0).normal(0, 1, 128)), 0.1, None)
    assert not judged["learned"] and not judged["enough"]  # flat at the random return: no budget is chosen there


ENV = "dmc:cartpole-balance"  # a real task (the budget's floor reads its batch size); the runs are synthetic


SLOW_K = 2  # this K learns twice slower than flat PPO: still learning at flat PPO's budget


def write_sweep(results: str, policy: str, ks: list, seeds: list, steps: int) -> None:
    """A sweep's results as run_class_sweep leaves them: sweep.json, a tidy metrics.csv and controller_scores.csv."""
    os.makedirs(os.path.join(results, "controllers"), exist_ok=True)
    with open(os.path.join(results, "sweep.json"), "w") as f:
        json.dump({"spec": {"steps": steps}}, f)
    lines, rows = ["env,policy,K,seed,run,iteration,env_steps,episode_return,episodes,eval_return"], {}
    for k in ks or [1]:
        for seed in seeds:
            env_steps, returns = curve(steps, seed, knee=2 * KNEE if policy == "mixture" and k == SLOW_K else KNEE)
            for i, (s, r) in enumerate(zip(env_steps, returns)):
                lines.append(f"{ENV},{policy},{k},{seed},{seed},{i + 1},{s},{r},10,{r if policy == 'mlp' else ''}")
            label = f"{policy}-K{k}-s{seed}"
            rows[label] = {"label": label, "env": ENV, "policy": policy, "K": "" if policy == "mlp" else k,
                           "seed": seed, "controller_score": float(returns[-1])}
    with open(os.path.join(results, "metrics.csv"), "w") as f:
        f.write("\n".join(lines) + "\n")
    controller_scores.write_scores(os.path.join(results, controller_scores.FILE), rows)


def test_the_answer_trains_every_class_to_the_chosen_budget(tmp_path):
    calls = []

    def train(out, name, spec, log, where="results", runs_per_program=0, watch=None):
        calls.append((name, spec["steps"], spec.get("clusters", []), runs_per_program))
        write_sweep(os.path.join(out, where, name), spec["policies"][0], spec.get("clusters", []), spec["seeds"],
                    spec["steps"])
        return {"seconds": 1.0, "compile_s": 0.0, "compile_wall_s": 0.0, "status": 0}

    spec = {"steps": 1_000_000, "chunk": 1, "eval_every": 1, "hparams": {}, "config": {}}
    setup = A.Setup(ENV, (1, 2), 0.1, (10, 40), {"mlp": spec, "mixture": spec}, max_steps=1_000_000)
    state = L.run_answer(str(tmp_path), setup, 1e9, random_policy(), log=lambda m: None, train=train)
    q = L.budget_quantum(setup)  # a chunk of 1 iteration here: the budgets are whole iterations of flat PPO's batch
    first, second, third = (round(b / q) * q for b in (62_500, 125_000, 250_000))
    assert state["steps"]["budget"] == second  # confirmed by the controllers trained to the next budget
    assert [c["steps"] for c in state["steps"]["calibration"]] == [first, second, third]
    assert [c[1] for c in calls[:3]] == [first, second, third] and {c[1] for c in calls[3:]} == {second}  # equal steps
    assert all(c[3] == 10 for c in calls)  # every sweep padded to one program's run count
    scores = A.collect_scores(str(tmp_path), setup)
    flat = sorted(scores[A.FLAT])  # the 125k calibration runs are flat PPO's first look, once; later looks add seeds
    assert flat == list(range(len(flat))) and len(flat) in (10, 40)
    assert state["baseline"]["learning"]["stopped"] and state["baseline"]["learning"]["steps"] == second
    # the mixtures' own curves at that budget: K = 1 has stopped learning, the slow K has not, and the answer says so
    assert state["mixture_learning"]["1"]["stopped"] and not state["mixture_learning"][str(SLOW_K)]["stopped"]
    from gsa_jax.commands.answer import finish

    sentence = finish(str(tmp_path), setup, state, ["--env", ENV])
    # K = 1 suffices: the slow K above it cannot change the answer, so the sentence does not name it; the report does
    assert verdict.smallest_sufficient({int(k): r["verdict"] for k, r in state["judged"].items()})[0] == 1
    assert "still" not in sentence and f"K = {SLOW_K}: last fifth" in (tmp_path / "report.md").read_text()
    assert "**still learning**" in (tmp_path / "report.md").read_text()
    state["judged"]["1"]["verdict"] = verdict.INSUFFICIENT  # were K = 1 not sufficient, the slow K could decide it
    assert (f"The training returns of K = {SLOW_K} were still rising at {second:,} steps: a longer --steps may change "
            "its verdict.") in finish(str(tmp_path), setup, state, ["--env", ENV])


def test_a_sweep_is_estimated_from_the_line_through_the_last_two():
    """Sweeps costing compile + 15 s + 1e-5 s per run-step: after two of different work the estimate is exact; before,
    a class not run yet borrows the first sweep's compile."""
    from gsa_jax.analysis.verdicts import round_time

    def sweep(policy, steps, compile_s):
        return {"policy": policy, "runs": 10, "steps": steps, "compile_wall_s": compile_s,
                "seconds": compile_s + 15.0 + 1e-5 * 10 * steps}

    history = [sweep("mlp", 50_000, 30.0), sweep("mlp", 100_000, 2.0)]
    assert round_time.sweep_estimate(history, "mlp", 10, 400_000) == pytest.approx(2.0 + 15.0 + 40.0)
    assert round_time.sweep_estimate(history, "mixture", 10, 400_000) == pytest.approx(30.0 + 15.0 + 40.0)
    assert round_time.sweep_estimate([], "mlp", 10, 1) is None
