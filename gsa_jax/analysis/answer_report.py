"""The report of `python -m gsa_jax.answer`: the answer in one sentence, the verdict table at the answer's margin and
at verdict.MARGINS, score against K with the margin drawn, the seeds each cell got, the command that reproduces
it, and the chosen controller exported (npz, C header, ONNX)."""

import glob
import os

import numpy as np

from gsa_jax.algorithm.kinds import MLP
from gsa_jax.analysis import verdict
from gsa_jax.analysis.answering import Setup
from gsa_jax.analysis.controller_scores import EPISODES, START_SEED
from gsa_jax.analysis.results import write_csv
from gsa_jax.running.checkpoint import write_atomic


def margin_verdicts(setup: Setup, scores: dict, random_return: float, frozen: dict, flat_key: str = "flat") -> list:
    """Rows per K and margin: the answer's margin takes the sequential design's (frozen) verdicts; the other
    margins are judged once on all the seeds the answer trained, at the same per-look level."""
    flat = None if setup.target is not None else [scores[flat_key][s] for s in sorted(scores.get(flat_key, {}))]
    rows = []
    for m in sorted(set(verdict.MARGINS) | {setup.margin}):
        for k in setup.ladder:
            mix = [scores[k][s] for s in sorted(scores.get(k, {}))]
            if m == setup.margin and str(k) in frozen:
                r = frozen[str(k)]
                g = verdict.Gap(r["gap"], r["low"], r["high"], r["verdict"], m, r["level"], r["n"], r["seeds_to_decide"])
            elif len(mix) < 2 or (flat is not None and len(flat) < 2):
                continue
            else:
                g = verdict.judge(mix, flat, random_return, m, len(setup.looks), setup.target)
            rows.append({"K": k, "margin": m, "answer_margin": int(m == setup.margin), "seeds": len(mix),
                         "reference_seeds": len(flat) if flat else "", "iqm": round(float(verdict.iqm(mix)), 2) if mix else "",
                         "gap": round(g.point, 4), "gap_low": round(g.low, 4), "gap_high": round(g.high, 4),
                         "level": round(g.level, 4), "verdict": g.verdict,
                         "seeds_to_decide": "" if g.seeds_to_decide is None else g.seeds_to_decide})
    return rows


def plot_answer(setup: Setup, scores: dict, random_return: float, path: str, flat_key: str = "flat") -> None:
    """Score against K: every seed's controller score, each cell's IQM with its 95% bootstrap interval, flat PPO's
    IQM (or the target) and the margin the mixtures must be shown above (dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ks = [k for k in setup.ladder if scores.get(k)]
    for i, k in enumerate(ks):
        x = np.array([scores[k][s] for s in sorted(scores[k])])
        lo, hi = np.quantile(verdict.resampled_iqms(x, 2000, rng), [0.025, 0.975])
        ax.scatter(np.full(len(x), i) + rng.uniform(-0.12, 0.12, len(x)), x, s=10, color="tab:blue", alpha=0.5)
        ax.errorbar(i, verdict.iqm(x), yerr=[[verdict.iqm(x) - lo], [hi - verdict.iqm(x)]], fmt="o", color="tab:blue",
                    capsize=4, label="mixture: IQM (95% CI), dots = seeds" if i == 0 else None)
    if setup.target is None and scores.get(flat_key):
        flat = np.array([scores[flat_key][s] for s in sorted(scores[flat_key])])
        ref = float(verdict.iqm(flat))
        ax.scatter(np.full(len(flat), -1) + rng.uniform(-0.12, 0.12, len(flat)), flat, s=10, color="k", alpha=0.5)
        ax.axhline(ref, color="k", lw=1.5, label=f"flat PPO IQM ({len(flat)} seeds; dots at the left)")
    else:
        ref = float(setup.target)
        ax.axhline(ref, color="k", lw=1.5, label=f"target {ref:g}")
    ax.axhline(ref - setup.margin * (ref - random_return), color="tab:red", ls="--",
               label=f"margin: {setup.margin:g} of the gain over a random policy ({random_return:.0f})")
    flat_tick = setup.target is None and bool(scores.get(flat_key))
    ax.set_xticks(([-1] if flat_tick else []) + list(range(len(ks))), (["flat PPO"] if flat_tick else []) + [str(k) for k in ks])
    ax.set(xlabel="K (linear controllers)", ylabel="controller score (MuJoCo C, fixed starts)", title=setup.env)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def export_choice(out: str, results_root: list, env: str, k: int, scores: dict) -> dict | None:
    """The chosen K's best-scoring seed's controller written as out/controller/controller.{npz,h,onnx} ->
    {seed, score, files}; None where its file is not found."""
    from gsa_jax.deployment.exporting import load_arrays, write
    from gsa_jax.running.trained import path_part

    seed = max(scores[k], key=lambda s: scores[k][s])
    label = f"{path_part(env)}-mixture-K{k}-s{seed}.npz"
    hits = [p for root in results_root for p in glob.glob(os.path.join(root, "**", "controllers", label), recursive=True)]
    if not hits:
        return None
    arrays = load_arrays(hits[0])
    os.makedirs(os.path.join(out, "controller"), exist_ok=True)
    files = []
    for fmt, suffix in (("npz", ".npz"), ("c", ".h"), ("onnx", ".onnx")):
        path = os.path.join(out, "controller", "controller" + suffix)
        try:
            write(arrays, fmt, path)
            files.append(path)
        except ImportError:  # ONNX needs the deploy extra
            continue
    return {"seed": seed, "score": scores[k][seed], "source": hits[0], "files": files}


def table_text(rows: list) -> str:
    """The verdict rows as a markdown table (K, margin, seeds, IQM, gap [interval], verdict, seeds likely to decide)."""
    lines = ["| K | margin | seeds (flat PPO) | IQM | gap [interval] | verdict | seeds per cell likely to decide |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        bold = "**" if r["answer_margin"] else ""
        lines.append(f"| {r['K']} | {bold}{r['margin']:g}{bold} | {r['seeds']} ({r['reference_seeds']}) | {r['iqm']} | "
                     f"{r['gap']:+.3f} [{r['gap_low']:+.3f}, {r['gap_high']:+.3f}] | {bold}{r['verdict']}{bold} | "
                     f"{r['seeds_to_decide'] if r['verdict'] == verdict.UNDECIDED else ''} |")
    return "\n".join(lines)


def rounds_text(state: dict) -> tuple:
    """(markdown table of the rounds: what each trained and how long it took, compile share of the whole)."""
    lines = ["| round | trained | seconds | of it compiling or loading programs |", "|---|---|---|---|"]
    total = compile_s = 0.0
    for r in state["rounds"]:
        what = "; ".join(f"{'flat PPO' if p == MLP else 'K = ' + ', '.join(map(str, ks))}: seeds {seeds[0]}-{seeds[-1]}"
                         for p, (ks, seeds) in r["plan"].items())
        secs = sum(s["seconds"] for s in r["sweeps"].values())
        comp = sum(s["compile_s"] for s in r["sweeps"].values())
        total, compile_s = total + secs, compile_s + comp
        lines.append(f"| {r['round']} | {what} | {secs:.0f} | {comp:.0f} s |")
    return "\n".join(lines), (compile_s / total if total else float("nan"))


def write_report(out: str, setup: Setup, state: dict, scores: dict, rows: list, sentence: str, choice: dict | None,
                 command: str, versions: dict) -> str:
    """out/report.md (and verdicts.csv, score_vs_k.png) -> its path."""
    plot_answer(setup, scores, state["random_return"], os.path.join(out, "score_vs_k.png"))
    write_csv(os.path.join(out, "verdicts.csv"), rows)
    rounds, share = rounds_text(state)
    if not state["rounds"]:
        rounds, share = "No round trained: every cell was judged on the runs of --start-from.", None
    versus = "flat PPO" if setup.target is None else f"the target score {setup.target:g}"
    seeds = ", ".join(f"{'flat PPO' if k == 'flat' else 'K = ' + str(k)}: {len(v)}" for k, v in scores.items())
    lines = [f"# How many linear controllers does {setup.env} need?", "", f"**{sentence}**", "",
             f"Stopped: {state['stopped']}. Scores are the committed controllers' deterministic returns in MuJoCo C from "
             "fixed start states (controller_scores.csv beside each controllers/ folder).", "",
             "## Design", "",
             f"- Gap of a cell: (IQM(mixture) - IQM({versus})) / (IQM({versus}) - random return), random return "
             f"{state['random_return']:.2f}; stratified bootstrap interval; margin {setup.margin:g} "
             f"(sufficient: interval above -{setup.margin:g}; insufficient: below).",
             f"- Looks at {', '.join(map(str, setup.looks))} seeds per cell; each look's interval has level "
             f"{verdict.look_level(len(setup.looks)):.4f} (Bonferroni over {len(setup.looks)} looks: at most 2.5% chance "
             "of calling sufficient a cell whose true gap is the margin); a decided cell is frozen; seeds are added "
             "only to undecided cells below the smallest sufficient K (and to flat PPO).",
             f"- Seeds per cell: {seeds}.", "",
             f"![score against K](score_vs_k.png)", "", "## Verdicts", "",
             table_text(rows), "",
             "Other margins are judged once on the same seeds (the seeds were added for the answer's margin, bold).", "",
             "## Rounds", "", rounds, ""]
    if share is not None:
        lines += [f"Compiling or loading programs: {share:.0%} of the training time.", ""]
    if choice:
        lines += ["## The chosen controller", "",
                  f"K = {choice.get('K')}, seed {choice['seed']} (the best of its seeds: {choice['score']:.1f}), from "
                  f"`{choice['source']}`: " + ", ".join(f"`{os.path.relpath(f, out)}`" for f in choice["files"]), "",
                  f"Re-score it: `python -m gsa_jax.deploy {os.path.join(out, 'controller', 'controller.npz')} "
                  f"--episodes {EPISODES} --seed {START_SEED}`", ""]
    lines += ["## Reproduce", "", f"    {command}", "",
              "Versions: " + ", ".join(f"{k} {v}" for k, v in versions.items()), ""]
    path = os.path.join(out, "report.md")
    write_atomic(path, "\n".join(lines))
    return path

