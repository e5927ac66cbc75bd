"""The answer loop of `gsa answer`: train flat PPO and a ladder of K in rounds, judged at the design's looks by the
answer's decisions (gsa_jax.analysis.verdicts.answering.decide: a pure function of the runs' values, so
experiments/verdicts/error_rates.py simulates this very loop), with seeds added only where the smallest sufficient K is
not decided yet.

First the step budget (step_budget: flat PPO's first seeds at doubling budgets until it has learned the task and
stopped learning; every class then trains to it). A round trains one sweep per class (a sweep job in a subprocess,
resumable: flat PPO's new seeds, then every K's), whose runs are trained in parts of the first look's seed count, each
padded to it, so every sweep of a class runs one program: compiled by its first part, reused by the sweep's later
parts, loaded from the answer's compilation cache by its later sweeps. Each exports every run's controller and
scores it in MuJoCo C (gsa_jax.analysis.sweeps.controller_scores); each is estimated before it runs (round_time), and a
round that would overrun the budget is not started. The state (DIR/answer.json) is written after every step, so the
same command resumes where it stopped.
"""

import os
import re
import shutil
import subprocess
import time
from typing import Callable, Sequence

from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.analysis.sweeps import controller_scores
from gsa_jax.analysis.sweeps.extraction import collect_results
from gsa_jax.analysis.verdicts import baseline, round_time, sequential, step_budget
from gsa_jax.analysis.verdicts.answering import (
    FLAT, AnswerError, Setup, collect_evidence, collect_evidence_in, decide, load_state, save_state, task_max_return,
    trained_steps,
)
from gsa_jax.orchestration import answer_progress
from gsa_jax.orchestration.sweep_job import SweepJob, job_command
from gsa_jax.running.checkpoint import write_atomic
from gsa_jax.running.spec import SpecError, SweepSpec, check_spec, load_spec
from gsa_jax.running.tuning import to_toml


# ----------------------------------------------------------------------------------------------- a class's sweeps
def sweep_spec(setup: Setup, policy: str, ks: list, seeds: list, name: str, steps: int | None = None) -> dict:
    """The experiment spec of one sweep of a class: the base spec with its K, seeds and step budget (default the
    setup's), and the settings that fix its program's shape for the whole answer (program_settings)."""
    spec = {k: v for k, v in setup.specs[policy].items() if k not in ("clusters", "cluster_multipliers", "name")}
    spec.update(name=name, envs=[setup.env], policies=[policy], seeds=list(seeds), steps=int(steps or setup.steps()))
    spec.update(program_settings(setup, policy, spec))
    if policy == MIXTURE:
        spec["clusters"] = sorted(ks)
        spec["config"] = {**spec.get("config", {}), "k_max": max(setup.ladder)}
    return spec


EVALUATIONS = 12  # the calibration floor: flat PPO trains at least this many iterations (>= MIN_EVALUATIONS)


def probe_config(setup: Setup, policy: str, spec: dict | None = None) -> tuple:
    """(checked spec, Config) of one run of the class: what fixes its program's shape."""
    from gsa_jax.running.spec import build_grid, check_spec, group_config

    base = {k: v for k, v in (spec or setup.specs[policy]).items() if k not in ("clusters", "cluster_multipliers", "name")}
    probe = check_spec({**base, "name": "probe", "envs": [setup.env], "policies": [policy], "clusters": [1],
                        "seeds": [0], "steps": setup.steps()}, source=f"the {policy} spec")
    return probe, group_config(probe, build_grid(probe)[0])


def batch_size(setup: Setup, policy: str) -> int:
    """Env steps per PPO iteration of the class's runs."""
    return probe_config(setup, policy)[1].batch_size


def program_settings(setup: Setup, policy: str, spec: dict) -> dict:
    """chunk and evaluations of a sweep: the base spec's where it sets them, else one chunk length for every budget of
    the answer (the cap's default, so every sweep of a class runs one compiled program) and, for flat PPO, evaluations
    only at the chunk ends the still-learning test reads at the sweep's budget (baseline.steps_read: the same test as
    with an evaluation after every chunk, without the others' cost); none for the mixtures, whose curves no decision
    reads."""
    from gsa_jax.running.spec import default_chunk

    base = setup.specs[policy]
    given = base.get("eval_every") is not None or base.get("eval_at") is not None
    if base.get("chunk") is not None and given:
        return {}
    probe, cfg = probe_config(setup, policy, spec)
    chunk = int(base.get("chunk") or default_chunk(probe, cfg))
    out = {"chunk": chunk}
    if not given and policy == MLP:
        out.update(flat_evaluations(int(spec["steps"]), chunk * cfg.batch_size))
    elif not given:
        out["eval_every"] = 0
    return out


def flat_evaluations(steps: int, every: int) -> dict:
    """Flat PPO's evaluation settings at a budget of `steps` with a chunk of `every` env steps: eval_at, the steps the
    still-learning test reads and `steps` itself (the last chunk, where the budget is not whole chunks); a budget
    shorter than one chunk (one chunk trained) evaluates after every chunk."""
    read = baseline.steps_read(steps, every)
    if not read:
        return {"eval_every": 1}
    return {"eval_at": read + ([steps] if read[-1] < steps else [])}


def check_setup(setup: Setup) -> None:
    """AnswerError in one line for what cannot be answered, before anything compiles."""
    if not setup.ladder:
        raise AnswerError("the K ladder is empty: give --clusters K [K ...]")
    if any(int(k) < 1 for k in setup.ladder):
        raise AnswerError(f"every K must be >= 1, got {list(setup.ladder)}")
    if not 0.0 < setup.margin < 1.0:
        raise AnswerError(f"--margin must be in (0, 1), got {setup.margin}")
    if not 0.0 <= setup.futility < 1.0:
        raise AnswerError(f"--futility must be in [0, 1), got {setup.futility:g}")
    try:
        sequential.check_design(setup.design())
    except ValueError as e:
        raise AnswerError(f"--looks: {e}" if "look" in str(e) else str(e)) from None
    if setup.target is None:
        try:
            baseline.load_references(setup.references or baseline.REFERENCES)
        except baseline.ReferencesError as e:
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
    # eval_at (evaluated where the test reads): the curve's resolution is the run's iterations
    every = 1 if spec.eval_at is not None else group_eval_every(spec, iterations)
    evaluations = iterations // every if every else 0
    if evaluations < MIN_EVALUATIONS:
        need = MIN_EVALUATIONS * cfg.batch_size * (every if spec.eval_every else 1)
        what = "iterations" if spec.eval_at is not None else "evaluations"
        raise AnswerError(f"--steps {spec.steps} gives flat PPO {evaluations} {what} per run; the still-learning "
                          f"test needs at least {MIN_EVALUATIONS}: give --steps {need} or more")


COMPILE_LINE = re.compile(r"program ((?:compiled|loaded).*?) \(([\d.]+)s\)")  # not "reused": no compile


def run_class_sweep(out: str, name: str, spec: dict, log: Callable, where: str = "results",
                    runs_per_program: int = 0, watch: Callable = lambda line: None) -> dict:
    """Train one sweep in a subprocess (gsa_jax.orchestration.sweep_job, as gsa sweep: resumes if interrupted; its runs trained in parts of
    `runs_per_program`, each padded to it, so a class's sweeps share one program: compiled once, reused by the sweep's
    later parts, loaded from the answer's compilation cache by its later sweeps), collect its
    results (sweep.json, tidy metrics, controllers) into out/<where>/<name> and score its controllers ->
    {seconds, compile_s (summed over the worker processes), compile_wall_s (the slowest worker's), status}.
    watch: handed every line the sweep prints, then None at its end (answer_progress.watch)."""
    for d in ("specs", "logs", "sweeps"):
        os.makedirs(os.path.join(out, d), exist_ok=True)
    toml = os.path.join(out, "specs", name + ".toml")
    write_atomic(toml, to_toml(spec, f"gsa answer's sweep {name}"))
    sweep_dir, results = os.path.join(out, "sweeps", name), os.path.join(out, where, name)
    job = SweepJob(load_spec(toml), sweep_dir, local=os.cpu_count() or 1, tensorboard=False,
                   runs_per_program=runs_per_program)  # as `gsa sweep TOML --out DIR --no-tensorboard` runs it
    cmd = job_command(job)
    env = dict(os.environ)  # a compilation cache the user configured, else the answer's own (shared by its sweeps)
    env.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.abspath(os.path.join(out, "xla_cache")))
    t0, compiles = time.monotonic(), []
    with open(os.path.join(out, "logs", name + ".log"), "a") as logf:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        try:
            for line in proc.stdout:
                logf.write(line)
                logf.flush()
                m = COMPILE_LINE.search(line)
                compiles += [float(m.group(2))] if m else []
                watch(line)
        except KeyboardInterrupt:  # the sweep had the Ctrl-C too: it saves its chunk and stops; its last lines logged
            logf.write(proc.communicate()[0] or "")
            raise
        status = proc.wait()
    if status == 130:  # the sweep was interrupted (a Ctrl-C that reached it alone): so is the answer
        raise KeyboardInterrupt
    if status not in (0, 1):  # 1: some runs failed (NaN/inf): they are left out, as gsa_jax.plot leaves them out
        raise AnswerError(f"the sweep {name} stopped with exit status {status} (log: {os.path.join(out, 'logs', name + '.log')}); "
                          "run the same command again to resume", exit_status=3)
    collect_results(sweep_dir, results)
    controller_scores.score_directory(results, log=None, jobs=controller_scores.default_jobs())
    watch(None)
    return {"seconds": round(time.monotonic() - t0, 1), "compile_s": round(sum(compiles), 1),
            "compile_wall_s": round(max(compiles, default=0.0), 1), "status": status}


def unit(setup: Setup) -> int:
    """Runs per program: the first look's seeds. Every sweep trains its runs in parts of this many, each padded to it
    (gsa sweep --runs-per-program), so every sweep of a class runs one compiled program whatever the round."""
    return int(setup.looks[0])


def plan_sweeps(setup: Setup, plan: dict, index: int) -> list:
    """[(name, policy, [K] or [], seeds)] of a planned round: one sweep per class, holding all its K and seeds (one
    worker start and one program load per class and round; its runs trained in parts of unit(setup))."""
    out = []
    for policy in (MLP, MIXTURE):
        if policy in plan:
            ks, seeds = plan[policy]
            cell = "flat_ppo" if policy == MLP else "mixture-K" + "-".join(str(k) for k in ks)
            out.append((f"round{index}-{cell}-s{seeds[0]}-{seeds[-1]}", policy, [] if policy == MLP else list(ks),
                        list(seeds)))
    return out


def sweep_runs(sweep: tuple) -> int:
    """The runs a planned sweep (name, policy, ks, seeds) trains: its K x seeds (flat PPO: its seeds)."""
    _, _, ks, seeds = sweep
    return max(len(ks), 1) * len(seeds)


def padded_runs(setup: Setup, sweep: tuple) -> int:
    """The runs a planned sweep's program calls train: its K x seeds in parts of unit(setup), each padded to it."""
    return -(-sweep_runs(sweep) // unit(setup)) * unit(setup)


def sweeps_seconds(setup: Setup, state: dict, sweeps: list, steps: int) -> float | None:
    """Estimated seconds of planned sweeps at `steps` (round_time.sweep_estimate each; None before any sweep)."""
    each = [round_time.sweep_estimate(history(state), s[1], padded_runs(setup, s), steps) for s in sweeps]
    return None if any(e is None for e in each) else sum(each)


def train_sweep(out: str, setup: Setup, state: dict, sweep: tuple, steps: int, log: Callable, train: Callable,
                where: str = "results") -> dict:
    """Train one planned sweep (name, policy, ks, seeds) at `steps` -> its record (run_class_sweep's, with its class,
    padded runs, steps and the seconds estimated before it ran: eta_s, None before any sweep)."""
    name, policy, ks, seeds = sweep
    eta = sweeps_seconds(setup, state, [sweep], steps)
    feed = answer_progress.watch(whereabouts(setup, state, sweep, steps, eta, where), log)
    record = train(out, name, sweep_spec(setup, policy, ks, seeds, name, steps), log, where=where,
                   runs_per_program=unit(setup), watch=feed)
    return {**record, "policy": policy, "runs": padded_runs(setup, sweep), "steps": int(steps),
            "eta_s": None if eta is None else round(eta, 1)}


def whereabouts(setup: Setup, state: dict, sweep: tuple, steps: int, eta: "float | None",
                where: str) -> answer_progress.Where:
    """Where a planned sweep is in the answer, for its progress line: the step budget's calibration, or the running
    round's sweep i of n (with the round's runs and the seconds of its sweeps done and still to come)."""
    name, policy, ks, seeds = sweep
    cells = f"{'flat PPO' if policy == MLP else 'K=' + ','.join(map(str, ks))} seeds {seeds[0]}-{seeds[-1]}"
    parts, runs = padded_runs(setup, sweep) // unit(setup), sweep_runs(sweep)
    budget, elapsed = state.get("budget_s", float("inf")), state["elapsed_s"]
    if where != "results":
        return answer_progress.Where(f"step budget: {cells} at {steps:,} steps", "the step budget", parts, runs, runs, 0,
                                     elapsed, eta, 0.0, budget)
    record = state["rounds"][-1]
    planned = plan_sweeps(setup, record["plan"], record["round"])
    index = [s[0] for s in planned].index(name)
    done = [record["sweeps"][s[0]] for s in planned[:index] if s[0] in record["sweeps"]]
    later = sweeps_seconds(setup, state, planned[index + 1:], steps) if index + 1 < len(planned) else 0.0
    return answer_progress.Where(
        f"round {record['round']}, sweep {index + 1} of {len(planned)} ({cells})", f"round {record['round']}", parts,
        runs, sum(map(sweep_runs, planned)), sum(map(sweep_runs, planned[:index])), elapsed + sum(d["seconds"] for d in done), eta,
        later, budget)


def run_round(out: str, setup: Setup, state: dict, plan: dict, log: Callable, verdicts_before: dict | None = None,
              train: Callable | None = None) -> dict:
    """Train a planned round (flat PPO first; plan_sweeps), recording it in the state before and after each sweep.
    train(out, name, spec, log, where=, runs_per_program=): what trains one sweep and scores its controllers (default
    run_class_sweep)."""
    train = train or run_class_sweep
    index = len([r for r in state["rounds"] if r["status"] == "done"]) + 1
    if not state["rounds"] or state["rounds"][-1]["status"] == "done":
        state["rounds"].append({"round": index, "plan": {p: [ks, seeds] for p, (ks, seeds) in plan.items()},
                                "verdicts_before": verdicts_before, "status": "running", "sweeps": {}})
        save_state(out, state)
    record = state["rounds"][-1]
    sweeps = plan_sweeps(setup, record["plan"], record["round"])
    check_round_sweeps(out, record, [s[0] for s in sweeps])
    for sweep in sweeps:
        if sweep[0] not in record["sweeps"]:
            record["sweeps"][sweep[0]] = train_sweep(out, setup, state, sweep, trained_steps(setup, state), log, train)
            save_state(out, state)
    record["status"] = "done"
    save_state(out, state)
    return record


def check_round_sweeps(out: str, record: dict, planned: list) -> None:
    """Refuse to resume a round whose recorded sweeps are not among those planned now (a round an older gsa_jax split
    otherwise, e.g. one sweep per K): training the plan's sweeps would give its finished cells a second copy of the
    same seeds. Raises AnswerError."""
    stray = sorted(set(record["sweeps"]) - set(planned))
    if stray:
        raise AnswerError(f"{out}: round {record['round']} was started with other sweeps ({', '.join(stray)}) than this "
                          f"gsa_jax plans ({', '.join(planned)}); finish it with the gsa_jax that started it, or answer "
                          "in a new directory")


# ----------------------------------------------------------------------------------------------- the step budget
def history(state: dict) -> list:
    """Every sweep the answer ran, in order: the calibration's, then the rounds'."""
    calibration = [c["sweep"] for c in state.get("steps", {}).get("calibration", [])]
    return calibration + [s for r in state["rounds"] for s in r["sweeps"].values()]


def first_round_seconds(setup: Setup, state: dict, steps: int) -> float | None:
    """Estimated seconds of the first round's mixture sweep at `steps` (None before any sweep)."""
    return sweeps_seconds(setup, state, plan_sweeps(setup, {MIXTURE: (list(setup.ladder), list(range(setup.looks[0])))}, 1),
                          steps)


def check_budget_floor(setup: Setup, state: dict, budget_s: float) -> None:
    """AnswerError in one line, before anything trains, where the budget is below the first round's least time
    (round_time.scoring_floor: scoring its controllers alone)."""
    if history(state):
        return
    runs = unit(setup) * (len(setup.ladder) + (setup.target is None))
    floor = round_time.scoring_floor(state["random"], runs)
    if floor is not None and floor > budget_s - state["elapsed_s"]:
        raise AnswerError(f"--budget-minutes {budget_s / 60:g} is less than the first round's least time: scoring its "
                          f"{runs} controllers alone takes ~{floor / 60:.1f} min here; give more minutes")


def calibrate(out: str, setup: Setup, state: dict, budget_s: float, log: Callable, train: Callable) -> None:
    """Choose the step budget (step_budget): flat PPO's first look trained at doubling budgets until it has learned
    the task and stopped learning, confirmed by its controllers at the next budget; the chosen budget's results become
    the first look (out/results/<name>)."""
    fresh = step_budget.candidates(setup.steps(), calibration_floor(setup), budget_quantum(setup))
    steps = state.setdefault("steps", {"mode": "auto", "budget": None, "calibration": [], "candidates": fresh})
    budgets = steps.get("candidates") or fresh  # a resumed answer keeps the budgets it started with
    while steps["budget"] is None:
        chosen, nxt = step_budget.next_budget(steps["calibration"], budgets)
        if chosen is None and not fits(setup, state, nxt, budget_s, log):
            if not steps["calibration"]:
                raise AnswerError(f"--budget-minutes {budget_s / 60:g} does not fit the first round at {nxt:,} steps per "
                                  "run; give more minutes")
            chosen, steps["limited"] = int(steps["calibration"][-1]["steps"]), "the time budget"
        if chosen is not None:
            steps["budget"] = chosen
            adopt_calibration(out, steps, chosen)
            break
        steps["calibration"].append(calibration_sweep(out, setup, state, nxt, log, train))
        save_state(out, state)
    save_state(out, state)


def calibration_floor(setup: Setup) -> int:
    """The smallest budget giving flat PPO EVALUATIONS evaluations per run (one per iteration)."""
    return min(setup.steps(), EVALUATIONS * batch_size(setup, MLP))


def budget_quantum(setup: Setup) -> int:
    """Env steps of one chunk of flat PPO's program (chunk x batch): the step budgets are whole chunks of it, so a
    run's iterations (whole chunks) train exactly its budget."""
    base = setup.specs[MLP]
    chunk = base.get("chunk") or program_settings(setup, MLP, {**base, "steps": setup.steps()})["chunk"]
    return int(chunk) * batch_size(setup, MLP)


def fits(setup: Setup, state: dict, steps: int, budget_s: float, log: Callable) -> bool:
    """Whether a calibration sweep at `steps` and the mixtures' first round after it fit in what is left of the budget
    (unknown before the first sweep: it fits)."""
    flat = round_time.sweep_estimate(history(state), MLP, unit(setup), steps)
    mixtures = first_round_seconds(setup, state, steps)
    if flat is None or mixtures is None:
        return True
    left = budget_s - state["elapsed_s"]
    ok = flat + mixtures <= left
    if not ok:
        log(f"answer: the step budget stops below {steps:,}: flat PPO there and the first round would take "
            f"~{(flat + mixtures) / 60:.1f} min of the {left / 60:.1f} left")
    return ok


def calibration_sweep(out: str, setup: Setup, state: dict, steps: int, log: Callable, train: Callable) -> dict:
    """Train flat PPO's first-look seeds at `steps` (out/calibration/<name>) and judge them (step_budget)."""
    name = f"calibrate-flat_ppo-{steps}"
    log(f"answer: step budget: flat PPO's first {unit(setup)} seeds at {steps:,} steps")
    sweep = train_sweep(out, setup, state, (name, MLP, [], list(range(unit(setup)))), steps, log, train,
                        where="calibration")
    evidence = collect_evidence_in([os.path.join(out, "calibration", name)], setup)
    scores = [evidence.scores.get(FLAT, {})[s] for s in sorted(evidence.scores.get(FLAT, {}))]
    curves = [evidence.curves[s] for s in sorted(evidence.curves)]
    before = (state["steps"]["calibration"] or [None])[-1]
    judged = step_budget.judge_budget(steps, scores, curves, state["random"]["returns"], setup.margin,
                                      task_max_return(setup.env), before)
    log(f"answer: at {steps:,} steps flat PPO has {'learned' if judged['learned'] else 'not learned'} the task and "
        f"{'stopped' if judged['stopped'] else 'not stopped'} learning" + confirmation_words(before, judged))
    return {**judged, "name": name, "sweep": sweep}


def confirmation_words(before: dict | None, judged: dict) -> str:
    """'; its controllers confirm (or do not confirm) N steps' where this budget judged the one before it."""
    if judged.get("confirms") is None:
        return ""
    c = judged["confirms"]
    within = " (shown within the margin above them)" if c.get("shown_within") else ""
    return (f"; its controllers {'confirm' if step_budget.chosen_by(before, judged) else 'do not confirm'} "
            f"{int(before['steps']):,} steps{within}")


def adopt_calibration(out: str, steps: dict, chosen: int) -> None:
    """Copy the chosen budget's calibration results into out/results: they are flat PPO's first look."""
    for c in steps["calibration"]:
        if int(c["steps"]) == chosen:
            src, dst = os.path.join(out, "calibration", c["name"]), os.path.join(out, "results", c["name"])
            if os.path.isdir(src) and not os.path.isdir(dst):
                shutil.copytree(src, dst)


# ----------------------------------------------------------------------------------------------- the loop
def round_eta(setup: Setup, state: dict, plan: dict) -> float:
    """Seconds the planned round likely takes: the sum of its sweeps' estimates (round_time; 0 before any sweep)."""
    return sweeps_seconds(setup, state, plan_sweeps(setup, plan, 0), trained_steps(setup, state)) or 0.0


def progress_line(state: dict, judged: dict, plan: dict | None, eta: float) -> str:
    """One line per round: the cells it trains and their seeds, the verdicts so far, its ETA."""
    so_far = " ".join(f"K={k}:{r['verdict']}({r.get('seeds', 0)})" for k, r in sorted(judged.items(), key=lambda kv: int(kv[0])))
    if plan is None:
        return f"answer: verdicts {so_far}"
    cells = "; ".join(f"{'flat PPO' if p == MLP else 'K=' + ','.join(map(str, ks))} seeds {seeds[0]}-{seeds[-1]}"
                      for p, (ks, seeds) in plan.items())
    head = f"answer: round {len([r for r in state['rounds'] if r['status'] == 'done']) + 1}: {cells} | verdicts {so_far}"
    return head + (f" | ETA {eta / 60:.1f} min" if eta else "")


def prepare(out: str, setup: Setup, state: dict, budget_s: float, random_policy: Callable, log: Callable,
            train: Callable) -> None:
    """What comes before the first round: the random policy's episodes (timed), the budget's floor, the step budget."""
    if "random" not in state:
        t0 = time.monotonic()
        state["random"] = {**dict(random_policy()), "seconds": round(time.monotonic() - t0, 2)}
        save_state(out, state)
    check_budget_floor(setup, state, budget_s)
    if setup.auto_steps() and (state.get("steps") or {}).get("budget") is None:
        calibrate(out, setup, state, budget_s, log, train)
    elif "steps" not in state:
        state["steps"] = {"mode": "fixed", "budget": setup.steps(), "calibration": []}
        save_state(out, state)


def run_answer(out: str, setup: Setup, budget_s: float, random_policy: Callable, log: Callable = print,
               train: Callable | None = None, interim: Callable | None = None) -> dict:
    """The answer loop (resumable): the step budget, then rounds until the smallest sufficient K is decided, the seed
    cap or the budget -> the final state (with 'judged' and 'stopped'). random_policy: a function measuring the random
    policy's episodes (controller_scores.score_random_policy's record; called once, the state keeps it); train: see
    run_round; interim: called before each further round with the state as it would end now ('judged' and 'stopped'
    saying which round comes next), once runs are in hand: the answer so far, readable while more seeds train."""
    os.makedirs(out, exist_ok=True)
    state, train = load_state(out, setup), train or run_class_sweep
    state["budget_s"] = budget_s  # this invocation's budget: the progress lines say what is left of it
    t0, before = time.monotonic(), state["elapsed_s"]
    clock = lambda: state.update(elapsed_s=round(before + time.monotonic() - t0, 1))  # noqa: E731
    for d in controller_dirs_of(setup.start_from):
        controller_scores.score_directory(d, log=log, jobs=controller_scores.default_jobs())
    prepare(out, setup, state, budget_s, random_policy, lambda m: (clock(), log(m)), train)
    while True:
        if state["rounds"] and state["rounds"][-1]["status"] == "running":
            log(f"answer: resuming round {state['rounds'][-1]['round']}")
            run_round(out, setup, state, None, log, train=train)
        records, plan, stop = decide(setup, collect_evidence(out, setup), state)
        clock()
        eta = round_eta(setup, state, plan) if plan else 0.0
        if plan and state["elapsed_s"] + eta > budget_s:
            stop = f"budget ({budget_s / 60:.0f} min; {state['elapsed_s'] / 60:.1f} used, next round ~{eta / 60:.1f})"
        log(progress_line(state, records, None if stop else plan, eta))
        if stop:
            state.update(judged=records, stopped=stop)
            save_state(out, state)
            return state
        save_state(out, state)
        if interim is not None and (state["rounds"] or setup.start_from):
            interim({**state, "judged": records, "stopped": f"not yet: round {len(state['rounds']) + 1} is training "
                     f"(~{eta / 60:.1f} min)"})
        run_round(out, setup, state, plan, log, {k: r["verdict"] for k, r in records.items()}, train)


def controller_dirs_of(roots: Sequence[str]) -> list:
    return controller_scores.controller_dirs(roots) if roots else []
