"""Time the compiled PPO program part by part, to see where its time goes (`gsa profile [--envs A,B]
[--out DIR]`, make profile).

For each task and policy, one PPO iteration of a sweep worker's sub-batch of runs (--runs, default the sweep's
8) is split into MuJoCo C, the host calls, the env step's compiled side and PPO's own parts (policy sampling,
targets, shuffles and gathers, gradients, Adam, ...; gsa_jax/benchmark/parts.py), each timed alone (median of
--repeats) with its FLOPs and the rate it reaches beside a dense matmul's in the same process. Run it on an
otherwise idle machine: one process, timings are wall-clock. Writes parts.json (every profile, versions, commit)
after each profile and parts.md (one table per profile).
"""

import argparse
import json
import os
import sys
import time

import envs
from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.algorithm.config import Config
from gsa_jax.commands.command_line import command_parser
from gsa_jax.errors import run_command
from gsa_jax.running.checkpoint import write_atomic
from gsa_jax.running.runinfo import run_metadata
from gsa_jax.running.supervise import SINGLE_THREAD_EIGEN
from gsa_jax.running.spec import RUN_BATCH, SpecError, single_group

DEFAULT_ENVS = "Hopper-v5,Walker2d-v5,HalfCheetah-v5,InvertedDoublePendulum-v5,Ant-v5,dmc:cartpole-swingup"


def build_parser() -> argparse.ArgumentParser:
    """`gsa profile`'s options."""
    p = command_parser("profile", __doc__)
    p.runs_jax = True  # it runs JAX programs (command_line.CommandParser)
    p.add_argument("--envs", default=DEFAULT_ENVS, help=f"comma-separated task names (default {DEFAULT_ENVS})")
    p.add_argument("--policies", default="mixture,mlp", help="comma-separated: mixture, mlp (default both)")
    p.add_argument("--clusters", type=int, default=6, help="K of the mixture (default 6, as gsa bench)")
    p.add_argument("--runs", type=int, default=RUN_BATCH, help=f"runs vmapped together (default {RUN_BATCH}: one sweep sub-batch)")
    p.add_argument("--physics", default="c", help="physics backend: c (default: MuJoCo C inside the program) or mjx")
    p.add_argument("--repeats", type=int, default=5, help="timed calls per piece (median; default 5)")
    p.add_argument("--cores", type=int, default=1,
                   help="CPU cores the profile runs on (default 1: one of a sweep's worker processes on its share of "
                        "the machine, with the workers' single-threaded Eigen; 0: all, as XLA and MuJoCo C choose)")
    p.add_argument("--out", default="runs/profile",
                   help="output directory of parts.json and parts.md (default %(default)s)")
    return p


def pin_cores(cores: int) -> None:
    """Before jax starts its backend: run on the first `cores` cores, with a sweep worker's XLA flag when one."""
    if not cores:
        return
    available = sorted(os.sched_getaffinity(0))
    if cores > len(available):
        raise SpecError(f"--cores {cores}: only {len(available)} available")
    os.sched_setaffinity(0, set(available[:cores]))
    if cores == 1 and "xla_cpu_multi_thread_eigen" not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + SINGLE_THREAD_EIGEN).strip()


def sweep_config(env: str, policy: str, K: int, runs: int, backend: str) -> Config:
    """The static Config a sweep of these runs would train with (its defaults, this backend); a task defined in
    Python is made here, so that a missing dependency (dm_control for dmc: tasks) is refused before any profiling."""
    envs.resolve(env).load()
    return single_group(env, policy, K, list(range(runs)), backend, source="gsa-profile")[1]


def table(prof: dict) -> str:
    """A profile as a markdown table (one row per part)."""
    fmt = lambda v, f: "" if v is None else format(v, f)  # noqa: E731
    head = (f"### {prof['env']}, {prof['policy']}" + (f" K={prof['K']}" if prof["K"] else "") + f", {prof['runs']} runs, "
            f"backend {prof['backend']}: iteration {prof['iteration_s'] * 1e3:.0f} ms, PPO's own program "
            f"{prof['ppo_program_s'] * 1e3:.0f} ms ({prof['ppo_program_s'] / prof['iteration_s']:.0%}); matmul "
            f"{prof['matmul_gflop_per_s']:.0f} GFLOP/s; the gradients' matrix products {prof['matrix_products_s'] * 1e3:.0f} ms "
            f"({prof['matrix_products_s'] / prof['ppo_program_s']:.0%} of the PPO program)\n\n"
            "| part | ms / iteration | us / env step | of iteration | of PPO program | kFLOP / env step | GFLOP/s | of matmul |\n"
            "|---|---:|---:|---:|---:|---:|---:|---:|\n")
    rows = [f"| {r['part']} | {r['s_per_iteration'] * 1e3:.1f} | {r['us_per_env_step']:.2f} | {r['share_of_iteration']:.1%} | "
            f"{fmt(r['share_of_ppo'], '.1%')} | {fmt(r['kflop_per_env_step'], '.1f')} | {fmt(r['gflop_per_s'], '.1f')} | "
            f"{fmt(r['of_matmul_rate'], '.0%')} |" for r in prof["parts"]]
    return head + "\n".join(rows) + "\n"


def profile(argv: list | None) -> int:
    """Profile every task x policy asked for; bad input changes nothing."""
    args = build_parser().parse_args(argv)
    envs_, policies = [e for e in args.envs.split(",") if e], [q for q in args.policies.split(",") if q]
    try:
        for flag, value, least in (("--runs", args.runs, 1), ("--repeats", args.repeats, 1), ("--cores", args.cores, 0)):
            if value < least:
                raise SpecError(f"{flag} must be >= {least}, got {value}")
        if not envs_ or not policies:
            raise SpecError(f"--envs and --policies must name at least one each, got {args.envs!r} and {args.policies!r}")
        configs = [(sweep_config(e, q, args.clusters, args.runs, args.physics), q) for e in envs_ for q in policies]
        pin_cores(args.cores)  # last: a refused command leaves the calling process as it was
    except ValueError as e:
        raise SpecError(e) from None
    from gsa_jax.benchmark.parts import profile_parts  # loads JAX: not for `gsa profile --help`

    os.makedirs(args.out, exist_ok=True)
    report = {"command": sys.argv, "cores": sorted(os.sched_getaffinity(0)), "profiles": [], **run_metadata()}
    t0 = time.perf_counter()
    for cfg, policy in configs:
        print(f"profiling {cfg.env}, {policy}, {args.runs} runs ...", flush=True)
        prof = profile_parts(cfg, args.runs, args.clusters if policy == MIXTURE else 1, args.repeats)
        report["profiles"].append(prof)
        report["wall_s"] = time.perf_counter() - t0
        write_atomic(os.path.join(args.out, "parts.json"), json.dumps(report, indent=1))
        write_atomic(os.path.join(args.out, "parts.md"), "\n".join(table(q) for q in report["profiles"]))
        print(table(prof), flush=True)
    print(f"wrote {args.out}/parts.json and parts.md in {(time.perf_counter() - t0) / 60:.1f} min")
    return 0


def main(argv: list | None = None) -> int:
    """`gsa profile`: exit status 0, or 2 on bad input (nothing changed)."""
    return run_command("profile", lambda: profile(argv))
