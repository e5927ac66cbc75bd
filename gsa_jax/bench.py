"""The vmapped seed benchmark: `python -m gsa_jax.bench [--quick] [--out DIR]` (make bench).

For `hopper` it measures end-to-end training throughput (env steps per second, PPO updates
included, compile excluded and reported separately) of sweeps of 1, 16, 64 and 256 runs
(mixture K=6, and mlp), with 1 and with 2 worker processes (each one XLA CPU device, as
`gsa_jax.sweep` runs them), plus compile time and peak resident
memory; and, in the same invocation, the raw step rate of MuJoCo C on the same MJCF
(`mujoco.rollout`, one thread per core, batch 256, the task's substeps per env step).
Every figure is the median of repeated chunks of one PPO iteration; workers of a 2-process
measurement start their timed chunks together. Writes bench.json (with `ratio_vs_mujoco_c`
for each sweep) and bench.png.
"""

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from gsa_jax.checkpoint import write_atomic

SIZES = (1, 16, 64, 256)
QUICK_SIZES = (1, 16)


# ----------------------------------------------------------------------------------------------- workers
def worker(args):
    """One process: compile the group program for args.runs runs, wait at the barrier, time chunks."""
    import jax

    from gsa_jax.sweep import check_spec, make_group_program, pad_runs, stack_hparams

    spec = check_spec({"envs": [args.env], "policies": [args.policy], "clusters": [args.clusters],
                       "seeds": list(range(args.seed0, args.seed0 + args.runs)), "steps": 10**9})
    from gsa_jax.sweep import build_grid, group_config

    _, _, runs = build_grid(spec)[0]
    cfg = group_config(spec, args.env, args.policy, runs)
    devices = jax.local_devices()[:1]
    t0 = time.perf_counter()
    _, init, run, place = make_group_program(cfg, 1, devices)
    runs = pad_runs(runs, len(devices))
    hps = place(stack_hparams(runs, [], 1000))
    keys = place(jax.numpy.stack([jax.random.PRNGKey(r["seed"]) for r in runs]))
    states = init(keys, hps)
    run = run.lower(states, hps).compile()
    states, _ = run(states, hps)  # first execution (allocations, page faults) is not timed
    jax.block_until_ready(states)
    compile_s = time.perf_counter() - t0
    open(os.path.join(args.barrier, f"ready-{args.worker_id}"), "w").close()
    while len([n for n in os.listdir(args.barrier) if n.startswith("ready-")]) < args.num_workers:
        time.sleep(0.01)
    times = []
    for _ in range(args.repeats):
        t = time.perf_counter()
        states, m = run(states, hps)
        jax.block_until_ready(states)
        times.append(time.perf_counter() - t)
    steps = len(runs) * cfg.batch_size
    print(json.dumps({
        "compile_s": compile_s, "chunk_s": times, "env_steps_per_chunk": steps,
        "env_steps_per_s": steps / statistics.median(times),
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }), flush=True)


def measure_sweep(env, policy, runs, processes, repeats, clusters=6):
    """Throughput of `runs` runs split over `processes` workers, measured together."""
    share = [runs // processes + (1 if i < runs % processes else 0) for i in range(processes)]
    barrier = tempfile.mkdtemp(prefix="gsa_bench_")
    procs, seed0 = [], 0
    for i, n in enumerate(share):
        cmd = [sys.executable, "-m", "gsa_jax.bench", "--worker", "--env", env, "--policy", policy,
               "--clusters", str(clusters), "--runs", str(n), "--seed0", str(seed0), "--repeats", str(repeats),
               "--barrier", barrier, "--worker-id", str(i), "--num-workers", str(processes)]
        procs.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
        seed0 += n
    results = []
    for p in procs:
        out, err = p.communicate()
        if p.returncode != 0:
            raise RuntimeError(f"bench worker failed:\n{err[-3000:]}")
        results.append(json.loads(out.strip().splitlines()[-1]))
    return {
        "env": env, "policy": policy, "runs": runs, "processes": processes,
        "env_steps_per_s": sum(r["env_steps_per_s"] for r in results),
        "compile_s": max(r["compile_s"] for r in results),
        "peak_rss_mib": sum(r["peak_rss_mib"] for r in results),
        "peak_rss_mib_per_process": max(r["peak_rss_mib"] for r in results),
        "chunk_s": [r["chunk_s"] for r in results],
        "env_steps_per_iteration": sum(r["env_steps_per_chunk"] for r in results),
    }


def measure_mujoco_c(env_name, batch=256, steps=200, repeats=3, threads=None):
    """Env-steps/s of MuJoCo C (`mujoco.rollout`) on the env's own MJCF: random controls, the env's
    substeps (n_frames) per env step, one MjData per thread."""
    import mujoco
    from mujoco import rollout

    import envs

    base = envs.make_base(env_name)
    model = base.sys.mj_model
    n_frames = int(getattr(base, "_n_frames", 1))
    threads = threads or os.cpu_count() or 1
    datas = [mujoco.MjData(model) for _ in range(threads)]
    d0 = mujoco.MjData(model)
    mujoco.mj_resetData(model, d0)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.zeros((mujoco.mj_stateSize(model, spec),))
    mujoco.mj_getState(model, d0, state, spec)
    rng = np.random.default_rng(0)
    init = np.repeat(state[None], batch, axis=0)
    nq = model.nq
    init[:, 1:1 + nq] += rng.uniform(-0.005, 0.005, size=(batch, nq))  # state[0] is time
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    ctrl = rng.uniform(lo, hi, size=(batch, steps, model.nu))
    ctrl = np.repeat(ctrl, n_frames, axis=1)  # each action held for n_frames physics steps
    times = []
    with rollout.Rollout(nthread=threads) as r:
        r.rollout([model] * batch, datas, init, ctrl)  # warm-up
        for _ in range(repeats):
            t = time.perf_counter()
            r.rollout([model] * batch, datas, init, ctrl)
            times.append(time.perf_counter() - t)
    med = statistics.median(times)
    return {"env": env_name, "batch": batch, "threads": threads, "substeps_per_env_step": n_frames,
            "env_steps_per_s": batch * steps / med, "physics_steps_per_s": batch * steps * n_frames / med, "times_s": times}


# ----------------------------------------------------------------------------------------------- report
def plot(results, mujoco_c, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.4))
    for policy in sorted({r["policy"] for r in results}):
        for procs in sorted({r["processes"] for r in results}):
            pts = sorted((r["runs"], r["env_steps_per_s"]) for r in results if r["policy"] == policy and r["processes"] == procs)
            if pts:
                ax.plot(*zip(*pts), "o-" if policy == "mixture" else "s--", label=f"{policy}, {procs} process(es)")
    ax.axhline(mujoco_c["env_steps_per_s"], color="k", ls=":", label=f"MuJoCo C rollout ({mujoco_c['threads']} threads, physics only)")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("runs trained together (vmapped)")
    ax.set_ylabel("env steps / s (training, end to end)")
    ax.set_title(f"{results[0]['env']}: sweep throughput vs MuJoCo C")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m gsa_jax.bench", description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="1 and 16 runs, mixture only (~3 min)")
    p.add_argument("--out", default="runs/bench")
    p.add_argument("--env", default="hopper")
    p.add_argument("--sizes", default=None, help="comma-separated run counts (default 1,16,64,256)")
    p.add_argument("--policies", default=None, help="comma-separated (default mixture,mlp)")
    p.add_argument("--processes", default=None, help="comma-separated worker counts (default 1,<cores>)")
    p.add_argument("--repeats", type=int, default=None)
    # worker-only arguments
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    for a, t in (("--policy", str), ("--clusters", int), ("--runs", int), ("--seed0", int), ("--barrier", str),
                 ("--worker-id", int), ("--num-workers", int)):
        p.add_argument(a, type=t, default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        args.repeats = args.repeats or 3
        worker(args)
        return 0

    cores = os.cpu_count() or 1
    sizes = [int(s) for s in args.sizes.split(",")] if args.sizes else list(QUICK_SIZES if args.quick else SIZES)
    policies = args.policies.split(",") if args.policies else (["mixture"] if args.quick else ["mixture", "mlp"])
    procs = [int(s) for s in args.processes.split(",")] if args.processes else sorted({1, cores})
    repeats = args.repeats or (2 if args.quick else 3)
    plan = [(pol, n, k) for pol in policies for n in sizes for k in procs if k <= n]
    # rough: ~45 s compile + start per configuration, plus the timed chunks at ~7k steps/s per process
    est = sum(45 + (repeats + 1) * n * 2048 / (7000 * k) for _, n, k in plan) + 30
    print(f"gsa_jax.bench: {args.env}, {len(plan)} sweep configurations (runs {sizes}, policies {policies}, "
          f"processes {procs}), {repeats} timed iterations each; about {est / 60:.0f} min", flush=True)
    from gsa_jax.runinfo import run_metadata

    os.makedirs(args.out, exist_ok=True)
    t_start = time.perf_counter()
    mujoco_c = measure_mujoco_c(args.env)
    print(f"MuJoCo C rollout: {mujoco_c['env_steps_per_s']:,.0f} env-steps/s ({mujoco_c['threads']} threads, "
          f"batch {mujoco_c['batch']}, {mujoco_c['substeps_per_env_step']} substeps)", flush=True)
    results = []
    header = f"{'policy':8} {'runs':>5} {'procs':>5} {'env-steps/s':>12} {'ratio_vs_C':>10} {'compile_s':>9} {'peak_MiB':>9}"
    print(header, flush=True)
    for pol, n, k in plan:
        r = measure_sweep(args.env, pol, n, k, repeats)
        r["ratio_vs_mujoco_c"] = r["env_steps_per_s"] / mujoco_c["env_steps_per_s"]
        results.append(r)
        print(f"{pol:8} {n:5d} {k:5d} {r['env_steps_per_s']:12,.0f} {r['ratio_vs_mujoco_c']:10.3f} "
              f"{r['compile_s']:9.1f} {r['peak_rss_mib']:9.0f}", flush=True)
        report = {"env": args.env, "quick": args.quick, "repeats": repeats, "mujoco_c": mujoco_c, "sweeps": results,
                  "wall_s": time.perf_counter() - t_start, **run_metadata()}
        write_atomic(os.path.join(args.out, "bench.json"), json.dumps(report, indent=1))
    plot(results, mujoco_c, os.path.join(args.out, "bench.png"))
    print(f"wrote {args.out}/bench.json and bench.png in {(time.perf_counter() - t_start) / 60:.1f} min", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
