"""How closely MJX steps each DeepMind Control Suite task like MuJoCo C: `.venv/bin/python
experiments/dmc_reference/mjx_agreement.py [task ...]` -> mjx_agreement.csv (beside this file).

Per task: MJX's version (float32) from its own reset and MuJoCo C (envs.task.TaskC, float64) from the same state and
goal, under the same U(-1, 1) actions: the largest |observation| and |reward| differences over the first 10 and 50
env steps, or the error MJX raised.
"""

import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import envs
from gsa_jax import write_csv

HORIZONS = (10, 50)


def agreement(name, key=0):
    env, c = envs.make_base(name), envs.resolve(name).make_c()
    t0 = time.perf_counter()
    s = jax.jit(env.reset)(jax.random.PRNGKey(key))
    step = jax.jit(env.step)
    ps = s.pipeline_state
    goal = np.asarray(ps.goal, np.float64) if hasattr(ps, "goal") else None
    c.set_start(np.asarray(ps.qpos, np.float64), np.asarray(ps.qvel, np.float64), goal)
    rng, obs_diff, rew_diff, row = np.random.default_rng(0), 0.0, 0.0, {"task": name}
    for t in range(max(HORIZONS)):
        a = rng.uniform(-1, 1, env.action_size).astype(np.float32)
        s = step(s, jnp.asarray(a))
        obs, reward, _ = c.step(a.astype(np.float64))
        obs_diff = max(obs_diff, float(np.abs(np.asarray(s.obs) - obs).max()))
        rew_diff = max(rew_diff, abs(float(s.reward) - reward))
        if t + 1 in HORIZONS:
            row.update({f"obs_diff_{t + 1}": f"{obs_diff:.2e}", f"reward_diff_{t + 1}": f"{rew_diff:.2e}"})
    row["seconds"] = f"{time.perf_counter() - t0:.0f}"
    return row


def main():
    rows = []
    for name in sys.argv[1:] or envs.DMC_TASKS:
        try:
            rows.append(agreement(name))
        except Exception as e:  # recorded, not hidden: what MJX cannot step
            rows.append({"task": name, "error": f"{type(e).__name__}: {' '.join(str(e).split())[:160]}"})
        print(rows[-1], flush=True)
    write_csv(os.path.join(os.path.dirname(os.path.abspath(__file__)), "mjx_agreement.csv"), rows)


if __name__ == "__main__":
    main()
