"""The answer loop of `gsa answer`: train flat PPO and a ladder of K in rounds, judge every cell at the
design's looks (gsa_jax.analysis.verdicts.ladder: Yuen's trimmed-mean t, an alpha-spending function over the looks, Holm over
the K) against a baseline shown adequate (gsa_jax.analysis.verdicts.baseline), and add seeds only where the smallest
sufficient K is not decided yet.

First the step budget (step_budget: flat PPO's first seeds at doubling budgets until it has learned the task and
stopped learning; every class then trains to it). A round trains one sweep per class (gsa_jax.sweep in a subprocess,
resumable: flat PPO's new seeds, then every K's), whose runs are trained in parts of the first look's seed count, each
padded to it, so every sweep of a class runs one program: compiled by its first part, reused by the sweep's later
parts, loaded from the answer's compilation cache by its later sweeps. Each exports every run's controller and
scores it in MuJoCo C (gsa_jax.analysis.sweeps.controller_scores); each is estimated before it runs (round_time), and a
round that would overrun the budget is not started. The decisions are a pure function of the
runs' values (decide), so experiments/verdicts/error_rates.py simulates this very loop. The state (DIR/answer.json)
is written after every step, so the same command resumes where it stopped.
"""

import dataclasses
import glob
import json
import os
import re
import shutil
import subprocess
import sys
import time
from typing import Callable, NamedTuple, Sequence

from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.analysis.sweeps import columns as C
from gsa_jax.analysis.sweeps import controller_scores
from gsa_jax.analysis.sweeps.extraction import collect_results
from gsa_jax.analysis.sweeps.results import task_records
from gsa_jax.analysis.verdicts import answer_progress, baseline, ladder, round_time, sequential, step_budget, trimmed, verdict
from gsa_jax.errors import UserError
from gsa_jax.running.checkpoint import write_atomic
from gsa_jax.running.spec import SpecError, SweepSpec, check_spec
from gsa_jax.running.tuning import to_toml

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
    controllers are the first seeds; references: the references table (None: the shipped one); max_steps: the cap of
    a step budget chosen by flat PPO's learning (step_budget; None: every run trains its spec's steps); futility: an
    undecided K whose chance to be decided by the seed cap (verdict.chance_to_decide) is below it gets no more seeds
    (0: every undecided K goes on to the cap). Stopping for futility never decides a K and a stopped K keeps its
    Holm share, so every test made is one the design without futility makes at the same level (a non-binding
    futility rule: the stated error holds)."""

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
    max_steps: int | None = None
    futility: float = verdict.FUTILITY

    def design(self) -> sequential.Design:
        return sequential.Design(tuple(self.looks), self.alpha, self.spending, self.multiplicity)

    def steps(self) -> int:
        """The fixed step budget of every run (the cap where the budget is chosen: auto_steps)."""
        return int(self.max_steps or self.specs[MLP if self.target is None else MIXTURE]["steps"])

    def auto_steps(self) -> bool:
        """Whether the step budget is chosen by flat PPO's learning (gsa_jax.analysis.verdicts.step_budget)."""
        return self.max_steps is not None and self.target is None

    def to_json(self) -> dict:
        return {**dataclasses.asdict(self), "ladder": list(self.ladder), "looks": list(self.looks),
                "start_from": list(self.start_from)}


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
    # eval_at (evaluated where the test reads): the curve's resolution is the run's iterations
    every = 1 if spec.eval_at is not None else group_eval_every(spec, iterations)
    evaluations = iterations // every if every else 0
    if evaluations < MIN_EVALUATIONS:
        need = MIN_EVALUATIONS * cfg.batch_size * (every if spec.eval_every else 1)
        what = "iterations" if spec.eval_at is not None else "evaluations"
        raise AnswerError(f"--steps {spec.steps} gives flat PPO {evaluations} {what} per run; the still-learning "
                          f"test needs at least {MIN_EVALUATIONS}: give --steps {need} or more")


def load_state(out: str, setup: Setup) -> dict:
    """The answer's state in `out` (new if none); AnswerError if `out` holds another answer's."""
    path = os.path.join(out, STATE)
    if not os.path.exists(path):
        return {"setup": setup.to_json(), "rounds": [], "records": {}, "elapsed_s": 0.0}
    with open(path) as f:
        state = json.load(f)
    mine = json.loads(json.dumps(setup.to_json()))
    # written before the step budget was chosen (fixed steps) or before futility stopping (every K to the cap)
    before_futility = "futility" not in state["setup"]
    state["setup"] = {"max_steps": None, "futility": 0.0, **state["setup"]}
    if state["setup"] != mine:
        changed = sorted(k for k in set(state["setup"]) | set(mine) if state["setup"].get(k) != mine.get(k))
        hint = (" (it was started before futility stopping: resume it with --futility 0)"
                if before_futility and "futility" in changed else "")
        raise AnswerError(f"{out} holds an answer with other settings ({', '.join(changed)}){hint}; use another --out"
                          + (" or resume it as it was started" if hint else ""))
    return state


def save_state(out: str, state: dict) -> None:
    write_atomic(os.path.join(out, STATE), json.dumps(state, indent=1))


# ----------------------------------------------------------------------------------------------- evidence
class Evidence(NamedTuple):
    """What the decisions read: per cell (FLAT or K) {seed: value} of the controller scores and of the mean return of
    the last 100 training episodes, flat PPO's learning curves {seed: (env_steps [T], eval_return [T])} and the
    mixtures' training curves (training)."""

    scores: dict
    last100: dict
    curves: dict
    training: dict = {}  # {FLAT or K: {seed: (env_steps [T], training episode return [T])}}: every class's training curves


def score_roots(out: str, setup: Setup) -> list:
    """The results directories whose controllers are this answer's runs: --start-from's and the rounds'."""
    return list(setup.start_from) + [os.path.join(out, "results")]


def cell_key(setup: Setup, policy: str, k: int | str) -> int | str | None:
    """FLAT, a K of the ladder, or None for a cell the answer does not judge."""
    key = FLAT if policy == MLP else int(k)
    return key if key == FLAT or key in setup.ladder else None


def collect_scores(out: str, setup: Setup, roots: Sequence[str] | None = None) -> dict:
    """{FLAT or K: {seed: controller score}} of the task's scored controllers under `roots` (default score_roots)."""
    found = {}
    for root in score_roots(out, setup) if roots is None else roots:
        for path in sorted(glob.glob(os.path.join(root, "**", controller_scores.FILE), recursive=True)):
            for row in controller_scores.read_scores(path).values():
                key = cell_key(setup, row["policy"], row["K"])
                if row["env"] == setup.env and row.get(C.CONTROLLER_SCORE, "") != "" and key is not None:
                    found.setdefault(key, {})[int(row["seed"])] = float(row[C.CONTROLLER_SCORE])
    return found


def collect_runs(out: str, setup: Setup, roots: Sequence[str] | None = None) -> tuple:
    """({FLAT or K: {seed: last-100-episode training return}}, flat PPO's {seed: (env_steps, eval_return)}, every
    class's {FLAT or K: {seed: (env_steps, training episode return)}}) from the tidy metrics under `roots` (default
    score_roots), runs that failed at a NaN/inf left out (their series end early)."""
    from gsa_jax.analysis.sweeps.results import drop_failed, load_failed, load_sweep
    from gsa_jax.analysis.sweeps.stats import last_episodes_return

    last100, curves, training = {}, {}, {}
    dirs = sorted({os.path.dirname(p) for root in (score_roots(out, setup) if roots is None else roots)
                   for p in glob.glob(os.path.join(root, "**", "sweep.json"), recursive=True)})
    for d in dirs:
        try:
            cells, _ = drop_failed(load_sweep(d), load_failed(d))  # a failed run's curve ends early: never read
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
                training.setdefault(key, {})[seed] = (s["env_steps"], s["episode_return"])
    return last100, curves, training


def collect_evidence(out: str, setup: Setup) -> Evidence:
    """The evidence of the answer's runs (score_roots)."""
    return collect_evidence_in(score_roots(out, setup), setup)


def collect_evidence_in(roots: Sequence[str], setup: Setup) -> Evidence:
    """The evidence of the runs under `roots`."""
    last100, curves, training = collect_runs("", setup, roots)
    return Evidence(collect_scores("", setup, roots), last100, curves, training)


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
    return baseline.choose(setup.env, trained_steps(setup, state), setup.margin, flat, random_summary(state), refs,
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


def mixtures_learning(setup: Setup, evidence: Evidence, state: dict) -> dict:
    """{str(K): the still-learning test (baseline.learning) on the K's training curves (the stochastic policy's episode
    returns) at the step budget, on the scale of flat PPO's gain over the random policy}: a K judged worse than flat
    PPO while it still learns may be judged otherwise at a longer budget (the budget is where flat PPO stopped)."""
    flat = list(evidence.scores.get(FLAT, {}).values())
    if setup.target is not None or len(flat) < 2:
        return {}
    scale = trimmed.trimmed(flat).mean - random_summary(state).mean
    out = {}
    for k in setup.ladder:
        curves = [evidence.training[k][s] for s in sorted(evidence.training.get(k, {}))]
        if len(curves) >= 2:
            learn = baseline.learning(curves, trained_steps(setup, state), scale, setup.margin)
            out[str(k)] = {n: (round(v, 4) if isinstance(v, float) else v) for n, v in learn._asdict().items()}
    return out


def open_cells(setup: Setup, records: dict, scores: dict) -> list:
    """The K the answer still asks about: those not yet at the first look, and the undecided ones below the smallest
    sufficient K (none once there is no answer)."""
    verdicts = {k: records[str(k)]["verdict"] for k in setup.ladder if str(k) in records}
    if verdict.NO_SCALE in verdicts.values():
        return []
    untrained = [k for k in setup.ladder if len(scores.get(k, {})) < setup.looks[0]]
    if untrained:
        return untrained
    chosen, below = verdict.smallest_sufficient(verdicts)
    return below if chosen is not None else [k for k, v in verdicts.items() if v == verdict.UNDECIDED]


def futile(setup: Setup, record: dict) -> bool:
    """Whether an undecided K's chance to be decided by the seed cap is below the setup's futility threshold."""
    chance = record.get("chance_by_cap")
    return record.get("verdict") == verdict.UNDECIDED and chance is not None and chance < setup.futility


def stop_futile(setup: Setup, state: dict, asked: list) -> list:
    """The K of `asked` that get more seeds: those not stopped for futility, now or at an earlier look. A stopped K
    stays stopped (state['futile']: {str(K): its chance when stopped}) even where Holm later raises its share, so
    the K that go on always hold the same seeds (a round trains them as one sweep)."""
    stopped = state.setdefault("futile", {})
    for k in asked:
        if str(k) not in stopped and futile(setup, state["records"].get(str(k), {})):
            stopped[str(k)] = state["records"][str(k)]["chance_by_cap"]
    return [k for k in asked if str(k) not in stopped]


def percent(x: float) -> str:
    """A chance as the report and the stop reason print it: two significant digits (0.009 -> '0.9%')."""
    return f"{100.0 * x:.2g}%"


def futility_text(setup: Setup, state: dict, ks: list) -> str:
    """The stop reason of an answer whose open K were all stopped for futility."""
    chances = ", ".join(f"K = {k}: {percent(state['futile'][str(k)])}" for k in ks)
    return (f"futility (no undecided K had a {percent(setup.futility)} chance to be decided by the seed cap of "
            f"{setup.looks[-1]} seeds per cell if its gap is what it looked when it was stopped: {chances})")


def next_look(setup: Setup, scores: dict, ks: list) -> int | None:
    """The seed count the cells `ks` go to next (the first look above the most seeds any of them has), or None
    at the seed cap."""
    have = max(len(scores.get(k, {})) for k in ks)
    return next((n for n in setup.looks if n > have), None)


def plan_round(setup: Setup, scores: dict, ks: list, look: int) -> dict:
    """{policy: (K list, seeds)} of the round that brings the cells `ks` (and flat PPO, compared with them) to
    `look` seeds per cell: the seeds each lacks."""
    counts = {len(scores.get(k, {})) for k in ks}
    if len(counts) > 1:  # one sweep trains every K the same seeds: K of different seed counts cannot share it
        raise AnswerError(f"K = {sorted(ks)} hold different numbers of seeds ({sorted(counts)}): cannot plan one round")
    have = counts.pop()
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
        state["mixture_learning"] = mixtures_learning(setup, evidence, state)
    asked = open_cells(setup, state["records"], scores)
    ks = stop_futile(setup, state, asked)
    if asked and not ks:
        return state["records"], None, futility_text(setup, state, asked)
    if not ks:
        no = any(r["verdict"] == verdict.NO_SCALE for r in state["records"].values())
        return state["records"], None, "no answer" if no else "decided"
    look = next_look(setup, scores, ks)
    if look is None:
        return state["records"], None, f"seed cap ({setup.looks[-1]} seeds per cell)"
    return state["records"], plan_round(setup, scores, ks, look), None


# ----------------------------------------------------------------------------------------------- rounds
COMPILE_LINE = re.compile(r"program ((?:compiled|loaded).*?) \(([\d.]+)s\)")  # not "reused": no compile


def run_class_sweep(out: str, name: str, spec: dict, log: Callable, where: str = "results",
                    runs_per_program: int = 0, watch: Callable = lambda line: None) -> dict:
    """Train one sweep in a subprocess (gsa_jax.sweep: resumes if interrupted; its runs trained in parts of
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
    cmd = [sys.executable, "-m", "gsa_jax.sweep", toml, "--out", sweep_dir, "--no-tensorboard",
           "--runs-per-program", str(runs_per_program)]
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
def trained_steps(setup: Setup, state: dict) -> int:
    """The env steps every run trains: the budget step_budget chose (auto), else the setup's."""
    return int(state.get("steps", {}).get("budget") or setup.steps())


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
    the task and stopped learning; the chosen budget's results become the first look (out/results/<name>)."""
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
    judged = step_budget.judge_budget(steps, scores, curves, state["random"]["returns"], setup.margin,
                                      task_max_return(setup.env))
    log(f"answer: at {steps:,} steps flat PPO has {'learned' if judged['learned'] else 'not learned'} the task and "
        f"{'stopped' if judged['stopped'] else 'not stopped'} learning")
    return {**judged, "name": name, "sweep": sweep}


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
               train: Callable | None = None) -> dict:
    """The answer loop (resumable): the step budget, then rounds until the smallest sufficient K is decided, the seed
    cap or the budget -> the final state (with 'judged' and 'stopped'). random_policy: a function measuring the random
    policy's episodes (controller_scores.score_random_policy's record; called once, the state keeps it); train: see
    run_round."""
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
        run_round(out, setup, state, plan, log, {k: r["verdict"] for k, r in records.items()}, train)


def controller_dirs_of(roots: Sequence[str]) -> list:
    return controller_scores.controller_dirs(roots) if roots else []
