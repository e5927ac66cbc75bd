"""The published answers re-judged: `.venv/bin/python experiments/verdicts/rejudge.py` (after regenerate.sh).

Reads the answers of the bootstrap rule (results/bootstrap_rule_rejudged.csv: this file's output at 48a94e1, before
the sequential design: a 95% percentile-bootstrap interval per K, no correction over the K, a 16-episode random
return taken as exact) and the verdicts that gsa_jax.plot now writes (sufficient_k.csv and verdicts.csv: each table
judged as gsa_jax.answer's first look, against a baseline shown adequate), and per run both scores
(per_run_scores.csv). Writes results/rejudged.csv and results/rejudged.md: per task the old answer, the new smallest
sufficient K at margin 0.1 (0.05 and 0.2 as sensitivity), what it was judged against, flat PPO's standing against
its reference and whether it still learns, and what happened to the answer (held, moved, undecided, no answer); and results/score_change.csv: per task how far the controller score lies from
the training-time evaluation average; and results/episode_noise.csv: per cell the episode noise of a controller's
score beside the spread over seeds, and flat PPO's interquartile range over seeds as a share of its gain; and
results/answers.csv: the committed answers of gsa_jax.answer (answers/<task>/).
"""

import os
from collections import Counter

import numpy as np

from gsa_jax import read_csv, write_csv

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..")
TASK_DIRS = {"dmc": os.path.join(ROOT, "atlas_dmc", "results"), "v5": os.path.join(ROOT, "fig1_v5", "results", "merged")}


def new_answers():
    """{(family, env): {margin: sufficient_k row}} from the regenerated tables."""
    out = {}
    paths = [("v5", os.path.join(TASK_DIRS["v5"], "sufficient_k.csv"))]
    paths += [("dmc", os.path.join(TASK_DIRS["dmc"], t, "sufficient_k.csv")) for t in sorted(os.listdir(TASK_DIRS["dmc"]))
              if os.path.exists(os.path.join(TASK_DIRS["dmc"], t, "sufficient_k.csv"))]
    for family, path in paths:
        for r in read_csv(path):
            out.setdefault((family, r["env"]), {})[float(r["margin"])] = r
    return out


def baselines():
    """{env: the default-margin verdicts.csv row's baseline columns} of the regenerated tables."""
    paths = [os.path.join(TASK_DIRS["v5"], "verdicts.csv")]
    paths += [os.path.join(TASK_DIRS["dmc"], t, "verdicts.csv") for t in sorted(os.listdir(TASK_DIRS["dmc"]))
              if os.path.exists(os.path.join(TASK_DIRS["dmc"], t, "verdicts.csv"))]
    return {r["env"]: r for p in paths for r in read_csv(p) if r["role"] == "answer"}


def status(old, new, undecided, no_answer):
    """What happened to a task's answer at the default margin."""
    if no_answer:
        return "no answer"
    if new and new == old:
        return "held" + (" (a smaller K undecided)" if undecided else "")
    if new and old:
        return "moved"
    if new:
        return "moved (was none)"
    if undecided:
        return "undecided" + (f" (was K = {old})" if old else "")
    return "none sufficient" + (f" (was K = {old})" if old else " (held)")


def standing(b):
    """A task's baseline in a few words: what the verdicts judge against and why."""
    if not b:
        return ""
    if b.get("binding_reference_score", "") == "":
        return "flat PPO (no reference known)"
    ratio = float(b["flat_gain_ratio_to_reference"])
    where = "below" if b["flat_below_reference"] == "1" else "at or above (1 - margin of)"
    return f"flat PPO {ratio:.2f} of the reference's gain: {where} {b['binding_reference'].split(' (')[0]} ({b['binding_reference_score']})"


def rejudged_rows():
    """Per task: the answer under the bootstrap rule (the committed rejudged.csv before the sequential design), the
    answer now, the baseline's standing and whether flat PPO still learns."""
    old = {(r["family"], r["env"]): r for r in read_csv(os.path.join(HERE, "results", "bootstrap_rule_rejudged.csv"))}
    bases = baselines()
    rows = []
    for (family, env), by_margin in sorted(new_answers().items()):
        d = by_margin[0.1]
        why = d["answer"].split("no answer: ", 1)[1].rstrip(".") if "no answer" in d["answer"] else ""
        o = old.get((family, env), {})
        b = bases.get(env, {})
        rows.append({"family": family, "env": env, "ks_tried": d["ks_tried"],
                     "bootstrap_rule_K": o.get("K_margin_0.1", ""), "bootstrap_rule_verdicts": o.get("verdicts_0.1", ""),
                     "K_margin_0.1": d["smallest_sufficient_K"], "versus": d["versus"],
                     "K_margin_0.05_sensitivity": by_margin.get(0.05, {}).get("smallest_sufficient_K", ""),
                     "K_margin_0.2_sensitivity": by_margin.get(0.2, {}).get("smallest_sufficient_K", ""),
                     "undecided_below_0.1": d["undecided_below"], "verdicts_0.1": d["verdicts"], "seeds": d["seeds"],
                     "baseline": standing(b), "flat_below_reference": b.get("flat_below_reference", ""),
                     "last_fifth_gain": b.get("last_fifth_gain", ""), "last_fifth_gain_upper": b.get("last_fifth_gain_upper", ""),
                     "stopped_learning": b.get("stopped_learning", ""), "no_answer": why,
                     "status": status(o.get("K_margin_0.1", ""), d["smallest_sufficient_K"], d["undecided_below"], why)})
    return rows


def score_change_rows():
    """Per task: the controller score against the training-time evaluation average, run by run."""
    rows = []
    dirs = [("v5", TASK_DIRS["v5"])] + [("dmc", os.path.join(TASK_DIRS["dmc"], t)) for t in sorted(os.listdir(TASK_DIRS["dmc"]))]
    for family, d in dirs:
        runs = [r for r in read_csv(os.path.join(d, "per_run_scores.csv")) if r.get("controller_score", "") != ""]
        for env in dict.fromkeys(r["env"] for r in runs):
            c = np.array([float(r["controller_score"]) for r in runs if r["env"] == env])
            f = np.array([float(r["final_score"]) for r in runs if r["env"] == env])
            last = np.array([float(r["last_eval_return"]) for r in runs if r["env"] == env])
            scale = np.maximum(np.abs(f), 1.0)
            rows.append({"family": family, "env": env, "runs": len(c),
                         "median_abs_rel_diff_to_final_score": round(float(np.median(np.abs(c - f) / scale)), 4),
                         "max_abs_rel_diff_to_final_score": round(float(np.max(np.abs(c - f) / scale)), 4),
                         "median_abs_rel_diff_to_last_eval": round(float(np.median(np.abs(c - last) / np.maximum(np.abs(last), 1.0))), 4),
                         "max_abs_rel_diff_to_last_eval": round(float(np.max(np.abs(c - last) / np.maximum(np.abs(last), 1.0))), 4)})
    return rows


def noise_rows():
    """Per task and policy class: the episode noise of a controller's score (its 10 episodes' standard deviation over
    sqrt(10), median over the cell's controllers) beside the spread of the scores over seeds (standard deviation), and
    flat PPO's interquartile range over seeds as a share of its gain over a random policy."""
    import glob
    import json

    from gsa_jax import iqm

    rows = []
    for d in [os.path.join(ROOT, "fig1_v5", "results", n) for n in sorted(os.listdir(os.path.join(ROOT, "fig1_v5", "results")))
              if n.startswith("fig1_v5_") and "seeds" not in n] + [os.path.join(TASK_DIRS["dmc"], t) for t in sorted(os.listdir(TASK_DIRS["dmc"]))]:
        scored = [r for p in glob.glob(os.path.join(os.path.dirname(d), os.path.basename(d) + "*", "**", "controller_scores.csv"),
                                       recursive=True) for r in read_csv(p)]
        randoms = {}
        for p in glob.glob(os.path.join(d, "random_policy.json")):
            with open(p) as f:
                randoms = {env: record["mean"] for env, record in json.load(f).items()}
        for (env, policy, k) in dict.fromkeys((r["env"], r["policy"], r["K"]) for r in scored):
            cell = [r for r in scored if (r["env"], r["policy"], r["K"]) == (env, policy, k)]
            scores = np.array([float(r["controller_score"]) for r in cell])
            noise = np.median([float(r["episode_std"]) / np.sqrt(float(r["episodes"])) for r in cell])
            row = {"env": env, "policy": policy, "K": k, "controllers": len(cell), "median_episode_noise": round(float(noise), 3),
                   "seed_std": round(float(np.std(scores, ddof=1)), 3), "noise_over_seed_std": round(float(noise / max(np.std(scores, ddof=1), 1e-9)), 4)}
            if policy == "mlp" and env in randoms:
                gain = float(iqm(scores)) - randoms[env]
                q75, q25 = np.percentile(scores, [75, 25])
                row["flat_iqr_over_gain"] = round(float((q75 - q25) / gain), 4) if gain > 0 else ""
            rows.append(row)
    return rows


def answer_rows():
    """Per committed answer (answers/<task>/answer.json, longer_budget/answer): the answer at its margin, its
    constructive answer, why it stopped, the verdicts, the seeds per cell and the rounds' minutes."""
    import glob
    import json

    from gsa_jax.analysis.verdicts import verdict

    rows = []
    paths = glob.glob(os.path.join(HERE, "answers", "*", "answer.json"))
    paths += glob.glob(os.path.join(HERE, "longer_budget", "answer", "answer.json"))
    for path in sorted(paths):
        with open(path) as f:
            state = json.load(f)
        setup, judged = state["setup"], state["judged"]
        verdicts = {int(k): r["verdict"] for k, r in judged.items()}
        minutes = sum(sw["seconds"] for r in state["rounds"] for sw in r["sweeps"].values()) / 60
        compile_min = sum(sw["compile_s"] for r in state["rounds"] for sw in r["sweeps"].values()) / 60
        rows.append({"env": setup["env"], "answer_dir": os.path.relpath(os.path.dirname(path), HERE),
                     "steps": setup["specs"]["mlp"]["steps"], "margin": setup["margin"],
                     "looks": " ".join(map(str, setup["looks"])), "design": "sequential" if "records" in state else "bootstrap rule",
                     "answer": verdict.sentence(setup["env"], verdicts, setup["margin"],
                                                state.get("baseline", {}).get("versus", "flat PPO")),
                     "constructive": state.get("constructive", {}).get("sentence", ""),
                     "stopped": state["stopped"], "verdicts": " ".join(f"{k}:{v}" for k, v in sorted(verdicts.items())),
                     "seeds": " ".join(f"{k}:{judged[str(k)].get('seeds', judged[str(k)].get('n'))}" for k in sorted(verdicts)),
                     "rounds": len(state["rounds"]), "training_minutes": round(minutes, 1),
                     "compile_share": round(compile_min / minutes, 3) if minutes else ""})
    return rows


def markdown(rows):
    head = ["family", "task", "K tried", "bootstrap rule (before)", "now, margin 0.1", "judged against", "undecided below",
            "verdicts now (K:verdict)", "flat PPO's standing", "still learning? (last fifth's gain, upper bound)",
            "sensitivity: margin 0.05 / 0.2", "at 0.1"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        learn = ("" if r["stopped_learning"] == "" else
                 ("stopped" if r["stopped_learning"] == "1" else "not shown stopped")
                 + f" ({float(r['last_fifth_gain']):+.2f}, {float(r['last_fifth_gain_upper']):+.2f})")
        lines.append("| " + " | ".join([r["family"], r["env"], r["ks_tried"], r["bootstrap_rule_K"] or "none",
                                        r["K_margin_0.1"] or "none", r["versus"], r["undecided_below_0.1"], r["verdicts_0.1"],
                                        r["baseline"], learn,
                                        f"{r['K_margin_0.05_sensitivity'] or 'none'} / {r['K_margin_0.2_sensitivity'] or 'none'}",
                                        r["status"] + (f": {r['no_answer']}" if r["no_answer"] else "")]) + " |")
    return "\n".join(lines + ["", summary(rows)]) + "\n"


def summary(rows):
    """One line: how many answers held, moved, became undecided, gave no answer at margin 0.1."""
    counts = Counter(r["status"].split(" (")[0] for r in rows)
    return "At margin 0.1: " + ", ".join(f"{n} {s}" for s, n in sorted(counts.items())) + f" (of {len(rows)} tasks)."


def baseline_counts(rows):
    """How many tasks have flat PPO below its binding reference, and not shown to have stopped learning."""
    return [{"what": "below_reference", "tasks": sum(r["flat_below_reference"] == "1" for r in rows)},
            {"what": "not_shown_stopped", "tasks": sum(r["stopped_learning"] == "0" for r in rows)}]


def main():
    rows = rejudged_rows()
    write_csv(os.path.join(HERE, "results", "baseline_counts.csv"), baseline_counts(rows))
    write_csv(os.path.join(HERE, "results", "rejudged.csv"), rows)
    with open(os.path.join(HERE, "results", "rejudged.md"), "w") as f:
        f.write(markdown(rows))
    write_csv(os.path.join(HERE, "results", "rejudged_summary.csv"), [{"summary": summary(rows)}])
    write_csv(os.path.join(HERE, "results", "score_change.csv"), score_change_rows())
    write_csv(os.path.join(HERE, "results", "episode_noise.csv"), noise_rows())
    write_csv(os.path.join(HERE, "results", "answers.csv"), answer_rows())
    print(markdown(rows))


if __name__ == "__main__":
    main()
