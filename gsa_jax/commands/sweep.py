"""Train a sweep: a grid of (env, policy, K, seed, hyperparameters) as one vmapped program per (env, policy).

    gsa sweep experiments/fig1_small/fig1_small.toml [--out DIR] [--devices N]
    make sweep EXP=experiments/fig1_small/fig1_small.toml
    gsa sweep --resume DIR      # continue the sweep in DIR as its sweep.json recorded it

Every run of an (env, policy) group trains at once: `jax.vmap` over the runs, the run axis
sharded over the local devices (`shard_map`). On a CPU, use the cores with --local-processes N
(default: one per core): N worker processes, each training its share of every group's runs
on its own XLA CPU device (or set --xla_force_host_platform_device_count and --local-processes 1); worker 0
compiles each group's program and the others load it from the sweep's compilation cache (gsa_jax.running.xla_cache).
Training goes in chunks of iterations; after each chunk the group's state, its
metrics and the tidy `metrics.csv` are written atomically, so a killed sweep resumes from its
last chunk when the same command runs again (or `--resume DIR` alone) and ends with the same results. A supervisor
process watches a heartbeat and restarts a worker whose chunk takes far longer than usual
(XLA:CPU has been seen to hang in large vmapped MJX programs).

Output (DIR, default runs/sweeps/<name>):
  sweep.json            the spec, every run of the grid, runs per sub-batch, versions, git commit; failed_runs at the end
  metrics.csv           tidy: one row per run per iteration (env, policy, K, seed, swept hparams, metrics with
                        eval_return, the deterministic controller's mean return where evaluated; a swept
                        hparam named like a metric is hparam_<name>, e.g. hparam_lr next to the annealed lr)
  groups/<env>-<policy>/{state.npz, metrics.npz (+ their .prev.npz), params.npz, runs.csv, failed.json, DONE}
                        (with --runs-per-program N, a group of more than N runs: groups/<env>-<policy>-part2/, ...)
  tensorboard/<run>/    TensorBoard event files of every run (tensorboard --logdir DIR; --no-tensorboard: none)
  LOCK                  pid and host of the sweep writing DIR (a second one is refused)
  xla_cache/            compiled programs (JAX's persistent cache): worker 0 compiles each group's
                        program once, the other workers and any resumed run load it (seconds)
With --num-processes P each process writes its share under DIR/process-<i>/ (`gsa plot` merges them).

Failures are loud and lose nothing: a run whose loss or parameters turn NaN/inf is frozen inside the
compiled program (ppo.guarded_iteration; the others train on bit for bit), its metrics end there and
its last finite parameters are kept; sweep.json and the final summary list it and the sweep exits 1.
A checkpoint unreadable on resume falls back to its previous version; a full disk stops with one line
(exit 4) and the same command resumes once space is freed; a changed experiment file is refused with
the difference (--force continues with it). Exit status: 0 done (or stopped as asked), 1 some runs failed
(NaN/inf), 2 bad input or a locked / changed / unreadable output directory, 3 a worker hung repeatedly, 4 disk full,
130 interrupted.

Experiment file (TOML):
  name = "fig1_small"
  envs = ["inverted_double_pendulum", "hopper"]
  policies = ["mlp", "mixture"]
  cluster_multipliers = [0.5, 1, 2, 4]   # K = ceil(m * action_dim); or: clusters = [2, 4, 6]
  subpolicies = ["constant", "linear"]    # optional: sub-policy classes of the mixtures (default linear)
  partitions = ["mlp", "linear"]          # optional: partition classes of the mixtures (default mlp)
  value_targets = ["gae", "retrace"]      # optional: the critics to compare (default [config] value_target, gae)
  seeds = 8                               # seeds 0..7, or a list [0, 5, 9]
  steps = 200_000                         # env steps per run
  chunk = 10                              # PPO iterations per compiled chunk (optional)
  eval_every = 8                          # iterations between deterministic evaluations (default ~25 per run; 0: none)
                                          # or: eval_at = [40_000, 100_000] (after the chunks holding these env steps)
  eval_seed = 0                           # evaluation start states: the same for every run of the sweep
  [hparams]                               # scalars, or lists to sweep over (every combination)
  lr = 3e-4
  eps_decay = [0.99, 0.995]
  [config]                                # static gsa_jax.algorithm.config.Config fields (num_envs, unroll_length, ...)
  num_envs = 32
"""

import argparse
import os
import sys
from typing import Callable

from gsa_jax.commands.command_line import command_parser, options_over_saved
from gsa_jax.errors import run_command
from gsa_jax.orchestration.sweep_job import SweepJob, run_job
from gsa_jax.running.spec import SpecError, check_spec, load_spec

# JAX and gsa_jax.running.sweeps (which loads it) are imported in the functions that use them: `gsa sweep --help`
# loads no JAX
DEFAULTS = SweepJob._field_defaults


def build_parser() -> argparse.ArgumentParser:
    """`gsa sweep`'s options (its worker processes run gsa_jax.orchestration.sweep_job)."""
    p = command_parser("sweep", __doc__)
    p.runs_jax = True  # it runs JAX programs (command_line.CommandParser)
    p.add_argument("experiment", nargs="?", default=None,
                   help="experiment file (TOML), e.g. experiments/fig1_small/fig1_small.toml (with --resume: optional)")
    p.add_argument("--resume", metavar="DIR", default=None,
                   help="continue the sweep in DIR with the experiment, local worker count, sub-batch size and "
                        "TensorBoard setting its sweep.json recorded (an experiment file given too must match it, or --force)")
    p.add_argument("--out", default=None, help="output directory (default runs/sweeps/<name>)")
    p.add_argument("--devices", type=int, default=None, help="shard each worker's runs over its first N local devices (default: all)")
    p.add_argument("--local-processes", type=int, default=None,
                   help="worker processes on this machine, each with its share of the runs (default: one per CPU core)")
    p.add_argument("--no-watchdog", action="store_true", help="run in this process, without the restarting supervisor")
    p.add_argument("--watchdog-min", type=float, default=DEFAULTS["watchdog_min"],
                   help="seconds without progress before a restart (at least; default %(default)s)")
    p.add_argument("--max-restarts", type=int, default=DEFAULTS["max_restarts"],
                   help="restarts of a hung worker before the sweep stops with exit status 3 (default %(default)s)")
    p.add_argument("--stop-after-chunks", type=int, default=None,
                   help="stop (resumably) after N chunks (default: train to the end)")
    p.add_argument("--coordinator", default=None,
                   help="host:port of process 0, for multi-process sweeps (default: none, this machine alone)")
    p.add_argument("--num-processes", type=int, default=1,
                   help="processes of a multi-process sweep, one per host (with --coordinator; default %(default)s)")
    p.add_argument("--process-id", type=int, default=0,
                   help="this process's index among --num-processes, 0 the coordinator (default %(default)s)")
    p.add_argument("--run-batch", type=int, default=DEFAULTS["run_batch"],
                   help=f"train each device's runs in sequential sub-batches of N (default {DEFAULTS['run_batch']}; 0: all at once). "
                        "Same runs; MJX's batched solver loops stop at each sub-batch's slowest env")
    p.add_argument("--runs-per-program", type=int, default=0, metavar="N",
                   help="every compiled program trains N runs: a group of more is trained in consecutive parts of N (one "
                        "program, compiled once), one of fewer is padded to N (copies, trained and dropped), so sweeps of "
                        "any size run one program (gsa answer: one program per class for all its sweeps)")
    p.add_argument("--force", action="store_true", help="resume even if the experiment file changed (continues with the new spec)")
    p.add_argument("--no-tensorboard", dest="tensorboard", action="store_false",
                   help="no TensorBoard event files (default: OUT/tensorboard/<run>/, open with tensorboard --logdir OUT)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


def saved_options(meta: dict, out: str, coordinator: str | None) -> dict:
    """Option values (dest -> value) that give back a saved sweep's settings (its sweep.json): what --resume DIR
    continues with (the spec is checked apart; a record without one is not a sweep's: KeyError)."""
    if "spec" not in meta:
        raise KeyError("spec")
    saved = {k: meta[k] for k in ("run_batch", "tensorboard") if k in meta}
    saved["runs_per_program"] = int(meta["runs_per_program"])
    if coordinator is None and meta.get("num_processes"):  # the same split of the runs over local workers
        saved["local_processes"] = meta["num_processes"]
    return {"out": out, **saved}


def parse_args(argv: list) -> argparse.Namespace:
    """The command line; with --resume DIR, parsed again over the settings DIR/sweep.json recorded (options not
    typed take them). Raises SpecError."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.resume is None:
        if args.experiment is None:
            raise SpecError("give an experiment file (TOML), or --resume DIR to continue a sweep")
        return args
    if args.out is not None and os.path.abspath(args.out) != os.path.abspath(args.resume):
        raise SpecError(f"--resume {args.resume} and --out {args.out} name different directories")
    path = os.path.join(args.resume, "sweep.json")
    if not os.path.exists(path):
        raise SpecError(f"--resume {args.resume}: no sweep there (no sweep.json); start one with gsa sweep "
                        f"EXPERIMENT --out {args.resume}")
    coordinator = args.coordinator
    args, meta = options_over_saved(parser, argv, path, lambda m: saved_options(m, args.resume, coordinator), SpecError,
                                      "sweep")
    args.saved_spec = meta["spec"]
    return args


def check_args(args: argparse.Namespace) -> tuple:
    """(spec, out, local worker count) after checking every argument; raises SpecError. Nothing compiles."""
    if args.experiment is None:
        spec = check_spec(args.saved_spec, source=os.path.join(args.resume, "sweep.json"))
    else:
        spec = load_spec(args.experiment)
    if args.num_processes < 1 or not 0 <= args.process_id < args.num_processes:
        raise SpecError(f"--process-id must be in 0..{args.num_processes - 1}")
    out = args.out or os.path.join("runs", "sweeps", spec.name)
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as e:
        raise SpecError(f"--out {out!r} cannot be created: {e.strerror or e}") from None
    local = args.local_processes if args.local_processes is not None else (1 if args.no_watchdog else (os.cpu_count() or 1))
    if args.num_processes > 1:
        local = 1  # multi-host: one process per host runs here, as launched
    if local < 1:
        raise SpecError("--local-processes must be >= 1")
    if args.run_batch < 0:
        raise SpecError(f"--run-batch must be >= 0, got {args.run_batch}")
    if args.runs_per_program < 0:
        raise SpecError(f"--runs-per-program must be >= 0, got {args.runs_per_program}")
    return spec, out, local


def job_of(args: argparse.Namespace) -> SweepJob:
    """The sweep's job (gsa_jax.orchestration.sweep_job) from the checked command line; raises SpecError."""
    spec, out, local = check_args(args)
    return SweepJob(spec, out, local, not args.no_watchdog, False, args.devices, args.coordinator, args.num_processes,
                    args.process_id, args.run_batch, args.runs_per_program, args.force, args.tensorboard, args.quiet,
                    args.stop_after_chunks, args.watchdog_min, args.max_restarts)


def sweep(argv: list, after_chunk: Callable | None = None) -> int:
    """Check the command line, then run its job (gsa_jax.orchestration.sweep_job.run_job: this process's share or
    the supervised workers) -> the exit status. after_chunk: see sweep_job.run_worker."""
    return run_job(job_of(parse_args(argv)), after_chunk)


def main(argv: list | None = None, after_chunk: Callable | None = None) -> int:
    """`gsa sweep` (exit statuses: the module docstring). after_chunk: see sweep_job.run_worker."""
    argv = list(sys.argv[1:] if argv is None else argv)
    return run_command("sweep", lambda: sweep(argv, after_chunk))
