"""Re-score the atlas's committed controllers in dm_control itself (an independent check of our `dmc:` ports).

    MUJOCO_GL=egl nice -n 19 /tmp/dmcref/bin/python experiments/atlas_dmc/rescore_dm_control.py [--episodes 10]

Runs in a reference virtualenv with dm_control 1.0.50, mujoco 3.17.0 and numpy only (no gsa_jax, no JAX:
`python3 -m venv /tmp/dmcref && /tmp/dmcref/bin/pip install mujoco==3.17.0 dm_control==1.0.50`). For every task
folder of results/ with a per_run_scores.csv, it loads all seeds of flat PPO and of the best mixture K (atlas.csv's
best_K), evaluates each deterministic controller with its own NumPy code written from the exported .npz's documented
format, in `dm_control.suite.load(domain, task, task_kwargs={'random': seed})` for seeds 0..episodes-1, and writes

    results/dm_control_rescore.csv          per controller: its dm_control mean return (and every episode's) next to
                                            our final_score and last_eval_return (per_run_scores.csv)
    results/dm_control_rescore_summary.csv  per task and policy: means and IQMs over seeds, their ratios, and the
                                            standard error the shared sample of start states puts on the seed-mean
    results/dm_control_rescore.json         versions (dm_control, mujoco, numpy), date, git commit, settings

It resumes: controllers already in the per-controller CSV are skipped.

The controller (what gsa_jax/deployment/numpy_policy.py documents and gsa_jax/algorithm/policies.py computes):
z = clip((float32(obs) - obs_mean) / sqrt(obs_var + 1e-8), -obs_clip, obs_clip). 'mixture': the cluster is the argmax
of the partition MLP's first K logits (tanh hidden layers w0/b0.., linear last layer; the eps-uniform mix does not
move the argmax), the action L[c] z + b[c] (L multiplies the *normalised* observation; 'constant' / 'quadratic'
sub-policies use phi(z) = [] / [z, z_i z_j, i <= j]). 'mlp': the policy MLP's output (tanh hidden layers, linear
output: the Gaussian's mean, no squashing). The action is then clipped to [action_low, action_high] (training clips to
[-1, 1]), and mapped onto the actuators' ctrlrange where the file has ctrl_low / ctrl_high (quadruped only).
The observation vector is dm_control's observation dict flattened in its own key order (envs/dmc/*.py's
observation_keys state it; checked here against every time step's dict).

Verification mode (`--starts FILE --controller NPZ`): run one controller from given start states (an .npz of qpos
[n, nq] and qvel [n, nv]) instead of dm_control's own resets, to compare with our port episode for episode.
"""

import argparse
import csv
import datetime
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
REPO = os.path.dirname(os.path.dirname(HERE))

# dm_control's observation dict (key, size) per domain, in its own order (as envs/dmc/<domain>.py states it)
OBS_KEYS = {
    "acrobot": (("orientations", 4), ("velocity", 2)),
    "ball_in_cup": (("position", 4), ("velocity", 4)),
    "cartpole": (("position", 3), ("velocity", 2)),
    "cheetah": (("position", 8), ("velocity", 9)),
    "finger": (("position", 4), ("velocity", 3), ("touch", 2)),
    "fish": (("joint_angles", 7), ("upright", 1), ("target", 3), ("velocity", 13)),
    "hopper": (("position", 6), ("velocity", 7), ("touch", 2)),
    "pendulum": (("orientation", 2), ("velocity", 1)),
    "point_mass": (("position", 2), ("velocity", 2)),
    "quadruped": (("egocentric_state", 44), ("torso_velocity", 3), ("torso_upright", 1), ("imu", 6),
                  ("force_torque", 24)),
    "reacher": (("position", 2), ("to_target", 2), ("velocity", 2)),
    "walker": (("orientations", 14), ("height", 1), ("velocity", 9)),
}

CSV_COLUMNS = ("task", "policy", "K", "seed", "episodes", "dm_control_mean_return", "dm_control_std_return",
               "final_score", "last_eval_return", "controller", "dm_control_returns")
SUMMARY_COLUMNS = ("task", "policy", "K", "seeds", "episodes", "dm_control_mean", "final_score_mean", "ratio_mean",
                   "dm_control_iqm", "final_score_iqm", "ratio_iqm", "last_eval_mean", "ratio_to_last_eval_mean",
                   "seed_std_final_score", "mean_abs_diff_per_seed", "dm_control_start_se")


# ---------------------------------------------------------------- the controller, in NumPy


def load_controller(path):
    """The exported controller's arrays (float32 where numeric), as a dict; what act() needs and nothing more."""
    with np.load(path, allow_pickle=False) as f:
        a = {k: f[k] for k in f.files}
    ctrl = {"kind": str(a["kind"]), "obs_mean": a["obs_mean"].astype(np.float32),
            "obs_std": np.sqrt(a["obs_var"].astype(np.float32) + np.float32(1e-8)),
            "obs_clip": np.float32(a["obs_clip"]),
            "layers": [(a[f"w{i}"].astype(np.float32), a[f"b{i}"].astype(np.float32))
                       for i in range(int(a["n_layers"]))],
            "low": a["action_low"].astype(np.float32), "high": a["action_high"].astype(np.float32),
            "ctrl_range": (a["ctrl_low"], a["ctrl_high"]) if "ctrl_low" in a else None,
            "config": json.loads(str(a["config_json"]))}
    if ctrl["kind"] == "mixture":
        ctrl["subpolicy"] = str(a["subpolicy"]) if "subpolicy" in a else "linear"
        ctrl["L"], ctrl["b"] = a["L"].astype(np.float32), a["b"].astype(np.float32)
    elif ctrl["kind"] != "mlp":
        raise ValueError(f"{path}: unknown controller kind {ctrl['kind']!r}")
    return ctrl


def mlp(layers, x):
    """tanh between layers, linear last layer (gsa_jax.algorithm.nn.apply_mlp)."""
    for i, (w, b) in enumerate(layers):
        x = x @ w + b
        if i < len(layers) - 1:
            x = np.tanh(x)
    return x


def features(subpolicy, z):
    """phi(z) of a sub-policy class: [] (constant), z (linear), [z, z_i z_j for i <= j] (quadratic)."""
    if subpolicy == "constant":
        return z[:0]
    if subpolicy == "linear":
        return z
    i, j = np.triu_indices(z.shape[-1])
    return np.concatenate([z, z[i] * z[j]])


def act(ctrl, obs):
    """(control for dm_control's step, cluster) of the deterministic controller at one flat observation."""
    z = np.clip((np.asarray(obs, np.float32) - ctrl["obs_mean"]) / ctrl["obs_std"], -ctrl["obs_clip"], ctrl["obs_clip"])
    if ctrl["kind"] == "mlp":
        raw, c = mlp(ctrl["layers"], z), 0
    else:
        k = ctrl["L"].shape[0]
        c = int(np.argmax(mlp(ctrl["layers"], z)[:k]))
        raw = ctrl["L"][c] @ features(ctrl["subpolicy"], z) + ctrl["b"][c]
    action = np.clip(raw, ctrl["low"], ctrl["high"]).astype(np.float64)
    if ctrl["ctrl_range"] is not None:  # envs/task.py ctrl_range 'model': [-1, 1] onto the actuators' ctrlrange
        low, high = ctrl["ctrl_range"]
        action = low + (action + 1.0) * (0.5 * (high - low))
    return action, c


# ---------------------------------------------------------------- dm_control episodes


def flatten(observation, domain):
    """dm_control's observation dict as one float64 vector, in the dict's own order, checked against OBS_KEYS."""
    got = tuple((k, int(np.size(v))) for k, v in observation.items())
    if got != OBS_KEYS[domain]:
        raise RuntimeError(f"{domain}: dm_control's observation dict is {got}, the port states {OBS_KEYS[domain]}")
    return np.concatenate([np.ravel(v).astype(np.float64) for v in observation.values()])


def load_env(task, seed):
    """dm_control.suite's environment of 'dmc:<domain>-<task>' with task_kwargs={'random': seed}."""
    from dm_control import suite

    domain, name = task.split(":")[-1].split("-")
    return suite.load(domain, name, task_kwargs={"random": seed}), domain


def episode(env, domain, ctrl, start=None):
    """(return, steps, clusters used) of one deterministic episode to dm_control's time limit. start: optional
    (qpos, qvel) set after dm_control's reset (verification mode)."""
    ts = env.reset()
    if start is not None:
        with env.physics.reset_context():
            env.physics.data.qpos[:], env.physics.data.qvel[:] = start
        obs = flatten(env.task.get_observation(env.physics), domain)  # the observation of the set state
    else:
        obs = flatten(ts.observation, domain)
    total, steps, used = 0.0, 0, set()
    while True:
        action, c = act(ctrl, obs)
        used.add(c)
        ts = env.step(action)
        total, steps = total + float(ts.reward), steps + 1
        if ts.last():
            return total, steps, len(used)
        obs = flatten(ts.observation, domain)


def check_bounds(ctrl, env, path):
    """The controls the file can emit span exactly dm_control's action spec (not taken from the port on trust)."""
    low, high = ctrl["ctrl_range"] if ctrl["ctrl_range"] is not None else (ctrl["low"], ctrl["high"])
    spec = env.action_spec()
    if not (np.allclose(low, spec.minimum, atol=1e-6) and np.allclose(high, spec.maximum, atol=1e-6)):
        raise ValueError(f"{path}: action bounds [{low}, {high}] differ from dm_control's [{spec.minimum}, {spec.maximum}]")


def score(task, path, episodes):
    """Returns [episodes] of the controller at `path` in dm_control's task, episode i with random=i."""
    ctrl = load_controller(path)
    out = []
    for seed in range(episodes):
        env, domain = load_env(task, seed)
        check_bounds(ctrl, env, path)
        ret, steps, _ = episode(env, domain, ctrl)
        if steps != 1000:
            raise RuntimeError(f"{task}: an episode of {steps} steps, expected 1000")
        out.append(ret)
    return np.array(out)


# ---------------------------------------------------------------- which controllers, and our scores


def read_csv(path):
    """The rows of a CSV file as dicts."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def best_k():
    """{task folder: best mixture K} from atlas.csv (dmc rows)."""
    return {r["task"].split(":")[-1]: int(r["best_K"]) for r in read_csv(os.path.join(RESULTS, "atlas.csv"))
            if r["family"] == "dmc" and r["best_K"]}


def controllers(tasks=None):
    """Rows (task, policy, K, seed, final_score, last_eval_return, controller path) to score: per task folder with a
    per_run_scores.csv, every flat PPO seed and every seed of the best K."""
    ks, out = best_k(), []
    for folder in sorted(os.listdir(RESULTS)):
        scores = os.path.join(RESULTS, folder, "per_run_scores.csv")
        if not os.path.isfile(scores) or (tasks and folder not in tasks):
            continue
        for r in read_csv(scores):
            policy, k = r["policy"], (int(r["K"]) if r["K"] else "")
            if policy == "mixture" and k != ks.get(folder):  # a task atlas.csv lacks: flat PPO only
                continue
            sub = "flat_ppo" if policy == "mlp" else "mixture"
            label = f"dmc.{folder}-mlp-s{r['seed']}" if policy == "mlp" else f"dmc.{folder}-mixture-K{k}-s{r['seed']}"
            path = os.path.join(RESULTS, folder, sub, "controllers", label + ".npz")
            out.append({"task": r["env"], "policy": policy, "K": k, "seed": int(r["seed"]),
                        "final_score": r["final_score"], "last_eval_return": r["last_eval_return"],
                        "controller": os.path.relpath(path, REPO)})
    return out


def done_keys(path):
    """(task, policy, K, seed, episodes) already scored in the per-controller CSV (resume)."""
    if not os.path.isfile(path):
        return set()
    return {(r["task"], r["policy"], str(r["K"]), int(r["seed"]), int(r["episodes"])) for r in read_csv(path)}


def append_row(path, row):
    """Append one row to the per-controller CSV (header first if new), flushed: an interruption loses nothing."""
    new = not os.path.isfile(path)
    with open(path, "a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_COLUMNS)
        if new:
            w.writeheader()
        w.writerow({c: row.get(c, "") for c in CSV_COLUMNS})


# ---------------------------------------------------------------- summary and provenance


def iqm(x):
    """Interquartile mean as rliable computes it (scipy.stats.trim_mean(x, 0.25): int(0.25 n) cut from each end)."""
    x = np.sort(np.asarray(x, float))
    cut = int(0.25 * len(x))
    return float(np.mean(x[cut: len(x) - cut]))


def start_se(rows):
    """Standard error of the seed-mean dm_control score from its finite sample of start states, which every seed
    shares (random=0..N-1): std over starts of the seed-averaged per-start return / sqrt(N). The seeds' spread does
    not contain this error, as it is common to all of them."""
    per = np.array([[float(x) for x in r["dm_control_returns"].split()] for r in rows])
    return round(float(per.mean(0).std(ddof=1) / math.sqrt(per.shape[1])), 2) if per.shape[1] > 1 else math.nan


def summary_rows(rows):
    """Per (task, policy, K): means and IQMs over seeds of the dm_control score and of our final_score, ratios."""
    groups = {}
    for r in rows:
        groups.setdefault((r["task"], r["policy"], str(r["K"])), []).append(r)
    out = []
    for (task, policy, k), rs in sorted(groups.items()):
        dm = np.array([float(r["dm_control_mean_return"]) for r in rs])
        ours = np.array([float(r["final_score"]) for r in rs])
        last = np.array([float(r["last_eval_return"]) for r in rs])
        ratio = lambda a, b: round(a / b, 3) if b else math.nan  # noqa: E731
        out.append({"task": task, "policy": policy, "K": k, "seeds": len(rs),
                    "episodes": ",".join(sorted({str(r["episodes"]) for r in rs})),
                    "dm_control_mean": round(dm.mean(), 2), "final_score_mean": round(ours.mean(), 2),
                    "ratio_mean": ratio(dm.mean(), ours.mean()), "dm_control_iqm": round(iqm(dm), 2),
                    "final_score_iqm": round(iqm(ours), 2), "ratio_iqm": ratio(iqm(dm), iqm(ours)),
                    "last_eval_mean": round(last.mean(), 2), "ratio_to_last_eval_mean": ratio(dm.mean(), last.mean()),
                    "seed_std_final_score": round(float(ours.std(ddof=1)), 2),
                    "mean_abs_diff_per_seed": round(float(np.abs(dm - ours).mean()), 2),
                    "dm_control_start_se": start_se(rs)})
    return out


def write_summary(rows, path):
    """The per-task summary (summary_rows) of the per-controller rows, as a CSV file."""
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=SUMMARY_COLUMNS)
        w.writeheader()
        w.writerows(summary_rows(rows))


def provenance(args, wall_s, path):
    """Versions, date, git commit and settings, as JSON beside the CSVs."""
    import importlib.metadata as md

    import mujoco

    try:
        commit = subprocess.run(["git", "-C", REPO, "describe", "--always", "--dirty"], capture_output=True,
                                text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    info = {"dm_control": md.version("dm_control"), "mujoco": mujoco.__version__, "numpy": np.__version__,
            "python": sys.version.split()[0], "date": datetime.datetime.now().isoformat(timespec="seconds"),
            "git_commit": commit, "episodes_per_controller": args.episodes,
            "dm_control_random_seeds": list(range(args.episodes)), "wall_s_this_invocation": round(wall_s, 1),
            "score": "mean over episodes of the summed rewards of 1000-step deterministic episodes",
            "policies": "flat PPO (mlp) and the best mixture K of atlas.csv, every seed"}
    with open(path, "w") as f:
        json.dump(info, f, indent=1)


# ---------------------------------------------------------------- commands


def rescore(args):
    """Score every listed controller not yet in the CSV, then rewrite the summary and the provenance JSON."""
    t0 = time.perf_counter()
    out_csv = os.path.join(args.out, "dm_control_rescore.csv")
    done = done_keys(out_csv)
    todo = [r for r in controllers(args.tasks)
            if (r["task"], r["policy"], str(r["K"]), r["seed"], args.episodes) not in done]
    if args.limit:
        todo = todo[: args.limit]
    print(f"{len(todo)} controllers to score ({len(done)} already in {out_csv})", flush=True)
    for i, r in enumerate(todo):
        t = time.perf_counter()
        rets = score(r["task"], os.path.join(REPO, r["controller"]), args.episodes)
        row = {**r, "episodes": args.episodes, "dm_control_mean_return": round(float(rets.mean()), 3),
               "dm_control_std_return": round(float(rets.std()), 3),
               "dm_control_returns": " ".join(f"{x:.3f}" for x in rets)}
        append_row(out_csv, row)
        print(f"[{i + 1}/{len(todo)}] {r['task']} {r['policy']} K={r['K']} s{r['seed']}: dm_control "
              f"{rets.mean():.1f} (ours {r['final_score']}, last eval {r['last_eval_return']}) "
              f"{time.perf_counter() - t:.1f}s", flush=True)
    rows = [r for r in read_csv(out_csv) if int(r["episodes"]) == args.episodes] if os.path.isfile(out_csv) else []
    if rows and not args.limit:
        write_summary(rows, os.path.join(args.out, "dm_control_rescore_summary.csv"))
        provenance(args, time.perf_counter() - t0, os.path.join(args.out, "dm_control_rescore.json"))
    print(f"done in {time.perf_counter() - t0:.0f}s", flush=True)


def verify(args):
    """Verification mode: one controller from the given start states; prints per-episode returns as JSON."""
    ctrl = load_controller(args.controller)
    task = ctrl["config"]["config"]["env"]
    with np.load(args.starts) as f:
        qpos, qvel = f["qpos"], f["qvel"]
    rets = []
    for i in range(len(qpos)):
        env, domain = load_env(task, i)
        rets.append(episode(env, domain, ctrl, (qpos[i], qvel[i]))[0])
    print(json.dumps({"task": task, "controller": args.controller, "returns": rets}))


def main(argv=None):
    """Re-score the atlas (default), or run one controller from given start states (--starts, --controller)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--episodes", type=int, default=10, help="episodes per controller, dm_control random=0..N-1")
    p.add_argument("--tasks", nargs="*", default=None, help="task folders (default: all with per_run_scores.csv)")
    p.add_argument("--limit", type=int, default=0, help="score only the first N remaining controllers (timing)")
    p.add_argument("--out", default=RESULTS, help="where the CSVs and JSON go (default: results/)")
    p.add_argument("--starts", default=None, help="verification: an .npz of start states qpos [n, nq], qvel [n, nv]")
    p.add_argument("--controller", default=None, help="verification: the controller .npz to run from --starts")
    args = p.parse_args(argv)
    if args.starts:
        verify(args)
    else:
        rescore(args)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("MUJOCO_GL", "egl")  # no window system is needed; quiets GLFW's warning on import
    sys.exit(main())
