"""Tune flat PPO and the mixtures with an equal budget: every policy class of a tuning file gets the same
number of configurations drawn from its stated ranges (the first the defaults), trained on the tuning seeds;
the best by IQM of the final deterministic score is trained on the evaluation seeds.

    gsa tune TUNING.toml --out DIR [--phase tune|evaluate|all|rank] [--baseline SWEEP_DIR ...]

(gsa_jax.running.tuning says what a tuning file holds.) Per class under DIR/<class>/: tuning.toml and the
tuning sweep (tuning/), selection.csv (every configuration's tuning scores, best first), evaluation.toml and
its sweep (evaluation/). DIR/tuning.csv: per class the chosen configuration, its evaluation IQM [95% CI] and
P(beats the flat PPO class) [CI]; with --baseline (sweep directories holding the same env, policy and K at
the defaults on the evaluation seeds, e.g. Figure 1's) the defaults' IQM and P next to them. Each sweep is
gsa sweep's (resumable: run the same command again); a phase already done is not run twice.

--phase rank (after tune) checks that short tuning runs rank configurations as full-length ones would: per
class the configurations at --rank-check's ranks are trained on the tuning seeds for the evaluation's env
steps (DIR/<class>/ranking/); DIR/<class>/ranking.csv gives each one's short and full-length tuning IQM, and
DIR/ranking.csv per class their Spearman correlation and whether the short tuning's best is still the best.
"""

import argparse
import json
import os

import numpy as np

from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.analysis.sweeps import stats
from gsa_jax.analysis.sweeps.results import Cell, final_scores, load_sweep, load_sweeps, read_csv, write_csv
from gsa_jax.commands.command_line import command_parser
from gsa_jax.errors import run_command
from gsa_jax.running.spec import SpecError
from gsa_jax.running.tuning import TuningSpec, class_experiment, draw_configurations, load_tuning, to_toml


def select(scores: dict, sets: list, seeds: list) -> list:
    """selection.csv rows, best first: per configuration its knobs, its runs' final scores on the tuning seeds
    and their IQM; a configuration with a failed (non-finite) run ranks last. scores: {set index: [scores]}."""
    rows = []
    for i, s in enumerate(sets):
        got = np.asarray(scores.get(i, []), float)
        ok = len(got) == len(seeds) and np.isfinite(got).all()
        rows.append({"hparam_set": i, **s, "tuning_runs": len(got), "tuning_iqm": round(stats.iqm(got[:, None]), 3) if ok else "",
                     "tuning_scores": " ".join(f"{v:.1f}" for v in got)})
    rows.sort(key=lambda r: (r["tuning_iqm"] == "", -(r["tuning_iqm"] or 0.0), r["hparam_set"]))
    for rank, r in enumerate(rows, 1):
        r["rank"] = rank
    return rows


def run_phase(spec: TuningSpec, cls: str, phase: str, sets: list, out: str, sweep_args: list) -> int:
    """Write DIR/<class>/<phase>.toml and run its sweep into DIR/<class>/<phase>/ -> gsa sweep's status."""
    from gsa_jax.commands import sweep

    cdir = os.path.join(out, cls)
    os.makedirs(cdir, exist_ok=True)
    path = os.path.join(cdir, f"{phase}.toml")
    what = "every configuration on the tuning seeds" if phase == "tuning" else "the chosen configuration on the evaluation seeds"
    with open(path, "w") as f:
        f.write(to_toml(class_experiment(spec, cls, phase, sets), f"{spec.name}, class {cls}: {what} (written by gsa tune)"))
    return sweep.main([path, "--out", os.path.join(cdir, phase), *sweep_args])


def cell_scores(sweep_dir: str) -> dict:
    """{hparam_set (int, or None without sets): [final scores in seed order]} of a one-cell-per-set sweep."""
    out = {}
    for cell, (scores, _) in final_scores(load_sweep(sweep_dir)).items():
        cols = dict(cell.settings)
        out[int(cols["hparam_set"]) if "hparam_set" in cols else None] = list(scores)
    return out


def choose(spec: TuningSpec, cls: str, out: str) -> tuple:
    """selection.csv of a class's finished tuning sweep -> the chosen configuration {knob: value}."""
    sets = draw_configurations(spec, cls)
    rows = select(cell_scores(os.path.join(out, cls, "tuning")), sets, spec.tuning_seeds)
    write_csv(os.path.join(out, cls, "selection.csv"), rows)
    if rows[0]["tuning_iqm"] == "":
        raise SpecError(f"class {cls}: no configuration finished every tuning run with a finite score")
    return {k: rows[0][k] for k in sets[0]}, rows[0]["hparam_set"]


def baseline_scores(dirs: list, env_name: str, classes: tuple) -> dict:
    """{class: [scores]} of the default configuration of each class in Figure-1 style sweeps (cells without
    swept columns), {} without dirs."""
    if not dirs:
        return {}
    scores = final_scores(load_sweeps(dirs))
    return {cls: list(scores[Cell(env_name, c["policy"], c["K"])][0]) for cls, c in classes.items()
            if Cell(env_name, c["policy"], c["K"]) in scores}


def report(spec: TuningSpec, out: str, chosen: dict, baseline: dict, reps: int = stats.REPS) -> list:
    """DIR/tuning.csv rows: per class the chosen set, evaluation IQM [CI], P(> the flat class) [CI], and the
    defaults' (baseline) IQM [CI] and P where given."""
    evaluated = {cls: np.asarray(cell_scores(os.path.join(out, cls, "evaluation"))[None], float) for cls in chosen}
    flat = next((c for c in spec.classes if spec.classes[c]["policy"] == MLP), None)
    iqm = stats.iqm_ci({c: v[:, None] for c, v in evaluated.items()}, reps=reps)
    base = stats.iqm_ci({c: np.asarray(v, float)[:, None] for c, v in baseline.items()}, reps=reps) if baseline else {}
    pairs = lambda d: {c: (np.asarray(d[c], float)[:, None], np.asarray(d[flat], float)[:, None])  # noqa: E731
                       for c in d if c != flat and flat in d}
    p_tuned = stats.improvement_probability(pairs(evaluated), reps=reps) if flat in evaluated else {}
    p_base = stats.improvement_probability(pairs(baseline), reps=reps) if flat in baseline else {}
    r1 = lambda t, i: round(t[i], 3) if t else ""  # noqa: E731
    rows = []
    for cls, (knobs, index) in chosen.items():
        c = spec.classes[cls]
        rows.append({"env": spec.env, "class": cls, "policy": c["policy"], "K": c["K"] if c["policy"] == MIXTURE else "",
                     "chosen_set": index, "chosen": json.dumps(knobs), "runs": len(evaluated[cls]),
                     "tuned_iqm": r1(iqm[cls], 0), "tuned_ci_low": r1(iqm[cls], 1), "tuned_ci_high": r1(iqm[cls], 2),
                     "p_tuned_above_flat": r1(p_tuned.get(cls), 0), "p_tuned_ci_low": r1(p_tuned.get(cls), 1),
                     "p_tuned_ci_high": r1(p_tuned.get(cls), 2), "default_iqm": r1(base.get(cls), 0),
                     "default_ci_low": r1(base.get(cls), 1), "default_ci_high": r1(base.get(cls), 2),
                     "p_default_above_flat": r1(p_base.get(cls), 0), "p_default_ci_low": r1(p_base.get(cls), 1),
                     "p_default_ci_high": r1(p_base.get(cls), 2)})
    write_csv(os.path.join(out, "tuning.csv"), rows)
    return rows


def rank_check(spec: TuningSpec, cls: str, out: str, ranks: list, sweep_args: list) -> tuple:
    """Train the class's configurations at `ranks` (1-based ranks of its selection.csv) on the tuning seeds for
    the evaluation's env steps -> (the sweep's status, DIR/<class>/ranking.csv rows)."""
    selection = read_csv(os.path.join(out, cls, "selection.csv"))
    if not selection:
        raise SpecError(f"class {cls}: no {os.path.join(out, cls, 'selection.csv')}: run --phase tune first")
    knobs = list(draw_configurations(spec, cls)[0])
    picked = [selection[r - 1] for r in ranks if r <= len(selection)]
    status = run_phase(spec, cls, "ranking", [{k: float(r[k]) for k in knobs} for r in picked], out, sweep_args)
    if status:
        return status, []
    long = cell_scores(os.path.join(out, cls, "ranking"))
    rows = [{"rank": int(r["rank"]), "hparam_set": int(r["hparam_set"]), "tuning_iqm": r["tuning_iqm"],
             "long_iqm": round(stats.iqm(np.asarray(long[i], float)[:, None]), 3),
             "long_scores": " ".join(f"{v:.1f}" for v in long[i])} for i, r in enumerate(picked)]
    write_csv(os.path.join(out, cls, "ranking.csv"), rows)
    return 0, rows


def rank_summary(cls: str, rows: list, spec: TuningSpec) -> dict:
    """DIR/ranking.csv's row of one class: Spearman's rho of short vs full-length tuning IQM over the checked
    configurations, and whether the short tuning's best is the full-length best among them."""
    from scipy.stats import spearmanr

    short = np.array([float(r["tuning_iqm"]) if r["tuning_iqm"] != "" else -np.inf for r in rows])
    long = np.array([r["long_iqm"] for r in rows])
    return {"env": spec.env, "class": cls, "configurations": len(rows), "ranks": " ".join(str(r["rank"]) for r in rows),
            "short_steps": spec.tuning_steps, "long_steps": spec.evaluation_steps,
            "spearman": round(float(spearmanr(short, long).statistic), 3),
            "best_stays_best": int(np.argmax(long) == np.argmax(short))}


def run_rank_checks(spec: TuningSpec, args: argparse.Namespace) -> int:
    """--phase rank: every class's rank check, then DIR/ranking.csv."""
    ranks = [int(r) for r in args.rank_check.split(",")]
    summary = []
    for cls in spec.classes:
        status, rows = rank_check(spec, cls, args.out, ranks, args.sweep_args.split())
        if status:
            return status
        summary.append(rank_summary(cls, rows, spec))
        print(f"{spec.env} {cls}: Spearman {summary[-1]['spearman']} over ranks {summary[-1]['ranks']}", flush=True)
    write_csv(os.path.join(args.out, "ranking.csv"), summary)
    print(f"wrote {os.path.join(args.out, 'ranking.csv')}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """`gsa tune`'s options."""
    p = command_parser("tune", __doc__)
    p.add_argument("tuning", help="tuning file (TOML; gsa_jax.running.tuning)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--phase", choices=("tune", "evaluate", "all", "rank"), default="all",
                   help="tune: the tuning sweeps and selection only; evaluate: the chosen configurations (after tune); "
                        "rank: do the tuning runs rank configurations as full-length runs would (after tune); "
                        "all: tune, then evaluate (default %(default)s)")
    p.add_argument("--rank-check", default="1,2,12,24", help="with --phase rank: the ranks checked (default %(default)s)")
    p.add_argument("--baseline", nargs="*", default=[],
                   help="sweep directories with the defaults on the evaluation seeds (default: none)")
    p.add_argument("--reps", type=int, default=stats.REPS, help="bootstrap resamples (default %(default)s)")
    p.add_argument("--sweep-args", default="--no-tensorboard", help="flags passed to each gsa sweep (default %(default)s)")
    return p


def tune(argv: list | None) -> int:
    """Run the phases --phase asks for. Returns the exit status (a sweep's that did not finish)."""
    args = build_parser().parse_args(argv)
    spec = load_tuning(args.tuning)
    for d in args.baseline:
        if not os.path.isdir(d):
            raise SpecError(f"--baseline {d!r} is not a directory")
    if args.phase == "rank":
        try:
            return run_rank_checks(spec, args)
        except ValueError as e:
            raise SpecError(e) from None
    return run_tuning(spec, args)


def run_tuning(spec: TuningSpec, args: argparse.Namespace) -> int:
    """The phases in order, stopping at the first sweep that does not finish (its status)."""
    sweep_args = args.sweep_args.split()
    chosen = {}
    try:
        for cls in spec.classes:
            if args.phase in ("tune", "all"):
                status = run_phase(spec, cls, "tuning", draw_configurations(spec, cls), args.out, sweep_args)
                if status:
                    return status
            chosen[cls] = choose(spec, cls, args.out)
            print(f"{spec.name}, class {cls}: chose configuration {chosen[cls][1]}: {chosen[cls][0]}", flush=True)
        if args.phase == "tune":
            return 0
        for cls, (knobs, _) in chosen.items():
            status = run_phase(spec, cls, "evaluation", [knobs], args.out, sweep_args)
            if status:
                return status
        rows = report(spec, args.out, chosen, baseline_scores(args.baseline, spec.env, spec.classes), args.reps)
    except (FileNotFoundError, KeyError) as e:
        raise SpecError(e) from None
    for r in rows:
        print(f"{r['env']} {r['class']}: tuned IQM {r['tuned_iqm']} [{r['tuned_ci_low']}, {r['tuned_ci_high']}]"
              + (f", defaults {r['default_iqm']}" if r["default_iqm"] != "" else ""))
    print(f"wrote {os.path.join(args.out, 'tuning.csv')}")
    return 0


def main(argv: list | None = None) -> int:
    """`gsa tune`: exit status 0, 2 on bad input, else the status of the sweep that did not finish."""
    return run_command("tune", lambda: tune(argv))
