"""Exported controllers evaluated under shifted physics, observations and actions: loading them, the random
policy's score (the retained fraction's 0), action sensitivity, the resumable loop that writes robustness.csv
and sensitivity.csv, and robustness.json's settings."""

import glob
import json
import math
import os
from typing import Callable, Sequence

import numpy as np

from envs.randomization import DEFAULT_PUSH_RATE
from gsa_jax.algorithm import subpolicies
from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.analysis.robustness.shift_rows import TIDY, RobustnessError, controller_key
from gsa_jax.analysis.sweeps.results import read_csv, write_csv
from gsa_jax.deployment.evaluation import DeployError, load_controller
from gsa_jax.deployment.numpy_policy import Controller, action_size
from gsa_jax.deployment.shifts import Shift, applies, run_shifted
from gsa_jax.deployment.starts import SELECTION_SEED as START_SEED  # the selection starts
from gsa_jax.running.runinfo import run_metadata


def load_controllers(paths: Sequence[str]) -> list:
    """[(path, meta {env, policy, K, seed}, controller)] of exported controllers in files or directories."""
    files = []
    for p in paths:
        if os.path.isdir(p):
            files += sorted(glob.glob(os.path.join(p, "**", "*.npz"), recursive=True))
        elif os.path.isfile(p):
            files.append(p)
        else:
            raise RobustnessError(f"{p!r} is neither a controller file nor a directory")
    if not files:
        raise RobustnessError(f"no exported controller (.npz) in {', '.join(paths)}")
    out = []
    for f in files:
        try:
            ctrl, task, _ = load_controller(f)  # a task defined outside the package: importable here, one line if not
            env_name = task.name
            meta = json.loads(str(ctrl.arrays["config_json"]))
        except (DeployError, ValueError) as e:
            raise RobustnessError(f"{f}: {e}") from None
        k = ctrl.num_clusters if ctrl.kind == MIXTURE else ""
        out.append((f, {"env": env_name, "policy": ctrl.kind, "K": k, "seed": int(meta.get("seed", 0))}, ctrl))
    return out


class RandomController:
    """Uniform random actions in [-1, 1] (seeded): the 0 of the retained fraction."""

    def __init__(self, action_size, seed=0):
        self.rng, self.action_size = np.random.default_rng(seed), action_size
        self.obs_std = np.ones(1)  # unused: a random policy's shifts never read it (same law under noise)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, obs.shape[:-1] + (self.action_size,))


def random_score(env_name: str, shift: Shift, seeds: np.ndarray, size: int) -> float:
    """Mean return of the random policy (actions [size] uniform in [-1, 1]) under the shift from the same starts."""
    ctrl = RandomController(size)
    same_law = shift.kind in ("obs_noise", "action_delay")  # a random policy ignores what it sees and when
    returns, _, _ = run_shifted(ctrl, env_name, Shift("nominal") if same_law else shift, seeds)
    return float(returns.mean())


def action_jacobian_norms(ctrl: Controller, obs: np.ndarray) -> np.ndarray:
    """[N] Frobenius norms of d action / d z at observations obs [N, d_s], z the normalized observation:
    a mixture's active piece L_c times its sub-policy class's d phi / d z (L_c itself for linear pieces), an MLP's
    Jacobian through its tanh layers."""
    x = ctrl.normalize(obs)
    if ctrl.kind == MIXTURE:
        feature_jacobian = subpolicies.get(ctrl.subpolicy).jacobian
        L = ctrl.L[ctrl.cluster(obs)]
        return np.linalg.norm(np.stack([l @ feature_jacobian(z).astype(l.dtype) for l, z in zip(L, x)]), axis=(1, 2))
    jac = np.broadcast_to(np.eye(x.shape[-1], dtype=np.float32), (len(x),) + (x.shape[-1],) * 2)
    for i, (w, b) in enumerate(ctrl.layers):
        x = x @ w + b
        jac = jac @ w
        if i < len(ctrl.layers) - 1:
            x = np.tanh(x)
            jac = jac * (1.0 - x * x)[:, None, :]
    return np.linalg.norm(jac, axis=(1, 2))


def evaluate_controller(meta: dict, ctrl: Controller, shifts: Sequence[Shift], seeds: np.ndarray, randoms: dict) -> tuple:
    """Tidy rows of one controller under every applicable shift, and its sensitivity along its nominal episodes."""
    nominal, _, seen = run_shifted(ctrl, meta["env"], Shift("nominal"), seeds, record=True)
    rows = []
    for shift in shifts:
        if not applies(meta["env"], shift):
            continue
        score = nominal.mean() if shift.kind == "nominal" else run_shifted(ctrl, meta["env"], shift, seeds)[0].mean()
        rand = randoms[(meta["env"], shift)]
        scale = nominal.mean() - rand
        rows.append({**meta, "shift": shift.kind, "level": shift.level, "score": round(float(score), 3),
                     "nominal_score": round(float(nominal.mean()), 3), "random_score": round(rand, 3),
                     "retained_fraction": round(float((score - rand) / scale), 4) if abs(scale) > 1e-9 else math.nan})
    return rows, float(np.mean(action_jacobian_norms(ctrl, seen.astype(np.float32))))


def evaluate_all(controllers: list, shifts: Sequence[Shift], episodes: int, out: str,
                 log: Callable = lambda m: print(m, flush=True)) -> tuple:
    """Evaluate every controller not yet in OUT/robustness.csv; returns (tidy rows, sensitivity rows)."""
    tidy_path, sens_path = os.path.join(out, "robustness.csv"), os.path.join(out, "sensitivity.csv")
    rows, sens = read_csv(tidy_path), read_csv(sens_path)
    done = {controller_key(r) for r in sens}
    seeds = np.arange(START_SEED, START_SEED + episodes)
    randoms = {}
    for i, (path, meta, ctrl) in enumerate(controllers):
        if controller_key(meta) in done:
            continue
        for shift in shifts:
            if applies(meta["env"], shift) and (meta["env"], shift) not in randoms:
                randoms[(meta["env"], shift)] = random_score(meta["env"], shift, seeds, action_size(ctrl.arrays))
        new, sensitivity = evaluate_controller(meta, ctrl, shifts, seeds, randoms)
        kept = [float(r["retained_fraction"]) for r in new if r["shift"] != "nominal"]
        rows += new
        sens.append({**meta, "sensitivity": round(sensitivity, 5), "mean_retained_fraction": round(float(np.nanmean(kept)), 4),
                     "controller": os.path.basename(path)})
        write_csv(tidy_path, rows, TIDY)
        write_csv(sens_path, sens)
        log(f"[{i + 1}/{len(controllers)}] {os.path.basename(path)}: nominal {new[0]['score']:.1f}, "
            f"mean retained fraction {np.nanmean(kept):.3f}, sensitivity {sensitivity:.3g}")
    return rows, sens


def write_settings(out: str, shifts: Sequence[Shift], episodes: int, pushes: dict | None = None) -> None:
    """robustness.json: the shifts, episodes, start seeds, push rate and paired pushes ({sizes, windows,
    per_episode}), versions and commit; a re-run into the same OUT with other settings is refused (its rows
    would not be comparable). A setting the file lacks (an evaluation made before it existed) is added, with
    the versions and commit that add it under 'added'."""
    from gsa_jax.running.checkpoint import write_atomic

    settings = {"shifts": [list(s) for s in shifts], "episodes": episodes, "start_seeds": [START_SEED, START_SEED + episodes],
                "push_rate": DEFAULT_PUSH_RATE}
    if pushes:
        settings["paired_pushes"] = {k: list(v) if isinstance(v, tuple) else v for k, v in pushes.items()}
    path = os.path.join(out, "robustness.json")
    if not os.path.exists(path):
        return write_atomic(path, json.dumps({**settings, **run_metadata()}, indent=1))
    with open(path) as f:
        old = json.load(f)
    held = {k: old[k] for k in settings if k in old}
    if any(held[k] != settings[k] for k in held):
        raise RobustnessError(f"{out} holds an evaluation with other settings ({held}); use another --out")
    new = [k for k in settings if k not in old]
    if new:
        added = {**old.get("added", {}), **{k: run_metadata() for k in new}}
        write_atomic(path, json.dumps({**old, **{k: settings[k] for k in new}, "added": added}, indent=1))
