"""What `gsa answer` decides: the answer's setup and state (DIR/answer.json), the evidence read from its results
(controller scores, training returns, learning curves), and the decisions of a round (decide, a pure function of the
runs' values): flat PPO and a ladder of K judged at the design's looks (gsa_jax.analysis.verdicts.ladder: Yuen's
trimmed-mean t, an alpha-spending function over the looks, Holm over the K) against a baseline shown adequate
(gsa_jax.analysis.verdicts.baseline), and the next round's seeds only where the smallest sufficient K is not decided
yet. The loop that trains those rounds is gsa_jax.orchestration.answer_loop; experiments/verdicts/error_rates.py
simulates it with these very decisions."""

import dataclasses
import glob
import json
import os
from typing import NamedTuple, Sequence

from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.analysis.sweeps import columns as C
from gsa_jax.analysis.sweeps import controller_scores
from gsa_jax.analysis.sweeps.results import task_records
from gsa_jax.analysis.verdicts import baseline, ladder, sequential, trimmed, verdict
from gsa_jax.errors import UserError
from gsa_jax.running.checkpoint import write_atomic
from gsa_jax.running.formats import read_json, stamped


# ----------------------------------------------------------------------------------------------- the setup and its state
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


def load_state(out: str, setup: Setup) -> dict:
    """The answer's state in `out` (new if none); AnswerError if `out` holds another answer's."""
    path = os.path.join(out, STATE)
    if not os.path.exists(path):
        return {"setup": setup.to_json(), "rounds": [], "records": {}, "elapsed_s": 0.0}
    state = read_json(path, "answer")  # an older answer.json in the current layout (running.formats)
    mine = json.loads(json.dumps(setup.to_json()))
    before_futility = state.get("before_futility", False)  # started before futility stopping: every K to the cap
    if state["setup"] != mine:
        changed = sorted(k for k in set(state["setup"]) | set(mine) if state["setup"].get(k) != mine.get(k))
        hint = (" (it was started before futility stopping: resume it with --futility 0)"
                if before_futility and "futility" in changed else "")
        raise AnswerError(f"{out} holds an answer with other settings ({', '.join(changed)}){hint}; use another --out"
                          + (" or resume it as it was started" if hint else ""))
    return state


def save_state(out: str, state: dict) -> None:
    write_atomic(os.path.join(out, STATE), json.dumps(stamped(state), indent=1))


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


# ----------------------------------------------------------------------------------------------- the step budget
def trained_steps(setup: Setup, state: dict) -> int:
    """The env steps every run trains: the budget step_budget chose (auto), else the setup's."""
    return int(state.get("steps", {}).get("budget") or setup.steps())
