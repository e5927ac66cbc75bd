"""Does state abstraction regularize? Exported controllers under shifted physics, observations and actions
(gsa_jax.deployment.shifts), in MuJoCo C, with rliable statistics:

    python -m gsa_jax.robustness CONTROLLERS [CONTROLLERS ...] --out OUT [--episodes 20] [--shifts mass,push]
                                 [--level push=0.5,1]

CONTROLLERS: exported controller files (gsa_jax.export, gsa_jax.extract --controllers) or directories of
them. Every controller plays `--episodes` deterministic episodes under every shift that applies to its
task, from the same fixed start states (seeds 10,000 + i); --level replaces a kind's default levels (pushes
of other sizes keep their times and directions: a dose-response). Writes to OUT:
  robustness.csv    tidy: env, policy, K, seed, shift, level, score, nominal_score, random_score,
                    retained_fraction = (score - random) / (nominal - random), the random policy's return
                    from the same starts as 0; written after every controller, and a re-run skips what it holds
  sensitivity.csv   per controller: the mean Frobenius norm of d action / d (normalized observation) along its
                    nominal episodes (a mixture: its active piece's L_c; an MLP: its Jacobian), and its mean
                    retained fraction over the shifts
  aggregate.csv     per task x configuration x shift: IQM of the retained fraction and of the shifted score
                    (95% stratified-bootstrap CIs) and P(the mixture retains more than flat PPO) with its CI
  correlation.csv   per task and pooled: Spearman's rho between sensitivity and mean retained fraction
  robustness.png    per task, retained fraction (IQM, 95% CI) under each shift for flat PPO and each K
  profile.png       over all tasks: the fraction of (controller, shift) pairs retaining more than tau
"""

import argparse
import json
import os
import sys

from gsa_jax.analysis import stats
from gsa_jax.analysis.retention import RobustnessError, analyse, evaluate_all, load_controllers, write_settings
from gsa_jax.deployment.shifts import DEFAULT_SHIFTS, KINDS, Shift


def parse_levels(items):
    """--level KIND=V1,V2 (repeatable) -> {kind: (levels,)}: the levels that replace a kind's defaults."""
    levels = {}
    for item in items:
        kind, _, values = item.partition("=")
        if kind not in KINDS or kind in ("nominal", "simulator"):
            raise RobustnessError(f"--level {item!r}: KIND must be one of {', '.join(KINDS[2:])}")
        try:
            levels[kind] = tuple(float(v) for v in values.split(","))
        except ValueError:
            raise RobustnessError(f"--level {item!r}: levels must be numbers, e.g. push=0.5,1") from None
        if not levels[kind] or min(levels[kind]) <= 0:
            raise RobustnessError(f"--level {item!r}: levels must be > 0")
    return levels


def parse_shifts(text, levels=None):
    """--shifts ('all' or comma-separated kinds, every default level of each) and --level overrides ->
    [Shift] with nominal first."""
    kinds = list(dict.fromkeys(s.kind for s in DEFAULT_SHIFTS)) if text == "all" else [k.strip() for k in text.split(",") if k.strip()]
    bad = [k for k in kinds if k not in KINDS]
    if bad:
        raise RobustnessError(f"unknown shift(s) {', '.join(bad)}; choose from {', '.join(KINDS)}")
    levels = levels or {}
    shifts = [Shift("nominal")]
    for kind in kinds:
        if kind in levels:
            shifts += [Shift(kind, v) for v in levels[kind]]
        else:
            shifts += [s for s in DEFAULT_SHIFTS if s.kind == kind and kind != "nominal"]
    return shifts


def resolve_settings(args):
    """(shifts, episodes): as given, and where not given, what OUT's robustness.json recorded (a re-run
    continues the evaluation it holds), else the defaults (every shift, 20 episodes). Raises RobustnessError."""
    saved = {}
    path = os.path.join(args.out, "robustness.json")
    if os.path.exists(path):
        try:
            with open(path) as f:
                saved = json.load(f)
        except (OSError, ValueError) as e:
            raise RobustnessError(f"{path} is unreadable ({e}); use another --out") from None
    if args.shifts is None and not args.level and "shifts" in saved:
        shifts = [Shift(kind, level) for kind, level in saved["shifts"]]
    else:
        shifts = parse_shifts(args.shifts or "all", parse_levels(args.level))
    episodes = args.episodes if args.episodes is not None else saved.get("episodes", 20)
    return shifts, episodes


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m gsa_jax.robustness", description=__doc__.split("\n")[0])
    p.add_argument("controllers", nargs="+", help="exported controller files or directories of them")
    p.add_argument("--out", required=True, help="output directory (a re-run continues what it holds, with the shifts "
                                                "and episodes it recorded unless given again)")
    p.add_argument("--episodes", type=int, default=None, help="deterministic episodes per controller and shift (default 20)")
    p.add_argument("--shifts", default=None, help=f"'all' (default) or comma-separated kinds of {', '.join(KINDS[1:])}")
    p.add_argument("--level", action="append", default=[], metavar="KIND=V1,V2",
                   help="the levels of a kind instead of its defaults, e.g. push=0.5,1 (m/s); repeatable")
    p.add_argument("--reps", type=int, default=stats.REPS, help="bootstrap resamples (default %(default)s)")
    args = p.parse_args(argv)
    try:
        shifts, episodes = resolve_settings(args)
        if episodes < 1 or args.reps < 1:
            raise RobustnessError(f"--episodes and --reps must be >= 1, got {episodes} and {args.reps}")
        controllers = load_controllers(args.controllers)
        os.makedirs(args.out, exist_ok=True)
        write_settings(args.out, shifts, episodes)
    except (RobustnessError, OSError) as e:
        print(f"gsa_jax.robustness: error: {e}", file=sys.stderr)
        return 2
    rows, sens = evaluate_all(controllers, shifts, episodes, args.out)
    analyse(rows, sens, args.out, args.reps)
    print(f"wrote {args.out}/robustness.csv, aggregate.csv, sensitivity.csv, robustness.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
