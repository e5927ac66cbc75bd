"""The answer's error rate over every K and every look: a group-sequential design (looks fixed in advance, an
alpha-spending function over them) per hypothesis "K is no better than the margin", and Holm's step-down over the K.

A K's test statistic at its looks behaves like a Brownian motion in the information fraction t = n / n_last (seeds at
the look over seeds at the last look). An alpha-spending function alpha(t) (Lan and DeMets 1983) says how much of the
K's one-sided error may be spent by t; the one-sided boundaries c_j with

    P(Z_1 < c_1, ..., Z_{j-1} < c_{j-1}, Z_j >= c_j) = alpha(t_j) - alpha(t_{j-1})

are found by numerical integration of the motion's density over the looks (Armitage, McPherson and Rowe 1969;
Jennison and Turnbull 2000, ch. 19), and each look tests at the nominal one-sided level 1 - Phi(c_j). Across the K,
Holm's procedure (1979) in its group-sequential form (Maurer and Bretz 2013): each K not yet shown sufficient holds
alpha / (K not yet shown sufficient); a K shown sufficient passes its share on to the others, whose boundaries are
recomputed at their new level. The chance that the answer calls some K sufficient whose true gap is at or below
-margin is then at most alpha over all K and looks; experiments/verdicts/error_rates.py measures it by simulation.
"""

import functools
import math
from typing import NamedTuple

import numpy as np

SPENDING = ("pocock", "obf", "bonferroni")
# the error the design spends: below the 2.5% the answer states, because Yuen's t at 10-20 seeds and the normal
# boundaries over-reject a little together (experiments/verdicts/error_rates.py: spending 2.5% erred 2.7% with
# every K at the margin; spending 2%, under 2.5% for every law simulated)
DESIGN_ALPHA = 0.02
MULTIPLICITY = ("holm", "bonferroni", "none")


class Design(NamedTuple):
    """looks: seeds per cell at each look (increasing; the last is the seed cap); alpha: the one-sided chance of
    wrongly calling some K sufficient over the whole answer; spending: how each K's share is spread over its looks
    ('pocock': Lan-DeMets Pocock-type, alpha log(1 + (e - 1) t); 'obf': O'Brien-Fleming-type, 2 - 2 Phi(z_{alpha/2} /
    sqrt t); 'bonferroni': an equal share per look, ignoring the looks' correlation); multiplicity: how the K share
    alpha ('holm': Holm's step-down; 'bonferroni': alpha / K each; 'none': alpha each, the whole answer's error then
    unbounded by alpha: kept to measure what a correction buys, experiments/verdicts/error_rates.py)."""

    looks: tuple
    alpha: float = DESIGN_ALPHA
    spending: str = "pocock"
    multiplicity: str = "holm"


def check_design(design: Design) -> None:
    """ValueError in one line for a design that cannot be used."""
    looks = tuple(design.looks)
    if not looks or any(b <= a for a, b in zip(looks, looks[1:])):
        raise ValueError(f"looks must be increasing seed counts, got {list(looks)}")
    if looks[0] < MIN_SEEDS:
        raise ValueError(f"the first look needs at least {MIN_SEEDS} seeds per cell (got {looks[0]}): below that the "
                         "interquartile mean's standard error is unreliable (docs/answer.md)")
    if not 0.0 < design.alpha < 0.5:
        raise ValueError(f"alpha must be in (0, 0.5), got {design.alpha}")
    if design.spending not in SPENDING:
        raise ValueError(f"unknown spending {design.spending!r}: one of {', '.join(SPENDING)}")
    if design.multiplicity not in MULTIPLICITY:
        raise ValueError(f"unknown multiplicity {design.multiplicity!r}: one of {', '.join(MULTIPLICITY)}")


MIN_SEEDS = 10  # fewest seeds per cell at a look (experiments/verdicts/error_rates.py: calibration by seed count)


def spent(spending: str, t: np.ndarray, alpha: float, looks: int) -> np.ndarray:
    """Cumulative one-sided error alpha(t) spent by information fractions t."""
    from scipy import stats

    t = np.asarray(t, np.float64)
    if spending == "pocock":
        return alpha * np.log1p((math.e - 1.0) * t)
    if spending == "obf":
        return 2.0 - 2.0 * stats.norm.cdf(stats.norm.isf(alpha / 2.0) / np.sqrt(t))
    if spending == "bonferroni":
        return alpha * np.arange(1, len(t) + 1) / looks
    raise ValueError(f"unknown spending {spending!r}")


# points of the density grid per look. The tail sums are rectangle rules on this grid, which overstate a tail a
# little: the levels of the second and later looks come out about 1% (relative) below the exact ones (an independent
# check with scipy's multivariate normal: 0.00218 for 0.00220 at look 2 of 10-20-40 holding 0.02 / 3), so each look
# tests slightly stricter than it spends; no committed verdict sits between the two.
GRID = 2001


def next_density(grid: np.ndarray, dens: np.ndarray, dt: float, t: float) -> tuple:
    """(grid [G], density [G]) of S(t) = S(t - dt) + N(0, dt) on the continuation region given on `grid`."""
    new = np.linspace(-10.0 * math.sqrt(t), 10.0 * math.sqrt(t), 2 * GRID - 1)
    weights = dens * np.gradient(grid)
    z = (new[:, None] - grid[None, :]) / math.sqrt(dt)
    kernel = np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi * dt)
    return new, kernel @ weights


def boundary_from_tail(grid: np.ndarray, dens: np.ndarray, t: float, increment: float) -> float:
    """The boundary c (on the Z = S / sqrt t scale) whose upper tail of the density holds `increment`."""
    if increment <= 0:
        return math.inf
    tail = np.cumsum((dens * np.gradient(grid))[::-1])[::-1]  # P(S >= grid[i]) on the continuation region
    i = int(np.searchsorted(-tail, -increment))  # the first grid point whose tail is <= increment
    if i == 0:
        return grid[0] / math.sqrt(t)
    if i >= len(grid):
        return grid[-1] / math.sqrt(t)
    a, b = tail[i - 1], tail[i]  # linear interpolation between the two grid points around it
    s = grid[i - 1] + (grid[i] - grid[i - 1]) * (a - increment) / (a - b) if a != b else grid[i]
    return float(s / math.sqrt(t))


@functools.lru_cache(maxsize=256)
def boundaries(fractions: tuple, cumulative: tuple) -> tuple:
    """One-sided boundaries c_j (Z scale) at information fractions t_j for cumulative spends alpha_j."""
    from scipy import stats

    cs, prev_t, spent_so_far, grid, dens = [], 0.0, 0.0, None, None
    for t, a in zip(fractions, cumulative):
        increment = max(float(a) - spent_so_far, 0.0)
        if grid is None:  # the first look: Z_1 is standard normal
            c = float(stats.norm.isf(increment)) if increment > 0 else math.inf
            top = c * math.sqrt(t) if math.isfinite(c) else 10.0 * math.sqrt(t)
            grid = np.linspace(-10.0 * math.sqrt(t), top, GRID)
            dens = stats.norm.pdf(grid / math.sqrt(t)) / math.sqrt(t)
        else:
            new, g = next_density(grid, dens, t - prev_t, t)
            c = boundary_from_tail(new, g, t, increment)
            keep = new < c * math.sqrt(t)
            grid, dens = new[keep], g[keep]
        cs.append(c)
        spent_so_far, prev_t = spent_so_far + increment, t
    return tuple(cs)


@functools.lru_cache(maxsize=1024)
def look_levels(design: Design, alpha: float) -> tuple:
    """The nominal one-sided level of each look for a hypothesis that holds `alpha` of the design."""
    from scipy import stats

    looks = tuple(design.looks)
    fractions = tuple(n / looks[-1] for n in looks)
    if design.spending == "bonferroni":
        return tuple(alpha / len(looks) for _ in looks)
    cumulative = tuple(float(v) for v in spent(design.spending, np.asarray(fractions), alpha, len(looks)))
    return tuple(float(stats.norm.sf(c)) for c in boundaries(fractions, cumulative))


def look_index(design: Design, seeds: int) -> int | None:
    """The look a cell of `seeds` seeds is judged at: the largest look <= seeds (None below the first look)."""
    i = [j for j, n in enumerate(design.looks) if n <= seeds]
    return i[-1] if i else None


def holm_share(design: Design, hypotheses: int, shown: int) -> float:
    """The one-sided error a K holds when `shown` of the `hypotheses` K are already shown sufficient (Holm; the
    design's other multiplicity rules for comparison)."""
    if design.multiplicity == "none":
        return design.alpha
    if design.multiplicity == "bonferroni":
        return design.alpha / max(hypotheses, 1)
    return design.alpha / max(hypotheses - shown, 1)
