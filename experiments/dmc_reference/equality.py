"""The largest differences between our dmc: tasks (MuJoCo C, envs.task.TaskC) and dm_control's recorded episodes:
`.venv/bin/python experiments/dmc_reference/equality.py` -> equality.csv (beside this file).

Per task, from tests/golden/dmc/<task>.npz (experiments/dmc_reference/record.py): over the 3 whole episodes replayed
from dm_control's reset states with its actions, the largest |observation| and |reward| difference and the first
step where an observation differs by more than 1e-8 (none: never); over every single step of the first episode
taken from dm_control's own recorded state, the largest |observation| and |reward| difference.
"""

import os

import numpy as np

import envs
from gsa_jax import write_csv

GOLDEN = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "tests", "golden", "dmc")


def whole_episodes(c, f):
    worst_obs, worst_rew, first = 0.0, 0.0, None
    for i in range(int(f["episodes"]) if "episodes" in f.files else 3):
        goal = f[f"ep{i}_target"][: c.task.goal_size] if c.task.goal_size else None
        obs = [c.set_start(f[f"ep{i}_qpos0"], f[f"ep{i}_qvel0"], goal)]
        rewards = []
        for a in f[f"ep{i}_actions"]:
            o, r, _ = c.step_controls(a.astype(np.float64))
            obs.append(o)
            rewards.append(r)
        d = np.abs(np.array(obs) - f[f"ep{i}_obs"]).max(axis=1)
        worst_obs, worst_rew = max(worst_obs, d.max()), max(worst_rew, np.abs(np.array(rewards) - f[f"ep{i}_rewards"]).max())
        apart = np.flatnonzero(d > 1e-8)
        if len(apart):
            first = int(apart[0]) if first is None else min(first, int(apart[0]))
    return worst_obs, worst_rew, first


def single_steps(c, f):
    m, worst_obs, worst_rew = c.model, 0.0, 0.0
    goal = f["ep0_target"][: c.task.goal_size] if c.task.goal_size else None
    for t, (state, a) in enumerate(zip(f["ep0_states"], f["ep0_actions"])):
        c.set_start(state[: m.nq], state[m.nq: m.nq + m.nv], goal)
        c.data.act[:] = state[m.nq + m.nv: m.nq + m.nv + m.na]
        c.data.qacc_warmstart[:] = state[m.nq + m.nv + m.na:]
        o, r, _ = c.step_controls(a.astype(np.float64))
        worst_obs = max(worst_obs, np.abs(o - f["ep0_obs"][t + 1]).max())
        worst_rew = max(worst_rew, abs(r - f["ep0_rewards"][t]))
    return worst_obs, worst_rew


def main():
    rows = []
    for name in envs.DMC_TASKS:
        f, c = np.load(os.path.join(GOLDEN, f"{name.removeprefix('dmc:')}.npz")), envs.resolve(name).make_c()
        obs, rew, first = whole_episodes(c, f)
        step_obs, step_rew = single_steps(c, f)
        rows.append({"task": name, "episode_obs_diff": f"{obs:.1e}", "episode_reward_diff": f"{rew:.1e}",
                     "first_step_apart_1e-8": "" if first is None else first, "single_step_obs_diff": f"{step_obs:.1e}",
                     "single_step_reward_diff": f"{step_rew:.1e}", "mujoco_reference": str(f["mujoco"]),
                     "dm_control": str(f["dm_control"])})
        print(rows[-1], flush=True)
    write_csv(os.path.join(os.path.dirname(os.path.abspath(__file__)), "equality.csv"), rows)


if __name__ == "__main__":
    main()
