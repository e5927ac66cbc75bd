"""Statistics over runs with rliable (Agarwal et al., "Deep RL at the edge of the statistical precipice"):
IQM with stratified bootstrap confidence intervals, probability of improvement, performance profiles.
Plain NumPy in, plain NumPy out; gsa_jax.plot draws and tabulates them. The package's one IQM (iqm) and one
stratified bootstrap (bootstrap); robustness.paired.crossed_interval resamples the push events that all controllers
share as well, which a bootstrap stratified by configuration cannot.

A run's final score is the mean deterministic return of its last FINAL_EVALUATIONS scheduled evaluations
(gsa_jax.running.metrics; an evaluation's failed episodes count up to their last finite step, gsa_jax.algorithm.episodes);
runs of a sweep without evaluations fall back to the mean training return over the last 10% of
iterations (final_score says which).
"""

import contextlib
import math
import warnings
from typing import Callable, Iterator

import numpy as np

from gsa_jax.running.metrics import FINAL_EVALUATIONS

REPS = 2000  # bootstrap resamples of the tables' intervals
LAST_EPISODES = 100  # a run's training score as published PPO tables give it: its last 100 episodes
CURVE_REPS = 300  # ... of learning-curve bands (one interval per plotted point: rliable takes ~0.5 ms a resample)
# two-sided 95% Student t quantiles by degrees of freedom (1..30); beyond, 1.96
_T95 = [12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
        2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042]


def t95(n: int) -> float:
    """The two-sided 95% t quantile for a mean over n values."""
    return _T95[n - 2] if 2 <= n <= 31 else 1.96


def final_score(eval_returns: np.ndarray, train_returns: np.ndarray, scheduled: np.ndarray | None = None) -> tuple:
    """(score, kind) of one run: the mean deterministic return of its last FINAL_EVALUATIONS scheduled
    evaluations ('deterministic'; NaN when one of those has no finite return, which evaluations that
    count their failed episodes never give), else the mean training return over the last 10% of
    iterations ('training'). scheduled [T] bool: the iterations evaluated (default: finite returns)."""
    ev = np.asarray(eval_returns, float)
    scheduled = np.isfinite(ev) if scheduled is None else np.asarray(scheduled, bool)[: len(ev)]
    if scheduled.any():
        return float(np.mean(ev[scheduled][-FINAL_EVALUATIONS:])), "deterministic"
    tr = np.asarray(train_returns, float)
    tail = tr[-max(1, len(tr) // 10):]
    return (float(np.nanmean(tail)) if np.any(np.isfinite(tail)) else math.nan), "training"


def last_episodes_return(episode_returns: np.ndarray, episodes: np.ndarray, n: int = LAST_EPISODES) -> float:
    """The mean return of a run's last n finished training episodes (CleanRL's and openrlbenchmark's
    score: the mean of the last 100 logged episodic returns), from per-iteration means (episode_returns
    [T], NaN where none ended) and counts (episodes [T]): the latest iterations' episodes in full and, from
    the iteration that reaches n, as many of its episodes as are still needed, each at that iteration's
    mean (which of its episodes ended last is not recorded). Fewer than n episodes in all: their mean;
    none: NaN."""
    ret = np.asarray(episode_returns, float)
    cnt = np.where(np.isfinite(ret), np.nan_to_num(np.asarray(episodes, float)), 0.0)
    later = np.concatenate([np.cumsum(cnt[::-1])[::-1][1:], [0.0]])  # episodes ended after each iteration
    weight = np.clip(n - later, 0.0, cnt)
    total = weight.sum()
    return float(np.sum(weight * np.nan_to_num(ret)) / total) if total > 0 else math.nan


def unscored_evaluations(eval_returns: np.ndarray, scheduled: np.ndarray) -> list:
    """The 1-based iterations among a run's last FINAL_EVALUATIONS scheduled evaluations that have no
    finite return (what makes final_score NaN)."""
    ev = np.asarray(eval_returns, float)
    its = np.flatnonzero(np.asarray(scheduled, bool)[: len(ev)])[-FINAL_EVALUATIONS:]
    return [int(i) + 1 for i in its if not np.isfinite(ev[i])]


def curve_score(eval_returns: np.ndarray) -> float:
    """The mean of a run's finite deterministic returns over all its evaluations: the area under its
    learning curve per evaluation, which rewards learning early (NaN without evaluations)."""
    ev = np.asarray(eval_returns, float)
    ev = ev[np.isfinite(ev)]
    return float(np.mean(ev)) if len(ev) else math.nan


def mean_ci(x: np.ndarray) -> tuple:
    """(mean, 95% t half-width) of the values x [n] (half-width NaN for n < 2)."""
    x = np.asarray(x, float)
    n = len(x)
    return float(x.mean()), (float(t95(n) * x.std(ddof=1) / math.sqrt(n)) if n > 1 else math.nan)


def iqm_ci(scores: dict, seed: int = 0, reps: int = REPS) -> dict:
    """{name: (IQM, low, high)} of score matrices {name: [runs, tasks]}: the interquartile mean over all
    runs and tasks, with a 95% stratified bootstrap interval (rliable)."""
    from rliable import metrics

    point, interval = bootstrap({k: np.asarray(v, float) for k, v in scores.items()},
                                lambda x: np.array([metrics.aggregate_iqm(x)]), seed, reps)
    return {k: (float(np.ravel(point[k])[0]), *(float(v) for v in np.ravel(interval[k])[:2])) for k in scores}


def iqm(scores: np.ndarray) -> float:
    """The interquartile mean of scores [runs, tasks] or [runs] (rliable's aggregate_iqm): a point, no interval. The
    one IQM of the package: tables, the baseline and reports call it; the verdict's test (verdicts.trimmed) computes
    the same number with its standard error."""
    from rliable import metrics

    return float(metrics.aggregate_iqm(np.asarray(scores, float)))


@contextlib.contextmanager
def seeded(seed: int) -> Iterator[None]:
    """NumPy's global RNG, from which rliable draws its resamples, seeded with `seed` inside the block (reproducible
    tables and figures) and restored after it."""
    saved = np.random.get_state()
    np.random.seed(seed)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)  # arch: "random_state is deprecated"
            yield
    finally:
        np.random.set_state(saved)


def bootstrap(score_dict: dict, func: Callable, seed: int, reps: int = REPS) -> tuple:
    """rliable.library.get_interval_estimates (stratified bootstrap, 95% percentile intervals), its resamples drawn
    from `seed`."""
    from rliable import library as rly

    with seeded(seed):
        return rly.get_interval_estimates(score_dict, func, reps=reps)


def improvement_probability(pairs: dict, seed: int = 0, reps: int = REPS) -> dict:
    """{name: (P(X > Y), low, high)} for pairs {name: (X [runs, tasks], Y [runs, tasks])}: the probability
    that a run of X scores higher than a run of Y on the same task (ties count half), averaged over tasks,
    with a 95% stratified bootstrap interval (rliable)."""
    from rliable import metrics

    point, interval = bootstrap(
        {k: (np.asarray(x, float), np.asarray(y, float)) for k, (x, y) in pairs.items()}, metrics.probability_of_improvement, seed,
        reps)
    return {k: (float(np.ravel(point[k])[0]), *(float(v) for v in np.ravel(interval[k])[:2])) for k in pairs}


def iqm_curves(curves: dict, points: int = 20, seed: int = 0, reps: int = CURVE_REPS) -> dict:
    """{name: (index [P], IQM [P], low [P], high [P])} of learning curves {name: [runs, T]} at P points
    spread over T (every column where every run has a value); stratified bootstrap bands (rliable)."""
    out = {}
    for name, m in curves.items():
        m = np.asarray(m, float)
        cols = np.where(np.all(np.isfinite(m), axis=0))[0]
        if len(cols) == 0:
            continue
        cols = cols[np.unique(np.linspace(0, len(cols) - 1, min(points, len(cols))).round().astype(int))]
        est = iqm_ci({str(c): m[:, [c]] for c in cols}, seed, reps)
        out[name] = (cols, *(np.array([est[str(c)][i] for c in cols]) for i in range(3)))
    return out


def performance_profiles(scores: dict, taus: np.ndarray, reps: int = REPS, seed: int = 0) -> dict:
    """{name: (fraction [len(taus)], low, high)}: the fraction of runs (averaged over tasks) whose
    normalized score exceeds each tau, with 95% stratified bootstrap bands (rliable; resamples drawn from `seed`)."""
    from rliable import library as rly

    with seeded(seed):
        dist, cis = rly.create_performance_profile({k: np.asarray(v, float) for k, v in scores.items()},
                                                   np.asarray(taus), reps=reps)
    return {k: (np.asarray(dist[k]), np.asarray(cis[k][0]), np.asarray(cis[k][1])) for k in scores}


def normalize(score: np.ndarray | float, random_return: float, reference: float) -> np.ndarray:
    """(score - random_return) / (reference - random_return): 0 = a random policy, 1 = the reference."""
    scale = reference - random_return
    return (np.asarray(score, float) - random_return) / (scale if abs(scale) > 1e-9 else 1.0)
