"""Every answer the repository states is what the current design gives for its data: each table's verdicts
(verdicts.csv, sufficient_k.csv) recomputed from its committed runs as gsa plot judges them, the re-judged answers
(rejudged.csv) from those tables, the constructive answers (constructive.csv) from the committed fresh-start
episodes, and every committed gsa answer folder's verdicts from its runs. The READMEs quote these files, and
test_docs checks every quote against them: a sentence that the design no longer gives fails here or there."""

import glob
import importlib.util
import json
import os
import sys

import pytest

from gsa_jax.analysis.sweeps import controller_scores
from gsa_jax.analysis.sweeps.results import (
    drop_failed, load_failed, load_sweeps, read_csv, setting_columns, spec_steps, task_records,
)
from gsa_jax.analysis.verdicts.grid import sufficient_k_table, verdict_table

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
EXP = os.path.join(ROOT, "experiments")
ATLAS = os.path.join(EXP, "atlas_dmc", "results")
V5 = os.path.join(EXP, "fig1_v5", "results")
V5_RUNS = ["fig1_v5_InvertedDoublePendulum-v5", "fig1_v5_Hopper-v5", "fig1_v5_HalfCheetah-v5", "fig1_v5_Walker2d-v5_seeds_0_4",
           "fig1_v5_Walker2d-v5_seeds_5_9", "fig1_v5_Ant-v5_seeds_0_4", "fig1_v5_Ant-v5_seeds_5_9"]
TABLES = {"gymnasium v5": ([os.path.join(V5, d) for d in V5_RUNS], os.path.join(V5, "merged"))}
TABLES.update({f"dmc:{t}": ([os.path.join(ATLAS, t, "flat_ppo"), os.path.join(ATLAS, t, "mixture")], os.path.join(ATLAS, t))
               for t in sorted(os.listdir(ATLAS)) if os.path.isdir(os.path.join(ATLAS, t, "flat_ppo"))})
BRAX = os.path.join(EXP, "fig1", "results")
BRAX_HALVES = {t: [os.path.join(BRAX, f"fig1_{t}_seeds_{h}") for h in ("0_4", "5_9")] for t in ("halfcheetah", "ant")}
TABLES.update({f"brax {t}": ([os.path.join(BRAX, f"fig1_{t}")], os.path.join(BRAX, f"fig1_{t}"))
               for t in ("inverted_double_pendulum", "hopper", "walker2d")})
TABLES.update({f"brax {t}": (halves, os.path.join(BRAX, f"fig1_{t}")) for t, halves in BRAX_HALVES.items()})
TABLES["brax merged"] = ([os.path.join(BRAX, f"fig1_{t}") for t in ("inverted_double_pendulum", "hopper", "walker2d")]
                         + [d for halves in BRAX_HALVES.values() for d in halves], os.path.join(BRAX, "merged"))
TABLES["brax hopper_walker2d"] = ([os.path.join(BRAX, "fig1_hopper"), os.path.join(BRAX, "fig1_walker2d")],
                                  os.path.join(BRAX, "hopper_walker2d"))
PARTITION = os.path.join(EXP, "partition", "results")
TABLES.update({f"partition {t}": ([os.path.join(PARTITION, t, a) for a in ("flat_ppo", "mlp", "linear")], os.path.join(PARTITION, t))
               for t in sorted(os.listdir(PARTITION)) if os.path.isdir(os.path.join(PARTITION, t, "linear"))})
VERDICT_KEY = ("env", "K", "margin", "role", "verdict", "gap", "gap_low", "gap_high", "seeds")


def load_script(path: str, name: str):
    """An experiment script as a module (its folder on sys.path, as when it runs)."""
    sys.path.insert(0, os.path.dirname(path))
    try:
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    finally:
        sys.path.remove(os.path.dirname(path))


def kept_random_policies(out: str, dirs: list, env_names: list) -> dict:
    """{env: random policy record} as gsa plot reads it without measuring: random_policy.json for a task with a
    MuJoCo C version (refusing one measured otherwise than gsa plot measures it now: it would measure anew), else the
    sweeps' random_returns.json (theirs over the table's), taken as exact."""
    kept, path = {}, os.path.join(out, controller_scores.RANDOM_FILE)
    if os.path.exists(path):
        with open(path) as f:
            kept = json.load(f)
    for env, r in kept.items():
        assert (r["episodes"], r["start_seed"]) == (controller_scores.RANDOM_EPISODES, controller_scores.RANDOM_START_SEED), env
    exact = {}
    for p in [os.path.join(out, "random_returns.json")] + [q for d in dirs for q in glob.glob(os.path.join(d, "**", "random_returns.json"), recursive=True)]:
        if os.path.exists(p):
            with open(p) as f:
                exact.update(json.load(f))
    for env, task in task_records(env_names).items():
        if not task.has_c:
            kept[env] = {"returns": float(exact[env]), "episodes": 0, "start_seed": ""}
    return {e: kept[e] for e in env_names if e in kept}


def regenerated(dirs: list, out: str) -> tuple:
    """(verdicts.csv rows, sufficient_k.csv rows) of the runs in `dirs`, as gsa plot computes them (sweep_report)."""
    data, _ = drop_failed(load_sweeps(dirs), [f for d in dirs for f in load_failed(d)])
    controller_scores.attach(data, dirs)
    settings = setting_columns(data)
    envs_here = sorted({c.env for c in data})
    rows = verdict_table(data, kept_random_policies(out, dirs, envs_here), spec_steps(dirs), settings)
    return rows, sufficient_k_table(rows, settings)


def as_text(rows: list, columns: tuple) -> list:
    """The rows' columns as the CSV holds them (write_csv's text)."""
    return [tuple(str(r.get(c, "")) for c in columns) for r in rows]


@pytest.mark.parametrize("name", sorted(TABLES))
def test_each_table_states_the_verdicts_its_runs_give(name):
    dirs, out = TABLES[name]
    verdicts, sufficient = regenerated(dirs, out)
    assert as_text(sufficient, ("env", "margin", "answer")) == as_text(read_csv(os.path.join(out, "sufficient_k.csv")),
                                                                      ("env", "margin", "answer"))
    assert as_text(verdicts, VERDICT_KEY) == as_text(read_csv(os.path.join(out, "verdicts.csv")), VERDICT_KEY)


def test_the_rejudged_answers_are_what_the_tables_give():
    rejudge = load_script(os.path.join(EXP, "verdicts", "rejudge.py"), "rejudge")
    committed = read_csv(os.path.join(EXP, "verdicts", "results", "rejudged.csv"))
    rows = rejudge.rejudged_rows()
    columns = tuple(committed[0])
    assert as_text(rows, columns) == as_text(committed, columns)
    assert [{"summary": rejudge.summary(rows)}] == read_csv(os.path.join(EXP, "verdicts", "results", "rejudged_summary.csv"))


def test_the_replayed_answers_are_what_the_design_gives():
    speed = load_script(os.path.join(EXP, "verdicts", "answer_speed.py"), "answer_speed")
    committed = read_csv(os.path.join(EXP, "verdicts", "results", "answer_speed.csv"))
    columns = tuple(committed[0])
    assert as_text(speed.speed_rows(log=lambda row: None), columns) == as_text(committed, columns)


def test_the_constructive_answers_are_what_the_fresh_episodes_give():
    answers = load_script(os.path.join(EXP, "constructive", "answers.py"), "constructive_answers")
    rows, exhibits = answers.answer_rows(log=lambda line: None)
    for table, mine in (("constructive.csv", rows), ("exhibits.csv", exhibits)):
        committed = read_csv(os.path.join(EXP, "constructive", "results", table))
        columns = tuple(committed[0])
        assert as_text(mine, columns) == as_text(committed, columns), table


def test_the_partition_verdicts_are_what_its_tables_give():
    compare = load_script(os.path.join(EXP, "partition", "compare.py"), "partition_compare")
    tasks = sorted(os.path.join(PARTITION, t) for t in os.listdir(PARTITION) if os.path.isdir(os.path.join(PARTITION, t, "linear")))
    committed = read_csv(os.path.join(PARTITION, "verdicts.csv"))
    columns = tuple(committed[0])
    assert as_text(compare.judge_rows(tasks), columns) == as_text(committed, columns)


def test_the_partition_constructive_answers_are_what_its_fresh_episodes_give():
    constructive = load_script(os.path.join(EXP, "partition", "constructive.py"), "partition_constructive")
    committed = read_csv(os.path.join(PARTITION, "constructive.csv"))
    columns = tuple(committed[0])
    assert as_text(constructive.answer_rows(), columns) == as_text(committed, columns)


ANSWER_FOLDERS = ["answers/InvertedDoublePendulum-v5", "answers/cartpole-swingup", "answers/reacher-hard", "longer_budget/answer"]


@pytest.mark.parametrize("folder", ANSWER_FOLDERS)
def test_each_committed_answer_folder_states_what_its_runs_give(folder):
    """The folder's answer.json verdicts and sentence are answering.decide's and verdict.sentence's on its runs
    (regenerate_answers.py's setup: the task's committed runs and the folder's rounds)."""
    from gsa_jax.analysis.verdicts import verdict
    from gsa_jax.analysis.verdicts.answering import STATE, collect_evidence, decide
    from gsa_jax.commands.answer import build_parser, make_setup

    regen = load_script(os.path.join(EXP, "verdicts", "regenerate_answers.py"), "regenerate_answers")
    env, start_from = regen.ANSWERS[folder]
    out = os.path.join(EXP, "verdicts", folder)
    with open(os.path.join(out, STATE)) as f:
        state = json.load(f)
    setup = make_setup(build_parser().parse_args(["--env", env, "--start-from", *[os.path.join(ROOT, d) for d in start_from]]))
    fresh = {"rounds": state["rounds"], "random": state["random"], "steps": state["steps"], "records": {}}
    records, _, _ = decide(setup, collect_evidence(out, setup), fresh)
    assert {k: r["verdict"] for k, r in records.items()} == {k: r["verdict"] for k, r in state["judged"].items()}
    report = open(os.path.join(out, "report.md")).read()
    versus = state.get("baseline", {}).get("versus", "flat PPO")
    assert verdict.sentence(env, {int(k): r["verdict"] for k, r in records.items()}, setup.margin, versus) in report
    assert state["constructive"]["sentence"] in report
