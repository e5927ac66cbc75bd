"""The atlas's table and figure from the committed results: `.venv/bin/python experiments/atlas_dmc/atlas.py`.

Reads results/<task>/final_returns.csv and sufficient_k.csv (gsa_jax.plot's, one folder per finished task) and,
for comparison, Figure 1 on gymnasium's v5 tasks (experiments/fig1_v5/results/merged: a different protocol, the PPO
paper's settings and Brax-style resets, marked apart). Writes results/atlas.csv (one row per task: d_a, flat PPO's
IQM, the best mixture's K, IQM and P(> flat PPO), the smallest sufficient K as gsa_jax judges it (the answer's first
look; what it was judged against: flat PPO, or the reference flat PPO falls below), flat PPO's last-100-episode
training return next to CleanRL's published PPO on the same task at 8M steps (the 1M entries are in
gsa_jax/analysis/verdicts/ppo_references.csv and verdicts.csv), the random policy's return (128 episodes in MuJoCo C,
random_policy.json), and no_answer: why gsa_jax gives no answer (flat PPO does not learn the task at this budget, or
its gain over the random policy is not shown positive); such rows are marked in the table and figure),
results/atlas.md (the same as a Markdown table) and results/atlas.png.
"""

import json
import os

from gsa_jax import read_csv, write_csv
from gsa_jax.analysis.verdicts.verdict import MARGINS

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
V5 = os.path.join(HERE, "..", "fig1_v5", "results", "merged")


def task_rows(final_csv, sufficient_csv, family):
    """One atlas row per task of a gsa_jax.plot output."""
    by_margin = {}
    for r in read_csv(sufficient_csv):  # one row per margin: the default's answers the table, the others beside it
        by_margin.setdefault(r["env"], {})[float(r["margin"])] = r
    finals = read_csv(final_csv)
    sufficient = {env: next(r for r in rows.values() if r["default_margin"] == "1") for env, rows in by_margin.items()}
    randoms = {}
    if os.path.exists(random_json := os.path.join(os.path.dirname(final_csv), "random_policy.json")):
        with open(random_json) as f:
            randoms = {env: record["mean"] for env, record in json.load(f).items()}
    rows = []
    for env in dict.fromkeys(r["env"] for r in finals):
        flat = next(r for r in finals if r["env"] == env and r["policy"] == "mlp")
        mixtures = [r for r in finals if r["env"] == env and r["policy"] == "mixture"]
        best = max(mixtures, key=lambda r: float(r["iqm"]))
        d_a = round(int(best["K"]) / float(best["K_over_action_dim"]))
        s = sufficient.get(env, {})
        no_answer = s["answer"].split("no answer: ", 1)[1].rstrip(".") if "no answer" in s.get("answer", "") else ""
        rows.append({"task": env, "family": family, "d_a": d_a, "flat_iqm": flat["iqm"],
                     "flat_iqm_ci_low": flat["iqm_ci_low"], "flat_iqm_ci_high": flat["iqm_ci_high"], "best_K": best["K"],
                     "best_iqm": best["iqm"], "best_over_flat": f"{float(best['iqm']) / float(flat['iqm']):.3f}",
                     "p_best_gt_flat": best["p_better_than_flat_ppo"],
                     "p_ci_low": best["p_ci_low"], "p_ci_high": best["p_ci_high"],
                     "smallest_sufficient_K": s.get("smallest_sufficient_K", ""), "versus": s.get("versus", ""),
                     "ks_tried": s.get("ks_tried", ""),
                     "margin": s.get("margin", ""), "undecided_below": s.get("undecided_below", ""),
                     "verdicts": s.get("verdicts", ""), "seeds": s.get("seeds", ""),
                     **{f"smallest_sufficient_K_margin_{m:g}": by_margin.get(env, {}).get(m, {}).get("smallest_sufficient_K", "")
                        for m in MARGINS},
                     "flat_training_return": flat["training_return_mean"],
                     "random_return": f"{randoms[env]:.3f}" if env in randoms else "",
                     "no_answer": no_answer})
    return rows


def published(rows):
    """CleanRL's PPO (published_ppo.csv, plain PPO rows) beside each DMC task."""
    table = {r["task"]: r for r in read_csv(os.path.join(HERE, "published_ppo.csv")) if "rpo" not in r["algorithm"].lower()}
    for row in rows:
        p = table.get(row["task"].removeprefix("dmc:"), {})
        row["published_ppo"] = f"{p['published_mean']} ± {p['published_std']} ({int(p['env_steps']) // 10**6}M)" if p else ""
        row["published_mean"], row["published_std"] = p.get("published_mean", ""), p.get("published_std", "")
    return rows


def markdown(rows):
    """The atlas table as Markdown (results/atlas.md)."""
    head = ["task", "d_a", "flat PPO IQM [95% CI]", "best mixture: K, IQM", "P(best > flat) [95% CI]",
            "smallest sufficient K, margin 0.1 (K tried; vs the reference flat PPO falls below; undecided: smaller K not decided; no answer: why)",
            "at margins 0.05 / 0.2", "flat PPO training return (last 100 ep.)", "CleanRL PPO (published)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        low, high, p_low, p_high = r["flat_iqm_ci_low"], r["flat_iqm_ci_high"], r["p_ci_low"], r["p_ci_high"]
        lines.append("| " + " | ".join([
            r["task"], str(r["d_a"]), f"{float(r['flat_iqm']):,.0f} [{float(low):,.0f}, {float(high):,.0f}]",
            f"K = {r['best_K']}: {float(r['best_iqm']):,.0f}", f"{float(r['p_best_gt_flat']):.2f} [{p_low}, {p_high}]",
            f"{r['smallest_sufficient_K'] or 'none'} ({r['ks_tried']})"
            + (f" vs {r['versus']}" if r["versus"] not in ("", "flat PPO") else "")
            + (f"; undecided: {r['undecided_below']}" if r["undecided_below"] else "")
            + (f" no answer: {r['no_answer']}" if r["no_answer"] else ""),
            f"{r['smallest_sufficient_K_margin_0.05'] or 'none'} / {r['smallest_sufficient_K_margin_0.2'] or 'none'}",
            f"{float(r['flat_training_return']):,.0f}",
            r.get("published_ppo", "")]) + " |")
    return "\n".join(lines) + "\n"


def draw_ratios(a, rows):
    """Left panel: the best mixture's IQM over flat PPO's per task (hatched: no answer)."""
    rows = sorted(rows, key=lambda r: float(r["best_over_flat"]))
    colors = ["tab:blue" if r["family"] == "dmc" else "tab:gray" for r in rows]
    bars = a.barh([r["task"] for r in rows], [float(r["best_over_flat"]) for r in rows], color=colors)
    for bar, r in zip(bars, rows):
        if r["no_answer"]:
            bar.set_alpha(0.35)
            bar.set_hatch("//")
    a.axvline(1.0, color="k", lw=1)
    a.set_xscale("log")
    a.set_xticks([0.25, 0.5, 1, 2, 4, 8], ["1/4", "1/2", "1", "2", "4", "8"])
    a.minorticks_off()
    for i, r in enumerate(rows):
        note = f"  K={r['best_K']}, P={float(r['p_best_gt_flat']):.2f}"
        note += f" (no answer: {r['no_answer']})" if r["no_answer"] else ""
        a.text(float(r["best_over_flat"]), i, note, va="center", fontsize=7)
    a.set_xlabel("best mixture's IQM / flat PPO's IQM (deterministic controllers)")
    a.set_title("How good is the best mixture? (blue: DMC atlas, grey: v5 Figure 1)", fontsize=9)


def draw_sufficient(b, rows):
    """Right panel: the smallest sufficient K against d_a (x: none of the K tried); tasks with no answer left out."""
    points = {}  # (d_a, y, marker, color) -> task names (tasks at the same point share one label)
    for r in [r for r in rows if not r["no_answer"]]:
        d_a, k, k_max = int(r["d_a"]), r["smallest_sufficient_K"], max(int(x) for x in r["ks_tried"].split())
        name = r["task"].removeprefix("dmc:") + ("" if k else f" (none of K = {r['ks_tried']})")
        marker = ("o" if not r["undecided_below"] else "^") if k else ("$?$" if r["undecided_below"] else "x")
        key = (d_a, int(k) if k else k_max * 1.6, marker, "tab:blue" if r["family"] == "dmc" else "tab:gray")
        points.setdefault(key, []).append(name)
    for (d_a, y, marker, color), names in points.items():
        v5 = color == "tab:gray"  # v5 hollow and on top, so a DMC point at the same place still shows
        b.scatter(d_a, y, marker=marker, color=color, facecolors="none" if v5 and marker == "o" else color, zorder=3 if v5 else 2)
        # where labels go, so that the tasks crowding at K <= 3 all read: v5 on a line (below the crowded K = 2 row,
        # above elsewhere), DMC on the left where d_a = 1, another DMC point sits just right of it or the point is at
        # the right edge, else on the right
        crowded = any(k[1] == y and k[3] == color and d_a < k[0] <= 2 * d_a for k in points)
        left, below = d_a == 1 or crowded or d_a >= 10, y <= 2
        offset = (0, -22 if below else 12) if v5 else (-5 if left else 5, 0)
        b.annotate("\n".join(names), (d_a, y), fontsize=6, xytext=offset, textcoords="offset points",
                   va=("top" if below else "bottom") if v5 else "center", ha="center" if v5 else "right" if left else "left",
                   color="dimgray" if v5 else "black", arrowprops={"arrowstyle": "-", "color": "lightgray"} if v5 else None)
    b.plot([0.8, 40], [0.8, 40], "k:", lw=1, label="K = d_a")
    b.axhline(10, color="tab:red", lw=1, ls="--", label="K = 10 (the paper: 'typically less than ten')")
    b.set_xscale("log"), b.set_yscale("log")
    b.set_xlim(0.25, 60)
    b.set_xlabel("action dimension d_a")
    b.set_ylabel("smallest sufficient K (within 0.1 of flat PPO's gain)")
    b.legend(fontsize=7)
    b.set_title("How few linear controllers suffice? (triangle: a smaller K undecided;\nx: every K tried insufficient; ?: none sufficient, "
                "some undecided; tasks with no answer left out)", fontsize=9)


def plot(rows, path):
    """results/atlas.png: both panels side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(14, 6))
    draw_ratios(a, rows)
    draw_sufficient(b, rows)
    fig.tight_layout()
    fig.savefig(path, dpi=130)


def main():
    rows = []
    for task in sorted(os.listdir(RESULTS)) if os.path.isdir(RESULTS) else []:
        final = os.path.join(RESULTS, task, "final_returns.csv")
        if os.path.exists(final):
            rows += task_rows(final, os.path.join(RESULTS, task, "sufficient_k.csv"), "dmc")
    rows = published(rows) + task_rows(os.path.join(V5, "final_returns.csv"), os.path.join(V5, "sufficient_k.csv"), "v5")
    write_csv(os.path.join(RESULTS, "atlas.csv"), rows)
    with open(os.path.join(RESULTS, "atlas.md"), "w") as f:
        f.write(markdown(rows))
    plot(rows, os.path.join(RESULTS, "atlas.png"))
    print(open(os.path.join(RESULTS, "atlas.csv")).read())


if __name__ == "__main__":
    main()
