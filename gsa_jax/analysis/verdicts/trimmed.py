"""Inference for interquartile means without resampling: Yuen's trimmed-mean t (Yuen 1974; Wilcox, "Introduction to
Robust Estimation and Hypothesis Testing", ch. 5) for a linear contrast of several groups.

A group's interquartile mean (IQM: rliable's aggregate_iqm for one task, gsa_jax.analysis.sweeps.stats.iqm) is its
25% trimmed mean: the mean of the sorted values g .. n - g - 1, g = int(n / 4). Its squared standard error is Yuen's (n - 1) s_w^2 / (h (h - 1)), with
s_w^2 the variance of the winsorized sample (the g lowest values set to the (g+1)-th, the g highest to the (n-g)-th)
and h = n - 2 g the values the mean keeps. A contrast sum_j c_j T_j of independent groups gets the Welch-Satterthwaite
degrees of freedom (sum c_j^2 d_j)^2 / sum (c_j^2 d_j)^2 / (h_j - 1). For two groups and c = (1, -1) this is
scipy.stats.ttest_ind(trim=0.25, equal_var=False) (tests/test_verdict.py checks it). A plain mean (g = 0: the random
policy's episodes) and a fixed value with a known standard error (a published score) enter the same way.

Everything here is a deterministic function of the scores: a verdict built on it does not depend on a resampling seed.
"""

import math
from typing import NamedTuple, Sequence

import numpy as np

TRIM = 0.25  # the interquartile mean


class Summary(NamedTuple):
    """One group as a contrast sees it: its estimate, the estimate's squared standard error, the degrees of freedom
    of that error (inf: known exactly) and the number of values (0 for a fixed value)."""

    mean: float
    var: float
    df: float
    n: int


def trimmed(values: Sequence[float], trim: float = TRIM) -> Summary:
    """The trimmed mean of values [n] with Yuen's squared standard error; var is inf below two kept values (nothing
    can be said of its error). The mean is scipy.stats.trim_mean(values, trim), which rliable's aggregate_iqm calls:
    at trim 0.25 it is gsa_jax.analysis.sweeps.stats.iqm(values) to the bit (tests/test_verdict.py)."""
    from scipy import stats

    values = np.asarray(values, np.float64)
    n = len(values)
    if n == 0:
        raise ValueError("a group needs at least one value")
    g = int(trim * n)
    h = n - 2 * g
    mean = float(stats.trim_mean(values, trim))
    x = np.sort(values)
    if h < 2:
        return Summary(mean, math.inf, 1.0, n)
    w = x.copy()
    w[:g], w[n - g:] = x[g], x[n - g - 1]
    var = float((n - 1) * w.var(ddof=1) / (h * (h - 1)))
    return Summary(mean, var, float(h - 1), n)


def plain(values: Sequence[float]) -> Summary:
    """The ordinary mean of values [n] with its squared standard error s^2 / n (n - 1 degrees of freedom)."""
    return trimmed(values, trim=0.0)


def fixed(value: float, std: float = 0.0, seeds: int = 0) -> Summary:
    """A published mean: its standard error from the std over its seeds (std ddof 0 as openrlbenchmark reports it:
    the squared error is std^2 / (seeds - 1)); exact (no error) where the seeds or the std are not given."""
    if seeds >= 2 and std > 0:
        return Summary(float(value), float(std) ** 2 / (seeds - 1), float(seeds - 1), int(seeds))
    return Summary(float(value), 0.0, math.inf, 0)


class Contrast(NamedTuple):
    """sum c_j mean_j, its standard error and Welch-Satterthwaite degrees of freedom."""

    estimate: float
    se: float
    df: float


def contrast(parts: Sequence[tuple]) -> Contrast:
    """The contrast of [(coefficient, Summary), ...] of independent groups."""
    estimate = sum(c * s.mean for c, s in parts)
    terms = [(c * c * s.var, s.df) for c, s in parts if c != 0 and s.var > 0]
    var = sum(v for v, _ in terms)
    if not terms:
        return Contrast(float(estimate), 0.0, math.inf)
    if not math.isfinite(var):
        return Contrast(float(estimate), math.inf, 1.0)
    denom = sum(v * v / df for v, df in terms if math.isfinite(df))
    df = var * var / denom if denom > 0 else math.inf
    return Contrast(float(estimate), math.sqrt(var), float(df))


def p_above(c: Contrast) -> float:
    """One-sided p-value of 'the contrast is <= 0' (small: shown above 0)."""
    from scipy import special

    if c.se == 0:
        return 0.0 if c.estimate > 0 else 1.0
    if not math.isfinite(c.se):
        return 1.0
    t = c.estimate / c.se
    return float(special.ndtr(-t) if not math.isfinite(c.df) else special.stdtr(c.df, -t))


def p_below(c: Contrast) -> float:
    """One-sided p-value of 'the contrast is >= 0' (small: shown below 0)."""
    return p_above(Contrast(-c.estimate, c.se, c.df))


def t_quantile(p: float, df: float) -> float:
    """The upper p-quantile of Student's t with df degrees of freedom (the normal's where df is infinite)."""
    from scipy import stats

    return float(stats.norm.isf(p) if not math.isfinite(df) else stats.t.isf(p, df))
