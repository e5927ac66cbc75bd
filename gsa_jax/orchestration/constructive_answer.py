"""The answer's constructive part: every class's runs re-run on the fresh starts, its best run exhibited, and the
verdict of gsa_jax.analysis.verdicts.constructive.

Each class's best run on the selection starts (the answer's controller scores) runs EXHIBIT fresh starts (100, from
seed 20,000: paired across the classes); every other run the first SHARE of them, which the share of seeds reads.
The episodes are kept in out/fresh_episodes.csv as each controller finishes (keyed by the controller file's sha256),
so an interrupted or resumed answer re-runs nothing it has.
"""

import csv
import glob
import os
from typing import Callable

import numpy as np

from gsa_jax.analysis.sweeps import controller_scores
from gsa_jax.analysis.verdicts import baseline, constructive, trimmed
from gsa_jax.analysis.verdicts.answering import FLAT, Evidence, Setup, score_roots, task_max_return
from gsa_jax.deployment import starts

EXHIBIT, SHARE = starts.FRESH_EPISODES, 20
FILE = "fresh_episodes.csv"
COLUMNS = ("label", "sha256", "episode", "start_seed", "return", "length")


def controller_path(roots: list, env: str, cls: "int | str", seed: int) -> "str | None":
    """A run's committed controller under the results roots (None where there is none)."""
    from gsa_jax.running.trained import path_part

    label = f"{path_part(env)}-mlp-s{seed}" if cls == FLAT else f"{path_part(env)}-mixture-K{cls}-s{seed}"
    hits = sorted(p for root in roots for p in glob.glob(os.path.join(root, "**", "controllers", label + ".npz"), recursive=True))
    return hits[0] if hits else None


def read_episodes(path: str) -> dict:
    """{(label, sha256): {episode: return}} of a fresh_episodes.csv ({} where there is none)."""
    out = {}
    if os.path.exists(path):
        with open(path, newline="") as f:
            for r in csv.DictReader(f):
                out.setdefault((r["label"], r["sha256"]), {})[int(r["episode"])] = float(r["return"])
    return out


def run_fresh(job: tuple) -> list:
    """One controller's fresh-start episodes as rows (job: its path and how many)."""
    path, episodes = job
    ident, returns, lengths = controller_scores.controller_episodes(path, episodes, starts.FRESH_SEED)
    return [{"label": ident["label"], "sha256": ident["sha256"], "episode": i, "start_seed": starts.FRESH_SEED + i,
             "return": round(float(r), 4), "length": int(n)} for i, (r, n) in enumerate(zip(returns, lengths))]


def fresh_jobs(out: str, setup: Setup, evidence: Evidence) -> dict:
    """{(class, seed): (controller path, episodes)}: EXHIBIT for each class's best run, SHARE for the others."""
    roots, jobs = score_roots(out, setup), {}
    for cls, seeds in evidence.scores.items():
        best = constructive.exhibit([constructive.Candidate(s, v, np.zeros(0)) for s, v in seeds.items()]).seed
        for seed in seeds:
            path = controller_path(roots, setup.env, cls, seed)
            if path is not None:
                jobs[(cls, seed)] = (path, EXHIBIT if seed == best else SHARE)
    return jobs


def fresh_episodes(out: str, jobs: dict, log: Callable = print) -> dict:
    """{(class, seed): fresh returns [episodes]} for every job, running only what out/fresh_episodes.csv lacks."""
    path = os.path.join(out, FILE)
    have = read_episodes(path)
    keys = {cs: (os.path.basename(p)[:-4], controller_scores.file_sha256(p)) for cs, (p, _) in jobs.items()}
    todo = [jobs[cs] for cs in jobs if len(have.get(keys[cs], {})) < jobs[cs][1]]
    if todo:
        log(f"answer: {len(todo)} controllers on the fresh starts ({EXHIBIT} episodes for each class's best, {SHARE} "
            f"for the others, from seed {starts.FRESH_SEED})")
        new = not os.path.exists(path)
        with open(path, "a", newline="") as f:
            w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
            if new:
                w.writeheader()
            for rows in controller_scores.parallel_map(run_fresh, todo, controller_scores.default_jobs()):
                w.writerows(rows)
                f.flush()
        have = read_episodes(path)
    return {cs: np.array([have[keys[cs]][i] for i in range(jobs[cs][1])]) for cs in jobs}


def judge_constructive(out: str, setup: Setup, state: dict, evidence: Evidence, log: Callable = print) -> tuple:
    """The constructive answer of the answer's runs -> (constructive.Answer, {class: controller path of its exhibit}),
    or (None, {}) where flat PPO or every mixture has no scored controller."""
    jobs = fresh_jobs(out, setup, evidence)
    has_flat = any(cls == FLAT for cls, _ in jobs)
    if all(cls == FLAT for cls, _ in jobs) or not (has_flat or setup.target is not None):
        return None, {}
    fresh = fresh_episodes(out, jobs, log)
    classes = {}
    for (cls, seed), returns in sorted(fresh.items(), key=lambda kv: (str(kv[0][0]), kv[0][1])):
        classes.setdefault(cls, []).append(constructive.Candidate(seed, evidence.scores[cls][seed], returns))
    answer = constructive.judge(classes, state["random"]["returns"], setup.margin, bar_reference(setup, state), SHARE,
                                flat_key=FLAT, max_return=task_max_return(setup.env))
    shown = {cls: jobs[(cls, e.seed)][0] for cls, e in answer.exhibits.items()}
    return answer, shown


def bar_reference(setup: Setup, state: dict) -> "constructive.Bar | None":
    """What may set the bar above flat PPO's best controller: the user's target, else the highest published
    reference at the answer's budget; None where there is neither."""
    if setup.target is not None:
        return constructive.Bar(f"the target score {setup.target:g}", trimmed.fixed(float(setup.target)), None)
    refs = baseline.load_references(setup.references or baseline.REFERENCES)
    return constructive.published_bar(refs, setup.env, int(state["steps"]["budget"]))


def record(answer: constructive.Answer, sentence: str, search: str) -> dict:
    """The constructive answer as answer.json keeps it (JSON: classes as 'flat' or the K as text)."""
    rows = {}
    for cls, e in answer.exhibits.items():
        s = answer.shares[cls]
        rows[str(cls)] = {**{k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in e._asdict().items()},
                          "reached": s.reached, "seeds": s.seeds, "share": s.share, "share_low": s.low,
                          "share_high": s.high, "share_p": answer.share_p.get(cls), "share_verdict": answer.share_verdicts.get(cls)}
    return {"sentence": sentence, "search": search, "margin": answer.margin, "bar": answer.bar.name,
            "bar_score": answer.bar.summary.mean, "random_mean": answer.random.mean, "threshold": answer.threshold,
            "smallest": answer.smallest, "exhibit_episodes": EXHIBIT, "share_episodes": SHARE,
            "fresh_start_seed": starts.FRESH_SEED, "classes": rows}


def search_words(seeds: dict, steps: int) -> str:
    """The search every class trained, in words, from {FLAT or K: seeds}: '10 seeds x 1,000,000 steps per class', or
    'flat PPO 40, K = 1 10, K = 2 40 seeds x 1,000,000 steps' where the classes' seeds differ."""
    if len(set(seeds.values())) == 1:
        return f"{next(iter(seeds.values()))} seeds x {steps:,} steps per class"
    parts = [f"flat PPO {seeds[FLAT]}"] if FLAT in seeds else []
    parts += [f"K = {k} {n}" for k, n in sorted((k, n) for k, n in seeds.items() if k != FLAT)]
    return f"{', '.join(parts)} seeds x {steps:,} steps"
