"""Do trained controllers run where robots and benchmarks run them? For each run directory: export the
deterministic controller as .npz, ONNX and a C header; score it for N episodes in MJX (the training
simulator), in our MuJoCo C port (same MJCF) and in gymnasium's own v5 task; check the ONNX graph
(onnxruntime) and the compiled C header against numpy_policy on the observations the controller
visits in MuJoCo C; and list what differs between Brax's and gymnasium's models of the task.

    .venv/bin/python experiments/deploy_gymnasium/deploy_gymnasium.py RUN_DIR [RUN_DIR ...] \
        --episodes 20 --out experiments/deploy_gymnasium/results
"""

import argparse
import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

GYM_IDS = {"hopper": "Hopper-v5", "walker2d": "Walker2d-v5", "halfcheetah": "HalfCheetah-v5", "ant": "Ant-v5"}
HARNESS = r"""
#define GSA_CONTROLLER_IMPLEMENTATION
#include "controller.h"
#include <stdio.h>
int main(void) {
    float obs[GSA_OBS_DIM], action[GSA_ACT_DIM];
    int cluster;
    while (fread(obs, sizeof(float), GSA_OBS_DIM, stdin) == GSA_OBS_DIM) {
        gsa_act(obs, action, &cluster);
        fwrite(action, sizeof(float), GSA_ACT_DIM, stdout);
        fwrite(&cluster, sizeof(int), 1, stdout);
    }
    return 0;
}
"""


def visited_observations(ctrl, env_name, episodes=5, length=1000):
    """Observations [n, d_s] the controller visits in our MuJoCo C port."""
    from envs.mujoco_c import make_c

    task, out = make_c(env_name), []
    for e in range(episodes):
        obs = task.reset(1000 + e)
        for _ in range(length):
            out.append(obs)
            obs, _, done = task.step(np.clip(ctrl.act(obs), -1.0, 1.0))
            if done:
                break
    return np.array(out, np.float32)


def agreement(ctrl, obs, action, cluster):
    ref_a, ref_c = ctrl.act(obs), ctrl.cluster(obs)
    same = cluster == ref_c
    return {"observations": int(len(obs)), "cluster_agreement": float(same.mean()),
            "max_abs_action_diff": float(np.abs(action[same] - ref_a[same]).max()),
            "max_abs_action": float(np.abs(ref_a).max())}


def check_onnx(ctrl, path, obs):
    import onnxruntime as ort

    sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    action, cluster = sess.run(["action", "cluster"], {"obs": obs})
    return agreement(ctrl, obs, action, cluster)


def check_c(ctrl, header, obs):
    """Compile the header with a harness, run it on obs; agreement plus the object code's size."""
    cc = shutil.which("cc") or shutil.which("gcc")
    with tempfile.TemporaryDirectory() as tmp:
        shutil.copy(header, os.path.join(tmp, "controller.h"))
        with open(os.path.join(tmp, "main.c"), "w") as f:
            f.write(HARNESS)
        subprocess.run([cc, "-std=c99", "-O2", "-Wall", "-Wextra", "-pedantic", "-Werror", "-c", "main.c"], cwd=tmp, check=True)
        subprocess.run([cc, "-o", "ctrl", "main.o", "-lm"], cwd=tmp, check=True)
        size = subprocess.run(["size", "main.o"], cwd=tmp, capture_output=True, text=True).stdout.split("\n")[1].split()
        r = subprocess.run([os.path.join(tmp, "ctrl")], input=obs.tobytes(), capture_output=True, check=True)
    d_a = ctrl.act(obs[:1]).shape[-1]
    rec = np.frombuffer(r.stdout, dtype=np.dtype([("a", np.float32, (d_a,)), ("c", np.int32)]))
    return {**agreement(ctrl, obs, rec["a"], rec["c"].astype(np.int64)),
            "object_text_bytes": int(size[0]), "object_data_bytes": int(size[1])}


def model_differences(env_name):
    """What differs between Brax's model of the task (as MJX steps it) and gymnasium's v5 model."""
    import gymnasium

    from envs.mujoco_c import make_c
    from gsa_jax.deployment.gymnasium_rollout import GYM_OPTIONS

    ours = make_c(env_name)
    gym_env = gymnasium.make(GYM_IDS[env_name], **GYM_OPTIONS.get(env_name, {})).unwrapped
    a, b = ours.model, gym_env.model
    import mujoco

    integrators = {int(v): k for k, v in mujoco.mjtIntegrator.__members__.items()}

    def colliding_geoms(m):
        return int(np.sum((m.geom_contype != 0) | (m.geom_conaffinity != 0)))

    rows = {
        "integrator": (integrators[int(a.opt.integrator)], integrators[int(b.opt.integrator)]),
        "timestep x substeps": (f"{a.opt.timestep} x {ours.n_frames}", f"{b.opt.timestep} x {gym_env.frame_skip}"),
        "solver iterations / line search": (f"{a.opt.iterations} / {a.opt.ls_iterations}", f"{b.opt.iterations} / {b.opt.ls_iterations}"),
        "geoms that can collide": (colliding_geoms(a), colliding_geoms(b)),
        "contact condim (distinct)": (sorted(set(a.geom_condim.tolist())), sorted(set(b.geom_condim.tolist()))),
        "contact margin (max)": (float(a.geom_margin.max()), float(b.geom_margin.max())),
        "total mass (kg)": (round(float(a.body_mass.sum()), 3), round(float(b.body_mass.sum()), 3)),
        "max |friction diff|": round(float(np.abs(a.geom_friction - b.geom_friction).max()), 3) if a.ngeom == b.ngeom else "ngeom differs",
        "armature (distinct)": (sorted(set(np.round(a.dof_armature, 4).tolist())), sorted(set(np.round(b.dof_armature, 4).tolist()))),
        "damping (distinct)": (sorted(set(np.round(a.dof_damping, 4).tolist())), sorted(set(np.round(b.dof_damping, 4).tolist()))),
        "gear": (sorted(set(a.actuator_gear[:, 0].tolist())), sorted(set(b.actuator_gear[:, 0].tolist()))),
    }
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in rows.items()}


def score(run_dir, out, episodes):
    from gsa_jax.deployment import numpy_policy
    from gsa_jax.deployment.evaluation import load_controller, open_gymnasium, run_gymnasium, run_mjx, run_mujoco_c
    from gsa_jax.deployment.exporting import load_arrays, write

    arrays = load_arrays(run_dir)
    env_name = json.loads(str(arrays["config_json"]))["config"]["env"]
    dest = os.path.join(out, os.path.basename(os.path.normpath(run_dir)))
    os.makedirs(dest, exist_ok=True)
    paths = {fmt: os.path.join(dest, name) for fmt, name in (("npz", "controller.npz"), ("onnx", "controller.onnx"), ("c", "controller.h"))}
    for fmt, path in paths.items():
        write(arrays, fmt, path)
    ctrl, task, config = load_controller(paths["npz"])
    row = {"run": os.path.basename(os.path.normpath(run_dir)), "env": env_name, "gymnasium": GYM_IDS[env_name],
           "kind": str(arrays["kind"]), "K": int(np.asarray(arrays["L"]).shape[0]) if "L" in arrays else ""}
    for name, summary in (("mjx", run_mjx(run_dir, episodes)[1]),
                          ("mujoco_c", run_mujoco_c(ctrl, task, config, episodes)),
                          ("gymnasium_v5", run_gymnasium(ctrl, open_gymnasium(ctrl, env_name, GYM_IDS[env_name]),
                                                         GYM_IDS[env_name], episodes))):
        row[f"{name}_return"] = round(summary["return_mean"], 1)
        row[f"{name}_ci95"] = round(summary["return_ci95"], 1)
        row[f"{name}_length"] = round(summary["length_mean"], 1)
        print(f"{row['run']}: {name}: {summary['return_mean']:.1f} +- {summary['return_ci95']:.1f}", flush=True)
    obs = visited_observations(numpy_policy.load(paths["npz"]), env_name)
    from gsa_jax.deployment.export_c import cost

    details = {"onnx": check_onnx(ctrl, paths["onnx"], obs), "c": {**check_c(ctrl, paths["c"], obs), **cost(arrays)},
               "onnx_file_bytes": os.path.getsize(paths["onnx"]), "header_file_bytes": os.path.getsize(paths["c"]),
               "model_differences": model_differences(env_name)}
    return row, details


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("runs", nargs="+")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--out", default="experiments/deploy_gymnasium/results")
    args = p.parse_args(argv)

    import gymnasium

    from gsa_jax import run_metadata

    os.makedirs(args.out, exist_ok=True)
    rows, details = [], {}
    for run_dir in args.runs:
        row, det = score(run_dir, args.out, args.episodes)
        rows.append(row)
        details[row["run"]] = det
        print(json.dumps({k: det[k] for k in ("onnx", "c")}), flush=True)
    with open(os.path.join(args.out, "returns.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    meta = run_metadata()
    meta["versions"]["gymnasium"] = gymnasium.__version__
    with open(os.path.join(args.out, "details.json"), "w") as f:
        json.dump({"episodes": args.episodes, "runs": [os.path.abspath(r) for r in args.runs], "details": details, **meta},
                  f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
