"""The answer loop of `python -m gsa_jax.answer`: train flat PPO and a ladder of K in rounds, judge every cell
(gsa_jax.analysis.verdict) and add seeds only where the smallest sufficient K is not decided yet.

A round trains, per policy class, one sweep (one vmapped program; gsa_jax.sweep in a subprocess, resumable,
with the answer's shared compilation cache so a later round with the same shapes loads its program), exports
every run's controller and scores it in MuJoCo C (gsa_jax.analysis.controller_scores). Cells are judged at
the looks fixed in the setup (seeds per cell); a decided verdict is frozen at the look that decided it. The
state (DIR/answer.json) is written after every step, so the same command resumes where it stopped.
"""

import dataclasses
import glob
import json
import os
import re
import subprocess
import sys
import time
from typing import Callable, Sequence

from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.analysis import controller_scores, verdict
from gsa_jax.analysis.extraction import collect_results
from gsa_jax.running.checkpoint import write_atomic
from gsa_jax.running.spec import SpecError, check_spec

STATE = "answer.json"
FLAT = "flat"  # the key of flat PPO's cell beside the K of the mixtures


class AnswerError(Exception):
    pass


@dataclasses.dataclass(frozen=True)
class Setup:
    """What an answer computes (recorded in answer.json; a resumed answer must match it). specs: the base
    experiment spec per policy ('mlp', 'mixture': steps, hparams, config); looks: seeds per cell at each look;
    start_from: results directories whose committed controllers are the first seeds."""

    env: str
    ladder: tuple
    margin: float
    looks: tuple
    specs: dict
    target: float | None = None
    start_from: tuple = ()

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
    if not setup.looks or any(b <= a for a, b in zip(setup.looks, setup.looks[1:])) or setup.looks[0] < 2:
        raise AnswerError(f"--looks must be increasing seed counts >= 2, got {list(setup.looks)}")
    for policy in (MLP, MIXTURE):
        if policy == MLP and setup.target is not None:
            continue
        try:
            check_spec(sweep_spec(setup, policy, list(setup.ladder), list(range(setup.looks[0])), "answer_check"),
                       source=f"the {policy} spec")
        except SpecError as e:
            raise AnswerError(str(e)) from None


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
        return {"setup": setup.to_json(), "rounds": [], "frozen": {}, "elapsed_s": 0.0}
    with open(path) as f:
        state = json.load(f)
    if state["setup"] != json.loads(json.dumps(setup.to_json())):
        changed = sorted(k for k in state["setup"] if state["setup"][k] != json.loads(json.dumps(setup.to_json())).get(k))
        raise AnswerError(f"{out} holds an answer with other settings ({', '.join(changed)}); use another --out")
    return state


def save_state(out: str, state: dict) -> None:
    write_atomic(os.path.join(out, STATE), json.dumps(state, indent=1))


# ----------------------------------------------------------------------------------------------- scores
def score_roots(out: str, setup: Setup) -> list:
    """The results directories whose controllers are this answer's runs: --start-from's and the rounds'."""
    return list(setup.start_from) + [os.path.join(out, "results")]


def collect_scores(out: str, setup: Setup) -> dict:
    """{FLAT or K: {seed: controller score}} of the task's scored controllers under score_roots."""
    found = {}
    for root in score_roots(out, setup):
        for path in sorted(glob.glob(os.path.join(root, "**", controller_scores.FILE), recursive=True)):
            for row in controller_scores.read_scores(path).values():
                if row["env"] != setup.env or row.get("controller_score", "") == "":
                    continue
                key = FLAT if row["policy"] == MLP else int(row["K"])
                if key == FLAT or key in setup.ladder:
                    found.setdefault(key, {})[int(row["seed"])] = float(row["controller_score"])
    return found


def first_seeds(scores: dict, n: int) -> list:
    """The scores of a cell's first n seeds (in seed order)."""
    return [scores[s] for s in sorted(scores)[:n]]


def judge_cells(setup: Setup, scores: dict, random_return: float, frozen: dict) -> dict:
    """{K: verdict record} at the margin of the setup: a frozen (decided) record kept; every other cell judged
    with all its seeds against all of flat PPO's, at the design's per-look level."""
    out = {}
    flat = None if setup.target is not None else first_seeds(scores.get(FLAT, {}), len(scores.get(FLAT, {})))
    for k in setup.ladder:
        if str(k) in frozen:
            out[k] = frozen[str(k)]
            continue
        mix = first_seeds(scores.get(k, {}), len(scores.get(k, {})))
        if len(mix) < setup.looks[0] or (flat is not None and len(flat) < setup.looks[0]):
            out[k] = {"verdict": "untrained", "n": len(mix)}
            continue
        g = verdict.judge(mix, flat, random_return, setup.margin, len(setup.looks), setup.target)
        out[k] = {"verdict": g.verdict, "n": g.n, "seeds": len(mix), "reference_seeds": len(flat) if flat else 0,
                  "gap": g.point, "low": g.low, "high": g.high, "level": g.level, "seeds_to_decide": g.seeds_to_decide}
    return out


def cells_to_extend(setup: Setup, judged: dict) -> list:
    """The K that need more seeds: untrained ones, and the undecided ones below the smallest sufficient K (none
    once flat PPO shows no gain over a random policy)."""
    verdicts = {k: r["verdict"] for k, r in judged.items()}
    if verdict.NO_SCALE in verdicts.values():
        return []
    untrained = [k for k, v in verdicts.items() if v == "untrained"]
    if untrained:
        return untrained
    chosen, below = verdict.smallest_sufficient(verdicts)
    return below if chosen is not None else [k for k, v in verdicts.items() if v == verdict.UNDECIDED]


def next_look(setup: Setup, scores: dict, ks: list) -> int | None:
    """The seed count the cells `ks` go to next (the first look above the most seeds any of them has), or None
    at the seed cap."""
    have = max(len(scores.get(k, {})) for k in ks)
    return next((n for n in setup.looks if n > have), None)


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
                          "run the same command again to resume")
    collect_results(sweep_dir, results)
    controller_scores.score_directory(results, log=None)
    return {"seconds": round(time.monotonic() - t0, 1), "compile_s": round(compile_s, 1), "status": status}


def plan_round(setup: Setup, scores: dict, ks: list, look: int) -> dict:
    """{policy: (K list, seeds)} of the round that brings the cells `ks` (and flat PPO, compared with them) to
    `look` seeds per cell: the seeds each lacks."""
    have = max(len(scores.get(k, {})) for k in ks)
    plan = {"mixture": (sorted(ks), list(range(have, look)))}
    flat = len(scores.get(FLAT, {}))
    if setup.target is None and flat < look:
        plan["mlp"] = ([], list(range(flat, look)))
    return plan


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
    so_far = " ".join(f"K={k}:{r['verdict']}({r.get('seeds', r.get('n', 0))})" for k, r in sorted(judged.items()))
    if plan is None:
        return f"answer: verdicts {so_far}"
    cells = "; ".join(f"{'flat PPO' if p == MLP else 'K=' + ','.join(map(str, ks))} seeds {seeds[0]}-{seeds[-1]}"
                      for p, (ks, seeds) in plan.items())
    return (f"answer: round {len([r for r in state['rounds'] if r['status'] == 'done']) + 1}: {cells} | verdicts "
            f"{so_far} | ETA {eta / 60:.0f} min" if eta else
            f"answer: round {len([r for r in state['rounds'] if r['status'] == 'done']) + 1}: {cells} | verdicts {so_far}")


def decide_next(setup: Setup, state: dict, out: str, random_return: float) -> tuple:
    """(judged cells, plan of the next round or None, why it stops or None), freezing decided cells."""
    scores = collect_scores(out, setup)
    judged = judge_cells(setup, scores, random_return, state["frozen"])
    for k, r in judged.items():
        if r["verdict"] in (verdict.SUFFICIENT, verdict.INSUFFICIENT) and str(k) not in state["frozen"]:
            state["frozen"][str(k)] = r
    ks = cells_to_extend(setup, judged)
    if not ks:
        return judged, None, "decided" if verdict.NO_SCALE not in {r["verdict"] for r in judged.values()} else "no scale"
    look = next_look(setup, scores, ks)
    if look is None:
        return judged, None, f"seed cap ({setup.looks[-1]} seeds per cell)"
    return judged, plan_round(setup, scores, ks, look), None


def run_answer(out: str, setup: Setup, budget_s: float, random_return: float, log: Callable = print,
               train: Callable | None = None) -> dict:
    """The answer loop (resumable): rounds until the smallest sufficient K is decided, the seed cap or the budget
    -> the final state (with 'judged' and 'stopped'). random_return: a function measuring the random policy's
    return (called once; the state keeps it); train: see run_round."""
    os.makedirs(out, exist_ok=True)
    state = load_state(out, setup)
    if "random_return" not in state:
        state["random_return"] = float(random_return())
        save_state(out, state)
    t0, before = time.monotonic(), state["elapsed_s"]
    for d in controller_dirs_of(setup.start_from):
        controller_scores.score_directory(d, log=log)
    while True:
        if state["rounds"] and state["rounds"][-1]["status"] == "running":
            log(f"answer: resuming round {state['rounds'][-1]['round']}")
            run_round(out, setup, state, None, log, train=train)
        judged, plan, stop = decide_next(setup, state, out, state["random_return"])
        state["elapsed_s"] = round(before + time.monotonic() - t0, 1)
        eta = round_eta(state, plan) if plan else 0.0
        if plan and state["elapsed_s"] + eta > budget_s:
            stop = f"budget ({budget_s / 60:.0f} min; {state['elapsed_s'] / 60:.0f} used, next round ~{eta / 60:.0f})"
        log(progress_line(state, judged, None if stop else plan, eta))
        if stop:
            state.update(judged={str(k): r for k, r in judged.items()}, stopped=stop)
            save_state(out, state)
            return state
        save_state(out, state)
        run_round(out, setup, state, plan, log, {str(k): r["verdict"] for k, r in judged.items()}, train)


def controller_dirs_of(roots: Sequence[str]) -> list:
    return controller_scores.controller_dirs(roots) if roots else []
