"""A run's score as anyone who re-runs its committed controller gets it: the exported final controller's
deterministic return in plain MuJoCo C (gsa_jax.deploy's episodes) over a fixed, recorded set of start states.

Each results directory holding controllers/<run label>.npz gets a controller_scores.csv beside it: one row per
controller with its file's sha256, the start seeds (`start_seed` + 0 .. episodes - 1, the seeds gsa_jax.deploy
--seed takes) and the mean return over them. Rows are written as each controller finishes (an interrupted scoring
loses nothing) and kept while the file's sha256, the episodes and the start seed are unchanged, so scoring a
directory again only scores what is new. `gsa score DIR [DIR ...]` is its command; gsa plot
and gsa_jax.answer read the scores (per_run_scores.csv `controller_score`) and every verdict uses them.
"""

import concurrent.futures
import csv
import functools
import glob
import hashlib
import io
import json
import multiprocessing
import os
import time
from typing import TYPE_CHECKING, Callable, Iterator, Sequence

import numpy as np

from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.analysis.sweeps import columns as C
from gsa_jax.deployment import starts
from gsa_jax.errors import UserError

if TYPE_CHECKING:
    from envs.families.record import TaskRecord

# the selection starts (every score and verdict) and the fresh starts (an answer's chosen controller re-scored on
# starts it was not picked on): gsa_jax.deployment.starts names them for every command
EPISODES, START_SEED = starts.SELECTION_EPISODES, starts.SELECTION_SEED
FRESH_EPISODES, FRESH_START_SEED = starts.FRESH_EPISODES, starts.FRESH_SEED
FILE = "controller_scores.csv"
COLUMNS = ("label", "env", "policy", "K", "seed", "sha256", "episodes", "start_seed", C.CONTROLLER_SCORE,
           "episode_std", "length_mean", "simulator", "mujoco_version")


class ScoreError(UserError):
    pass


def file_sha256(path: str) -> str:
    """The sha256 of a file's bytes (what identifies a committed controller)."""
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def read_scores(path: str) -> dict:
    """{label: row} of a controller_scores.csv ({} if there is none)."""
    if not os.path.exists(path):
        return {}
    with open(path, newline="") as f:
        return {r["label"]: r for r in csv.DictReader(f)}


def write_scores(path: str, rows: dict) -> None:
    """Write {label: row} as a controller_scores.csv (atomically, labels sorted)."""
    from gsa_jax.running.checkpoint import write_atomic  # imports JAX: not at module level, which plot and deploy read

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    w.writeheader()
    for label in sorted(rows):
        w.writerow({c: rows[label].get(c, "") for c in COLUMNS})
    write_atomic(path, buf.getvalue())


def controller_episodes(path: str, episodes: int, start_seed: int) -> tuple:
    """One controller's deterministic episodes in MuJoCo C from seeds start_seed .. start_seed + episodes - 1
    (gsa_jax.deployment.evaluation.mujoco_c_episodes, what gsa_jax.deploy runs) -> (identity {label, env, policy, K,
    seed, sha256}, returns [episodes], lengths [episodes])."""
    from gsa_jax.deployment.evaluation import DeployError, load_controller, mujoco_c_episodes

    try:
        ctrl, task, config = load_controller(path)
        env_name = task.name
        if not task.has_c:
            raise ScoreError(f"{env_name!r} has no MuJoCo C version: its controllers cannot be scored outside training")
        returns, lengths, _ = mujoco_c_episodes(ctrl, task, config, episodes, seed=start_seed)
    except DeployError as e:
        raise ScoreError(str(e)) from None
    k = ctrl.num_clusters if ctrl.kind == MIXTURE else ""
    seed = json.loads(str(ctrl.arrays["config_json"])).get("seed", "")
    identity = {"label": os.path.basename(path)[: -len(".npz")], "env": env_name, "policy": ctrl.kind, "K": k,
                "seed": seed, "sha256": file_sha256(path)}
    return identity, returns, lengths


def score_controller(path: str, episodes: int = EPISODES, start_seed: int = START_SEED) -> dict:
    """One controller's row: the mean of its deterministic episodes (controller_episodes) and their spread."""
    import mujoco

    identity, returns, lengths = controller_episodes(path, episodes, start_seed)
    return {**identity, "episodes": episodes, "start_seed": start_seed,
            C.CONTROLLER_SCORE: round(float(returns.mean()), 4),
            "episode_std": round(float(np.std(returns, ddof=1)) if episodes > 1 else 0.0, 4),
            "length_mean": round(float(lengths.mean()), 2), "simulator": "mujoco_c", "mujoco_version": mujoco.__version__}


def controller_dirs(roots: Sequence[str]) -> list:
    """Every directory holding controllers/*.npz under the given directories (sorted, no repeats)."""
    found = set()
    for root in roots:
        for path in glob.glob(os.path.join(root, "**", "controllers", "*.npz"), recursive=True):
            found.add(os.path.dirname(os.path.dirname(path)))
    return sorted(found)


def is_current(row: dict, sha: str, episodes: int, start_seed: int) -> bool:
    """Whether a stored row scores this very file with these episodes and start seed."""
    return (row.get("sha256") == sha and str(row.get("episodes")) == str(episodes)
            and str(row.get("start_seed")) == str(start_seed) and row.get(C.CONTROLLER_SCORE, "") != "")


def default_jobs() -> int:
    """Processes to score in: the cores this process may use."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def parallel_map(fn: Callable, items: Sequence, jobs: int) -> Iterator:
    """fn(item) for each item, yielded as each finishes: in this process, or in `jobs` fresh processes where there is
    more than one item (fn must be picklable; each item runs alone, so the results are the same either way)."""
    if jobs <= 1 or len(items) <= 1:
        yield from (fn(x) for x in items)
        return
    context = multiprocessing.get_context("spawn")  # not fork: the caller may hold JAX's threads
    with concurrent.futures.ProcessPoolExecutor(max_workers=min(jobs, len(items)), mp_context=context) as pool:
        futures = [pool.submit(fn, x) for x in items]
        try:
            for future in concurrent.futures.as_completed(futures):
                yield future.result()
        finally:
            for future in futures:
                future.cancel()


def scored_rows(todo: Sequence[str], episodes: int, start_seed: int, jobs: int) -> Iterator[dict]:
    """Each controller's row (score_controller) as it finishes, in `jobs` processes (parallel_map)."""
    yield from parallel_map(functools.partial(score_controller, episodes=episodes, start_seed=start_seed), todo, jobs)


def score_directory(results_dir: str, episodes: int = EPISODES, start_seed: int = START_SEED,
                    log: Callable = print, jobs: int = 1) -> dict:
    """Score every controllers/*.npz of one results directory that its controller_scores.csv does not hold
    yet (or holds for another file, episode count or start seed), in `jobs` processes -> {label: row as stored};
    rows of controllers no longer there are dropped."""
    path = os.path.join(results_dir, FILE)
    stored = read_scores(path)
    files = sorted(glob.glob(os.path.join(results_dir, "controllers", "*.npz")))
    rows = {}
    todo = []
    for f in files:
        label, sha = os.path.basename(f)[: -len(".npz")], file_sha256(f)
        if label in stored and is_current(stored[label], sha, episodes, start_seed):
            rows[label] = stored[label]
        else:
            todo.append(f)
    t0 = time.monotonic()
    for i, row in enumerate(scored_rows(todo, episodes, start_seed, jobs)):
        rows[row["label"]] = row
        write_scores(path, rows)  # after every controller: an interruption loses at most the ones being scored
        if log:
            eta = (time.monotonic() - t0) / (i + 1) * (len(todo) - i - 1)
            log(f"  {results_dir}: {i + 1}/{len(todo)} {row['label']}: {row['controller_score']:.1f} (ETA {eta:.0f} s)")
    if set(rows) != set(stored) or todo:
        write_scores(path, rows)
    return read_scores(path)  # as stored: strings, as a later read gives them


def label_scores(roots: Sequence[str]) -> dict:
    """{run label: controller_score} from every controller_scores.csv under the directories."""
    out = {}
    for root in roots:
        for path in glob.glob(os.path.join(root, "**", FILE), recursive=True):
            for label, row in read_scores(path).items():
                if row.get(C.CONTROLLER_SCORE, "") != "":
                    out[label] = float(row[C.CONTROLLER_SCORE])
    return out


def attach(data: dict, roots: Sequence[str]) -> int:
    """Put each run's controller_score (from the controller_scores.csv files under `roots`, matched by run label)
    into data {cell: {seed: {column: ...}}} as a float (NaN where not scored) -> how many runs have one."""
    from gsa_jax.running.trained import run_label

    scores, found = label_scores(roots), 0
    for cell, seeds in data.items():
        for seed, s in seeds.items():
            label = run_label({**cell.columns(), "seed": seed})
            s[C.CONTROLLER_SCORE] = scores.get(label, float("nan"))
            found += label in scores
    return found


# ------------------------------------------------------------------------------------------- the random policy
RANDOM_EPISODES = 128  # episodes of the uniformly random policy: the scale's zero, with its own uncertainty
RANDOM_START_SEED = 30_000  # its start states (and each episode's action stream): apart from the controllers'
RANDOM_FILE = "random_policy.json"


class RandomActions:
    """Uniformly random actions in [-1, 1] (the scale's zero: what a task scores with no control at all), drawn
    from NumPy's generator seeded per episode, so every episode is reproducible alone."""

    def __init__(self, size: int):
        self.size, self.rng = size, np.random.default_rng(0)

    def reseed(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, self.size)


def score_random_policy(task: "TaskRecord", episodes: int = RANDOM_EPISODES, start_seed: int = RANDOM_START_SEED) -> dict:
    """The random policy's episodes in MuJoCo C (the simulator every controller score comes from): the returns of
    episodes start_seed .. start_seed + episodes - 1, each from that seed's start state with actions drawn from a
    generator seeded with it -> {returns, mean, std, episodes, start_seed, simulator, mujoco_version}."""
    import mujoco

    length, task = task.episode_length(), task.make_c()
    actions = RandomActions(task.action_size)
    returns = []
    for e in range(episodes):
        obs, total = task.reset(start_seed + e), 0.0
        actions.reseed(start_seed + e)
        for _ in range(length):
            obs, r, done = task.step(actions.act(obs))
            total += r
            if done:
                break
        returns.append(round(float(total), 4))
    r = np.asarray(returns)
    return {"returns": returns, "mean": round(float(r.mean()), 4), "std": round(float(r.std(ddof=1)), 4),
            "episodes": episodes, "start_seed": start_seed, "simulator": "mujoco_c", "mujoco_version": mujoco.__version__}


def random_policy(directory: str, task: "TaskRecord", episodes: int = RANDOM_EPISODES, start_seed: int = RANDOM_START_SEED,
                  log: Callable | None = print) -> dict:
    """The random policy's record of a task (task: its record) kept in directory/random_policy.json under its name
    (measured and added there when it is missing or was measured with other episodes or start seed)."""
    from gsa_jax.running.checkpoint import write_atomic

    path, env_name = os.path.join(directory, RANDOM_FILE), task.name
    found = {}
    if os.path.exists(path):
        with open(path) as f:
            found = json.load(f)
    kept = found.get(env_name)
    if kept and kept.get("episodes") == episodes and kept.get("start_seed") == start_seed:
        return kept
    if log:
        log(f"measuring the random policy's return on {env_name} ({episodes} episodes in MuJoCo C from seed {start_seed})")
    found[env_name] = score_random_policy(task, episodes, start_seed)
    os.makedirs(directory, exist_ok=True)
    write_atomic(path, json.dumps(found, indent=1))
    return found[env_name]
