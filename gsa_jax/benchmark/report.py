"""bench.png: env-steps/s against runs per sweep for every measured configuration, with MuJoCo C's rollout."""

from gsa_jax.algorithm.kinds import MIXTURE

_BACKEND_NAMES = {"mjx": "MJX", "c": "MuJoCo C in the program"}


def _lines(rows, keys, x):
    """{key values: [(x, env_steps_per_s)] sorted by x} over measurement rows (backend 'mjx' where absent)."""
    lines = {}
    for r in rows:
        key = tuple(r.get(k, "mjx") for k in keys)
        lines.setdefault(key, []).append((r[x], r["env_steps_per_s"]))
    return {k: sorted(v) for k, v in sorted(lines.items())}


def plot(results: list, raw: list, mujoco_c: dict, path: str, mujoco_c_variant: "dict | None" = None) -> None:
    """Left: training throughput vs runs (a line per policy and process count); right: raw stepping vs
    batch. Measurements with a changed solver are separate markers (stars), with their MuJoCo C line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.4))
    ax = axes[0]
    ok = [r for r in results if "error" not in r and "solver" not in r]
    for (policy, procs, be), pts in _lines(ok, ("policy", "processes", "backend"), "runs").items():
        ax.plot(*zip(*pts), ("o" if policy == MIXTURE else "s") + ("-" if be == "mjx" else "--"),
                label=f"{policy}, {procs} process(es), {_BACKEND_NAMES[be]}")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("runs trained together (vmapped)")
    ax.set_ylabel("env steps / s (training, end to end)")
    ax.set_title(f"{mujoco_c['env']}: sweep throughput vs MuJoCo C")
    ax2 = axes[1]
    okr = [r for r in raw if "error" not in r and "solver" not in r]
    for (procs, be), pts in _lines(okr, ("processes", "backend"), "batch").items():
        ax2.plot(*zip(*pts), "o-" if be == "mjx" else "o--", label=f"{_BACKEND_NAMES[be]} env.step, {procs} process(es)")
    ax2.set_xscale("log", base=2)
    ax2.set_xlabel("envs stepped together (batch)")
    ax2.set_ylabel("env steps / s (physics only, random actions)")
    ax2.set_title(f"{mujoco_c['env']}: raw stepping")
    for a, rows, x in ((ax, results, "runs"), (ax2, raw, "batch")):
        for r in rows:
            if "solver" in r and "error" not in r:
                sol = r["solver"]
                a.plot(r[x], r["env_steps_per_s"], "*", ms=13, color="C3",
                       label=f"solver {sol['iterations']}/{sol['ls_iterations']} (changed task), {r['processes']} process(es)"
                             + (f", {r['policy']}" if "policy" in r else ""))
    for a in axes:
        a.axhline(mujoco_c["env_steps_per_s"], color="k", ls=":", label=f"MuJoCo C rollout ({mujoco_c['threads']} threads)")
        if mujoco_c_variant:
            sol = mujoco_c_variant["solver"]
            a.axhline(mujoco_c_variant["env_steps_per_s"], color="C3", ls=":",
                      label=f"MuJoCo C, solver {sol['iterations']}/{sol['ls_iterations']}")
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
