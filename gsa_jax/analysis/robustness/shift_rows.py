"""The tidy rows of controllers under shifts (robustness.csv, nominal.csv): their columns (and aggregate.csv's
retained fraction, which retention_stats writes and retention_plots reads), each controller's key and the rows grouped
into cells; shared by the evaluation (retention_eval), its statistics (retention_stats),
the paired pushes (paired) and the fair comparisons (fairness)."""

from gsa_jax.deployment.shifts import Shift
from gsa_jax.errors import UserError

TIDY = ("env", "policy", "K", "seed", "shift", "level", "score", "nominal_score", "random_score", "retained_fraction")
RETAINED_CI = ("retained_iqm", "retained_ci_low", "retained_ci_high")  # aggregate.csv: IQM [95% CI] of the fraction


class RobustnessError(UserError, ValueError):
    pass


def controller_key(meta: dict) -> tuple:
    return (meta["env"], meta["policy"], str(meta["K"]), str(meta["seed"]))


def cells(rows: list) -> dict:
    """{(env, policy, K, shift name): {seed: row}} of tidy rows (strings or numbers)."""
    out = {}
    for r in rows:
        name = Shift(r["shift"], float(r["level"] or 0)).name
        out.setdefault((r["env"], r["policy"], str(r["K"]), name), {})[str(r["seed"])] = r
    return out
