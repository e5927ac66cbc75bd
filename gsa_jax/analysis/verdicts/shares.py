"""Exact inference for shares of seeds: how often training reaches a score.

- share_of: x of n seeds reach a score, with the exact (Clopper-Pearson) interval.
- share_p: the exact unconditional test (Chan 1998) of 'share <= reference share - margin', two independent binomial
  samples: the Z ordering of the outcomes, the chance of one at least as extreme maximized over the reference's
  share on the null's boundary. Its level holds for every pair of true shares there, ties at 0 or 1 included, so
  a class whose seeds often fail is not called 'as often' by luck of a few seeds.
- holm: Holm's step-down over named p-values (one error rate for several claims).
"""

import math
from functools import lru_cache
from typing import NamedTuple, Sequence

import numpy as np

NUISANCE_GRID = 401  # reference shares the exact test maximizes over (its endpoints included)


class Share(NamedTuple):
    """How often a class's seeds reach a score: reached of seeds, the share and its exact two-sided interval (each
    side at the level asked)."""

    reached: int
    seeds: int
    share: float
    low: float
    high: float


def share_of(scores: Sequence[float], bar_score: float, level: float = 0.025) -> Share:
    """How many of the seeds' scores [n] reach bar_score, with the exact Clopper-Pearson interval (each side `level`)."""
    from scipy import stats

    scores = np.asarray(scores, np.float64)
    n, x = len(scores), int(np.sum(scores >= bar_score))
    low = 0.0 if x == 0 else float(stats.beta.ppf(level, x, n - x + 1))
    high = 1.0 if x == n else float(stats.beta.isf(level, x + 1, n - x))
    return Share(x, n, x / n if n else math.nan, low, high)


def share_statistic(a: np.ndarray, n_a: int, b: np.ndarray, n_b: int, margin: float) -> np.ndarray:
    """The ordering of outcomes (a of n_a reached, b of n_b): (p_a - p_b + margin) / se with the shares shrunk by
    half a seed, so no outcome has zero error; larger is more evidence that p_a > p_b - margin."""
    pa, pb = (a + 0.5) / (n_a + 1.0), (b + 0.5) / (n_b + 1.0)
    se = np.sqrt(pa * (1 - pa) / n_a + pb * (1 - pb) / n_b)
    return (a / n_a - b / n_b + margin) / se


@lru_cache(maxsize=65536)
def share_p(reached: int, seeds: int, ref_reached: int, ref_seeds: int, margin: float) -> float:
    """Exact unconditional p-value of 'share <= ref share - margin' (Chan 1998): the chance, maximized over the
    reference's share q in [margin, 1] with the share at q - margin, of an outcome at least as extreme (by
    share_statistic) as the one seen. Its level holds for every true pair of shares on that boundary."""
    from scipy import stats

    a, b = np.arange(seeds + 1), np.arange(ref_seeds + 1)
    z = share_statistic(a[:, None], seeds, b[None, :], ref_seeds, margin)
    extreme = z >= share_statistic(np.array(reached), seeds, np.array(ref_reached), ref_seeds, margin) - 1e-12
    q = np.linspace(margin, 1.0, NUISANCE_GRID)
    pa = stats.binom.pmf(a[None, :], seeds, np.clip(q - margin, 0.0, 1.0)[:, None])  # [grid, seeds + 1]
    pb = stats.binom.pmf(b[None, :], ref_seeds, q[:, None])  # [grid, ref_seeds + 1]
    return float(min(1.0, np.max(np.einsum("ga,ab,gb->g", pa, extreme.astype(np.float64), pb))))


def holm(pvalues: dict, alpha: float) -> set:
    """The hypotheses Holm's step-down rejects at family-wise level alpha: {name: p} -> {names rejected}."""
    rejected = set()
    for i, (name, p) in enumerate(sorted(pvalues.items(), key=lambda kv: (kv[1], str(kv[0])))):
        if not p < alpha / (len(pvalues) - i):
            break
        rejected.add(name)
    return rejected
