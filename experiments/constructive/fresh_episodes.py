"""Every controller behind the 22 tasks' tables re-run on the fresh starts: `.venv/bin/python experiments/constructive/fresh_episodes.py [--jobs N]`.

The tables (experiments/fig1_v5/results/merged, experiments/atlas_dmc/results/<task>) score each run's committed
controller on the selection starts (10 episodes from seed 10,000: per_run_scores.csv `controller_score`), and an
answer picks its best seed there. The constructive answer reports the picked controllers on starts they were not
picked on, and counts the seeds that reach the margin's threshold there. Here, in MuJoCo C from the same fresh
starts (seeds 20,000 + i, gsa_jax.deployment.starts: paired across controllers), each cell's picked controller (the
best controller_score of its seeds; ties to the lower seed) runs EXHIBIT episodes (100), and every other controller
the first SHARE episodes (20) of them. Writes results/fresh_episodes.csv.gz (a row per controller and episode: its
return and length, the controller's file and sha256). Rows are appended as each controller finishes (results/fresh_episodes.partial.csv), so an
interrupted run resumes; the gzipped table is written at the end, sorted.
"""

import argparse
import csv
import glob
import gzip
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..")
sys.path.insert(0, os.path.join(ROOT, ".."))

from gsa_jax.analysis.sweeps import controller_scores as S  # noqa: E402
from gsa_jax import read_csv  # noqa: E402
from gsa_jax.deployment import starts  # noqa: E402

TABLES = {"v5": os.path.join(ROOT, "fig1_v5", "results", "merged")}
TABLES.update({f"dmc:{t}": os.path.join(ROOT, "atlas_dmc", "results", t) for t in sorted(os.listdir(os.path.join(ROOT, "atlas_dmc", "results")))
               if os.path.exists(os.path.join(ROOT, "atlas_dmc", "results", t, "per_run_scores.csv"))})
SOURCES = {"v5": sorted(d for d in glob.glob(os.path.join(ROOT, "fig1_v5", "results", "fig1_v5_*")) if os.path.isdir(d))}
EXHIBIT, SHARE, START_SEED = starts.FRESH_EPISODES, 20, starts.FRESH_SEED
OUT = os.path.join(HERE, "results", "fresh_episodes.csv.gz")
PARTIAL = os.path.join(HERE, "results", "fresh_episodes.partial.csv")
COLUMNS = ("env", "policy", "K", "seed", "episode", "start_seed", "return", "length", "label", "sha256", "controller")


def label_of(r: dict) -> str:
    """A per_run_scores row's run label (gsa_jax.running.trained.run_label's form)."""
    env = r["env"].replace(":", ".")
    return f"{env}-mixture-K{r['K']}-s{r['seed']}" if r["policy"] == "mixture" else f"{env}-mlp-s{r['seed']}"


def rel(path: str) -> str:
    """A path relative to the repository root."""
    return os.path.relpath(path, os.path.join(ROOT, ".."))


def controllers() -> list:
    """Every table's runs as (controller path, episodes): EXHIBIT for each cell's picked run, SHARE for the others
    (each label found exactly once in its table's own results)."""
    out = []
    for name, table in TABLES.items():
        found = {}
        for d in SOURCES.get(name, [table]):
            for p in glob.glob(os.path.join(d, "**", "controllers", "*.npz"), recursive=True):
                found.setdefault(os.path.basename(p)[:-4], set()).add(p)
        runs = read_csv(os.path.join(table, "per_run_scores.csv"))
        best = {}
        for r in sorted(runs, key=lambda r: int(r["seed"])):
            cell = (r["env"], r["policy"], r["K"])
            if cell not in best or float(r["controller_score"]) > float(best[cell]["controller_score"]):
                best[cell] = r
        picked = {label_of(r) for r in best.values()}
        for r in runs:
            hits = found.get(label_of(r), set())
            if len(hits) != 1:
                raise SystemExit(f"{name}: {label_of(r)} found {len(hits)} times: {sorted(hits)}")
            out.append((hits.pop(), EXHIBIT if label_of(r) in picked else SHARE))
    return sorted(out, key=lambda x: -x[1])  # the picked ones first: the constructive answer needs them


def episode_rows(job: tuple) -> list:
    """A controller's fresh-start episodes as rows (job: its path and how many episodes)."""
    path, episodes = job
    ident, returns, lengths = S.controller_episodes(path, episodes, START_SEED)
    return [{**{c: ident[c] for c in ("env", "policy", "K", "seed", "label", "sha256")}, "episode": i,
             "start_seed": START_SEED + i, "return": round(float(r), 4), "length": int(n), "controller": rel(path)}
            for i, (r, n) in enumerate(zip(returns, lengths))]


def episodes_done() -> dict:
    """{(controller, sha256): episodes 0 .. n - 1 all in the partial file -> n}."""
    if not os.path.exists(PARTIAL):
        return {}
    seen = {}
    with open(PARTIAL, newline="") as f:
        for r in csv.DictReader(f):
            seen.setdefault((r["controller"], r["sha256"]), set()).add(int(r["episode"]))
    return {k: len(v) for k, v in seen.items() if v == set(range(len(v)))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=S.default_jobs())
    args = ap.parse_args()
    jobs, have = controllers(), episodes_done()
    todo = [(p, n) for p, n in jobs if have.get((rel(p), S.file_sha256(p)), 0) < n]
    print(f"{len(jobs)} controllers, {len(todo)} to run (from seed {START_SEED})", flush=True)
    new = not os.path.exists(PARTIAL)
    with open(PARTIAL, "a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        if new:
            w.writeheader()
        for i, rows in enumerate(S.parallel_map(episode_rows, todo, args.jobs)):
            w.writerows(rows)
            f.flush()
            print(f"{i + 1}/{len(todo)} {rows[0]['label']} ({len(rows)} episodes): "
                  f"{sum(r['return'] for r in rows) / len(rows):.1f}", flush=True)
    write_table(jobs)


def write_table(jobs: list) -> None:
    """The gzipped table of the controllers behind the tables (sorted; stale rows and repeats dropped)."""
    wanted = {(rel(p), S.file_sha256(p)): n for p, n in jobs}
    rows = {}
    with open(PARTIAL, newline="") as f:
        for r in csv.DictReader(f):
            n = wanted.get((r["controller"], r["sha256"]))
            if n is not None and int(r["episode"]) < n:
                rows[(r["controller"], int(r["episode"]))] = r
    out = sorted(rows.values(), key=lambda r: (r["env"], r["policy"], int(r["K"] or 0), int(r["seed"]), int(r["episode"])))
    with gzip.open(OUT, "wt", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(out)
    print(f"{len(out)} rows -> {OUT}")


if __name__ == "__main__":
    main()
