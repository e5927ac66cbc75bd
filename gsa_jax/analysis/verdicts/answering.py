"""The answer loop of `gsa answer`: train flat PPO and a ladder of K in rounds, judge every cell at the
design's looks (gsa_jax.analysis.verdicts.ladder: Yuen's trimmed-mean t, an alpha-spending function over the looks, Holm over
the K) against a baseline shown adequate (gsa_jax.analysis.verdicts.baseline), and add seeds only where the smallest
sufficient K is not decided yet.

A round trains, per policy class, one sweep (one vmapped program; gsa_jax.sweep in a subprocess, resumable, with the
answer's shared compilation cache so a later round with the same shapes loads its program), exports every run's
controller and scores it in MuJoCo C (gsa_jax.analysis.sweeps.controller_scores). The decisions are a pure function of the
runs' values (decide), so experiments/verdicts/error_rates.py simulates this very loop. The state (DIR/answer.json)
is written after every step, so the same command resumes where it stopped.
"""

import dataclasses
import glob
import json
import os
import re
import subprocess
import sys
import time
from typing import Callable, NamedTuple, Sequence

from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.analysis.sweeps import columns as C
from gsa_jax.analysis.sweeps import controller_scores
from gsa_jax.analysis.sweeps.extraction import collect_results
from gsa_jax.analysis.sweeps.results import task_records
from gsa_jax.analysis.verdicts import baseline, ladder, sequential, trimmed, verdict
from gsa_jax.errors import UserError
from gsa_jax.running.checkpoint import write_atomic
from gsa_jax.running.spec import SpecError, SweepSpec, check_spec

STATE = "answer.json"
FLAT = "flat"  # the key of flat PPO's cell beside the K of the mixtures
DEFAULT_LOOKS = (10, 20, 40)
DEFAULT_SPENDING = "pocock"


class AnswerError(UserError):
    pass


@dataclasses.dataclass(frozen=True)
class Setup:
    """What an answer computes (recorded in answer.json; a resumed answer must match it). specs: the base
    experiment spec per policy ('mlp', 'mixture': steps, hparams, config); looks: seeds per cell at each look;
    alpha, spending: the design (gsa_jax.analysis.verdicts.sequential); start_from: results directories whose committed
    controllers are the first seeds; references: the references table (None: the shipped one)."""

    env: str
    ladder: tuple
    margin: float
    looks: tuple
    specs: dict
    target: float | None = None
    start_from: tuple = ()
    alpha: float = sequential.DESIGN_ALPHA
    spending: str = DEFAULT_SPENDING
    references: str | None = None
    multiplicity: str = "holm"

    def design(self) -> sequential.Design:
        return sequential.Design(tuple(self.looks), self.alpha, self.spending, self.multiplicity)

    def steps(self) -> int:
        return int(self.specs[MLP if self.target is None else MIXTURE]["steps"])

    def to_json(self) -> dict:
        return {**dataclasses.asdict(self), "ladder": list(self.ladder), "looks": list(self.looks),
                "start_from": list(self.start_from)}


def sweep_spec(setup: Setup, policy: str, ks: list, seeds: list, name: str) -> dict:
    """The experiment spec of one round's sweep of one class: the base spec with the round's K and seeds."""
    spec = {k: v for k, v in setup.specs[policy].items() if k not in ("clusters", "cluster_multipliers", "name")}
    spec.update(name=name, envs=[setup.env], policies=[policy], seeds=list(seeds))
    if policy == MIXTURE:
        spec["clusters"] = sorted(ks)
    return spec


def check_setup(setup: Setup) -> None:
    """AnswerError in one line for what cannot be answered, before anything compiles."""
    if not setup.ladder:
        raise AnswerError("the K ladder is empty: give --clusters K [K ...]")
    if any(int(k) < 1 for k in setup.ladder):
        raise AnswerError(f"every K must be >= 1, got {list(setup.ladder)}")
    if not 0.0 < setup.margin < 1.0:
        raise AnswerError(f"--margin must be in (0, 1), got {setup.margin}")
    try:
        sequential.check_design(setup.design())
    except ValueError as e:
        raise AnswerError(f"--looks: {e}" if "look" in str(e) else str(e)) from None
    if setup.target is None:
        try:
            baseline.load_references(setup.references or baseline.REFERENCES)
        except baseline.ReferenceError as e:
            raise AnswerError(str(e)) from None
    for policy in (MLP, MIXTURE):
        if policy == MLP and setup.target is not None:
            continue
        try:
            spec = check_spec(sweep_spec(setup, policy, list(setup.ladder), list(range(setup.looks[0])), "answer_check"),
                              source=f"the {policy} spec")
        except SpecError as e:
            raise AnswerError(str(e)) from None
        if policy == MLP:
            check_evaluations(spec)


MIN_EVALUATIONS = 10  # flat PPO's evaluations per run the still-learning test needs (baseline.learning)


def check_evaluations(spec: SweepSpec) -> None:
    """AnswerError in one line where flat PPO's runs would have too few evaluations for the still-learning test."""
    from gsa_jax.running.spec import build_grid, default_chunk, group_config, group_eval_every, group_iterations

    group = build_grid(spec)[0]
    cfg = group_config(spec, group)
    iterations = group_iterations(spec, cfg, default_chunk(spec, cfg))
    every = group_eval_every(spec, iterations)
    evaluations = iterations // every if every else 0
    if evaluations < MIN_EVALUATIONS:
        need = MIN_EVALUATIONS * cfg.batch_size * (every if spec.eval_every else 1)
        raise AnswerError(f"--steps {spec.steps} gives flat PPO {evaluations} evaluations per run; the still-learning "
                          f"test needs at least {MIN_EVALUATIONS}: give --steps {need} or more")


def to_toml(spec: dict) -> str:
    """An experiment spec as a TOML experiment file (scalars, lists, [hparams], [config], hparam_sets)."""

    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + "}"
        return json.dumps(v)

    lines = [f"{k} = {value(v)}" for k, v in spec.items() if k not in ("hparams", "config") and v is not None]
    for table in ("hparams", "config"):
        lines.append(f"[{table}]")
        lines += [f"{k} = {value(v)}" for k, v in (spec.get(table) or {}).items() if v is not None]
    return "\n".join(lines) + "\n"


def load_state(out: str, setup: Setup) -> dict:
    """The answer's state in `out` (new if none); AnswerError if `out` holds another answer's."""
    path = os.path.join(out, STATE)
    if not os.path.exists(path):
        return {"setup": setup.to_json(), "rounds": [], "records": {}, "elapsed_s": 0.0}
    with open(path) as f:
        state = json.load(f)
    mine = json.loads(json.dumps(setup.to_json()))
    if state["setup"] != mine:
        changed = sorted(k for k in set(state["setup"]) | set(mine) if state["setup"].get(k) != mine.get(k))
        raise AnswerError(f"{out} holds an answer with other settings ({', '.join(changed)}); use another --out")
    return state


def save_state(out: str, state: dict) -> None:
    write_atomic(os.path.join(out, STATE), json.dumps(state, indent=1))


# ----------------------------------------------------------------------------------------------- evidence
class Evidence(NamedTuple):
    """What the decisions read: per cell (FLAT or K) {seed: value} of the controller scores and of the mean return of
    the last 100 training episodes, and flat PPO's learning curves {seed: (env_steps [T], eval_return [T])}."""

    scores: dict
    last100: dict
    curves: dict


def score_roots(out: str, setup: Setup) -> list:
    """The results directories whose controllers are this answer's runs: --start-from's and the rounds'."""
    return list(setup.start_from) + [os.path.join(out, "results")]


def cell_key(setup: Setup, policy: str, k: int | str) -> int | str | None:
    """FLAT, a K of the ladder, or None for a cell the answer does not judge."""
    key = FLAT if policy == MLP else int(k)
    return key if key == FLAT or key in setup.ladder else None


def collect_scores(out: str, setup: Setup) -> dict:
    """{FLAT or K: {seed: controller score}} of the task's scored controllers under score_roots."""
    found = {}
    for root in score_roots(out, setup):
        for path in sorted(glob.glob(os.path.join(root, "**", controller_scores.FILE), recursive=True)):
            for row in controller_scores.read_scores(path).values():
                key = cell_key(setup, row["policy"], row["K"])
                if row["env"] == setup.env and row.get(C.CONTROLLER_SCORE, "") != "" and key is not None:
                    found.setdefault(key, {})[int(row["seed"])] = float(row[C.CONTROLLER_SCORE])
    return found


def collect_runs(out: str, setup: Setup) -> tuple:
    """({FLAT or K: {seed: last-100-episode training return}}, flat PPO's {seed: (env_steps, eval_return)}) from the
    tidy metrics under score_roots."""
    from gsa_jax.analysis.sweeps.results import load_sweep
    from gsa_jax.analysis.sweeps.stats import last_episodes_return

    last100, curves = {}, {}
    dirs = sorted({os.path.dirname(p) for root in score_roots(out, setup)
                   for p in glob.glob(os.path.join(root, "**", "sweep.json"), recursive=True)})
    for d in dirs:
        try:
            cells = load_sweep(d)
        except FileNotFoundError:
            continue
        for cell, seeds in cells.items():
            key = cell_key(setup, cell.policy, cell.k)
            if cell.env != setup.env or key is None:
                continue
            for seed, s in seeds.items():
                last100.setdefault(key, {})[seed] = last_episodes_return(s["episode_return"], s["episodes"])
                if key == FLAT:
                    curves[seed] = (s["env_steps"], s["eval_return"])
    return last100, curves


def collect_evidence(out: str, setup: Setup) -> Evidence:
    last100, curves = collect_runs(out, setup)
    return Evidence(collect_scores(out, setup), last100, curves)


# ----------------------------------------------------------------------------------------------- decisions
def random_summary(state: dict) -> trimmed.Summary:
    return verdict.summarize_random(state["random"]["returns"])


def choose_baseline(setup: Setup, evidence: Evidence, state: dict) -> dict:
    """The baseline record (what the verdicts judge against, and why), decided once at the answer's first look from
    flat PPO's first-look seeds: flat PPO, or the reference entry it falls below, or the user's target."""
    if setup.target is not None:
        return {"versus": f"the target score {setup.target:g}", "metric": C.CONTROLLER_SCORE, "entry": None,
                "standings": [], "learning": None, "learned": True}
    n = setup.looks[0]
    flat = baseline.FlatRuns(ladder.first_seeds(evidence.scores.get(FLAT, {}), n),
                             ladder.first_seeds(evidence.last100.get(FLAT, {}), n),
                             [evidence.curves[s] for s in sorted(evidence.curves)[:n]])
    refs = baseline.load_references(setup.references or baseline.REFERENCES)
    return baseline.choose(setup.env, setup.steps(), setup.margin, flat, random_summary(state), refs,
                           task_max_return(setup.env))


def task_max_return(env: str) -> float | None:
    """The task's declared maximum return (TaskRecord.max_return), None where it declares none or is not a task
    here."""
    try:
        return task_records([env])[env].max_return()
    except (ValueError, ImportError):
        return None


def reference_of(setup: Setup, evidence: Evidence, base: dict) -> "list | trimmed.Summary":
    """What judge_ladder compares with: flat PPO's values in seed order, a reference entry, or the target."""
    if setup.target is not None:
        return trimmed.fixed(setup.target)
    if base["entry"] is not None:
        return baseline.reference_summary(base["entry"])
    values = evidence.scores if base["metric"] == C.CONTROLLER_SCORE else evidence.last100
    return ladder.first_seeds(values.get(FLAT, {}), len(values.get(FLAT, {})))


def judge_cells(setup: Setup, evidence: Evidence, state: dict) -> dict:
    """{str(K): record} of every K at its looks (ladder.judge_ladder), against the state's baseline."""
    base = state["baseline"]
    if not base["learned"]:
        return {str(k): {"verdict": verdict.NO_SCALE, "why": base["why"]} for k in setup.ladder}
    values = evidence.scores if base["metric"] == C.CONTROLLER_SCORE else evidence.last100
    cells = {k: values.get(k, {}) for k in setup.ladder}
    return ladder.judge_ladder(setup.ladder, cells, reference_of(setup, evidence, base), state["random"]["returns"],
                               setup.margin, setup.design(), state["records"])


def cells_to_extend(setup: Setup, records: dict, scores: dict) -> list:
    """The K that need more seeds: those not yet at the first look, and the undecided ones below the smallest
    sufficient K (none once there is no answer)."""
    verdicts = {k: records[str(k)]["verdict"] for k in setup.ladder if str(k) in records}
    if verdict.NO_SCALE in verdicts.values():
        return []
    untrained = [k for k in setup.ladder if len(scores.get(k, {})) < setup.looks[0]]
    if untrained:
        return untrained
    chosen, below = verdict.smallest_sufficient(verdicts)
    return below if chosen is not None else [k for k, v in verdicts.items() if v == verdict.UNDECIDED]


def next_look(setup: Setup, scores: dict, ks: list) -> int | None:
    """The seed count the cells `ks` go to next (the first look above the most seeds any of them has), or None
    at the seed cap."""
    have = max(len(scores.get(k, {})) for k in ks)
    return next((n for n in setup.looks if n > have), None)


def plan_round(setup: Setup, scores: dict, ks: list, look: int) -> dict:
    """{policy: (K list, seeds)} of the round that brings the cells `ks` (and flat PPO, compared with them) to
    `look` seeds per cell: the seeds each lacks."""
    have = max(len(scores.get(k, {})) for k in ks)
    plan = {MIXTURE: (sorted(ks), list(range(have, look)))}
    flat = len(scores.get(FLAT, {}))
    if setup.target is None and flat < look:
        plan[MLP] = ([], list(range(flat, look)))
    return plan


def decide(setup: Setup, evidence: Evidence, state: dict) -> tuple:
    """(records, plan of the next round or None, why it stops or None), updating the state's baseline and records:
    the whole decision of a round, a pure function of the runs' values."""
    scores = evidence.scores
    first_ready = all(len(scores.get(k, {})) >= setup.looks[0] for k in list(setup.ladder)
                      + ([FLAT] if setup.target is None else []))
    if first_ready and "baseline" not in state:
        state["baseline"] = choose_baseline(setup, evidence, state)
    if "baseline" in state:
        state["records"] = judge_cells(setup, evidence, state)
    ks = cells_to_extend(setup, state["records"], scores)
    if not ks:
        no = any(r["verdict"] == verdict.NO_SCALE for r in state["records"].values())
        return state["records"], None, "no answer" if no else "decided"
    look = next_look(setup, scores, ks)
    if look is None:
        return state["records"], None, f"seed cap ({setup.looks[-1]} seeds per cell)"
    return state["records"], plan_round(setup, scores, ks, look), None


# ----------------------------------------------------------------------------------------------- rounds
COMPILE_LINE = re.compile(r"program (.*?) \(([\d.]+)s\)")


def run_class_sweep(out: str, name: str, spec: dict, log: Callable) -> dict:
    """Train one class's sweep of a round in a subprocess (gsa_jax.sweep: resumes if interrupted), collect its
    results (sweep.json, tidy metrics, controllers) into out/results/<name> and score its controllers ->
    {seconds, compile_s (program compile or cache load, from the sweep's log), status}."""
    os.makedirs(os.path.join(out, "specs"), exist_ok=True)
    os.makedirs(os.path.join(out, "logs"), exist_ok=True)
    toml = os.path.join(out, "specs", name + ".toml")
    write_atomic(toml, to_toml(spec))
    sweep_dir, results = os.path.join(out, "sweeps", name), os.path.join(out, "results", name)
    cmd = [sys.executable, "-m", "gsa_jax.sweep", toml, "--out", sweep_dir, "--no-tensorboard"]
    env = dict(os.environ)  # a compilation cache the user configured, else the answer's own (shared by its rounds)
    env.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.abspath(os.path.join(out, "xla_cache")))
    t0, compile_s, last = time.monotonic(), 0.0, 0.0
    with open(os.path.join(out, "logs", name + ".log"), "a") as logf:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        for line in proc.stdout:
            logf.write(line)
            logf.flush()
            m = COMPILE_LINE.search(line)
            compile_s += float(m.group(2)) if m else 0.0
            if "ETA" in line and time.monotonic() - last > 60:  # the sweep's chunk lines, one a minute
                log("    " + line.rstrip())
                last = time.monotonic()
        status = proc.wait()
    if status not in (0, 1):  # 1: some runs failed (NaN/inf): they are left out, as gsa_jax.plot leaves them out
        raise AnswerError(f"the sweep {name} stopped with exit status {status} (log: {os.path.join(out, 'logs', name + '.log')}); "
                          "run the same command again to resume", exit_status=3)
    collect_results(sweep_dir, results)
    controller_scores.score_directory(results, log=None)
    return {"seconds": round(time.monotonic() - t0, 1), "compile_s": round(compile_s, 1), "status": status}


def run_round(out: str, setup: Setup, state: dict, plan: dict, log: Callable, verdicts_before: dict | None = None,
              train: Callable | None = None) -> dict:
    """Train a planned round (flat PPO first), recording it in the state before and after. train(out, name, spec,
    log): what trains one class's sweep and scores its controllers (default run_class_sweep)."""
    train = train or run_class_sweep
    index = len([r for r in state["rounds"] if r["status"] == "done"]) + 1
    if not state["rounds"] or state["rounds"][-1]["status"] == "done":
        state["rounds"].append({"round": index, "plan": {p: [ks, seeds] for p, (ks, seeds) in plan.items()},
                                "verdicts_before": verdicts_before, "status": "running", "sweeps": {}})
        save_state(out, state)
    record = state["rounds"][-1]
    for policy in (MLP, MIXTURE):
        if policy not in record["plan"] or policy in record["sweeps"]:
            continue
        ks, seeds = record["plan"][policy]
        name = f"round{record['round']}-{'flat_ppo' if policy == MLP else 'mixture'}"
        record["sweeps"][policy] = train(out, name, sweep_spec(setup, policy, ks, seeds, name), log)
        save_state(out, state)
    record["status"] = "done"
    save_state(out, state)
    return record


# ----------------------------------------------------------------------------------------------- the loop
def round_eta(state: dict, plan: dict) -> float:
    """Seconds the planned round likely takes: the last round's seconds per trained run times the runs planned
    (0 before any round: the first round is not estimated)."""
    done = [r for r in state["rounds"] if r["status"] == "done" and r["sweeps"]]
    if not done:
        return 0.0
    last = done[-1]
    runs = sum(max(len(ks), 1) * len(seeds) for ks, seeds in last["plan"].values())
    secs = sum(s["seconds"] for s in last["sweeps"].values())
    return secs / max(runs, 1) * sum(max(len(ks), 1) * len(seeds) for ks, seeds in plan.values())


def progress_line(state: dict, judged: dict, plan: dict | None, eta: float) -> str:
    """One line per round: the cells it trains and their seeds, the verdicts so far, its ETA."""
    so_far = " ".join(f"K={k}:{r['verdict']}({r.get('seeds', 0)})" for k, r in sorted(judged.items(), key=lambda kv: int(kv[0])))
    if plan is None:
        return f"answer: verdicts {so_far}"
    cells = "; ".join(f"{'flat PPO' if p == MLP else 'K=' + ','.join(map(str, ks))} seeds {seeds[0]}-{seeds[-1]}"
                      for p, (ks, seeds) in plan.items())
    return (f"answer: round {len([r for r in state['rounds'] if r['status'] == 'done']) + 1}: {cells} | verdicts "
            f"{so_far} | ETA {eta / 60:.0f} min" if eta else
            f"answer: round {len([r for r in state['rounds'] if r['status'] == 'done']) + 1}: {cells} | verdicts {so_far}")


def run_answer(out: str, setup: Setup, budget_s: float, random_policy: Callable, log: Callable = print,
               train: Callable | None = None) -> dict:
    """The answer loop (resumable): rounds until the smallest sufficient K is decided, the seed cap or the budget
    -> the final state (with 'judged' and 'stopped'). random_policy: a function measuring the random policy's
    episodes (controller_scores.score_random_policy's record; called once, the state keeps it); train: see
    run_round."""
    os.makedirs(out, exist_ok=True)
    state = load_state(out, setup)
    if "random" not in state:
        state["random"] = dict(random_policy())
        save_state(out, state)
    t0, before = time.monotonic(), state["elapsed_s"]
    for d in controller_dirs_of(setup.start_from):
        controller_scores.score_directory(d, log=log)
    while True:
        if state["rounds"] and state["rounds"][-1]["status"] == "running":
            log(f"answer: resuming round {state['rounds'][-1]['round']}")
            run_round(out, setup, state, None, log, train=train)
        records, plan, stop = decide(setup, collect_evidence(out, setup), state)
        state["elapsed_s"] = round(before + time.monotonic() - t0, 1)
        eta = round_eta(state, plan) if plan else 0.0
        if plan and state["elapsed_s"] + eta > budget_s:
            stop = f"budget ({budget_s / 60:.0f} min; {state['elapsed_s'] / 60:.0f} used, next round ~{eta / 60:.0f})"
        log(progress_line(state, records, None if stop else plan, eta))
        if stop:
            state.update(judged=records, stopped=stop)
            save_state(out, state)
            return state
        save_state(out, state)
        run_round(out, setup, state, plan, log, {k: r["verdict"] for k, r in records.items()}, train)


def controller_dirs_of(roots: Sequence[str]) -> list:
    return controller_scores.controller_dirs(roots) if roots else []
