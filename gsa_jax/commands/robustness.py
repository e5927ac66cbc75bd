"""Run exported controllers under shifted physics, observations, actions and paired pushes: does state abstraction
regularize? (gsa_jax.deployment.shifts, in MuJoCo C, with rliable statistics)

    gsa robustness CONTROLLERS [CONTROLLERS ...] --out OUT [--episodes 20] [--shifts mass,push]
                   [--level push=0.5,1] [--push-sizes 0.25,0.5,1] [--windows 20,50,100]
                   [--pushes-per-episode 10]

CONTROLLERS: exported controller files (gsa export, gsa extract --controllers) or directories of
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
Paired pushes (gsa_jax.deployment.pushes; --pushes-per-episode 0 skips them): each push an event against
the same episode without it, counted only where that episode survives the window:
  pushes.csv.gz     tidy, one row per controller x start x push event x size: whether it counted and made
                    the robot fall within each window W, the return it cost
  nominal.csv       per controller: its control episodes' score, mean length, share reaching the time limit
  paired_pushes.csv per task x configuration x size x W: IQM [CI] of the fall probability per counted push
                    and of the return lost, P(the mixture falls / loses less than flat PPO) [CI], and
                    that P's CI with the push events resampled too (p_*_events_ci_*: another draw's variation)
  pushes.png        the fall probability (or return lost) against push size, per task and window
  fair.csv          per task x configuration x shift: the shifted score above the line the other
                    configurations' controllers set (shifted on nominal score), the retained fraction among
                    controllers whose nominal episodes all reach the time limit, and each one's verdict next
                    to the retained fraction's (gsa_jax.analysis.robustness.fairness)
correlation.csv also gives the partial rank correlation controlling for nominal score.
"""

import argparse
import os

import numpy as np

from gsa_jax.analysis.robustness.paired import evaluate_all_pushes
from gsa_jax.analysis.robustness.retention import analyse
from gsa_jax.analysis.robustness.retention_eval import START_SEED, evaluate_all, load_controllers, write_settings
from gsa_jax.analysis.robustness.shift_rows import RobustnessError
from gsa_jax.analysis.sweeps import stats
from gsa_jax.commands.command_line import command_parser, read_saved
from gsa_jax.errors import run_command
from gsa_jax.deployment.pushes import PER_EPISODE, PUSH_SIZES, WINDOWS
from gsa_jax.deployment.shifts import DEFAULT_SHIFTS, KINDS, Shift


def parse_levels(items: list) -> dict:
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


def parse_shifts(text: str, levels: dict | None = None) -> list:
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


def parse_numbers(flag: str, text: str, kind: type = float) -> tuple:
    """'0.25,0.5' -> (0.25, 0.5): positive numbers, sorted, RobustnessError in one line otherwise."""
    try:
        values = tuple(sorted(kind(v) for v in text.split(",")))
    except ValueError:
        raise RobustnessError(f"{flag} {text!r}: comma-separated {kind.__name__} values, e.g. {flag} 1,2") from None
    if not values or min(values) <= 0:
        raise RobustnessError(f"{flag} {text!r}: values must be > 0")
    return values


def resolve_pushes(args: argparse.Namespace, saved: dict) -> dict | None:
    """{sizes, windows, per_episode} of the paired pushes (None with --pushes-per-episode 0): as given, else
    as OUT's robustness.json recorded, else the defaults."""
    old = saved.get("paired_pushes") or {}
    per = args.pushes_per_episode if args.pushes_per_episode is not None else old.get("per_episode", PER_EPISODE)
    if per < 0:
        raise RobustnessError(f"--pushes-per-episode must be >= 0, got {per}")
    if per == 0:
        return None
    sizes = parse_numbers("--push-sizes", args.push_sizes) if args.push_sizes else tuple(old.get("sizes", PUSH_SIZES))
    windows = parse_numbers("--windows", args.windows, int) if args.windows else tuple(old.get("windows", WINDOWS))
    if max(windows) >= 1000:
        raise RobustnessError(f"--windows {args.windows}: windows must be shorter than the 1000-step episodes")
    return {"sizes": sizes, "windows": windows, "per_episode": per}


def resolve_settings(args: argparse.Namespace) -> tuple:
    """(shifts, episodes, paired pushes): as given, and where not given, what OUT's robustness.json recorded
    (a re-run continues the evaluation it holds), else the defaults (every shift, 20 episodes, paired pushes
    of PUSH_SIZES in WINDOWS). Raises RobustnessError."""
    path = os.path.join(args.out, "robustness.json")
    saved = read_saved(path, RobustnessError)[0] if os.path.exists(path) else {}
    if args.shifts is None and not args.level and "shifts" in saved:
        shifts = [Shift(kind, level) for kind, level in saved["shifts"]]
    else:
        shifts = parse_shifts(args.shifts or "all", parse_levels(args.level))
    episodes = args.episodes if args.episodes is not None else saved.get("episodes", 20)
    return shifts, episodes, resolve_pushes(args, saved)


def build_parser() -> argparse.ArgumentParser:
    """`gsa robustness`'s options."""
    p = command_parser("robustness", __doc__)
    p.add_argument("controllers", nargs="+", help="exported controller files or directories of them")
    p.add_argument("--out", required=True, help="output directory (a re-run continues what it holds, with the shifts "
                                                "and episodes it recorded unless given again)")
    p.add_argument("--episodes", type=int, default=None, help="deterministic episodes per controller and shift (default 20)")
    p.add_argument("--shifts", default=None, help=f"'all' (default) or comma-separated kinds of {', '.join(KINDS[1:])}")
    p.add_argument("--level", action="append", default=[], metavar="KIND=V1,V2",
                   help="the levels of a kind instead of its defaults, e.g. push=0.5,1 (m/s); repeatable")
    p.add_argument("--push-sizes", default=None, help="paired pushes' sizes in m/s (default 0.25,0.5,1)")
    p.add_argument("--windows", default=None, help="paired pushes' windows in env steps (default 20,50,100)")
    p.add_argument("--pushes-per-episode", type=int, default=None,
                   help=f"paired push events per start state (default {PER_EPISODE}; 0: no paired pushes)")
    p.add_argument("--reps", type=int, default=stats.REPS, help="bootstrap resamples (default %(default)s)")
    return p


def robustness(argv: list | None) -> int:
    """Evaluate every controller under every shift and paired push; write the tables and figures."""
    args = build_parser().parse_args(argv)
    shifts, episodes, pushes = resolve_settings(args)
    if episodes < 1 or args.reps < 1:
        raise RobustnessError(f"--episodes and --reps must be >= 1, got {episodes} and {args.reps}")
    try:
        controllers = load_controllers(args.controllers)
        os.makedirs(args.out, exist_ok=True)
        write_settings(args.out, shifts, episodes, pushes)
    except OSError as e:
        raise RobustnessError(e) from None
    rows, sens = evaluate_all(controllers, shifts, episodes, args.out)
    events, nominal = [], []
    if pushes:
        seeds = np.arange(START_SEED, START_SEED + episodes)
        events, nominal = evaluate_all_pushes(controllers, pushes, seeds, args.out)
    analyse(rows, sens, args.out, args.reps, events=events, nominal=nominal, windows=pushes["windows"] if pushes else ())
    print(f"wrote {args.out}/robustness.csv, aggregate.csv, sensitivity.csv, robustness.png"
          + (", pushes.csv.gz, nominal.csv, paired_pushes.csv, pushes.png, fair.csv" if pushes else ""))
    return 0


def main(argv: list | None = None) -> int:
    """`gsa robustness`: exit status 0, or 2 on bad input."""
    return run_command("robustness", lambda: robustness(argv))
