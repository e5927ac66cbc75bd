"""The verdicts of a fixed grid of seeds (a sweep's cells, as gsa_jax.plot tabulates them), judged exactly as
gsa_jax.answer judges its first look: verdicts.csv (each K at every margin, the baseline's columns) and
sufficient_k.csv (the smallest sufficient K per task, setting and margin, in one sentence)."""

import os
from collections import defaultdict
from typing import Callable, Sequence

import numpy as np

from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.analysis.sweeps import columns as C
from gsa_jax.analysis.sweeps import stats
from gsa_jax.analysis.sweeps.results import Cell, final_scores, write_csv
from gsa_jax.analysis.sweeps.tables import flat_cell
from gsa_jax.analysis.verdicts import verdict
from gsa_jax.analysis.verdicts.answering import DEFAULT_LOOKS, FLAT, Evidence, Setup, decide


def cell_setting(cell: Cell, settings: Sequence[str]) -> tuple:
    """((column, value) of `settings`...) of a cell: which return-vs-K curve it belongs to."""
    extra = dict(cell.settings)
    return tuple((c, extra.get(c, "")) for c in settings)


def grid_evidence(data: dict, scores: dict, cells: list) -> tuple:
    """answering.Evidence of one task's fixed grid: flat PPO's and each K's scores (final_scores: the committed
    controllers' where scored), last-100-episode training returns and flat PPO's learning curves."""
    values, last100, curves = {}, {}, {}
    for cell in cells:
        key = FLAT if cell.policy == MLP else cell.k
        seeds = sorted(data[cell])
        values[key] = dict(zip(seeds, (float(v) for v in scores[cell][0])))
        last100[key] = {s: stats.last_episodes_return(data[cell][s]["episode_return"], data[cell][s]["episodes"]) for s in seeds}
        if cell.policy == MLP:
            curves = {s: (data[cell][s]["env_steps"], data[cell][s]["eval_return"]) for s in seeds}
    return Evidence(values, last100, curves)


def grid_verdicts(env_name: str, cells: list, data: dict, scores: dict, random_policy: dict, steps: int,
                  target: float | None = None) -> tuple:
    """(answer rows, sensitivity rows, baseline record) of one task's fixed grid, judged exactly as gsa_jax.answer
    judges its first look (answering.decide with the default design): a table of n seeds is the look n reaches."""
    from gsa_jax.analysis.verdicts.answer_report import answer_rows, sensitivity_rows

    ladder = tuple(sorted(c.k for c in cells if c.policy == MIXTURE))
    spec = {"steps": int(steps), "hparams": {}, "config": {}}
    setup = Setup(env_name, ladder, verdict.DEFAULT_MARGIN, DEFAULT_LOOKS, {"mlp": spec, "mixture": spec}, target)
    evidence = grid_evidence(data, scores, cells)
    state = {"records": {}, "random": random_policy, "rounds": []}
    records, _, _ = decide(setup, evidence, state)
    few = min(len(v) for v in evidence.scores.values())
    if few < setup.looks[0]:
        why = f"too few seeds for a verdict ({few} per cell; the first look needs {setup.looks[0]})"
        records = {str(k): {"verdict": verdict.UNDECIDED, "why": why} for k in ladder}
    state["judged"] = records
    return answer_rows(setup, state), sensitivity_rows(setup, evidence, state), state.get("baseline")


def baseline_columns(base: dict | None) -> dict:
    """The baseline record as verdicts.csv columns: what was judged against, flat PPO's standing against the binding
    reference, and the still-learning test."""
    if not base:
        return {"versus": "flat PPO", "baseline_metric": "", "learned": ""}
    bind, learn = base.get("binding") or {}, base.get("learning") or {}
    return {"versus": base["versus"], "baseline_metric": base["metric"], "learned": int(base["learned"]),
            "binding_reference": f"{bind['algorithm']} ({bind['source']})" if bind else "",
            "binding_reference_score": bind.get("score", ""), "flat_on_its_metric": bind.get("ours", ""),
            "flat_gain_ratio_to_reference": bind.get("ratio", ""), "flat_below_reference": int(bind["below"]) if bind else "",
            "last_fifth_gain": learn.get("gain", ""), "last_fifth_gain_upper": learn.get("upper", ""),
            "stopped_learning": int(learn["stopped"]) if learn else ""}


def reference_value(cells: list, scores: dict, base: dict | None, target: float | None) -> float | None:
    """The score the margin line of a return-vs-K plot hangs from: flat PPO's IQM or the target (None where the
    verdicts judge against a reference on another metric, or there is no baseline)."""
    if target is not None:
        return float(target)
    if not base or base["metric"] != C.CONTROLLER_SCORE:
        return None
    if base["entry"] is not None:
        return float(base["entry"]["score"])
    return stats.iqm(scores[cells[0]][0])


def verdict_table(data: dict, random_policies: dict, steps: dict, settings: Sequence[str] = (),
                  target: float | None = None) -> list:
    """verdicts.csv rows: per task and setting, each K's verdict at the default margin as gsa_jax.answer's first look
    gives it (role 'answer'), the other margins as sensitivity, and the baseline's columns. random_policies: {env:
    controller_scores.random_policy record}; steps: {env: env steps of its runs} (default: the runs' last env_steps);
    tasks without a random policy are left out."""
    scores, groups = final_scores(data), defaultdict(list)
    for cell in data:
        if cell.policy == MIXTURE and len(scores[cell][0]) == len(data[cell]):
            groups[(cell.env, cell_setting(cell, settings))].append(cell)
    rows = []
    for (env_name, setting), cells in sorted(groups.items()):
        flat = flat_cell(cells[0], data)
        if flat is not None and len(scores[flat][0]) == len(data[flat]):
            cells = [flat] + cells
        elif target is None:
            continue
        if env_name not in random_policies:
            continue
        budget = steps.get(env_name) or max(float(np.nanmax(r["env_steps"])) for c in cells for r in data[c].values())
        answer, sensitivity, base = grid_verdicts(env_name, cells, data, scores, random_policies[env_name], budget, target)
        ref = reference_value(cells, scores, base, target)
        common = {"env": env_name, **dict(setting), **baseline_columns(base), "score": scores[cells[0]][1],
                  "reference_iqm": "" if ref is None else round(ref, 4),
                  "random_return": round(float(np.mean(random_policies[env_name]["returns"])), 4)}
        for r in answer + sensitivity:
            rows.append({**common, "default_margin": int(r["margin"] == verdict.DEFAULT_MARGIN), **r})
    return rows


def sufficient_k_table(verdict_rows: list, settings: Sequence[str] = ()) -> list:
    """sufficient_k.csv rows: per task, setting and margin the smallest K judged sufficient (verdict_table: the
    answer's first look at the default margin, sensitivity at the others), '' where none is, with the smaller K still
    undecided and the answer in one sentence. The product's answer to "how many linear controllers does this task
    need?"."""
    groups = defaultdict(dict)
    for r in verdict_rows:
        key = (r["env"], tuple((c, r.get(c, "")) for c in settings), r["margin"], r["versus"])
        groups[key][int(r["K"])] = r
    out = []
    for (env_name, extra, margin, versus), by_k in groups.items():
        verdicts = {k: r["verdict"] for k, r in by_k.items()}
        chosen, below = verdict.smallest_sufficient(verdicts)
        first = next(iter(by_k.values()))
        label = env_name + "".join(f" {c}={v}" for c, v in extra if v != "")
        answer = verdict.sentence(label, verdicts, margin, versus or "flat PPO")
        if first.get("why"):
            answer = f"{label}: {'no answer: ' if first['verdict'] == verdict.NO_SCALE else ''}{first['why']}."
        out.append({"env": env_name, **dict(extra), "margin": margin, "default_margin": first["default_margin"],
                    "role": first["role"], "versus": versus, "smallest_sufficient_K": "" if chosen is None else chosen,
                    "undecided_below": " ".join(map(str, below)), "ks_tried": " ".join(map(str, sorted(by_k))),
                    "verdicts": " ".join(f"{k}:{verdicts[k]}" for k in sorted(by_k)),
                    "seeds": " ".join(f"{k}:{by_k[k].get('seeds', '')}" for k in sorted(by_k)), "answer": answer})
    return out


def sufficient_k_lines(table: list) -> list:
    """One printed line per row of sufficient_k_table at the default margin."""
    return ["  " + r["answer"] for r in table if r["default_margin"]]


def write_verdicts(data: dict, random_policies: dict, steps: dict, settings: Sequence[str], out_dir: str,
                   log: Callable = print, target: float | None = None) -> tuple:
    """verdicts.csv and sufficient_k.csv of the cells' final scores (the committed controllers' where scored), judged
    as gsa_jax.answer's first look -> (verdict rows, sufficient_k rows); the answer at the default margin printed per
    task."""
    verdicts = verdict_table(data, random_policies, steps, settings, target=target)
    sufficient = sufficient_k_table(verdicts, settings)
    if verdicts:
        write_csv(os.path.join(out_dir, "verdicts.csv"), verdicts)
        write_csv(os.path.join(out_dir, "sufficient_k.csv"), sufficient)
        log(f"How many linear controllers does each task need (margin {verdict.DEFAULT_MARGIN:g} of the reference's gain "
            "over a random policy; docs/answer.md)?")
        for line in sufficient_k_lines(sufficient):
            log(line)
    return verdicts, sufficient
