"""Tables of experiments/verify/: `.venv/bin/python experiments/verify/summarize.py [--full]` (after run.py).

results/per_controller.csv: one row per verified controller (its verify.json's numbers). results/summary.csv: per
task, mixture K and metric, flat PPO's and the mixture's IQM with 95% stratified-bootstrap CIs and P(mixture > flat PPO)
(rliable, gsa_jax.iqm_ci). results/confound.csv: per task and K, the rank correlation of nominal return and ROA
volume over both classes' controllers, and P(mixture > flat PPO) on the ROA volume left after a linear fit on the
nominal return (pooled over both classes): the comparison at equal nominal score. results/cost.csv: each part's
mean seconds per controller (empty: the task has no such part). results/fixed_points.csv: per task and configuration,
how many controllers hold the equilibrium and have a (stable) closed-loop fixed point. results/summary.md: the three
tables in Markdown. --full: the same of results/full/ (run.py --full), and results/full/budgets.csv: each controller's
worst returns and ROA volume at both budgets.
"""

import argparse
import glob
import json
import os

import numpy as np
import scipy.stats

from gsa_jax import improvement_probability, iqm_ci, write_csv
from run import GROUPS  # this folder's run.py: the groups it verifies

HERE = os.path.dirname(os.path.abspath(__file__))
METRICS = ("nominal_mean", "nominal_p05", "worst_start_law", "worst_twice_the_spread", "worst_with_pushes",
           "roa_volume", "switches_per_second_second_half")


def row(group, doc):
    f = doc["falsification"]
    r = {"task": group, "controller": os.path.basename(doc["controller"]), "policy": doc["kind"], "K": doc["clusters"],
         "nominal_mean": doc["nominal"]["return_mean"], "nominal_p05": doc["nominal"]["return_p05"],
         "worst_start_law": f["start_law"]["worst_return"],
         "worst_twice_the_spread": f["twice_the_spread"]["worst_return"],
         "worst_with_pushes": f["start_law_and_pushes"]["worst_return"],
         "switches_per_second_second_half": doc["switching"]["switches_per_second_second_half"]}
    if "roa" in doc:
        fp = doc["local"]["closed_loop_fixed_point"]
        r.update({"holds": doc["roa"]["hold"]["holds"], "roa_volume": doc["roa"]["volume_fraction"],
                  "fixed_point": fp is not None,
                  "fixed_point_spectral_radius": "" if fp is None else fp["spectral_radius"],
                  "lqr_roa_volume": doc["lqr"].get("roa", {}).get("volume_fraction", "")})
        reach = doc["roa"].get("reach") or []  # the task's units, per tangent coordinate: qpos offsets, then qvel
        nv = len(reach) // 2
        r.update({f"reach_q{i}": x for i, x in enumerate(reach[:nv])} | {f"reach_v{i}": x for i, x in enumerate(reach[nv:])})
    return {**r, **{f"cost_{k}": v for k, v in doc["cost_seconds"].items()}}


def load_rows(base):
    """Every verify.json run.py wrote under base/<group>/ (run.GROUPS only: results/ holds other studies' folders)."""
    rows = []
    for group in sorted(GROUPS):
        for path in sorted(glob.glob(os.path.join(base, group, "*", "verify.json"))):
            with open(path) as f:
                rows.append(row(group, json.load(f)))
    return rows


def compare(task, k, metric, flat, mix):
    x, y = np.asarray(mix, float)[:, None], np.asarray(flat, float)[:, None]
    ci = iqm_ci({"flat": y, "mixture": x})
    p = improvement_probability({"p": (x, y)})["p"]
    return {"task": task, "K": k, "metric": metric, "flat_n": len(flat), "mixture_n": len(mix),
            "flat_iqm": ci["flat"][0], "flat_ci_low": ci["flat"][1], "flat_ci_high": ci["flat"][2],
            "mixture_iqm": ci["mixture"][0], "mixture_ci_low": ci["mixture"][1], "mixture_ci_high": ci["mixture"][2],
            "p_mixture_better": p[0], "p_ci_low": p[1], "p_ci_high": p[2]}


def confound(task, k, rows):
    nominal = np.array([r["nominal_mean"] for r in rows])
    volume = np.array([r["roa_volume"] for r in rows])
    mix = np.array([r["policy"] == "mixture" for r in rows])
    slope, intercept = np.polyfit(nominal, volume, 1)
    resid = volume - (slope * nominal + intercept)
    p = improvement_probability({"p": (resid[mix][:, None], resid[~mix][:, None])})["p"]
    rho = scipy.stats.spearmanr(nominal, volume)[0] if np.ptp(nominal) > 0 and np.ptp(volume) > 0 else float("nan")
    return {"task": task, "K": k, "controllers": len(rows), "spearman_nominal_vs_roa_volume": rho, "fit_slope": slope,
            "p_mixture_better_at_equal_nominal": p[0], "p_ci_low": p[1], "p_ci_high": p[2]}


def fixed_points(rows):
    """Per task x configuration: controllers, those whose closed loop holds the equilibrium, those with a
    closed-loop fixed point (a piece's, where the partition picks that piece) and those with a stable one, and
    the range of those fixed points' spectral radii."""
    out = []
    keys = dict.fromkeys((r["task"], r["policy"], r["K"] if r["policy"] == "mixture" else "") for r in rows if "fixed_point" in r)
    for task, policy, k in keys:
        mine = [r for r in rows if r["task"] == task and r["policy"] == policy and (not k or r["K"] == k) and "fixed_point" in r]
        radii = [float(r["fixed_point_spectral_radius"]) for r in mine if r["fixed_point"]]
        out.append({"task": task, "policy": policy, "K": k, "controllers": len(mine),
                    "holds": sum(bool(r["holds"]) for r in mine), "fixed_point": len(radii),
                    "stable_fixed_point": sum(x < 1 for x in radii),
                    "spectral_radius_min": min(radii, default=""), "spectral_radius_max": max(radii, default="")})
    return out


def budgets(full, quick):
    """Per controller verified at both budgets: each worst return and the ROA volume at --quick's budget and at
    the full one (a larger search finds lower worst cases; a finer one another volume)."""
    by = {r["controller"]: r for r in quick}
    cols = ("nominal_mean", "worst_start_law", "worst_twice_the_spread", "worst_with_pushes", "roa_volume")
    return [{"task": r["task"], "controller": r["controller"], "policy": r["policy"], "K": r["K"],
             **{f"{c}_{b}": row.get(c, "") for c in cols for b, row in (("quick", by[r["controller"]]), ("full", r))}}
            for r in full if r["controller"] in by]


def markdown(summary, confounds, cost) -> str:
    """results/summary.md: the three tables in Markdown."""
    f = lambda x: f"{float(x):.3g}"
    lines = ["| task | K | metric | flat PPO IQM [95% CI] | mixture IQM [95% CI] | P(mixture > flat PPO) [95% CI] |",
             "|---|---|---|---|---|---|"]
    for r in summary:
        lines.append(f"| {r['task']} | {r['K']} | {r['metric']} | {f(r['flat_iqm'])} [{f(r['flat_ci_low'])}, {f(r['flat_ci_high'])}] | "
                     f"{f(r['mixture_iqm'])} [{f(r['mixture_ci_low'])}, {f(r['mixture_ci_high'])}] | "
                     f"{r['p_mixture_better']:.2f} [{r['p_ci_low']:.2f}, {r['p_ci_high']:.2f}] |")
    lines += ["", "| task | K | controllers | Spearman(nominal, ROA volume) | P(mixture > flat PPO) at equal nominal [95% CI] |",
              "|---|---|---|---|---|"]
    for r in confounds:
        lines.append(f"| {r['task']} | {r['K']} | {r['controllers']} | {r['spearman_nominal_vs_roa_volume']:.2f} | "
                     f"{r['p_mixture_better_at_equal_nominal']:.2f} [{r['p_ci_low']:.2f}, {r['p_ci_high']:.2f}] |")
    parts = list(dict.fromkeys(k for r in cost for k in r if k not in ("task", "controllers")))
    lines += ["", "| task | controllers | " + " | ".join(parts) + " |", "|---" * (len(parts) + 2) + "|"]
    for r in cost:
        lines.append(f"| {r['task']} | {r['controllers']} | " + " | ".join(str(r.get(k, "")) for k in parts) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--full", action="store_true", help="the controllers verified at the full budget (results/full/)")
    args = p.parse_args(argv)
    out = os.path.join(HERE, "results", *(("full",) if args.full else ()))
    rows = load_rows(out)
    write_csv(os.path.join(out, "per_controller.csv"), rows)
    summary, confounds, cost = [], [], []
    for task in dict.fromkeys(r["task"] for r in rows):
        mine = [r for r in rows if r["task"] == task]
        for k in sorted({r["K"] for r in mine if r["policy"] == "mixture"}):  # each K against flat PPO
            pair = [r for r in mine if r["policy"] == "mlp" or r["K"] == k]
            for metric in METRICS:
                vals = {p: [r[metric] for r in pair if r["policy"] == p and metric in r] for p in ("mlp", "mixture")}
                if vals["mlp"] and vals["mixture"]:
                    summary.append(compare(task, k, metric, vals["mlp"], vals["mixture"]))
            if all("roa_volume" in r for r in pair):
                confounds.append(confound(task, k, pair))
        parts = [k for k in mine[0] if k.startswith("cost_")]
        cost.append({"task": task, "controllers": len(mine),
                     **{k[5:]: round(float(np.mean([r[k] for r in mine])), 1) for k in parts}})
    write_csv(os.path.join(out, "summary.csv"), summary)
    write_csv(os.path.join(out, "confound.csv"), confounds)
    write_csv(os.path.join(out, "cost.csv"), cost)
    write_csv(os.path.join(out, "fixed_points.csv"), fixed_points(rows))
    if args.full:
        write_csv(os.path.join(out, "budgets.csv"), budgets(rows, load_rows(os.path.join(HERE, "results"))))
    with open(os.path.join(out, "summary.md"), "w") as fh:
        fh.write(markdown(summary, confounds, cost))
    print(f"wrote {out}/per_controller.csv, summary.csv, confound.csv, cost.csv, fixed_points.csv "
          f"{'budgets.csv ' if args.full else ''}({len(rows)} controllers)")


if __name__ == "__main__":
    main()
