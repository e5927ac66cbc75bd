"""Does adding seeds until decided keep the verdict's error rate? `.venv/bin/python experiments/verdicts/optional_stopping.py`

Simulates cells whose true gap is exactly -delta (delta = 0.1: the mixture's IQM keeps exactly 90% of flat PPO's gain
over a random policy at 0) under three seed distributions (normal; bimodal, as when some seeds fail to learn;
right-skewed), and judges each with gsa_jax.analysis.verdict.judge under three designs: one look at 10 seeds; looks at
5, 10, 20, 40 seeds with Bonferroni-adjusted intervals (what gsa_jax.answer does); the same looks with unadjusted 95%
intervals (what naive optional stopping would do). Writes results/optional_stopping.csv: the share of trials that
call the cell sufficient (the error the design must keep at or below 5%), insufficient, undecided, and the mean
seeds per cell used.
"""

import os

import numpy as np

from gsa_jax.analysis import verdict
from gsa_jax.analysis.results import write_csv

HERE = os.path.dirname(os.path.abspath(__file__))
MARGIN, TRIALS = 0.1, 2000


def normal(rng, n):
    return 1.0 + 0.3 * rng.standard_normal(n)


def bimodal(rng, n):
    return 1.0 + np.where(rng.random(n) < 0.5, -0.3, 0.3) + 0.05 * rng.standard_normal(n)


def skewed(rng, n):  # mean 1, median below it: the IQM of the law is computed numerically below
    return 0.6 + 0.4 * rng.exponential(1.0, n)


def law_iqm(draw, rng):
    """The IQM of a law, from a large sample (what 'the true IQM' of a cell is)."""
    return float(verdict.iqm(draw(rng, 2_000_000)))


def simulate(draw, looks, adjusted, seed=0):
    """(share sufficient, insufficient, undecided, mean seeds) of TRIALS cells with true gap exactly -MARGIN."""
    rng = np.random.default_rng(seed)
    shift = MARGIN * law_iqm(draw, np.random.default_rng(99))  # random policy at 0: the gain is the law's IQM
    counts, seeds = {verdict.SUFFICIENT: 0, verdict.INSUFFICIENT: 0, verdict.UNDECIDED: 0}, 0
    for t in range(TRIALS):
        flat, mix = draw(rng, looks[-1]), draw(rng, looks[-1]) - shift
        v, used = verdict.UNDECIDED, looks[-1]
        for i, n in enumerate(looks):
            v = verdict.judge(mix[:n], flat[:n], 0.0, MARGIN, len(looks) if adjusted else 1, reps=1000, seed=t * 10 + i).verdict
            if v != verdict.UNDECIDED:
                used = n
                break
        counts[v] += 1
        seeds += used
    return [counts[k] / TRIALS for k in (verdict.SUFFICIENT, verdict.INSUFFICIENT, verdict.UNDECIDED)] + [seeds / TRIALS]


def main():
    rows = []
    designs = [("one look at 10 seeds", (10,), True), ("looks 5-10-20-40 with Bonferroni (gsa_jax.answer)", (5, 10, 20, 40), True),
               ("looks 5-10-20-40 unadjusted 95%", (5, 10, 20, 40), False)]
    for name, draw in (("normal", normal), ("bimodal", bimodal), ("skewed", skewed)):
        for design, looks, adjusted in designs:
            suff, insuff, und, seeds = simulate(draw, looks, adjusted)
            rows.append({"distribution": name, "design": design, "trials": TRIALS, "true_gap": -MARGIN, "margin": MARGIN,
                         "called_sufficient": round(suff, 4), "called_insufficient": round(insuff, 4),
                         "undecided": round(und, 4), "mean_seeds_per_cell": round(seeds, 2)})
            print(rows[-1], flush=True)
    os.makedirs(os.path.join(HERE, "results"), exist_ok=True)
    write_csv(os.path.join(HERE, "results", "optional_stopping.csv"), rows)


if __name__ == "__main__":
    main()
