"""The report of `gsa answer`: the answer in one sentence, the baseline's standing (still learning? below
a published or tuned PPO?), the verdicts with the seeds each interval used and the look that froze it, flat PPO's
IQM, the seeds per cell for 80% power, other margins as sensitivity (not the answer), score against K with the
margin drawn, the rounds, the command, and the chosen controller exported (npz, C header, ONNX) and re-scored on
fresh start states."""

import glob
import math
import os
import warnings
from typing import Any

import numpy as np

from gsa_jax.algorithm.kinds import MLP
from gsa_jax.analysis.sweeps import columns as C
from gsa_jax.analysis.sweeps import controller_scores, stats
from gsa_jax.analysis.sweeps.results import write_csv
from gsa_jax.analysis.verdicts import ladder, sequential, step_budget, trimmed, verdict
from gsa_jax.deployment import starts
from gsa_jax.analysis.verdicts.answering import FLAT, Evidence, Setup, percent, reference_of, trained_steps
from gsa_jax.running.checkpoint import write_atomic


def rounded(x: float | None, digits: int = 4) -> float | str:
    return "" if x is None or (isinstance(x, float) and not math.isfinite(x)) else round(float(x), digits)


def answer_rows(setup: Setup, state: dict) -> list:
    """The answer's rows: per K its record as the sequential design left it (the look that decided or last judged it,
    the seeds of the mixture and of the reference its interval used, the level, Holm's share)."""
    rows = []
    for k in setup.ladder:
        r = state["judged"].get(str(k), {})
        if "look" not in r:
            rows.append({"role": "answer", "K": k, "margin": setup.margin, "verdict": r.get("verdict", "untrained"),
                         "why": r.get("why", "")})
            continue
        decided = r["verdict"] in ladder.DECIDED
        rows.append({"role": "answer", "K": k, "margin": setup.margin, "verdict": r["verdict"],
                     "look": f"{r['look'] + 1} of {len(setup.looks)}", "frozen": "yes" if decided else "no",
                     "seeds": r["seeds"], "reference_seeds": r["reference_seeds"] or "fixed",
                     "gap": rounded(r["gap"]), "gap_low": rounded(r["low"]), "gap_high": rounded(r["high"]),
                     "level": rounded(r["level"], 8), "share": rounded(r["share"], 6),
                     "p_sufficient": rounded(r["p_sufficient"], 8), "p_insufficient": rounded(r["p_insufficient"], 8),
                     "p_failure_share": rounded(r.get("p_share"), 8),
                     "seeds_80pct_power_parity": "" if decided or r["seeds_parity"] is None else r["seeds_parity"],
                     "seeds_80pct_power_observed": "" if decided or r["seeds_observed"] is None else r["seeds_observed"],
                     "chance_decided_by_cap": "" if decided else rounded(r.get("chance_by_cap"))})
    return rows


def sensitivity_rows(setup: Setup, evidence: Evidence, state: dict) -> list:
    """Other margins, each K judged once on all the seeds it has against all of the reference's, at the level of a
    single look holding alpha / K: a sensitivity analysis, not the answer (the seeds were added for its margin)."""
    base = state.get("baseline")
    if not base or not base["learned"]:
        return []
    values = evidence.scores if base["metric"] == C.CONTROLLER_SCORE else evidence.last100
    reference = reference_of(setup, evidence, base)
    level = setup.alpha / len(setup.ladder)
    rows = []
    for m in sorted(set(verdict.MARGINS) - {setup.margin}):
        for k in setup.ladder:
            cell = values.get(k, {})
            if len(cell) < 2:
                continue
            g = verdict.judge(ladder.first_seeds(cell, len(cell)), reference, state["random"]["returns"], m, level)
            rows.append({"role": "sensitivity (not the answer)", "K": k, "margin": m, "verdict": g.verdict,
                         "seeds": g.n, "reference_seeds": g.n_ref or "fixed", "gap": rounded(g.point),
                         "gap_low": rounded(g.low), "gap_high": rounded(g.high), "level": rounded(level, 8)})
    return rows


def iqm_interval(values: list) -> tuple:
    """(IQM, 95% interval) of a cell's values by Yuen's trimmed-mean t (what the verdicts use)."""
    s = trimmed.trimmed(values)
    if not math.isfinite(s.var) or s.var == 0:
        return s.mean, s.mean, s.mean
    half = trimmed.t_quantile(0.025, s.df) * math.sqrt(s.var)
    return s.mean, s.mean - half, s.mean + half


def plot_answer(setup: Setup, scores: dict, random_mean: float, path: str) -> None:
    """Score against K: every seed's controller score, each cell's IQM with its 95% interval, flat PPO's IQM (or the
    target) and the margin the mixtures must be shown above (dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ks = [k for k in setup.ladder if scores.get(k)]
    for i, k in enumerate(ks):
        x = np.array([scores[k][s] for s in sorted(scores[k])])
        mid, lo, hi = iqm_interval(x)
        ax.scatter(np.full(len(x), i) + rng.uniform(-0.12, 0.12, len(x)), x, s=10, color="tab:blue", alpha=0.5)
        ax.errorbar(i, mid, yerr=[[mid - lo], [hi - mid]], fmt="o", color="tab:blue", capsize=4,
                    label="mixture: IQM (95% CI), dots = seeds" if i == 0 else None)
    flat_tick = setup.target is None and bool(scores.get(FLAT))
    if flat_tick:
        flat = np.array([scores[FLAT][s] for s in sorted(scores[FLAT])])
        ref = stats.iqm(flat)
        ax.scatter(np.full(len(flat), -1) + rng.uniform(-0.12, 0.12, len(flat)), flat, s=10, color="k", alpha=0.5)
        ax.axhline(ref, color="k", lw=1.5, label=f"flat PPO IQM ({len(flat)} seeds; dots at the left)")
    else:
        ref = float(setup.target)
        ax.axhline(ref, color="k", lw=1.5, label=f"target {ref:g}")
    ax.axhline(ref - setup.margin * (ref - random_mean), color="tab:red", ls="--",
               label=f"margin: {setup.margin:g} of the gain over a random policy ({random_mean:.0f})")
    ax.set_xticks(([-1] if flat_tick else []) + list(range(len(ks))), (["flat PPO"] if flat_tick else []) + [str(k) for k in ks])
    ax.set(xlabel="K (linear controllers)", ylabel="controller score (MuJoCo C, fixed starts)", title=setup.env)
    save_figure(fig, ax, path)


def save_figure(fig: "Any", ax: "Any", path: str) -> None:
    """The report's figures' finish (a matplotlib Figure and its Axes): grid, legend, written at 110 dpi, closed."""
    import matplotlib.pyplot as plt

    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def class_curves(runs: dict) -> tuple:
    """(env_steps [T], the seeds' training returns [seeds, T]) of one class's {seed: (env_steps, returns)}: the seeds
    with the most common curve length (those trained to the answer's step budget)."""
    lengths = [len(steps) for steps, _ in runs.values()]
    common = max(set(lengths), key=lengths.count)
    picked = [runs[s] for s in sorted(runs) if len(runs[s][0]) == common]
    return np.asarray(picked[0][0], float), np.array([np.asarray(r, float) for _, r in picked])


def plot_learning(setup: Setup, training: dict, random_mean: float, path: str) -> None:
    """Every class's learning curve: the median over seeds of the stochastic policy's training episode return
    against env steps, the interquartile range shaded (flat PPO in black, the K in colour), the random policy dotted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    cells = ([FLAT] if training.get(FLAT) else []) + [k for k in setup.ladder if training.get(k)]
    ks = [cell for cell in cells if cell != FLAT]
    colours = dict(zip(ks, plt.get_cmap("viridis")(np.linspace(0.0, 0.85, max(len(ks), 1)))))
    for cell in cells:
        steps, returns = class_curves(training[cell])
        colour = "k" if cell == FLAT else colours[cell]
        with warnings.catch_warnings():  # a point before any seed finished an episode is NaN: a gap in the curve
            warnings.simplefilter("ignore", RuntimeWarning)
            q1, mid, q3 = np.nanpercentile(returns, [25, 50, 75], axis=0)
        label = f"{'flat PPO' if cell == FLAT else f'K = {cell}'} ({len(returns)} seeds)"
        ax.plot(steps, mid, color=colour, lw=1.5, label=label)
        ax.fill_between(steps, q1, q3, color=colour, alpha=0.15, lw=0)
    ax.axhline(random_mean, color="grey", ls=":", lw=1, label="random policy")
    ax.set(xlabel="env steps", ylabel="training episode return (median, IQR over seeds)", title=setup.env)
    save_figure(fig, ax, path)


def export_choice(out: str, results_root: list, env: str, k: int, scores: dict) -> dict | None:
    """The chosen K's best-scoring seed's controller written as out/controller/controller.{npz,h,onnx} and re-scored
    on FRESH_EPISODES fresh start states (not those it was picked on) -> {seed, score, fresh, source, files}; None
    where its file is not found."""
    from gsa_jax.deployment.exporting import load_arrays, write
    from gsa_jax.running.trained import path_part

    seed = min(scores[k], key=lambda s: (-scores[k][s], s))  # the best, ties to the lower seed (constructive.exhibit)
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
    fresh = controller_scores.score_controller(files[0], controller_scores.FRESH_EPISODES, controller_scores.FRESH_START_SEED)
    return {"seed": seed, "score": scores[k][seed], "fresh": fresh, "source": hits[0], "files": files}


def table_text(rows: list, flat: tuple | None) -> str:
    """The answer's rows as a markdown table, flat PPO's IQM (95% interval) first where it is the reference."""
    lines = ["| K | verdict | look (frozen?) | seeds: mixture (reference) | gap [interval at the look's level] | level | "
             "seeds per cell for 80% power: at parity, at the observed gap | chance the seed cap decides it |",
             "|---|---|---|---|---|---|---|---|"]
    if flat is not None:
        lines.append(f"| flat PPO | IQM {flat[0]:.1f} [{flat[1]:.1f}, {flat[2]:.1f}] (95%) |  | {flat[3]} |  |  |  |  |")
    for r in rows:
        if "look" not in r or r["gap"] == "":
            lines.append(f"| {r['K']} | {r['verdict']} {r.get('why', '')} |  |  |  |  |  |  |")
            continue
        undecided = r["verdict"] == verdict.UNDECIDED
        power = f"{r['seeds_80pct_power_parity'] or '-'}, {r['seeds_80pct_power_observed'] or '-'}" if undecided else ""
        chance = r.get("chance_decided_by_cap", "")
        chance = percent(chance) if undecided and chance != "" else ""
        lines.append(f"| {r['K']} | **{r['verdict']}** | {r['look']} ({'frozen' if r['frozen'] == 'yes' else 'open'}) | "
                     f"{r['seeds']} ({r['reference_seeds']}) | {r['gap']:+.3f} [{r['gap_low']:+.3f}, {r['gap_high']:+.3f}] | "
                     f"{r['level']:.2g} | {power} | {chance} |")
    return "\n".join(lines)


def sensitivity_text(rows: list) -> str:
    lines = ["| margin | K | verdict | seeds (reference) | gap [interval] |", "|---|---|---|---|---|"]
    lines += [f"| {r['margin']:g} | {r['K']} | {r['verdict']} | {r['seeds']} ({r['reference_seeds']}) | "
              f"{r['gap']:+.3f} [{r['gap_low']:+.3f}, {r['gap_high']:+.3f}] |" for r in rows if r["gap"] != ""]
    return "\n".join(lines)


def rounds_text(state: dict) -> tuple:
    """(markdown table of the step budget's sweeps and the rounds: what each trained and how long it took, the share of
    the wall time spent compiling or loading programs)."""
    lines = ["| round | trained | seconds | compiling or loading programs (seconds, slowest worker per sweep) |",
             "|---|---|---|---|"]
    total = compile_s = 0.0
    rows = [("step budget", f"flat PPO at {c['steps']:,} steps: seeds 0-{c['sweep']['runs'] - 1}", [c["sweep"]])
            for c in state.get("steps", {}).get("calibration", [])]
    for r in state["rounds"]:
        what = "; ".join(f"{'flat PPO' if p == MLP else 'K = ' + ', '.join(map(str, ks))}: seeds {seeds[0]}-{seeds[-1]}"
                         for p, (ks, seeds) in r["plan"].items())
        rows.append((r["round"], what, list(r["sweeps"].values())))
    for label, what, sweeps in rows:
        secs = sum(s["seconds"] for s in sweeps)
        comp = sum(s["compile_wall_s"] for s in sweeps)
        total, compile_s = total + secs, compile_s + comp
        lines.append(f"| {label} | {what} | {secs:.0f} | {comp:.0f} s |")
    return "\n".join(lines), (compile_s / total if total else float("nan"))


def still_learning(state: dict) -> list:
    """The K whose training return still rose over the last fifth of the budget (answering.mixtures_learning)."""
    return sorted((int(k) for k, r in (state.get("mixture_learning") or {}).items() if not r["stopped"]))


def learning_text(setup: Setup, state: dict) -> list:
    """Per K the still-learning test on its training curves, and what it means for its verdict."""
    records = state.get("mixture_learning") or {}
    if not records:
        return []
    lines = [f"The mixtures at the step budget ({trained_steps(setup, state):,}), by the test flat PPO's budget was "
             "chosen with, on their training curves (the stochastic policy's episode returns; on the scale of flat "
             "PPO's gain over the random policy):", ""]
    for k, r in sorted(records.items(), key=lambda kv: int(kv[0])):
        word = "stopped learning" if r["stopped"] else "**still learning**: a longer budget may change its verdict"
        lines.append(f"- K = {k}: last fifth's gain {r['gain']:+.3f} (upper bound {r['upper']:+.3f}): {word}.")
    return lines + [""]


def step_budget_text(setup: Setup, state: dict) -> list:
    """The step budget section: the budget every run trained, and how it was chosen."""
    steps = state.get("steps") or {}
    budget = trained_steps(setup, state)
    if steps.get("mode") != "auto":
        return [f"- Every run trained {budget:,} env steps (fixed: --steps, --target or the committed runs' settings)."]
    tried = steps.get("candidates") or step_budget.candidates(setup.steps())
    lines = [f"- Every run trained **{budget:,} env steps**: {budget_how(steps, budget, tried)} (of "
             f"{', '.join(f'{c:,}' for c in tried)}; gsa_jax.analysis.verdicts.step_budget)."]
    records = steps.get("calibration", [])
    for i, c in enumerate(records):
        learn = c["learning"]
        gain = (f"last fifth's gain {learn['gain']:+.3f} of the gain over random (bounds {learn.get('lower', math.nan):+.3f}, "
                f"{learn['upper']:+.3f}): {'stopped' if c['stopped'] else 'still learning'}"
                if learn["gain"] == learn["gain"] else "no gain over random to judge learning on")
        lines.append(f"- At {c['steps']:,}: {'learned' if c['learned'] else 'not learned (' + c['why'] + ')'}; {gain}"
                     f"{confirms_words(c, records[i - 1] if i else None)}.")
    return lines


def budget_how(steps: dict, budget: int, tried: list) -> str:
    """How the step budget was chosen: confirmed by the next budget's controllers (after the curve's two-sided test,
    or shown within the margin by them), at the cap, or where the time budget stopped the search (the chosen budget
    unconfirmed where it was enough)."""
    records = steps.get("calibration", [])
    at = next((i for i, c in enumerate(records) if int(c["steps"]) == budget), None)
    chosen = records[at] if at is not None else None
    enough = bool(chosen and chosen["enough"])
    if steps.get("limited"):
        return (f"the largest budget tried before {steps['limited']} stopped the search"
                + (" (learned and stopped, **not confirmed** by the controllers at the next budget)" if enough else ""))
    later = records[at + 1] if at is not None and at + 1 < len(records) else None
    if later is not None and step_budget.chosen_by(chosen, later) and budget < int(tried[-1]):
        if enough:
            return ("the first budget at which flat PPO's first-look seeds, trained to it, had learned the task and "
                    "stopped learning, confirmed by their controllers trained to the next budget")
        return ("the first budget at which flat PPO's first-look seeds, trained to it, had learned the task, their "
                "curve was shown not falling, and their controllers trained to the next budget were shown within the "
                "margin above them (training longer is shown not to help by the margin)")
    if enough:
        return "the cap (--max-steps), at which flat PPO's first-look seeds had learned the task and stopped learning"
    return "the cap (--max-steps): flat PPO's first-look seeds had not both learned the task and stopped learning below it"


def confirms_words(record: dict, before: dict | None = None) -> str:
    """'; its controllers' IQM +0.012 of the budget before's gain (p 0.41; shown within the margin: p 0.003): confirm
    it' for a record judged after a budget that could be chosen (before: that budget's record)."""
    c = record.get("confirms")
    if not c:
        return ""
    if not c["confirmed"]:
        word = "shown above it by more than the margin: it is not chosen"
    elif before is None or step_budget.chosen_by(before, record):
        word = "confirm it"
    else:
        word = "not shown within the margin above it, and its curve was not shown stopped: it is not chosen"
    within = "" if "p_within" not in c else (f"; shown within the margin: p {c['p_within']:.3g}" if c["shown_within"]
                                             else f"; not shown within the margin: p {c['p_within']:.3g}")
    return (f"; its controllers' IQM {c['gain']:+.3f} of the budget before's gain over random (p {c['p']:.3g}{within}): "
            f"{word}")


def falling_text(learn: dict, margin: float) -> list:
    """A warning line where flat PPO is shown to have fallen over the last fifth (the gain's upper bound below
    -margin): the still-learning test reads that as stopped, but a falling curve is not shown converged."""
    if not learn["upper"] < -margin:
        return []
    return [f"- **Flat PPO fell back over the last fifth** (upper bound {learn['upper']:+.3f}, below -{margin:g}): 'stopped' "
            "here means not rising, not converged; the runs may be unstable at this budget, and flat PPO is shown "
            "adequate only as far as it reaches the task's references."]


def longer_words(state: dict, budget: int) -> str:
    """What training longer gives where flat PPO's curve still rose at the budget: its controllers at the next budget
    where the step budget read them and showed them within the margin, else that a longer --steps may move the answer."""
    records = (state.get("steps") or {}).get("calibration", [])
    at = next((i for i, c in enumerate(records) if int(c["steps"]) == budget), None)
    later = records[at + 1] if at is not None and at + 1 < len(records) else None
    c = (later or {}).get("confirms") or {}
    if not c.get("shown_within"):
        return "; a longer --steps may move the answer"
    return (f"; but its controllers trained to {int(later['steps']):,} steps score {c['gain']:+.3f} of that gain more, "
            f"shown within the margin (p {c['p_within']:.3g}): training longer is shown not to help by the margin")


def baseline_text(setup: Setup, state: dict) -> list:
    """The baseline section: what the verdicts judge against and why; still learning; the references that apply."""
    base, rand = state.get("baseline"), state["random"]
    r = trimmed.plain(rand["returns"])
    half = trimmed.t_quantile(0.025, r.df) * math.sqrt(r.var)
    lines = [f"- Random policy: {r.mean:.2f} ± {half:.2f} (95%; {rand['episodes']} episodes in MuJoCo C from seed "
             f"{rand['start_seed']}), in every test with its own uncertainty."]
    if not base:
        return lines + ["- No look reached: the baseline was not judged."]
    if not base["learned"]:
        lines.append(f"- **No answer**: {base['why']}.")
    lines.append(f"- The verdicts judge against **{base['versus']}** (metric: {base['metric']}).")
    learn = base.get("learning")
    if learn:
        state_word = "has stopped learning" if learn["stopped"] else "**is not shown to have stopped learning**"
        low = learn.get("lower")
        interval = (f"90% interval [{low:+.3f}, {learn['upper']:+.3f}]; stopped when inside ±{setup.margin:g}"
                    if low is not None and low == low else f"one-sided 95% upper bound {learn['upper']:+.3f}")
        lines.append(f"- Flat PPO {state_word} at {trained_steps(setup, state):,} steps: the last fifth of training gained "
                     f"{learn['gain']:+.3f} of its gain over the random policy (IQM over {learn['seeds']} seeds, each end "
                     f"averaging up to three evaluations; {interval})"
                     + ("" if learn["stopped"] else longer_words(state, trained_steps(setup, state))) + ".")
        lines += falling_text(learn, setup.margin)
    for s in base.get("standings", []):
        shown = "**shown below**" if s["below"] else "not shown below"
        p = "" if s.get("p_below") is None else f", p = {s['p_below']:.2g}"
        lines.append(f"- Reference {s['algorithm']} on {s['published_task']} at {s['steps']:,} steps ({s['metric']}, "
                     f"{s['seeds'] or '?'} seeds): {s['score']:g}; flat PPO {s['ours']:g} on that metric, "
                     f"{s['ratio']:.2f} of its gain over the random policy: {shown} 1 - margin of it (one-sided "
                     f"5%{p}). Source: {s['source']}.")
    if setup.target is None and not base.get("standings"):
        lines.append("- No published or tuned PPO score is known for this task at this budget: the verdicts rest on this "
                     "flat PPO alone.")
    return lines


def design_text(setup: Setup) -> list:
    d = setup.design()
    levels = sequential.look_levels(d, d.alpha / len(setup.ladder))
    return [f"- Gap of a cell: (IQM(mixture) - IQM(reference)) / (IQM(reference) - random return); Yuen's trimmed-mean "
            f"t for the contrast, no resampling (the verdict does not depend on a seed). Margin {setup.margin:g}.",
            f"- Looks at {', '.join(map(str, d.looks))} seeds per cell, {d.spending} alpha-spending of {d.alpha:.1%}, "
            f"{d.multiplicity} over the {len(setup.ladder)} K: the answer names a K that is not within the margin at most "
            f"{verdict.ALPHA:.1%} of the time over all K and looks (simulated: experiments/verdicts/error_rates.py; "
            "exact for the default design only). Per-look levels of a K holding alpha / K: "
            + ", ".join(f"{v:.2g}" for v in levels) + "; a K shown sufficient passes its share on (Holm).",
            "- A decided cell is frozen at its look; seeds are added only to the undecided K below the smallest "
            "sufficient K (and to flat PPO)" + (f", and not to one whose chance to be decided by the seed cap, if its gap "
            f"is what it looks, is below {percent(setup.futility)} (futility: it never decides a K, and a stopped K keeps "
            "its share of the error, so the rate stated holds)."
            if setup.futility > 0 else ".")]


def write_report(out: str, setup: Setup, state: dict, evidence: Evidence, sentence: str, choice: dict | None,
                 commands: tuple, versions: dict) -> str:
    """out/report.md (and verdicts.csv, score_vs_k.png, learning_curves.png) -> its path. commands: (the command that
    reproduces it, the next commands to run where it is not decided)."""
    command, steps = commands
    rows, sens = answer_rows(setup, state), sensitivity_rows(setup, evidence, state)
    random_mean = float(np.mean(state["random"]["returns"]))
    plot_answer(setup, evidence.scores, random_mean, os.path.join(out, "score_vs_k.png"))
    if evidence.training:
        plot_learning(setup, evidence.training, random_mean, os.path.join(out, "learning_curves.png"))
    write_csv(os.path.join(out, "verdicts.csv"), rows + sens)
    flat = evidence.scores.get(FLAT, {})
    flat_row = (*iqm_interval(list(flat.values())), len(flat)) if setup.target is None and len(flat) >= 2 else None
    rounds, share = rounds_text(state)
    lines = [f"# How many linear controllers does {setup.env} need?", "", f"**{sentence}**", ""]
    lines += constructive_text(state.get("constructive"))
    lines += [
             f"Stopped: {state['stopped']}. Scores are the committed controllers' deterministic returns in MuJoCo C from "
             f"{starts.describe(controller_scores.START_SEED, controller_scores.EPISODES)} "
             "(controller_scores.csv beside each controllers/ folder).", "", "## Step budget", ""]
    lines += step_budget_text(setup, state) + ["", "## Baseline", ""] + baseline_text(setup, state)
    lines += ["", "## Design", ""] + design_text(setup) + ["", "![score against K](score_vs_k.png)", "", "## Verdicts", "",
                                                           table_text(rows, flat_row), ""]
    if evidence.training:
        lines += ["![learning curves per class](learning_curves.png)", ""]
    lines += learning_text(setup, state)
    if sens:
        lines += ["## Other margins (sensitivity, not the answer)", "",
                  "Each K judged once on all its seeds at a single look's level (alpha / K): how the answer would read at "
                  "another margin, not a second answer (the seeds were added for the answer's margin).", "",
                  sensitivity_text(sens), ""]
    lines += ["## Rounds", "", rounds if state["rounds"] else "No round trained: every cell was judged on the runs of "
              "--start-from.", ""]
    if state["rounds"] and share == share:
        lines += [f"Compiling or loading programs: {share:.0%} of the sweeps' wall time (each sweep's slowest worker; every "
                  "sweep of a class runs one program, compiled once and loaded after).", ""]
    lines += choice_text(out, choice) + (["## Next", "", *(f"    {step}" for step in steps), ""] if steps else [])
    lines += ["## Reproduce", "", f"    {command}", "",
                                         "Versions: " + ", ".join(f"{k} {v}" for k, v in versions.items()), ""]
    path = os.path.join(out, "report.md")
    write_atomic(path, "\n".join(lines))
    return path


def signed(x: float | None) -> str:
    """'+0.012', or 'unbounded' for a bound answer.json keeps as null (an infinite interval end)."""
    return "unbounded" if x is None else f"{x:+.3f}"


def class_row(cls: str, r: dict, bar_is_flat: bool) -> str:
    """One class of the constructive answer as a table row."""
    gap = "no scale" if r["gap"] is None else f"{r['gap']:+.3f} [{signed(r['low'])}, {signed(r['high'])}]"
    flat = cls == FLAT
    judged = ("the bar" if bar_is_flat else "") if flat else r["verdict"]
    p = "" if r["share_p"] is None else format(r["share_p"], ".3g")
    return (f"| {'flat PPO' if flat else f'K = {cls}'} | {r['seed']} | {r['selection']:.1f} | {r['fresh']:.1f} "
            f"({r['episodes']}) | {gap} | {judged} | {r['reached']} of {r['seeds']} ({r['share']:.2f} "
            f"[{r['share_low']:.2f}, {r['share_high']:.2f}]) | {p} | {r['share_verdict'] or ''} |")


def constructive_text(c: dict | None) -> list:
    """The constructive answer's section: its sentence, how it is judged, and a row per class."""
    if not c:
        return []
    last = c["fresh_start_seed"] + c["exhibit_episodes"] - 1
    head = ["| class | exhibited seed | selection | fresh (episodes) | gap [interval] | verdict | seeds reaching "
            f"{c['threshold']:.1f} [exact interval] | share test p | share verdict |", "|" + "---|" * 9]
    rows = [class_row(cls, r, c["bar"].startswith("the best flat")) for cls, r in c["classes"].items()]
    return ["## The constructive answer", "", f"**{c['sentence']}**", "",
            f"Each class's best run on the selection starts is exhibited; only its score on {c['exhibit_episodes']} fresh "
            f"starts (seeds {c['fresh_start_seed']}-{last}, the same for every class: paired) is reported. The bar is "
            f"{c['bar']} ({c['bar_score']:.1f}); a K suffices by construction when its exhibited controller is shown "
            f"within {c['margin']:.0%} of the bar's gain over the random policy ({c['random_mean']:.1f}). A seed reaches "
            f"when its controller's mean over the first {c['share_episodes']} fresh starts is at least "
            f"{c['threshold']:.1f}; 'as often' is the exact test that K's share is not more than {c['margin']:.0%} "
            "below flat PPO's. Every exhibit and share test shares one error rate (Holm's step-down at 2.5%). "
            f"Search: {c['search']}.", "", *head, *rows, ""]


def choice_text(out: str, choice: dict | None) -> list:
    if not choice:
        return []
    fresh = choice["fresh"]
    return ["## The chosen controller", "",
            f"K = {choice.get('K')}, seed {choice['seed']}: the best of its seeds on "
            f"{starts.describe(controller_scores.START_SEED, controller_scores.EPISODES)} ({choice['score']:.1f}); "
            f"on {starts.describe(fresh['start_seed'], fresh['episodes'])} it scores {fresh['controller_score']:.1f} "
            f"(episode std {fresh['episode_std']:.1f}): the fresh score is what to expect, the selection score carries "
            f"the best-of-seeds pick. From `{choice['source']}`: "
            + ", ".join(f"`{os.path.relpath(f, out)}`" for f in choice["files"]), "",
            f"Re-score it: `gsa deploy {os.path.join(out, 'controller', 'controller.npz')} "
            f"--episodes {fresh['episodes']} --start-seed {fresh['start_seed']}`", "", *verify_lines(out, choice)]


def verify_lines(out: str, choice: dict) -> list:
    """Where gsa verify checked the exported controller's closed loop at the task's equilibrium (verify.json's fixed
    points, region of attraction and worst starts), and how to certify it."""
    where = choice.get("verify")
    if not where:
        return []
    npz = os.path.join(out, "controller", "controller.npz")
    return [f"Its closed loop at the task's equilibrium (`gsa verify --quick`): `{os.path.relpath(where, out)}/report.md` "
            f"(fixed points, region of attraction, the worst starts found). A certified region of attraction: "
            f"`gsa verify {npz} --certify`.", ""]
