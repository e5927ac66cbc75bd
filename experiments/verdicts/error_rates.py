"""The answer's error rate and power, simulated through gsa_jax.answer's own decisions:
`.venv/bin/python experiments/verdicts/error_rates.py [--trials N] [--only error|power]`.

Each trial draws every cell's seeds (flat PPO and K = 1, 2, 4, up to the last look) and 128 random-policy episodes from
known laws, then runs gsa_jax.analysis.verdicts.answering.decide round by round exactly as the answer loop does (the first
look for every cell, then seeds only for the undecided K below the smallest sufficient one, and for flat PPO), until
it stops. A cell's true gap is set by shifting flat PPO's law by gap x its IQM (the random policy's law has mean 0, so
the scale is flat PPO's IQM). Laws of the seeds: normal (coefficient of variation 0.3, the issue's realistic spread),
bimodal (half the seeds 0.6 apart, tight modes), right-skewed (exponential), and 'some fail' (a fifth of the seeds at
a fifth of the return); and laws where the mixtures' seeds follow another law than flat PPO's (PAIRS): three times
flat PPO's spread, failing on 29% of seeds (at the random policy's return; the others so high that the mean gap is
the margin, or three times it, while the IQM gap is above it), ties at the ceiling with 30% failing (IQM gap exactly
the margin), and near-ties at the ceiling a margin apart. A K is not sufficient under any of them: its IQM gap is at
the margin, or its seeds fail more often than flat PPO's by more than verdict.SHARE_MARGIN.

- error rows: every K exactly at the margin (gap -0.1): the share of trials in which the answer calls some K
  sufficient (the error the design must keep at or below 2.5%), per law and design;
- power rows: scenarios with a truly sufficient K (at parity, a little above, or clearly above) beside insufficient
  ones, monotone in K or not:
  the share of trials whose answer is the smallest truly sufficient K, any false 'sufficient', and the seeds used.

Designs: looks 10-20-40 with each spending function (O'Brien-Fleming-type, Pocock-type, Bonferroni over looks) under
Holm over the K, and Pocock-type spending with Bonferroni or no correction over the K; each spends the default 2%.
Writes results/error_rates.csv. `--futility P` stops adding seeds to an undecided K whose chance to be decided by
the seed cap is below P, as `gsa answer --futility` does (the answer's default is verdict.FUTILITY; here the default
0 keeps results/error_rates.csv the table of the design without it): `--futility 0 --designs pocock:holm --out
results/futility.csv` and `--futility 0.1` with the same --out compare the two on the same draws.
"""

import argparse
import os

import numpy as np

from gsa_jax.analysis.sweeps import stats
from gsa_jax import read_csv, write_csv
from gsa_jax.analysis.verdicts import answering, sequential, verdict

HERE = os.path.dirname(os.path.abspath(__file__))
MARGIN, LOOKS, LADDER = 0.1, (10, 20, 40), (1, 2, 4)


def normal(rng, n):
    return 1.0 + 0.3 * rng.standard_normal(n)


def bimodal(rng, n):
    return 1.0 + np.where(rng.random(n) < 0.5, -0.3, 0.3) + 0.05 * rng.standard_normal(n)


def skewed(rng, n):
    return 0.6 + 0.4 * rng.exponential(1.0, n)


def some_fail(rng, n):
    return np.where(rng.random(n) < 0.2, 0.2 + 0.05 * rng.standard_normal(n), 1.0 + 0.1 * rng.standard_normal(n))


LAWS = {"normal": normal, "bimodal": bimodal, "skewed": skewed, "some_fail": some_fail}


# laws where the mixtures' seeds follow another law than flat PPO's (every K at the margin; the random policy at 0):
# {name: (flat PPO's draw, a mixture's draw)}. A seed "fails" below half of flat PPO's gain (verdict.FAIL_GAIN).
def tight(rng, n):
    return 1.0 + 0.02 * rng.standard_normal(n)


def failing(fail, gap):
    """A mixture failing (at 0) on `fail` of its seeds, its others so high that its mean gap is `gap`."""
    high = (1.0 + gap) / (1.0 - fail)
    return lambda rng, n: np.where(rng.random(n) < fail, 0.0, high) + 0.02 * rng.standard_normal(n)


PAIRS = {
    "spread_3x": (lambda rng, n: 1.0 + 0.1 * rng.standard_normal(n), lambda rng, n: 0.9 + 0.3 * rng.standard_normal(n)),
    "failing_mixture": (tight, failing(0.29, -MARGIN)),  # its IQM gap above 0; 29% of seeds fail, flat PPO's none
    "failing_mixture_3x_gap": (tight, failing(0.29, -3 * MARGIN)),
    "ties_failing": (lambda rng, n: np.ones(n), lambda rng, n: np.where(rng.random(n) < 0.3, 0.0, 1.0)),  # IQM gap -0.1
    "near_ties": (lambda rng, n: 1.0 - np.abs(0.001 * rng.standard_normal(n)),
                  lambda rng, n: 0.9 - np.abs(0.001 * rng.standard_normal(n))),  # at the ceiling, a margin apart
}
SCENARIOS = {  # true gap per K
    "every K at the margin": {1: -0.1, 2: -0.1, 4: -0.1},
    "K = 2 at parity": {1: -0.5, 2: 0.0, 4: 0.0},
    "K = 2 above (+0.1)": {1: -0.5, 2: 0.1, 4: 0.1},
    "K = 2 at parity; K = 4 below": {1: -0.5, 2: 0.0, 4: -0.3},
    "K = 1 at parity; K = 4 fails": {1: 0.0, 2: 0.0, 4: -0.5},
    "clear: K = 2 well above": {1: -0.5, 2: 0.3, 4: 0.3},
}
DESIGNS = [("pocock", "holm"), ("obf", "holm"), ("bonferroni", "holm"), ("pocock", "bonferroni"), ("pocock", "none")]


def law_iqm(draw) -> float:
    return stats.iqm(draw(np.random.default_rng(99), 2_000_000))


def draw_cells(law: str, gaps: dict, rng, n: int, scale: float) -> dict:
    """Every cell's seeds [n]: flat PPO's law shifted by gap x scale per K, or a PAIRS law's two draws."""
    if law in PAIRS:
        flat, mix = PAIRS[law]
        return {answering.FLAT: flat(rng, n), **{k: mix(rng, n) for k in gaps}}
    draw = LAWS[law]
    return {answering.FLAT: draw(rng, n), **{k: draw(rng, n) + g * scale for k, g in gaps.items()}}


def run_trial(setup, cells: dict, random_returns: np.ndarray) -> tuple:
    """(final records, seeds used) of one simulated answer: cells {FLAT or K: scores [last look]}."""
    have = {key: setup.looks[0] for key in cells}
    state = {"records": {}, "random": {"returns": list(random_returns)}, "rounds": []}
    while True:
        evidence = answering.Evidence({key: dict(enumerate(v[: have[key]])) for key, v in cells.items()}, {}, {})
        records, plan, stop = answering.decide(setup, evidence, state)
        if stop:
            return records, sum(have.values())
        for policy, (ks, seeds) in plan.items():
            for key in (ks if ks else [answering.FLAT]):
                assert seeds[0] == have[key], f"round plans seeds {seeds[0]}.. for {key} holding {have[key]}"
                have[key] = seeds[-1] + 1


def simulate(law: str, gaps: dict, spending: str, multiplicity: str, trials: int, seed: int, references: str,
             alpha: float = sequential.DESIGN_ALPHA, futility: float = 0.0) -> dict:
    """One row: the share of trials whose answer is the smallest truly sufficient K, calls some truly insufficient K
    (gap <= -margin) sufficient, and the mean seeds trained (all cells)."""
    rng = np.random.default_rng(seed)
    scale = 1.0 if law in PAIRS else law_iqm(LAWS[law])
    spec = {"steps": 1_000_000, "hparams": {}, "config": {}}
    setup = answering.Setup("simulated", LADDER, MARGIN, LOOKS, {"mlp": spec, "mixture": spec}, spending=spending,
                            multiplicity=multiplicity, references=references, alpha=alpha,
                            futility=futility)
    truth = min([k for k, g in gaps.items() if g > -MARGIN + 1e-12], default=None)
    correct = wrong = seeds = 0
    for _ in range(trials):
        cells = draw_cells(law, gaps, rng, LOOKS[-1], scale)
        records, used = run_trial(setup, cells, 0.05 * scale * rng.standard_normal(128))
        verdicts = {int(k): r["verdict"] for k, r in records.items()}
        chosen, _ = verdict.smallest_sufficient(verdicts)
        correct += chosen == truth
        wrong += any(v == verdict.SUFFICIENT and gaps[k] <= -MARGIN + 1e-12 for k, v in verdicts.items())
        seeds += used
    return {"law": law, "spending": spending, "multiplicity": multiplicity, "alpha": alpha,
            **({"futility": futility} if futility else {}), "trials": trials,
            "answer_is_truth": round(correct / trials, 4), "some_K_wrongly_sufficient": round(wrong / trials, 4),
            "mean_seeds_all_cells": round(seeds / trials, 1)}


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=2000, help="trials per error row (power rows: a third as many)")
    p.add_argument("--only", choices=("error", "power"), default=None)
    p.add_argument("--designs", default=None, help="spending:multiplicity pairs, e.g. pocock:holm,obf:holm (default all)")
    p.add_argument("--laws", default=None, help="laws of the seeds, e.g. normal,bimodal (default all)")
    p.add_argument("--scenario", default=None, help="only this scenario (default all)")
    p.add_argument("--alpha", type=float, default=sequential.DESIGN_ALPHA, help="the error each design spends")
    p.add_argument("--futility", type=float, default=0.0,
                   help="the answer's futility threshold (gsa answer --futility; default 0: none)")
    p.add_argument("--out", default=os.path.join(HERE, "results", "error_rates.csv"))
    args = p.parse_args()
    references = args.out + ".no_references.csv"
    with open(references, "w") as f:
        f.write("task,published_task,score,std,seeds,steps,metric,algorithm,source,note\n")
    partial = args.only or args.designs or args.laws or args.scenario
    rows = [r for r in read_csv(args.out) if partial]  # a partial run keeps the others
    for r in rows:
        r["alpha"] = r.get("alpha") or sequential.DESIGN_ALPHA
    for i, (scenario, gaps) in enumerate(SCENARIOS.items()):
        kind = "error" if scenario == "every K at the margin" else "power"
        if (args.only and kind != args.only) or (args.scenario and scenario != args.scenario):
            continue
        laws = list(LAWS) + list(PAIRS) if kind == "error" else ("normal",)
        designs = [tuple(d.split(":")) for d in args.designs.split(",")] if args.designs else DESIGNS
        for law in [w for w in laws if not args.laws or w in args.laws.split(",")]:
            for spending, multiplicity in designs:
                if kind == "power" and multiplicity == "none":
                    continue
                trials = args.trials if kind == "error" else args.trials // 3
                row = {"scenario": scenario, "kind": kind,
                       **simulate(law, gaps, spending, multiplicity, trials, 1000 * i + 7, references, args.alpha,
                                   args.futility)}
                key = lambda r: (r["scenario"], r["law"], r["spending"], r["multiplicity"],  # noqa: E731
                                 float(r.get("alpha") or sequential.DESIGN_ALPHA), float(r.get("futility") or 0.0))
                rows = [r for r in rows if key(r) != key(row)] + [row]
                print(row, flush=True)
                write_csv(args.out, rows)
    os.remove(references)


if __name__ == "__main__":
    main()
