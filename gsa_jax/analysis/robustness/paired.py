"""Paired pushes (gsa_jax.deployment.pushes) over many controllers: the evaluation driver (resumable, one
controller at a time), each controller's fall probability per push and return lost, and per configuration
their IQM and P(a mixture falls less than flat PPO) with rliable's intervals; `gsa robustness`
runs it beside the shifts."""

import csv
import gzip
import io
import math
import os
from typing import Callable, Sequence

import numpy as np

from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.analysis.robustness.shift_rows import controller_key
from gsa_jax.analysis.sweeps import stats
from gsa_jax.analysis.sweeps.results import read_csv, write_csv
from gsa_jax.deployment.pushes import PushPlan, evaluate_pushes

KEY = ("env", "policy", "K", "seed")
NOMINAL = KEY + ("nominal_score", "mean_length", "full_length_fraction", "episodes")
# P(falls less / loses less)'s interval with the push events resampled too (crossed_interval)
EVENT_CI = ("p_fall_events_ci_low", "p_fall_events_ci_high", "p_lost_events_ci_low", "p_lost_events_ci_high")


def event_columns(windows: Sequence[int]) -> tuple:
    """The column order of pushes.csv.gz."""
    per = [f"{c}_W{w}" for w in windows for c in ("counted", "fell", "lost")]
    return KEY + ("start_seed", "event", "time", "size", "control_fall", "branch_fall", *per)


def write_gz(path: str, rows: list, columns: Sequence[str]) -> None:
    """rows as a gzipped CSV, written atomically (a fixed mtime: the same rows give the same bytes)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns)
    w.writeheader()
    w.writerows(rows)
    tmp = path + ".tmp"
    with open(tmp, "wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", mtime=0) as f:
        f.write(buf.getvalue().encode())
    os.replace(tmp, path)


def evaluate_all_pushes(controllers: list, settings: dict, seeds: np.ndarray, out: str,
                        log: Callable = lambda m: print(m, flush=True)) -> tuple:
    """Paired pushes of every controller not yet in OUT/nominal.csv -> (event rows, nominal rows); both
    files are rewritten after every controller. settings: {sizes, windows, per_episode}."""
    ev_path, nom_path = os.path.join(out, "pushes.csv.gz"), os.path.join(out, "nominal.csv")
    events, nominal = read_csv(ev_path), read_csv(nom_path)
    done = {controller_key(r) for r in nominal}
    for i, (path, meta, ctrl) in enumerate(controllers):
        if controller_key(meta) in done:
            continue
        plan = PushPlan(settings["sizes"], settings["windows"], settings["per_episode"])
        rows, nom = evaluate_pushes(ctrl, meta["env"], seeds, plan)
        events += [{**meta, **r} for r in rows]
        nominal.append({**meta, **nom})
        write_gz(ev_path, events, event_columns(settings["windows"]))
        write_csv(nom_path, nominal, NOMINAL)
        falls = sum(int(r[f"fell_W{max(settings['windows'])}"]) for r in rows)
        counted = sum(int(r[f"counted_W{max(settings['windows'])}"]) for r in rows)
        log(f"[{i + 1}/{len(controllers)}] {os.path.basename(path)}: paired pushes, nominal {nom['nominal_score']:.1f} "
            f"(mean length {nom['mean_length']:.0f}), {falls} falls in {counted} counted pushes")
    return events, nominal


def event_table(events: list, windows: Sequence[int]) -> dict:
    """{(env, size, W): {controller key: [E, 3] (counted, fell, lost)}}: every controller's outcome of each push
    event, the events (start seed, event) in one order per task and size (every controller of a task meets the
    same push times and directions, gsa_jax.deployment.pushes.push_events)."""
    ids = {}
    for r in events:
        ids.setdefault((str(r["env"]), float(r["size"])), set()).add((int(r["start_seed"]), int(r["event"])))
    order = {k: {e: i for i, e in enumerate(sorted(v))} for k, v in ids.items()}
    out = {}
    for r in events:
        env, size = str(r["env"]), float(r["size"])
        i = order[(env, size)][(int(r["start_seed"]), int(r["event"]))]
        for w in windows:
            counted = int(r[f"counted_W{w}"])
            m = out.setdefault((env, size, int(w)), {}).setdefault(tuple(str(r[k]) for k in KEY),
                                                                    np.zeros((len(order[(env, size)]), 3)))
            m[i] = (counted, int(r[f"fell_W{w}"]) if counted else 0, float(r[f"lost_W{w}"]) if counted else 0.0)
    return out


def per_controller(events: list, windows: Sequence[int]) -> dict:
    """{(env, policy, K, seed, size, W): (counted pushes, fall probability, mean return lost)}: a controller's
    falls per counted push and the mean return a counted push cost it (only controllers with a counted push)."""
    return controller_rates(event_table(events, windows))


def controller_rates(table: dict) -> dict:
    """per_controller of an event_table."""
    out = {}
    for (_, size, w), mats in table.items():
        for key, m in mats.items():
            n = int(m[:, 0].sum())
            if n:
                out[key + (size, w)] = (n, m[:, 1].sum() / n, m[:, 2].sum() / n)
    return out


def group(per: dict, events: list, windows: Sequence[int]) -> dict:
    """{(env, policy, K, size, W): {seed: (counted, fall prob, lost)}}, every controller of the events
    included (one with no counted push as (0, NaN, NaN))."""
    out = {}
    ctrls = sorted({tuple(str(r[k]) for k in KEY) for r in events})  # sorted: rliable's resamples follow the cells' order
    sizes = sorted({float(r["size"]) for r in events})
    for c in ctrls:
        for size in sizes:
            for w in windows:
                cell = out.setdefault((c[0], c[1], c[2], size, int(w)), {})
                cell[c[3]] = per.get(c + (size, int(w)), (0, math.nan, math.nan))
    return out


def rates(m: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """m [n, E, 3] (counted, fell, lost) of n controllers, weights [R, E] (each event's multiplicity in R
    resamples) -> [R, n, 2]: each controller's falls and return lost per counted push (NaN where none counted)."""
    counted = weights @ m[..., 0].T
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.stack([weights @ (m[..., 0] * m[..., 1]).T / counted,
                         weights @ (m[..., 0] * m[..., 2]).T / counted], -1)


def crossed_interval(x: np.ndarray, y: np.ndarray, reps: int = stats.REPS, seed: int = 0) -> tuple:
    """x [nx, E, 3], y [ny, E, 3]: two configurations' controllers over the same E push events (event_table) ->
    (fall low, fall high, lost low, high): the 95% percentile interval of P(x falls less / loses less per counted
    push than y; ties half) when the controllers (within each configuration) and the push events (shared by all
    controllers, as a fresh draw of pushes would be) are both resampled with replacement."""
    rng = np.random.default_rng(seed)
    ix, iy = rng.integers(0, len(x), (reps, len(x))), rng.integers(0, len(y), (reps, len(y)))
    e = x.shape[1]
    weights = np.stack([np.bincount(rng.integers(0, e, e), minlength=e) for _ in range(reps)]).astype(float)
    rx = np.take_along_axis(rates(x, weights), ix[..., None], 1)
    ry = np.take_along_axis(rates(y, weights), iy[..., None], 1)
    a, b = rx[:, :, None, :], ry[:, None, :, :]
    valid = np.isfinite(a) & np.isfinite(b)
    wins = np.where(valid, (a < b) + 0.5 * (a == b), 0.0).sum((1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        p = wins / valid.sum((1, 2))  # [R, 2]
    low, high = np.nanpercentile(p, [2.5, 97.5], axis=0) if np.isfinite(p).any() else np.full((2, 2), math.nan)
    return float(low[0]), float(high[0]), float(low[1]), float(high[1])


def crossed_intervals(table: dict, pairs: list, reps: int) -> dict:
    """{str(cell): crossed_interval of the cell's mixture against flat PPO} for cells (env, mixture, K, size, W)
    in pairs, over the controllers with a counted push; table: event_table."""
    out = {}
    for c in pairs:
        mats = table[(c[0], c[3], c[4])]
        pick = lambda policy, k: np.array([m for key, m in sorted(mats.items())  # noqa: E731
                                           if key[1] == policy and key[2] == k and m[:, 0].any()])
        out[str(c)] = crossed_interval(pick(MIXTURE, c[2]), pick(MLP, ""), reps)
    return out


def aggregate_pushes(events: list, windows: Sequence[int], reps: int = stats.REPS) -> list:
    """paired_pushes.csv rows: per task x configuration x push size x window, the controllers with a counted
    push, counted pushes per controller, IQM [CI] of the fall probability and of the return lost per push,
    P(a mixture falls less / loses less than flat PPO) [CI] (ties count half: two that never fall tie); that CI
    resamples controllers under the one draw of push events, the EVENT_CI columns resample the events too."""
    table = event_table(events, windows)
    cells = group(controller_rates(table), events, windows)
    col = lambda c, j: np.array([v[j] for v in cells[c].values()], float)  # noqa: E731
    fin = lambda x: x[np.isfinite(x)][:, None]  # noqa: E731
    fall = stats.iqm_ci({str(c): fin(col(c, 1)) for c in cells if np.isfinite(col(c, 1)).any()}, reps=reps)
    lost = stats.iqm_ci({str(c): fin(col(c, 2)) for c in cells if np.isfinite(col(c, 2)).any()}, reps=reps)
    flat = lambda c: (c[0], MLP, "", c[3], c[4])  # noqa: E731
    ok = [c for c in cells if c[1] == MIXTURE and flat(c) in cells and len(fin(col(c, 1))) and len(fin(col(flat(c), 1)))]
    p_fall = stats.improvement_probability({str(c): (-fin(col(c, 1)), -fin(col(flat(c), 1))) for c in ok}, reps=reps) if ok else {}
    p_lost = stats.improvement_probability({str(c): (-fin(col(c, 2)), -fin(col(flat(c), 2))) for c in ok}, reps=reps) if ok else {}
    crossed = crossed_intervals(table, ok, reps)
    r3 = lambda v: round(float(v), 4) if np.isfinite(v) else ""  # noqa: E731
    rows = []
    for c in sorted(cells, key=lambda c: (c[0], c[3], c[4], c[1] != MLP, int(c[2] or 0))):
        n = col(c, 0)
        f, lo, pf, pl = (fall.get(str(c), (math.nan,) * 3), lost.get(str(c), (math.nan,) * 3),
                         p_fall.get(str(c), (math.nan,) * 3), p_lost.get(str(c), (math.nan,) * 3))
        rows.append({"env": c[0], "policy": c[1], "K": c[2], "size": c[3], "window": c[4], "controllers": len(n),
                     "controllers_counted": int((n > 0).sum()), "counted_per_controller": r3(n.mean()),
                     "fall_iqm": r3(f[0]), "fall_ci_low": r3(f[1]), "fall_ci_high": r3(f[2]),
                     "lost_iqm": r3(lo[0]), "lost_ci_low": r3(lo[1]), "lost_ci_high": r3(lo[2]),
                     "p_falls_less_than_flat_ppo": r3(pf[0]), "p_fall_ci_low": r3(pf[1]), "p_fall_ci_high": r3(pf[2]),
                     "p_loses_less_than_flat_ppo": r3(pl[0]), "p_lost_ci_low": r3(pl[1]), "p_lost_ci_high": r3(pl[2]),
                     **dict(zip(EVENT_CI, map(r3, crossed.get(str(c), (math.nan,) * 4))))})
    return rows


def plot_pushes(agg: list, path: str) -> None:
    """Per task (rows) and window (columns): fall probability per counted push (IQM, 95% CI) against push
    size, flat PPO and each K; tasks where no controller ever falls show the return lost per push."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    env_names = list(dict.fromkeys(r["env"] for r in agg))
    windows = sorted({int(r["window"]) for r in agg})
    fig, axes = plt.subplots(len(env_names), len(windows), figsize=(3.6 * len(windows), 2.9 * len(env_names)), squeeze=False)
    for i, env_name in enumerate(env_names):
        rows = [r for r in agg if r["env"] == env_name]
        falls = any(r["fall_iqm"] not in ("", 0, 0.0) for r in rows)
        what, label = ("fall", "P(fall) per counted push") if falls else ("lost", "return lost per push")
        for j, w in enumerate(windows):
            ax = axes[i, j]
            for policy, k in dict.fromkeys((r["policy"], r["K"]) for r in rows):
                pts = [r for r in rows if (r["policy"], r["K"], int(r["window"])) == (policy, k, w) and r[f"{what}_iqm"] != ""]
                x = np.array([float(r["size"]) for r in pts])
                y = np.array([r[f"{what}_iqm"] for r in pts], float)
                err = np.array([[r[f"{what}_iqm"] - r[f"{what}_ci_low"], r[f"{what}_ci_high"] - r[f"{what}_iqm"]] for r in pts], float).T
                ax.errorbar(x, y, yerr=err if len(pts) else None, marker="o", ms=3, capsize=2, color="k" if policy == MLP else None,
                            label="flat PPO" if policy == MLP else f"K = {k}")
            ax.set(title=f"{env_name}, W = {w} steps", xlabel="push (m/s)", ylabel=label)
            ax.grid(alpha=0.3)
        axes[i, 0].legend(fontsize=7)
    fig.suptitle("Paired pushes: each push against the same episode without it, counted where that episode survives W steps",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
