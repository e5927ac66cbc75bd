"""Measure sweep throughput against MuJoCo C on this machine (`gsa bench [--quick] [--out DIR]`, make bench).

For a task (`--env`, default hopper; also allegro_cylinder) it measures, in one invocation:
- the raw step rate of MuJoCo C on the same MJCF (`mujoco.rollout`, one thread per core, batch 256,
  the task's substeps per env step) -- the physical reference;
- raw MJX stepping (vmapped env.step, random actions, auto-reset) at batch 256 and 4096, with 1 and
  with all-core worker processes;
- end-to-end training throughput (env steps per second, PPO updates included, compile excluded and
  reported separately) of sweeps of 1, 16, 64 and 256 runs of the mixture (K=6) with 1 and with
  <cores> worker processes, and of the flat mlp at 256 runs on all cores (`--policies mixture,mlp`
  for mlp at every size and process count); worker processes (each one XLA CPU device, as `gsa sweep` runs them,
  in its sub-batches of --run-batch runs), with compile time and peak resident memory;
- with --profile-runs N, a time profile of one PPO iteration (physics / rest of the rollout / update) on
  --profile-processes workers (default 1; <cores> measures the update as the sweep's workers run it), and
  the ceiling it puts on ours / MuJoCo C (ratio_ceiling);
- with --physics mjx,c, the raw stepping, sweeps and profile for each physics backend (envs/physics.py;
  'c': MuJoCo C stepped from inside the compiled program), in the same invocation; every 'c' sweep also
  splits its own timed chunks (MuJoCo C / the rest of the host calls / the rest of the program, from
  envs.c_hosts.host_seconds) and puts its ceiling on them (in_run_ceiling): no separate profile;
- the same largest raw batch and largest mixture sweep on all cores again with a cheaper MJX solver
  (`--solver-variant ITER,LS`, default 1,4: 1 Newton iteration, 4 line-search iterations), and MuJoCo C
  with those settings too -- a changed simulator, offered as the explicit `--solver-iterations` /
  `--ls-iterations` option of training and sweeps (experiments/solver_hopper/).
The default run takes ~20 min on 2 cores (the estimate is printed first), --quick ~3 min.
Every figure is the median of repeated timed chunks; workers of a multi-process measurement start
their timed chunks together. A worker that hangs (no heartbeat) is killed and the measurement retried
once, then recorded as an error. Writes bench.json (`ratio_vs_mujoco_c` for each measurement) and
bench.png.
"""

import argparse
import itertools
import json
import os
import time
from typing import Callable

import envs
from envs.physics import Physics
from gsa_jax.benchmark.measure import (
    QUICK_SIZES, RAW_BATCHES, RAW_UNROLL, SIZES, SOLVER_VARIANT, BenchError, SweepCell, solver_field, in_run_ceiling,
    measure_mujoco_c, measure_raw, measure_sweep, ratio_ceiling, time_profile,
)
from gsa_jax.benchmark.report import plot
from gsa_jax.commands.command_line import command_parser
from gsa_jax.errors import run_command
from gsa_jax.running.checkpoint import write_atomic
from gsa_jax.running.runinfo import run_metadata
from gsa_jax.running.spec import RUN_BATCH, check_spec


def parse_solver_variant(text: str | None, quick: bool) -> tuple | None:
    """--solver-variant: None -> SOLVER_VARIANT (none with --quick); 'none' -> None; 'I,L' -> (I, L)."""
    if text is None:
        return None if quick else SOLVER_VARIANT
    if text.strip().lower() == "none":
        return None
    try:
        it, ls = (int(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"--solver-variant must be ITER,LS (two integers) or none, got {text!r}") from None
    if it < 1 or ls < 1:
        raise ValueError(f"--solver-variant iterations must be >= 1, got {text!r}")
    return it, ls


def reps(repeats: int, runs: int, explicit: bool = False) -> int:
    """Timed chunks for a sweep of `runs` runs: chunks of >= 64 runs take 10-40 s each here, 2 are enough."""
    return repeats if explicit or runs < 64 else min(repeats, 2)


def estimate_s(plan: list, raw_plan: list, profile_runs: int, repeats: int, profiles: int = 1) -> float:
    """Rough wall time: ~50 s compile + start per measurement, timed chunks at ~10k steps/s per process;
    `profiles` time profiles of profile_runs runs."""
    t = 30 + sum(60 + (reps(repeats, n) + 1) * n * 2048 / (8000 + 4000 * k) / (2 if sol else 1) for _, n, k, sol, _ in plan)
    t += sum(40 + (repeats + 1) * b * RAW_UNROLL / (15000 * k) / (2 if sol else 1) for b, k, sol, _ in raw_plan)
    if profile_runs:
        t += profiles * (2 * (50 + (repeats + 1) * profile_runs * 2048 / 10000) + 40)
    return t


def positive_ints(flag: str, text: str | None, default: list) -> list:
    """Comma-separated positive integers of a flag (or the default); ValueError naming the flag."""
    if not text:
        return default
    try:
        values = [int(s) for s in text.split(",")]
    except ValueError:
        raise ValueError(f"{flag} takes comma-separated positive integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise ValueError(f"{flag} takes comma-separated positive integers, got {text!r}")
    return values


def build_parser() -> argparse.ArgumentParser:
    """`gsa bench`'s options."""
    p = command_parser("bench", __doc__)
    p.runs_jax = True  # it runs JAX programs (command_line.CommandParser)
    p.add_argument("--quick", action="store_true",
                   help="1 run on 1 process and 16 runs on all cores, mixture only, raw batch 256 on all cores (~3 min)")
    p.add_argument("--out", default="runs/bench",
                   help="output directory of bench.json and bench.png (default %(default)s)")
    p.add_argument("--env", default="hopper", help="any task name: a built-in one, or a task definition 'module:Class' "
                   "(docs/your_task.md; default %(default)s)")
    p.add_argument("--sizes", default=None, help="comma-separated run counts (default 1,16,64,256)")
    p.add_argument("--policies", default=None,
                   help="comma-separated (default: mixture at every size, mlp at the largest size)")
    p.add_argument("--processes", default=None, help="comma-separated worker counts (default 1,<cores>)")
    p.add_argument("--raw-batches", default=None, help="comma-separated env batches for raw stepping (default 256,4096)")
    p.add_argument("--profile-runs", type=int, default=0,
                   help="also profile one PPO iteration (physics / rest of rollout / update) at this many runs, "
                        "e.g. 64 (default 0: no profile)")
    p.add_argument("--profile-processes", default="1",
                   help="comma-separated worker counts of the time profile (default 1; <cores>: as the sweep's workers "
                        "run, which gives the ceiling the sweep on all cores can reach)")
    p.add_argument("--repeats", type=int, default=None,
                   help="timed chunks per measurement (default 3; 2 for sweeps of >= 64 runs, whose chunks are long)")
    p.add_argument("--run-batch", type=int, default=RUN_BATCH,
                   help=f"runs per sequential sub-batch in each worker, as gsa sweep --run-batch (default {RUN_BATCH}, "
                        "the sweep's; 0: all at once)")
    p.add_argument("--solver-variant", default=None,
                   help="ITER,LS: also measure the largest raw batch and mixture sweep (all cores) and MuJoCo C with this "
                        "many solver / line-search iterations (default 1,4; 'none' to skip; skipped with --quick)")
    p.add_argument("--value-target", default="gae",
                   help="the critic of the measured sweeps: gae (default) or retrace (with its default buffer)")
    p.add_argument("--physics", default="mjx",
                   help="comma-separated physics backends to measure, each for every raw batch, sweep and profile: "
                        "mjx (default), c (MuJoCo C inside the program), or mjx,c")
    p.add_argument("--physics-threads", type=int, default=0,
                   help="MuJoCo C threads per worker process for --physics c (default 0: its share of the cores)")
    p.add_argument("--randomize", default=None, metavar="TEXT",
                   help="also measure every sweep trained under this domain randomization (envs/randomization.py's "
                        "text), right after its nominal twin; bench.json gives each one's ratio_vs_nominal")
    return p


def parse_backends(text: str, env: str) -> list:
    """--physics: the backends to measure, each checked against the task; ValueError naming the flag."""

    backends = [b.strip() for b in text.split(",")]
    for b in backends:
        try:
            envs.check_backend(env, Physics(backend=b))
        except ValueError as e:
            raise ValueError(f"--physics: {e}") from None
    return list(dict.fromkeys(backends))


def make_plan(args: argparse.Namespace) -> dict:
    """What to measure: {sizes, procs, batches, policies, variant, repeats, backends, plan, raw_plan}: plan
    entries (policy, runs, processes, solver variant, backend), raw_plan (batch, processes, variant, backend);
    ValueError on bad input."""
    envs.check_name(args.env)
    backends = parse_backends(args.physics, args.env)
    cores = os.cpu_count() or 1
    policies = args.policies.split(",") if args.policies else ["mixture"]
    sizes = positive_ints("--sizes", args.sizes, list(QUICK_SIZES if args.quick else SIZES))
    procs = positive_ints("--processes", args.processes, sorted({1, cores}))
    batches = positive_ints("--raw-batches", args.raw_batches, [256] if args.quick else list(RAW_BATCHES))
    variant = parse_solver_variant(args.solver_variant, args.quick)
    profile_procs = positive_ints("--profile-processes", args.profile_processes, [1])
    if args.profile_runs and max(profile_procs) > args.profile_runs:
        raise ValueError(f"--profile-processes {max(profile_procs)} is more than --profile-runs {args.profile_runs}")
    for pol, be in itertools.product(policies, backends):  # the sweeps' own validation, before anything compiles
        randomize = {"randomize": args.randomize} if args.randomize else {}
        check_spec({"envs": [args.env], "policies": [pol], "clusters": [6], "steps": 1,
                    "config": {"value_target": args.value_target, "physics": {"backend": be}, **randomize}}, source="bench")
    plan = [(pol, n, k, None, be) for be in backends for pol in policies for n in sizes for k in procs if k <= n]
    raw_plan = [(b, k, None, be) for be in backends for b in batches for k in procs if k <= b]
    if args.quick and not args.processes:  # under 3 min: each size on as many processes as it can use
        plan = [(pol, n, max(k for k in procs if k <= n), None, be) for be in backends for pol in policies for n in sizes]
        raw_plan = [(b, max(k for k in procs if k <= b), None, be) for be in backends for b in batches]
    k_all = max(k for k in procs if k <= max(sizes))
    if not args.policies and not args.quick:  # the flat baseline where it matters most, to stay under ~20 min
        plan += [("mlp", max(sizes), k_all, None, be) for be in backends]
    if variant and "mjx" in backends:  # MJX's solver options
        plan += [("mixture", max(sizes), k_all, variant, "mjx")]
        raw_plan += [(max(batches), max(k for k in procs if k <= max(batches)), variant, "mjx")]
    if args.randomize:  # each sweep's randomized twin right after it (the same machine state, one ratio)
        plan = [entry for p in plan for entry in ((*p[:4], p[4]), (*p[:4], (p[4], args.randomize)))]
    return {"sizes": sizes, "procs": procs, "batches": batches, "policies": policies, "variant": variant, "backends": backends,
            "profile_procs": profile_procs,
            "repeats": args.repeats or (2 if args.quick else 3), "plan": plan, "raw_plan": raw_plan}


def add_ratios(r: dict, c_ref: dict, solver: tuple | None) -> None:
    """ratio_vs_mujoco_c: against MuJoCo C with the same solver settings (the same simulator);
    ratio_vs_mujoco_c_task_solver: against MuJoCo C with the MJCF's own (differs for the variant)."""
    r["ratio_vs_mujoco_c"] = r["env_steps_per_s"] / c_ref[solver]["env_steps_per_s"]
    r["ratio_vs_mujoco_c_task_solver"] = r["env_steps_per_s"] / c_ref[None]["env_steps_per_s"]


def solver_tag(solver: tuple | None) -> str:
    """The solver variant as printed beside a measurement ('' for the task's own)."""
    return f"  solver {solver[0]}/{solver[1]}" if solver else ""


def measure_references(env: str, variant: tuple | None) -> dict:
    """MuJoCo C's rate with the task's solver (key None) and, if asked, with the variant's."""
    mujoco_c = measure_mujoco_c(env)
    print(f"MuJoCo C rollout: {mujoco_c['env_steps_per_s']:,.0f} env-steps/s ({mujoco_c['threads']} threads, "
          f"batch {mujoco_c['batch']}, {mujoco_c['substeps_per_env_step']} substeps)", flush=True)
    c_ref = {None: mujoco_c}
    if variant:
        c_ref[variant] = measure_mujoco_c(env, solver=variant)
        print(f"MuJoCo C rollout with {variant[0]} solver / {variant[1]} line-search iterations: "
              f"{c_ref[variant]['env_steps_per_s']:,.0f} env-steps/s", flush=True)
    return c_ref


def measure_raw_plan(args: argparse.Namespace, info: dict, report: dict, c_ref: dict, save: Callable) -> None:
    """Measure raw stepping at every batch of the plan, printing a row and saving bench.json after each."""
    print(f"{'raw':8} {'physics':>7} {'batch':>5} {'procs':>5} {'env-steps/s':>12} {'ratio_vs_C':>10} {'compile_s':>9}", flush=True)
    for b, k, sol, be in info["raw_plan"]:
        try:
            r = measure_raw(args.env, b, k, info["repeats"], solver=sol, backend=be, physics_threads=args.physics_threads)
            add_ratios(r, c_ref, sol)
            print(f"{'':8} {be:>7} {b:5d} {k:5d} {r['env_steps_per_s']:12,.0f} {r['ratio_vs_mujoco_c']:10.3f} {r['compile_s']:9.1f}"
                  + solver_tag(sol), flush=True)
        except BenchError as e:
            r = {"env": args.env, "batch": b, "processes": k, **solver_field(sol), "backend": be, "error": str(e)}
        report["raw"].append(r)
        save()


def measure_sweep_plan(args: argparse.Namespace, info: dict, report: dict, c_ref: dict, save: Callable) -> None:
    """Measure every sweep of the plan, printing a row and saving bench.json after each."""
    print(f"{'policy':8} {'physics':>7} {'runs':>5} {'procs':>5} {'env-steps/s':>12} {'ratio_vs_C':>10} {'compile_s':>9} "
          f"{'peak_MiB':>9}", flush=True)
    nominal = {}  # (policy, runs, processes, solver, backend) -> its nominal rate, for the randomized twin's ratio
    for pol, n, k, sol, be in info["plan"]:
        be, randomize = be if isinstance(be, tuple) else (be, "")
        try:
            cell = SweepCell(args.env, pol, n, k, solver=sol, run_batch=args.run_batch, value_target=args.value_target,
                             backend=be, physics_threads=args.physics_threads, randomize=randomize)
            r = measure_sweep(cell, reps(info["repeats"], n, args.repeats is not None))
            add_ratios(r, c_ref, sol)
            twin = (pol, n, k, sol, be)
            if randomize and twin in nominal:
                r["ratio_vs_nominal"] = r["env_steps_per_s"] / nominal[twin]
            elif not randomize:
                nominal[twin] = r["env_steps_per_s"]
            print(f"{pol:8} {be:>7} {n:5d} {k:5d} {r['env_steps_per_s']:12,.0f} {r['ratio_vs_mujoco_c']:10.3f} "
                  f"{r['compile_s']:9.1f} {r['peak_rss_mib']:9.0f}" + solver_tag(sol)
                  + (f"  randomized: {r.get('ratio_vs_nominal', float('nan')):.3f} of nominal" if randomize else ""), flush=True)
            if "in_run" in r:
                r["in_run"].update(in_run_ceiling(r["in_run"], c_ref[sol]))
                r["in_run"]["sweep_of_ceiling"] = r["ratio_vs_mujoco_c"] / r["in_run"]["ratio_ceiling_in_run"]
                print_in_run(r["in_run"])
        except BenchError as e:
            r = {"env": args.env, "policy": pol, "runs": n, "processes": k, **solver_field(sol), "backend": be,
                 "randomize": randomize, "error": str(e)}
        report["sweeps"].append(r)
        save()


def print_in_run(split: dict) -> None:
    """One line: a 'c' sweep's split of its time and its in-run ceiling."""
    f = split["fractions"]
    print(f"{'':8} in the run: MuJoCo C {f['mujoco_c']:.0%} ({split['mujoco_c_us_per_env_step']:.1f} us per env step and "
          f"worker; its rollout {split['rollout_us_per_env_step']:.1f}), rest of the host calls {f['host_other']:.0%}, "
          f"program {f['program']:.0%}; ceiling {split['ratio_ceiling_in_run']:.2f} of MuJoCo C, the sweep at "
          f"{split['sweep_of_ceiling']:.2f} of it ({split['sweep_of_ceiling_at_own_mujoco_c']:.2f} with MuJoCo C at its "
          f"own cost in the run)", flush=True)


def measure_profile(args: argparse.Namespace, repeats: int, mujoco_c: dict, backend: str = "mjx", processes: int = 1) -> dict:
    """The time profile at --profile-runs runs on `processes` workers, with the ratio ceiling when MuJoCo C
    was measured."""
    try:
        prof = time_profile(args.env, "mixture", args.profile_runs, repeats, args.run_batch, backend=backend,
                            processes=processes)
        f = prof["fractions"]
        print(f"time profile ({backend}, mixture, {args.profile_runs} runs, {processes} process(es)), per PPO iteration "
              f"{prof['iteration_s']:.2f} s: "
              f"physics {f['physics']:.0%}, rest of rollout (policy, normalization, GAE) {f['rollout_other']:.0%}, "
              f"PPO update ({prof['num_epochs']} epochs) {f['update']:.0%}", flush=True)
        if "error" not in mujoco_c:
            prof.update(ratio_ceiling(prof, mujoco_c))
            print(f"with physics as cheap as MuJoCo C's and this policy + PPO update, ours / MuJoCo C could reach at most "
                  f"{prof['ratio_ceiling_with_mujoco_c_physics']:.2f}", flush=True)
    except BenchError as e:
        prof = {"backend": backend, "processes": processes, "error": str(e)}
    return prof


def bench(argv: list | None) -> int:
    """Measure the plan (its worker processes: gsa_jax.benchmark.workers) and write bench.json and bench.png."""
    args = build_parser().parse_args(argv)
    try:
        info = make_plan(args)
    except ValueError as e:
        raise BenchError(e) from None
    plan, raw_plan, variant, repeats = info["plan"], info["raw_plan"], info["variant"], info["repeats"]
    n_profiles = len(info["backends"]) * len(info["profile_procs"])
    print(f"gsa bench: {args.env}: raw stepping at batch {info['batches']}, {len(plan)} sweep configurations (runs "
          f"{info['sizes']}, policies {info['policies']}, processes {info['procs']})"
          + (f", a time profile at {args.profile_runs} runs on {info['profile_procs']} process(es)" if args.profile_runs else "")
          + (f", the largest sizes again with {variant[0]} solver / {variant[1]} line-search iterations" if variant else "")
          + f"; {repeats} timed chunks each (median); about {estimate_s(plan, raw_plan, args.profile_runs, repeats, n_profiles) / 60:.0f} min",
          flush=True)
    os.makedirs(args.out, exist_ok=True)
    t_start = time.perf_counter()
    c_ref = measure_references(args.env, variant)
    mujoco_c = c_ref[None]
    report = {"env": args.env, "quick": args.quick, "repeats": repeats, "run_batch": args.run_batch, "mujoco_c": mujoco_c,
              "raw": [], "sweeps": [],
              **({"mujoco_c_solver_variant": c_ref[variant]} if variant else {}), **run_metadata()}

    def save():
        report["wall_s"] = time.perf_counter() - t_start
        write_atomic(os.path.join(args.out, "bench.json"), json.dumps(report, indent=1))

    measure_raw_plan(args, info, report, c_ref, save)
    measure_sweep_plan(args, info, report, c_ref, save)
    if args.profile_runs:
        report["profiles"] = [measure_profile(args, repeats, mujoco_c, be, k) for be in info["backends"]
                              for k in info["profile_procs"]]
        save()
    plot([r for r in report["sweeps"] if not r.get("randomize")], report["raw"], mujoco_c, os.path.join(args.out, "bench.png"), report.get("mujoco_c_solver_variant"))
    print(f"wrote {args.out}/bench.json and bench.png in {(time.perf_counter() - t_start) / 60:.1f} min", flush=True)
    return 0


def main(argv: list | None = None) -> int:
    """`gsa bench`: exit status 0, or 2 on bad input."""
    return run_command("bench", lambda: bench(argv))
