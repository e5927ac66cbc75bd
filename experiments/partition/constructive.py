"""The partition experiment's constructive answer: `.venv/bin/python experiments/partition/constructive.py [--jobs N]`.

Per task, K and partition step size, each cell's best run on the selection starts (per_run_scores.csv
`controller_score`; ties to the lower seed) is exhibited on 100 fresh starts (seeds 20,000 + i,
gsa_jax.deployment.starts: the same starts for every controller, so the comparisons are paired), every other run on
the first 20 of them (the share of seeds). Then, with gsa_jax.analysis.verdicts.constructive.judge (margin 0.1, one
Holm step-down at 2.5% over each family's claims):

- the linear partition's exhibit against the MLP partition's (the bar) at equal K and step size: "suffices by
  construction" or "not found at this search", and the share of linear seeds reaching the MLP bar's threshold
  against the MLP partition's share;
- each partition's exhibit against flat PPO's (the bar; a published reference at 1M steps where that is higher, as in
  experiments/constructive/), per task and step size over every K and both partitions.

Writes results/fresh_episodes.csv.gz (a row per controller and episode; an interrupted run resumes from
results/fresh_episodes.partial.csv), results/constructive.csv (a row per task, K and step size) and
results/constructive.md (its table).
"""

import argparse
import csv
import glob
import gzip
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, ROOT)

from gsa_jax.analysis.sweeps import controller_scores as S  # noqa: E402
from gsa_jax import read_csv, write_csv  # noqa: E402
from gsa_jax.analysis.verdicts import baseline  # noqa: E402
from gsa_jax.analysis.verdicts import constructive as C  # noqa: E402
from gsa_jax.analysis.verdicts.answering import task_max_return  # noqa: E402
from gsa_jax.analysis.verdicts.verdict import DEFAULT_MARGIN  # noqa: E402
from gsa_jax.deployment import starts  # noqa: E402

RESULTS = os.path.join(HERE, "results")
OUT, PARTIAL = os.path.join(RESULTS, "fresh_episodes.csv.gz"), os.path.join(RESULTS, "fresh_episodes.partial.csv")
EXHIBIT, SHARE, START_SEED = starts.FRESH_EPISODES, 20, starts.FRESH_SEED
COLUMNS = ("env", "policy", "K", "partition", "lr_scale_partition", "seed", "episode", "return", "sha256", "controller")
FLAT = "flat"
STEPS = 1_000_000  # every arm's budget (their sweep.json specs)


def task_dirs() -> list:
    """The scored tasks' result folders, in name order."""
    return sorted(d for d in glob.glob(os.path.join(RESULTS, "*")) if os.path.exists(os.path.join(d, "per_run_scores.csv")))


def cell_of(r: dict) -> tuple:
    """A per_run_scores row's cell: FLAT, or (K, partition, lr_scale_partition)."""
    return FLAT if r["policy"] == "mlp" else (int(r["K"]), r["partition"], r["lr_scale_partition"])


def controller_of(task_dir: str, r: dict) -> str:
    """The committed controller file of a per_run_scores row (gsa_jax.running.trained's label)."""
    env = r["env"].replace(":", ".")
    label = (f"{env}-mlp-s{r['seed']}" if r["policy"] == "mlp" else
             f"{env}-mixture-K{r['K']}-partition={r['partition']}-lr_scale_partition={r['lr_scale_partition']}-s{r['seed']}")
    hits = glob.glob(os.path.join(task_dir, "*", "controllers", label + ".npz"))
    if len(hits) != 1:
        raise SystemExit(f"{label}: found {len(hits)} times in {task_dir}")
    return hits[0]


def jobs() -> list:
    """(controller path, episodes, row) of every run: EXHIBIT for each cell's best on the selection starts."""
    out = []
    for d in task_dirs():
        rows = sorted(read_csv(os.path.join(d, "per_run_scores.csv")), key=lambda r: int(r["seed"]))
        best = {}
        for r in rows:
            if cell_of(r) not in best or float(r["controller_score"]) > float(best[cell_of(r)]["controller_score"]):
                best[cell_of(r)] = r
        out += [(controller_of(d, r), EXHIBIT if best[cell_of(r)] is r else SHARE, r) for r in rows]
    return sorted(out, key=lambda j: -j[1])


def episode_rows(job: tuple) -> list:
    """One controller's fresh-start episodes as rows."""
    path, episodes, r = job
    ident, returns, _ = S.controller_episodes(path, episodes, START_SEED)
    return [{"env": r["env"], "policy": r["policy"], "K": r["K"], "partition": r["partition"],
             "lr_scale_partition": r["lr_scale_partition"], "seed": r["seed"], "episode": i, "return": round(float(x), 4),
             "sha256": ident["sha256"], "controller": os.path.relpath(path, ROOT)} for i, x in enumerate(returns)]


def run_episodes(todo: list, n_jobs: int) -> None:
    """Append the controllers' episodes to the partial file (resumable), then write the sorted gzipped table."""
    done = {}
    if os.path.exists(PARTIAL):
        for r in read_csv(PARTIAL):
            done.setdefault((r["controller"], r["sha256"]), set()).add(int(r["episode"]))
    left = [j for j in todo if len(done.get((os.path.relpath(j[0], ROOT), S.file_sha256(j[0])), ())) < j[1]]
    print(f"{len(todo)} controllers, {len(left)} to run", flush=True)
    new = not os.path.exists(PARTIAL)
    with open(PARTIAL, "a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        if new:
            w.writeheader()
        for i, rows in enumerate(S.parallel_map(episode_rows, left, n_jobs)):
            w.writerows(rows)
            f.flush()
            print(f"{i + 1}/{len(left)} {rows[0]['controller']}", flush=True)
    wanted = {(os.path.relpath(p, ROOT), S.file_sha256(p)): n for p, n, _ in todo}
    kept = {(r["controller"], int(r["episode"])): r for r in read_csv(PARTIAL)
            if int(r["episode"]) < wanted.get((r["controller"], r["sha256"]), 0)}
    with gzip.open(OUT, "wt", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(sorted(kept.values(), key=lambda r: (r["controller"], int(r["episode"]))))


def candidates() -> dict:
    """{task dir: {cell: [Candidate]}} from per_run_scores.csv and the committed fresh episodes."""
    fresh = {}
    with gzip.open(OUT, "rt", newline="") as f:
        for r in csv.DictReader(f):
            fresh.setdefault(r["controller"], []).append((int(r["episode"]), float(r["return"])))
    out = {}
    for d in task_dirs():
        for r in read_csv(os.path.join(d, "per_run_scores.csv")):
            episodes = np.array([x for _, x in sorted(fresh[os.path.relpath(controller_of(d, r), ROOT)])])
            out.setdefault(d, {}).setdefault(cell_of(r), []).append(
                C.Candidate(int(r["seed"]), float(r["controller_score"]), episodes))
    return out


def gap_text(e: "C.Exhibit") -> str:
    return "" if e.gap != e.gap else f"{e.gap:+.3f} [{e.low:+.3f}, {e.high:+.3f}]"


def task_rows(task_dir: str, cells: dict) -> list:
    """A row per K and step size of one task: the linear partition's exhibit against the MLP partition's, and each
    against flat PPO's (one Holm family per step size over every K and both partitions)."""
    env = read_csv(os.path.join(task_dir, "per_run_scores.csv"))[0]["env"]
    with open(os.path.join(task_dir, S.RANDOM_FILE)) as f:
        rand = json.load(f)[env]["returns"]
    top, rows = task_max_return(env), []
    bar = C.published_bar(baseline.load_references(), env, STEPS)  # the higher of it and flat PPO's exhibit
    for lr in sorted({c[2] for c in cells if c != FLAT}, key=float):
        ks = sorted({c[0] for c in cells if c != FLAT and c[2] == lr})
        versus_flat = C.judge({FLAT: cells[FLAT], **{(k, p): cells[(k, p, lr)] for k in ks for p in ("linear", "mlp")}},
                              rand, DEFAULT_MARGIN, bar, SHARE, flat_key=FLAT, max_return=top)
        for k in ks:
            pair = C.judge({"mlp": cells[(k, "mlp", lr)], "linear": cells[(k, "linear", lr)]}, rand, DEFAULT_MARGIN,
                           None, SHARE, flat_key="mlp", max_return=top)
            lin, mlp = pair.exhibits["linear"], pair.exhibits["mlp"]
            ls, ms = pair.shares["linear"], pair.shares["mlp"]
            rows.append({"env": env, "K": k, "lr_scale_partition": lr, "linear_seed": lin.seed,
                         "linear_fresh": round(lin.fresh, 1), "mlp_seed": mlp.seed, "mlp_fresh": round(mlp.fresh, 1),
                         "flat_fresh": round(versus_flat.exhibits[FLAT].fresh, 1), "bar": versus_flat.bar.name,
                         "bar_score": round(versus_flat.bar.summary.mean, 1), "linear_vs_mlp_gap": gap_text(lin),
                         "linear_vs_mlp": lin.verdict, "linear_reaching_mlp": f"{ls.reached}/{ls.seeds}",
                         "mlp_reaching_mlp": f"{ms.reached}/{ms.seeds}", "linear_share_vs_mlp": pair.share_verdicts.get("linear", ""),
                         "linear_vs_flat_gap": gap_text(versus_flat.exhibits[(k, "linear")]),
                         "linear_vs_flat_ppo": versus_flat.exhibits[(k, "linear")].verdict,
                         "mlp_vs_flat_gap": gap_text(versus_flat.exhibits[(k, "mlp")]),
                         "mlp_vs_flat_ppo": versus_flat.exhibits[(k, "mlp")].verdict,
                         "linear_reaching_flat": f"{versus_flat.shares[(k, 'linear')].reached}/{versus_flat.shares[(k, 'linear')].seeds}",
                         "mlp_reaching_flat": f"{versus_flat.shares[(k, 'mlp')].reached}/{versus_flat.shares[(k, 'mlp')].seeds}",
                         "flat_reaching_flat": f"{versus_flat.shares[FLAT].reached}/{versus_flat.shares[FLAT].seeds}"})
    return rows


def answer_rows() -> list:
    """Every task's rows (task_rows) from the committed fresh episodes."""
    return [r for d, cells in candidates().items() for r in task_rows(d, cells)]


MD = (("env", "task"), ("K", "K"), ("lr_scale_partition", "partition step size"), ("linear_fresh", "linear (fresh)"),
      ("mlp_fresh", "MLP (fresh)"), ("linear_vs_mlp_gap", "linear vs MLP: gap"), ("linear_vs_mlp", "linear vs MLP"),
      ("linear_reaching_mlp", "linear seeds reaching the MLP bar"), ("mlp_reaching_mlp", "MLP seeds reaching it"),
      ("flat_fresh", "flat PPO (fresh)"), ("bar_score", "bar"), ("linear_vs_flat_ppo", "linear vs flat PPO"), ("mlp_vs_flat_ppo", "MLP vs flat PPO"))


def write_markdown(rows: list) -> None:
    """results/constructive.md: the table of constructive.csv."""
    lines = ["| " + " | ".join(h for _, h in MD) + " |", "|" + "---|" * len(MD)]
    lines += ["| " + " | ".join(str(r[c]) for c, _ in MD) + " |" for r in rows]
    with open(os.path.join(RESULTS, "constructive.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=S.default_jobs())
    ap.add_argument("--judge-only", action="store_true", help="judge the committed fresh episodes, run none")
    args = ap.parse_args()
    if not args.judge_only:
        run_episodes(jobs(), args.jobs)
    rows = answer_rows()
    write_csv(os.path.join(RESULTS, "constructive.csv"), rows)
    write_markdown(rows)
    for r in rows:
        print(f"{r['env']} K={r['K']} lr_scale_partition={r['lr_scale_partition']}: linear {r['linear_fresh']} vs MLP "
              f"{r['mlp_fresh']} ({r['linear_vs_mlp_gap']}): {r['linear_vs_mlp']}; vs flat PPO {r['flat_fresh']}: linear "
              f"{r['linear_vs_flat_ppo']}, MLP {r['mlp_vs_flat_ppo']}")


if __name__ == "__main__":
    main()
