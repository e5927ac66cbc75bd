"""Figures: paper-style figures of a sweep (`python -m gsa_jax.plot <sweep dir> [--out fig.png]`), and the
learning curve of a single run (plot_curve, written by gsa_jax.train as curve.png).

Merges every metrics.csv under the directory (one per worker process or host), then draws, per
env, the mean training return vs env steps for flat PPO and each K (95% confidence band over
seeds, Student t), like the paper's Figure 1. Also writes `final_returns.csv` (per cell, the mean
return over the last 10% of iterations, averaged over seeds, with its 95% interval) and
`return_vs_k.png` (final return against K, flat PPO as a band: how many linear controllers a task needs).
Runs that stopped at a NaN/inf (sweep.json 'failed_runs') are left out of every mean and listed apart:
in the legend and in final_returns.csv's failed_runs column (seed@iteration).
"""

import argparse
import csv
import glob
import math
import os
import sys
import warnings
from collections import defaultdict

import numpy as np

from gsa_jax.metrics import ITERATION_METRICS

# two-sided 95% Student t quantiles by degrees of freedom (1..30); beyond, 1.96
_T95 = [12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
        2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042]
_ID_COLS = ("env", "policy", "K", "seed", "run")
_METRIC_COLS = set(ITERATION_METRICS)


def t95(n):
    return _T95[n - 2] if 2 <= n <= 31 else 1.96


def load_sweep(sweep_dir):
    """All tidy rows under sweep_dir -> {cell: {seed: (env_steps [T], returns [T])}}, cell = (env, policy, K, extra...)."""
    paths = sorted(glob.glob(os.path.join(sweep_dir, "**", "metrics.csv"), recursive=True))
    if not paths:
        raise FileNotFoundError(f"no metrics.csv under {sweep_dir!r} (is it a sweep directory?)")
    series = defaultdict(lambda: defaultdict(list))
    for path in paths:
        with open(path) as f:
            reader = csv.DictReader(f)
            if reader.fieldnames is None or not set(_ID_COLS) <= set(reader.fieldnames):
                continue  # a single-run metrics.csv (train.py) or foreign file
            extra = [c for c in reader.fieldnames if c not in _ID_COLS and c not in _METRIC_COLS]
            for r in reader:
                cell = (r["env"], r["policy"], int(r["K"])) + tuple((c, r[c]) for c in extra)
                ret = float(r["episode_return"]) if r["episode_return"] != "" else math.nan
                series[cell][int(r["seed"])].append((int(r["env_steps"]), ret))
    out = {}
    for cell, seeds in series.items():
        out[cell] = {}
        for seed, pts in seeds.items():
            pts.sort()
            out[cell][seed] = (np.array([p[0] for p in pts]), np.array([p[1] for p in pts]))
    if not out:
        raise FileNotFoundError(f"no sweep metrics.csv under {sweep_dir!r}")
    return out


def load_failed(sweep_dir):
    """Runs that stopped at a NaN/inf: sweep.json's 'failed_runs', or the workers' failed_runs.json."""
    import json

    failed = []
    metas = sorted(glob.glob(os.path.join(sweep_dir, "**", "sweep.json"), recursive=True))
    for path in metas:
        with open(path) as f:
            failed.extend(json.load(f).get("failed_runs", []))
    if not failed:  # a sweep still running or stopped: the workers' own lists
        for path in sorted(glob.glob(os.path.join(sweep_dir, "**", "failed_runs.json"), recursive=True)):
            with open(path) as f:
                failed.extend(json.load(f))
    return failed


def failed_cell(f):
    """The cell (env, policy, K, (column, value)...) of a failed run, as load_sweep keys them."""
    extras = [c for c in f if c not in ("run", "env", "policy", "K", "seed", "failed_at")]
    return (f["env"], f["policy"], int(f["K"])) + tuple(
        (f"hparam_{c}" if c in _METRIC_COLS else c, str(f[c])) for c in extras)


def drop_failed(data, failed):
    """(data without the failed runs, {cell: [(seed, failed_at)]}): failed runs are reported apart,
    never averaged into a cell (their series end early; a run failing at once has none)."""
    dropped = defaultdict(list)
    for f in failed:
        cell = failed_cell(f)
        if cell in data:
            data[cell].pop(int(f["seed"]), None)
        dropped[cell].append((int(f["seed"]), int(f["failed_at"])))
    return {c: s for c, s in data.items() if s}, dict(dropped)


def smooth(y, window):
    """Trailing mean over `window` iterations, ignoring NaN (iterations where no episode ended)."""
    if window <= 1:
        return y
    ok = np.isfinite(y)
    c = np.concatenate([[0.0], np.cumsum(np.where(ok, y, 0.0))])
    n = np.concatenate([[0], np.cumsum(ok)])
    idx = np.arange(1, len(y) + 1)
    lo = np.maximum(0, idx - window)
    cnt = n[idx] - n[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, (c[idx] - c[lo]) / np.maximum(cnt, 1), np.nan)


def cell_label(cell, action_dims):
    env, policy, k = cell[:3]
    extra = "".join(f", {v}" if c == "subpolicy" else f", {c}={v}" for c, v in cell[3:] if v != "")
    if policy == "mlp":
        return "flat PPO (MLP 64x64)" + extra
    d_a = action_dims.get(env)
    mult = f" ({k / d_a:.3g} d_a)" if d_a else ""
    return f"K={k}{mult}" + extra


def cell_curve(seeds, window):
    """Mean and 95% half-width over seeds of smoothed returns, on the common env_steps grid
    (NaN where no seed finished an episode yet)."""
    length = min(len(x) for x, _ in seeds.values())
    xs = next(iter(seeds.values()))[0][:length]
    ys = np.stack([smooth(y[:length], window) for _, y in seeds.values()])
    n = np.sum(np.isfinite(ys), axis=0)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: iterations before any episode ended
        mean = np.nanmean(np.where(np.isfinite(ys), ys, np.nan), axis=0) if ys.size else ys
        sd = np.nanstd(ys, axis=0, ddof=1) if ys.shape[0] > 1 else np.zeros_like(mean)
    half = np.array([t95(k) for k in n]) * sd / np.sqrt(np.maximum(n, 1))
    return xs, mean, half, ys


def final_table(data, action_dims, failed=None):
    """Per cell: final return (mean over the last 10% of iterations) mean and 95% t-interval over seeds;
    failed_runs lists the seeds that stopped at a NaN/inf (seed@iteration), left out of the statistics."""
    rows = []
    failed = failed or {}
    for cell in sorted(set(failed) - set(data), key=lambda c: (c[0], c[1] != "mlp", c[2], c[3:])):  # every seed failed
        rows.append({"env": cell[0], "policy": cell[1], "K": cell[2] if cell[1] == "mixture" else "", "K_over_action_dim": "",
                     **{c: v for c, v in cell[3:]}, "seeds": 0, "final_return_mean": "", "ci95_halfwidth": "",
                     "env_steps": "", "failed_runs": " ".join(f"{s}@{it}" for s, it in sorted(failed[cell]))})
    for cell, seeds in sorted(data.items(), key=lambda kv: (kv[0][0], kv[0][1] != "mlp", kv[0][2], kv[0][3:])):
        finals = []
        for _, y in seeds.values():
            tail = y[-max(1, len(y) // 10):]
            if np.any(np.isfinite(tail)):
                finals.append(np.nanmean(tail))
        finals = np.array(finals)
        n = len(finals)
        half = t95(n) * finals.std(ddof=1) / math.sqrt(n) if n > 1 else math.nan
        env, policy, k = cell[:3]
        rows.append({"env": env, "policy": policy, "K": k if policy == "mixture" else "",
                     "K_over_action_dim": round(k / action_dims[env], 3) if policy == "mixture" and env in action_dims else "",
                     **{c: v for c, v in cell[3:]}, "seeds": n, "final_return_mean": round(float(finals.mean()), 2) if n else "",
                     "ci95_halfwidth": round(float(half), 2) if n > 1 else "", "env_steps": int(next(iter(seeds.values()))[0][-1]),
                     "failed_runs": " ".join(f"{s}@{it}" for s, it in sorted(failed.get(cell, [])))})
    return rows


def plot_curve(rows, path, title=""):
    """A single run's learning curve: rows are metrics.csv rows as dicts. Training return per iteration
    (with a trailing mean), deterministic evaluation returns as markers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def col(name):
        pts = [(float(r["env_steps"]), float(r[name])) for r in rows if r.get(name, "") not in ("", None)]
        pts = [p for p in pts if not math.isnan(p[1])]
        return zip(*pts) if pts else ((), ())

    fig, ax = plt.subplots(figsize=(7, 4.2))
    xs, ys = col("episode_return")
    ax.plot(xs, ys, lw=0.8, alpha=0.35, color="C0", label="training episodes (stochastic policy)")
    if len(ys) >= 10:  # few episodes end per iteration late in training: show a trailing mean too
        w = max(5, len(ys) // 30)
        trailing = [sum(ys[max(0, i - w + 1):i + 1]) / len(ys[max(0, i - w + 1):i + 1]) for i in range(len(ys))]
        ax.plot(xs, trailing, lw=1.8, color="C0", label=f"  trailing mean over {w} iterations")
    xs, ys = col("eval_return")
    ax.plot(xs, ys, "o-", ms=4, lw=1, color="C1", label="evaluation (deterministic controller)")
    ax.set(xlabel="environment steps", ylabel="episode return", title=title)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_return_vs_k(rows, path):
    """Final return (mean, 95% CI over seeds) against K per env; flat PPO as a horizontal band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    env_names = list(dict.fromkeys(r["env"] for r in rows))
    fixed = {"env", "policy", "K", "K_over_action_dim", "seeds", "final_return_mean", "ci95_halfwidth", "env_steps", "failed_runs"}
    fig, axes = plt.subplots(1, len(env_names), figsize=(max(6.5, 4.6 * len(env_names)), 4.0), squeeze=False)
    for ax, env_name in zip(axes.flat, env_names):
        mix = [r for r in rows if r["env"] == env_name and r["policy"] == "mixture" and r["seeds"]]
        # one curve per sub-policy class (and per other swept setting): the whole complexity/return trade-off
        curves = defaultdict(list)
        for r in mix:
            curves[tuple((c, v) for c, v in r.items() if c not in fixed)].append(r)
        all_ks = sorted({r["K"] for r in mix})
        for extra, pts in curves.items():
            pts = sorted(pts, key=lambda r: r["K"])
            ks = np.array([r["K"] for r in pts], float)
            mean = np.array([r["final_return_mean"] for r in pts], float)
            half = np.array([r["ci95_halfwidth"] if r["ci95_halfwidth"] != "" else 0.0 for r in pts], float)
            sub = dict(extra).get("subpolicy") or "linear"
            rest = "".join(f", {c}={v}" for c, v in extra if c != "subpolicy")
            ax.errorbar(ks, mean, yerr=half, fmt="o-", capsize=3, label=f"mixture of K {sub} controllers{rest}")
        if all_ks:
            ax.set_xscale("log", base=2)
            ax.set_xticks(all_ks, [f"{int(k)}" for k in all_ks])
        for r in rows:
            if r["env"] == env_name and r["policy"] == "mlp" and r["seeds"]:
                h = r["ci95_halfwidth"] if r["ci95_halfwidth"] != "" else 0.0
                ax.axhspan(r["final_return_mean"] - h, r["final_return_mean"] + h, color="k", alpha=0.15, lw=0)
                ax.axhline(r["final_return_mean"], color="k", lw=1.5, label="flat PPO (MLP 64x64)")
        ax.set_title(env_name)
        ax.set_xlabel("K (number of clusters / sub-policies)")
        ax.set_ylabel("final return")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("How many (and how complex) controllers does the task need? (final return, mean, 95% CI over seeds)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_sweep(sweep_dir, out_png=None, window=None, action_dims=None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data, failed = drop_failed(load_sweep(sweep_dir), load_failed(sweep_dir))
    if action_dims is None:
        action_dims = {}
        for env_name in {c[0] for c in data}:
            try:
                import envs

                action_dims[env_name] = envs.action_size(env_name)
            except Exception:  # noqa: BLE001 - a label detail; plotting must not fail on it
                pass
    env_names = list(dict.fromkeys(c[0] for c in sorted(data)))
    ncols = min(3, len(env_names))
    nrows = math.ceil(len(env_names) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(max(7.0, 5.2 * ncols), 3.9 * nrows + 0.3), squeeze=False)
    for ax, env_name in zip(axes.flat, env_names):
        cells = sorted((c for c in data if c[0] == env_name), key=lambda c: (c[1] != "mlp", c[2], c[3:]))
        for i, cell in enumerate(cells):
            seeds = data[cell]
            w = window or max(1, len(next(iter(seeds.values()))[0]) // 50)
            xs, mean, half, _ = cell_curve(seeds, w)
            style = dict(color="black", lw=2.0) if cell[1] == "mlp" else dict(color=plt.cm.viridis(i / max(1, len(cells) - 1) * 0.9), lw=1.6)
            n_failed = f", {len(failed[cell])} failed (NaN/inf), not shown" if cell in failed else ""
            ax.plot(xs, mean, label=f"{cell_label(cell, action_dims)} (n={len(seeds)}{n_failed})", **style)
            ax.fill_between(xs, mean - half, mean + half, alpha=0.18, color=style["color"], lw=0)
        ax.set_title(env_name)
        ax.set_xlabel("environment steps")
        ax.set_ylabel("episode return")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    for ax in list(axes.flat)[len(env_names):]:
        ax.axis("off")
    fig.suptitle("Flat PPO vs mixtures of K linear controllers (mean, 95% CI over seeds)", fontsize=11)
    fig.tight_layout()
    out_png = out_png or os.path.join(sweep_dir, "figure.png")
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    rows = final_table(data, action_dims, failed)
    table_path = os.path.join(os.path.dirname(os.path.abspath(out_png)), "final_returns.csv")
    cols = list(dict.fromkeys(k for r in rows for k in r))
    with open(table_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        w.writerows(rows)
    plot_return_vs_k(rows, os.path.join(os.path.dirname(os.path.abspath(out_png)), "return_vs_k.png"))
    return out_png, table_path, rows


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m gsa_jax.plot", description=__doc__.split("\n")[0])
    p.add_argument("sweep_dir")
    p.add_argument("--out", default=None,
                   help="PNG path, or a directory for figure.png and the tables (default <sweep_dir>/figure.png)")
    p.add_argument("--window", type=int, default=None, help="smoothing window in iterations (default: 2%% of the run)")
    args = p.parse_args(argv)
    out = args.out
    if out is not None and (os.path.isdir(out) or not out.lower().endswith(".png")):
        os.makedirs(out, exist_ok=True)
        out = os.path.join(out, "figure.png")
    try:
        png, table, rows = plot_sweep(args.sweep_dir, out, args.window)
    except FileNotFoundError as e:
        print(f"gsa_jax.plot: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {png} and {table}")
    for r in rows:
        print("  " + "  ".join(f"{k}={v}" for k, v in r.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
