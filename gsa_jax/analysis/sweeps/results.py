"""Reading a sweep's results: the tidy metrics table (gzipped or not), sweep.json, failed runs, the random
policy's returns; merging several sweeps of one experiment."""

import csv
import glob
import gzip
import io
import json
import math
import os
from collections import defaultdict
from typing import Callable, Iterable, NamedTuple, Sequence

import numpy as np

from envs.physics import record_backend
from gsa_jax.algorithm.kinds import MIXTURE_COLUMNS
from gsa_jax.analysis.sweeps import columns as C
from gsa_jax.analysis.sweeps import stats
from gsa_jax.errors import UserError
from gsa_jax.running.formats import read_json
from gsa_jax.running.metrics import TIDY_METRICS
from gsa_jax.running.runinfo import describe_changes

_ID_COLS = ("env", "policy", "K", "seed", "run")
_METRIC_COLS = set(TIDY_METRICS)
_SERIES = ("env_steps", "episode_return", "episodes", "eval_return", "eval_failures")


class PlotError(UserError, ValueError):
    pass


class Cell(NamedTuple):
    """A sweep's cell, the runs its statistics pool: the task, the policy kind, K (as the tidy table writes it for
    flat PPO too) and the settings that set it apart beyond those: ((column, value), ...) of the sub-policy class,
    critic and swept hyperparameters, in the table's column order."""

    env: str
    policy: str
    k: int
    settings: tuple = ()

    def columns(self) -> dict:
        """The cell as the tidy table's columns: {env, policy, K, setting column: value, ...}."""
        return {"env": self.env, "policy": self.policy, "K": self.k, **dict(self.settings)}


def read_tidy(path: str, series: dict, columns: Sequence[str] = _SERIES) -> bool:
    """Add one tidy metrics.csv's columns to series {cell: {seed: {column: [(iteration, value)]}}}; False if not a
    sweep's."""
    with (gzip.open(path, "rt", newline="") if path.endswith(".gz") else open(path, newline="")) as f:
        reader = csv.DictReader(f)
        if reader.fieldnames is None or not set(_ID_COLS) <= set(reader.fieldnames):
            return False  # a single run's metrics.csv (train.py) or a foreign file
        extra = [c for c in reader.fieldnames if c not in _ID_COLS and c not in _METRIC_COLS]
        for r in reader:
            cell = Cell(r["env"], r["policy"], int(r["K"]), tuple((c, r[c]) for c in extra))
            run = series[cell][int(r["seed"])]
            for c in columns:
                v = r.get(c, "")
                run[c].append((int(r["iteration"]), float(v) if v != "" else math.nan))
    return True


def load_sweep(sweep_dir: str, columns: Sequence[str] = _SERIES) -> dict:
    """All tidy rows under sweep_dir (metrics*.csv, or gzipped as experiments/ keep them) ->
    {Cell: {seed: {column: [T] in iteration order}}}; by default the
    columns env_steps, episode_return, episodes, eval_return, eval_failures (any of TIDY_METRICS can be asked for).
    A column a table does not carry (eval_failures before it was recorded) is NaN throughout."""
    plain = glob.glob(os.path.join(sweep_dir, "**", "metrics*.csv"), recursive=True)
    zipped = glob.glob(os.path.join(sweep_dir, "**", "metrics*.csv.gz"), recursive=True)
    paths = sorted(plain + [p for p in zipped if p[:-3] not in plain])
    if not paths:
        raise FileNotFoundError(f"no metrics.csv under {sweep_dir!r} (is it a sweep directory?)")
    series = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    if not any([read_tidy(p, series, columns) for p in paths]):
        raise FileNotFoundError(f"no sweep metrics.csv under {sweep_dir!r}")
    return {cell: {seed: {c: np.array([v for _, v in sorted(pts)]) for c, pts in cols.items()}
                   for seed, cols in seeds.items()} for cell, seeds in series.items()}


def sweep_metas(sweep_dir: str) -> list:
    """The contents of every sweep.json under sweep_dir (one per sweep; merged results may hold several), in the
    current layout (running.formats)."""
    return [read_json(path, "sweep") for path in sorted(glob.glob(os.path.join(sweep_dir, "**", "sweep.json"),
                                                                     recursive=True))]


def group_settings(sweep_dir: str) -> dict:
    """{(env, policy, critic): what makes its runs comparable (steps, hyperparameters, static config)} of a
    sweep; a sweep listing no value_targets trained with its [config] critic (default GAE)."""
    out = {}
    for meta in sweep_metas(sweep_dir):
        spec = meta.get("spec", {})
        config = spec.get("config") or {}
        for critic in spec.get("value_targets") or [config.get("value_target", "gae")]:
            # retrace_iterations does not change a GAE run
            kept = {k: v for k, v in config.items() if k != "value_target" and (critic != "gae" or k != "retrace_iterations")}
            for env_name in spec.get("envs", []):
                for policy in spec.get("policies", []):
                    out[(env_name, policy, critic)] = {"steps": spec.get("steps"), "hparams": spec.get("hparams"), "config": kept}
    return out


def lists_critics(cells: Iterable[tuple]) -> bool:
    """Whether any of the cells carries a critic column (its sweep listed value_targets)."""
    return any(c == "value_target" for cell in cells for c, _ in cell.settings)


def with_critic(cell: tuple) -> tuple:
    """A cell with ("value_target", "gae") among its settings when it has no critic column (after the
    mixture's own classes, where sweeps write them): sweeps that list no value_targets trained with GAE."""
    if any(c == "value_target" for c, _ in cell.settings):
        return cell
    i = next((i for i, (c, _) in enumerate(cell.settings) if c not in MIXTURE_COLUMNS), len(cell.settings))
    return cell._replace(settings=cell.settings[:i] + (("value_target", "gae"),) + cell.settings[i:])


def load_sweeps(dirs: Sequence[str]) -> dict:
    """load_sweep of every directory, merged; PlotError naming the difference when two hold the same
    group with other settings, or the same run twice. When one sweep lists critics (value_targets), the
    cells of those that do not get the GAE critic's column, so the two critics' cells meet."""
    seen = {}
    for d in dirs:
        for group, settings in group_settings(d).items():
            if group in seen and seen[group][1] != settings:
                diff = describe_changes(seen[group][1], settings)
                raise PlotError(f"{seen[group][0]} and {d} both hold {group[0]}/{group[1]} runs ({group[2]} critic), "
                                f"with different settings ({diff}); plot them apart")
            seen.setdefault(group, (d, settings))
    loaded = [(d, load_sweep(d)) for d in dirs]
    if lists_critics(cell for _, cells in loaded for cell in cells):
        loaded = [(d, {with_critic(cell): seeds for cell, seeds in cells.items()}) for d, cells in loaded]
    data = {}
    for d, cells in loaded:
        for cell, seeds in cells.items():
            twice = set(seeds) & set(data.get(cell, {}))
            if twice:
                raise PlotError(f"{d}: seed {min(twice)} of {cell.env}/{cell.policy} K={cell.k} is already in another directory")
            data.setdefault(cell, {}).update(seeds)
    return data


def load_failed(sweep_dir: str) -> list:
    """Runs that stopped at a NaN/inf: sweep.json's 'failed_runs', or the workers' failed_runs.json."""
    failed = [f for meta in sweep_metas(sweep_dir) for f in meta.get("failed_runs", [])]
    if not failed:  # a sweep still running or stopped: the workers' own lists
        for path in sorted(glob.glob(os.path.join(sweep_dir, "**", "failed_runs.json"), recursive=True)):
            with open(path) as f:
                failed.extend(json.load(f))
    return failed


def failed_cell(f: dict) -> tuple:
    """The Cell of a failed run, as load_sweep keys them."""
    extras = [c for c in f if c not in ("run", "env", "policy", "K", "seed", "failed_at")]
    return Cell(f["env"], f["policy"], int(f["K"]), tuple((f"hparam_{c}" if c in _METRIC_COLS else c, str(f[c])) for c in extras))


def drop_failed(data: dict, failed: list) -> tuple:
    """(data without the failed runs, {cell: [(seed, failed_at)]}): failed runs are reported apart,
    never averaged into a cell (their series end early; a run failing at once has none)."""
    dropped = defaultdict(list)
    critics = lists_critics(data)
    for f in failed:
        cell = with_critic(failed_cell(f)) if critics else failed_cell(f)
        if cell in data:
            data[cell].pop(int(f["seed"]), None)
        dropped[cell].append((int(f["seed"]), int(f["failed_at"])))
    return {c: s for c, s in data.items() if s}, dict(dropped)


def cell_schedule(seeds: dict) -> np.ndarray:
    """[T] bool: the iterations a cell's runs were evaluated at. A group evaluates all its runs at once,
    so an evaluation that left one run without a return is still scheduled for that run."""
    mask = np.zeros(max(len(s["eval_return"]) for s in seeds.values()), bool)
    for s in seeds.values():
        for column in ("eval_return", "eval_failures"):
            mask[: len(s[column])] |= np.isfinite(s[column])
    return mask


def unscored_runs(data: dict) -> dict:
    """{cell: [(seed, [iterations])]}: runs whose final score is NaN because one of their last scheduled
    evaluations has no return (tables written before failed evaluation episodes were counted)."""
    out = {}
    for cell, seeds in data.items():
        sched = cell_schedule(seeds)
        got = [(seed, stats.unscored_evaluations(s["eval_return"], sched)) for seed, s in sorted(seeds.items())]
        if any(its for _, its in got):
            out[cell] = [(seed, its) for seed, its in got if its]
    return out


def eval_failures(seeds: dict) -> int | str:
    """Failed evaluation episodes over a cell's runs and evaluations (gsa_jax.algorithm.episodes); '' (unknown) for
    tables written before they were counted."""
    if not any(np.isfinite(s["eval_failures"]).any() for s in seeds.values()):
        return ""
    return int(sum(np.nansum(s["eval_failures"]) for s in seeds.values()))


def evaluation_scores(data: dict) -> dict:
    """{cell: (scores [n], kind)}: each run's score from its training-time evaluations (stats.final_score over the
    cell's schedule: the mean of its last scheduled evaluations, a learning-curve statistic), seeds in order,
    without the runs unscored_runs lists; kind is 'deterministic' when every run has evaluations, else 'training'."""
    out = {}
    for cell, seeds in data.items():
        sched = cell_schedule(seeds)
        got = [stats.final_score(s["eval_return"], s["episode_return"], sched) for _, s in sorted(seeds.items())]
        kind = "deterministic" if all(k == "deterministic" for _, k in got) else "training"
        if kind == "training":
            got = [stats.final_score([], s["episode_return"]) for _, s in sorted(seeds.items())]
        scores = np.array([v for v, _ in got])
        out[cell] = (scores[np.isfinite(scores)], kind)
    return out


def final_scores(data: dict) -> dict:
    """{cell: (scores [n], kind)}: each run's score, seeds in order. Where every run of a cell has its committed
    controller's score (controller_score, gsa_jax.analysis.sweeps.controller_scores: the final controller re-run in MuJoCo C
    from fixed start states) those, kind 'controller'; else evaluation_scores."""
    out = evaluation_scores(data)
    for cell, seeds in data.items():
        got = np.array([s.get(C.CONTROLLER_SCORE, math.nan) for _, s in sorted(seeds.items())], float)
        if len(got) and np.isfinite(got).all():
            out[cell] = (got, "controller")
    return out


def spec_steps(dirs: Sequence[str]) -> dict:
    """{env: env steps of its runs} from the sweeps' sweep.json (the largest where they differ)."""
    out = {}
    for d in dirs:
        for meta in sweep_metas(d):
            for env in meta["spec"]["envs"]:
                out[env] = max(out.get(env, 0), int(meta["spec"]["steps"]))
    return out


def spec_multipliers(dirs: Sequence[str]) -> dict:
    """{env: sorted cluster multipliers} of the sweeps that set K as multiples of the action dimension
    (cluster_multipliers), read from their sweep.json."""
    out = defaultdict(set)
    for spec in (meta.get("spec", {}) for d in dirs for meta in sweep_metas(d)):
        for env_name in spec.get("envs", []) if spec.get("cluster_multipliers") else []:
            out[env_name].update(spec["cluster_multipliers"])
    return {e: sorted(ms) for e, ms in out.items()}


def task_records(env_names: Iterable[str]) -> dict:
    """{env: its record (envs/registry.py)} of the task names result files hold (CSV rows, sweep.json): the one place
    analysis turns those names into records, once each; ValueError (one line) for a name that does not resolve here."""
    import envs

    return {e: envs.resolve(e) for e in dict.fromkeys(env_names)}


def action_dims_of(dirs: Sequence[str], env_names: Iterable[str]) -> dict:
    """{env: d_a}: as the sweeps' sweep.json recorded it for a task defined outside the package (`tasks`), so that
    reading results never imports a user's task code; else from the task registry (built-in tasks)."""
    recorded = {e: t["action_size"] for d in dirs for meta in sweep_metas(d)
                for e, t in (meta.get("tasks") or {}).items() if "action_size" in t}
    missing = [e for e in env_names if e not in recorded]
    recorded.update({e: task.action_size() for e, task in task_records(missing).items()})
    return {e: recorded[e] for e in env_names}


def setting_columns(data: dict) -> list:
    """The columns that set cells apart beyond (env, policy, K): sub-policy class, critic, swept hyperparameters."""
    return list(dict.fromkeys(c for cell in data for c, _ in cell.settings))


def backend_of(dirs: Sequence[str], env_name: str) -> str:
    """The physics backend the sweeps in dirs trained env_name with ([config] backend; 'mjx' when none says);
    'c' when they differ, since MuJoCo C steps every task and MJX not all."""
    named = {record_backend(settings["config"]) for d in dirs for (env, _, _), settings in group_settings(d).items()
             if env == env_name}
    return named.pop() if len(named) == 1 else "c" if named else "mjx"


def random_returns_of(dirs: Sequence[str], env_names: Iterable[str], out_dir: str, log: Callable = print) -> dict:
    """{env: random-policy return}: from the sweeps' random_returns.json, else from out_dir's (what an earlier
    invocation measured: tables redrawn from committed results normalize as they did), else measured (and
    saved in out_dir)."""
    found = {}
    saved = os.path.join(out_dir, "random_returns.json")
    for path in [saved] + [p for d in dirs for p in glob.glob(os.path.join(d, "**", "random_returns.json"), recursive=True)]:
        if os.path.exists(path):
            with open(path) as f:
                found.update(json.load(f))  # the sweeps' own, read last, take precedence
    missing = [e for e in env_names if e not in found]
    if missing:
        from gsa_jax.analysis.sweeps.random_return import random_policy_return

        for env_name, task in task_records(missing).items():
            backend = backend_of(dirs, env_name)
            log(f"measuring the random-policy return of {env_name} (for normalized scores; backend {backend!r})")
            found[env_name] = random_policy_return(task, backend=backend)
        with open(saved, "w") as f:
            json.dump({e: found[e] for e in env_names}, f, indent=1)
    return {e: found[e] for e in env_names}


def read_csv(path: str) -> list:
    """Rows (dicts of strings) of a CSV file, gzipped if its name ends in .gz; [] if it does not exist."""
    if not os.path.exists(path):
        return []
    with (gzip.open(path, "rt") if path.endswith(".gz") else open(path, newline="")) as f:
        return list(csv.DictReader(f))


def write_csv(path: str, rows: list, columns: Sequence[str] | None = None) -> None:
    """rows (dicts) as a CSV file, written atomically; columns: their order (default: as first seen)."""
    from gsa_jax.running.checkpoint import write_atomic

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns or list(dict.fromkeys(k for r in rows for k in r)))
    w.writeheader()
    w.writerows(rows)
    write_atomic(path, buf.getvalue())


def unscored_lines(rows: list) -> list:
    """Lines naming the cells with unscored runs (final_returns.csv 'unscored_runs'); [] if none."""
    cells = [r for r in rows if r.get("unscored_runs")]
    if not cells:
        return []
    return [f"{sum(len(r['unscored_runs'].split()) for r in cells)} run(s) have no return at one of their last "
            f"{stats.FINAL_EVALUATIONS} scheduled evaluations (metrics written before failed evaluation episodes were "
            "counted): left out of the statistics, listed as seed@iterations:"] + [
        f"  {r['env']} {r['policy']}{' K=' + str(r['K']) if r['K'] != '' else ''}: {r['unscored_runs']}" for r in cells]
