"""The constructive answer on the 22 tasks from the committed runs: `.venv/bin/python experiments/constructive/answers.py`
(after fresh_episodes.py).

Per task, every class (flat PPO, each K) of the tables' search (10 seeds x 1M steps) exhibits its best run on the
selection starts (per_run_scores.csv `controller_score`); that controller's 100 fresh-start episodes
(results/fresh_episodes.csv.gz) are compared, paired, with flat PPO's exhibited controller, or with the highest
published reference of ppo_references.csv at 1M steps where that is the higher bar
(gsa_jax.analysis.verdicts.constructive.judge: one Holm step-down at 2.5% over every K's exhibit and share test).
The share of seeds counts each run's mean over its first 20 fresh starts against the margin's threshold. Beside it,
the procedure's verdict (experiments/verdicts/results/rejudged.csv). Writes results/constructive.csv (a row per
task), results/exhibits.csv (a row per task and class), results/constructive.md, results/summary.csv and
results/exhibits.png.
"""

import csv
import gzip
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))

from gsa_jax import read_csv, write_csv  # noqa: E402
from gsa_jax.analysis.verdicts import baseline  # noqa: E402
from gsa_jax.analysis.verdicts import constructive as C  # noqa: E402
from gsa_jax.analysis.verdicts.answering import task_max_return  # noqa: E402
from gsa_jax.analysis.verdicts.verdict import DEFAULT_MARGIN  # noqa: E402

from fresh_episodes import OUT, ROOT, TABLES  # noqa: E402

RESULTS = os.path.join(HERE, "results")
STEPS = 1_000_000  # every table's budget (their sweep.json specs)
SHARE_EPISODES = 20
FLAT = "flat"


def fresh_returns() -> dict:
    """{(env, policy, K, seed): fresh-start returns [episodes] in episode order} and {same key: controller path}."""
    out, where = {}, {}
    with gzip.open(OUT, "rt", newline="") as f:
        for r in csv.DictReader(f):
            key = (r["env"], r["policy"], r["K"], int(r["seed"]))
            out.setdefault(key, []).append((int(r["episode"]), float(r["return"])))
            where[key] = r["controller"]
    return {k: np.array([x for _, x in sorted(v)]) for k, v in out.items()}, where


def classes_of(table: str, env: str, fresh: dict) -> dict:
    """{FLAT: [Candidate], K: [Candidate]} of one task's table."""
    out = {}
    for r in read_csv(os.path.join(table, "per_run_scores.csv")):
        if r["env"] != env:
            continue
        cls = FLAT if r["policy"] == "mlp" else int(r["K"])
        key = (r["env"], r["policy"], r["K"], int(r["seed"]))
        out.setdefault(cls, []).append(C.Candidate(int(r["seed"]), float(r["controller_score"]), fresh[key]))
    return out


def procedure() -> dict:
    """{env: the procedure's answer row} (experiments/verdicts/results/rejudged.csv)."""
    return {r["env"]: r for r in read_csv(os.path.join(ROOT, "verdicts", "results", "rejudged.csv"))}


def task_envs() -> list:
    """(family, table, env) of the 22 tasks."""
    out = []
    for name, table in TABLES.items():
        for env in sorted({r["env"] for r in read_csv(os.path.join(table, "per_run_scores.csv"))}):
            out.append(("dmc" if env.startswith("dmc:") else "gymnasium v5", table, env))
    return out


def exhibit_rows(env: str, a: C.Answer, runs: dict, where: dict) -> list:
    """A row per class of one task's answer."""
    rows = []
    for cls, e in a.exhibits.items():
        s = a.shares[cls]
        policy, k = ("mlp", "") if cls == FLAT else ("mixture", str(cls))
        rows.append({"env": env, "class": "flat PPO" if cls == FLAT else f"K = {cls}", "K": k, "seed": e.seed,
                     "selection_score": round(e.selection, 2), "fresh_score": round(e.fresh, 2),
                     "fresh_episode_std": round(e.fresh_std, 2), "fresh_episodes": e.episodes,
                     "gap": round(e.gap, 4), "gap_low": round(e.low, 4), "gap_high": round(e.high, 4),
                     "p_not_within_margin": "" if cls == FLAT else f"{e.p:.3g}", "verdict": "" if cls == FLAT else e.verdict,
                     "reached": s.reached, "seeds": s.seeds, "share": round(s.share, 3), "share_low": round(s.low, 3),
                     "share_high": round(s.high, 3), "share_p": "" if cls == FLAT else f"{a.share_p.get(cls, float('nan')):.3g}",
                     "share_verdict": "" if cls == FLAT else a.share_verdicts.get(cls, ""),
                     "controller": where[(env, policy, k, e.seed)]})
    return rows


def task_row(family: str, env: str, a: C.Answer, proc: dict, search: str) -> dict:
    """One task's row: the constructive answer beside the procedure's."""
    ks = sorted(k for k in a.exhibits if k != FLAT)
    shown = a.smallest if a.smallest is not None else max(ks, key=lambda k: a.exhibits[k].gap if a.exhibits[k].gap == a.exhibits[k].gap else -1e9)
    e, share = a.exhibits[shown], a.shares[shown]
    gap = "" if e.gap != e.gap else f"{e.gap:+.3f} [{e.low:+.3f}, {e.high:+.3f}]"
    return {"family": family, "env": env, "search": search, "bar": a.bar.name, "bar_score": round(a.bar.summary.mean, 2),
            "random_return": round(a.random.mean, 2), "threshold": round(a.threshold, 2),
            "constructive_K": "" if a.smallest is None else a.smallest,
            "found": " ".join(str(k) for k in ks if a.exhibits[k].verdict == C.FOUND),
            "as_often": " ".join(str(k) for k in ks if a.share_verdicts.get(k) == C.AS_OFTEN),
            "shown_K": shown, "shown_seed": e.seed, "shown_fresh": round(e.fresh, 1), "shown_gap": gap,
            "shown_share": f"{share.reached}/{share.seeds}", "shown_verdict": e.verdict,
            "flat_share": f"{a.shares[FLAT].reached}/{a.shares[FLAT].seeds}",
            "shares": " ".join(f"{k}:{a.shares[k].reached}/{a.shares[k].seeds}" for k in ks),
            "procedure_K": proc.get("K_margin_0.1", ""), "procedure_status": proc.get("status", ""),
            "answer": C.sentence(env, a, search)}


def answer_rows(log=print) -> tuple:
    """(a row per task, a row per task and class) of the constructive answers on the committed fresh episodes."""
    fresh, where = fresh_returns()
    proc, rows, exhibits = procedure(), [], []
    for family, table, env in task_envs():
        runs = classes_of(table, env, fresh)
        randoms = json.load(open(os.path.join(table, "random_policy.json")))[env]
        a = C.judge(runs, json.loads(randoms["returns"]) if isinstance(randoms["returns"], str) else randoms["returns"],
                    DEFAULT_MARGIN, C.published_bar(baseline.load_references(), env, STEPS), SHARE_EPISODES,
                    flat_key=FLAT, max_return=task_max_return(env))
        search = f"{len(runs[FLAT])} seeds x {STEPS:,} steps per class"
        rows.append(task_row(family, env, a, proc.get(env, {}), search))
        exhibits += exhibit_rows(env, a, runs, where)
        log(rows[-1]["answer"])
    return rows, exhibits


def main() -> None:
    rows, exhibits = answer_rows()
    write_csv(os.path.join(RESULTS, "constructive.csv"), rows)
    write_csv(os.path.join(RESULTS, "exhibits.csv"), exhibits)
    write_summary(rows)
    write_markdown(rows)
    plot(exhibits, rows)


def write_summary(rows: list) -> None:
    """results/summary.csv: the counts the README quotes."""
    found = sum(r["constructive_K"] != "" for r in rows)
    proc = sum(r["procedure_K"] != "" for r in rows)
    often = sum(r["as_often"] != "" for r in rows)
    write_csv(os.path.join(RESULTS, "summary.csv"), [{
        "tasks": len(rows), "found": found, "procedure_decided": proc, "as_often": often,
        "summary": (f"At margin {DEFAULT_MARGIN}: on {found} of {len(rows)} tasks some K suffices by construction; on "
                    f"{often} some K's seeds are shown to find one as often as flat PPO's; the procedure names a K on {proc}.")}])


def write_markdown(rows: list) -> None:
    """results/constructive.md: the table."""
    lines = ["| family | task | constructive K | K found | shares (flat PPO; K) | the procedure's K | bar |", "|" + "---|" * 7]
    for r in rows:
        lines.append(f"| {r['family']} | {r['env']} | {r['constructive_K'] or 'not found'} | {r['found'] or '-'} | "
                     f"{r['flat_share']}; {r['shares']} | {r['procedure_K'] or r['procedure_status']} | {r['bar']} ({r['bar_score']}) |")
    lines += ["", *[f"- {r['answer']}" for r in rows]]
    with open(os.path.join(RESULTS, "constructive.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


def plot(exhibits: list, rows: list) -> None:
    """results/exhibits.png: every exhibited mixture's gap with its interval, per task, the margin marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    envs = [r["env"] for r in rows]
    fig, ax = plt.subplots(figsize=(8, 0.42 * len(envs) + 1.2))
    for i, env in enumerate(envs):
        mine = [e for e in exhibits if e["env"] == env and e["K"] != "" and e["gap"] == e["gap"]]
        for j, e in enumerate(mine):
            y = i + (j - (len(mine) - 1) / 2) * 0.8 / max(len(mine), 1)
            lo, hi = max(e["gap_low"], -1.5), min(e["gap_high"], 1.0)
            color = "tab:green" if e["verdict"] == C.FOUND else "tab:gray"
            ax.plot([lo, hi], [y, y], color=color, lw=1.2)
            ax.plot([min(max(e["gap"], -1.5), 1.0)], [y], "o", color=color, ms=3)
            ax.text(1.02, y, f"K={e['K']}", fontsize=5, va="center", transform=ax.get_yaxis_transform())
    ax.axvline(-DEFAULT_MARGIN, color="tab:red", lw=0.8, ls="--", label=f"the margin (-{DEFAULT_MARGIN})")
    ax.axvline(0.0, color="black", lw=0.5)
    ax.set_yticks(range(len(envs)), envs, fontsize=6)
    ax.set_xlim(-1.5, 1.0)
    ax.invert_yaxis()
    ax.set_xlabel("gap of the exhibited K controller to the bar on 100 fresh starts (share of the bar's gain)")
    ax.set_title("Exhibited controllers (green: suffices by construction)", fontsize=9)
    ax.legend(fontsize=6, loc="lower left")
    fig.tight_layout()
    fig.savefig(os.path.join(RESULTS, "exhibits.png"), dpi=150)


if __name__ == "__main__":
    main()
