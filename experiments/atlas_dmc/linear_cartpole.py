"""Can one linear controller balance dm_control's cartpole? `.venv/bin/python experiments/atlas_dmc/linear_cartpole.py`

A reading for the atlas's K = 1 on cartpole-balance: discrete-time LQR on a finite-difference linearization of one
env step (MuJoCo C, RK4, the task's own model) at the upright rest state, applied as a linear function of dm_control's
observation (cart x, sin of the pole angle, their velocities; zero weight on the cosine), clipped to the actuator's
[-1, 1], and scored by the task's own reward over 20 of its resets (envs.task.TaskC). Writes
results/linear_cartpole.csv.
"""

import os

import mujoco
import numpy as np
import scipy.linalg as sla

import envs
from gsa_jax import write_csv

Q, R, EPS, RESETS = np.diag([1.0, 10.0, 0.1, 0.1]), np.eye(1) * 0.1, 1e-6, 20


def linearize(m):
    """(A [4, 4], B [4, 1]) of one physics step at qpos = qvel = 0, ctrl = 0 (central differences)."""
    d = mujoco.MjData(m)

    def f(x, u):
        mujoco.mj_resetData(m, d)
        d.qpos[:], d.qvel[:], d.ctrl[:] = x[:2], x[2:], u
        mujoco.mj_step(m, d)
        return np.concatenate([d.qpos, d.qvel])

    x0, u0 = np.zeros(4), np.zeros(1)
    A = np.stack([(f(x0 + EPS * e, u0) - f(x0 - EPS * e, u0)) / (2 * EPS) for e in np.eye(4)], 1)
    B = np.stack([(f(x0, u0 + EPS * e) - f(x0, u0 - EPS * e)) / (2 * EPS) for e in np.eye(1)], 1)
    return A, B


def main():
    c = envs.resolve("dmc:cartpole-balance").make_c()
    A, B = linearize(c.model)
    P = sla.solve_discrete_are(A, B, Q, R)
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    scores = []
    for seed in range(RESETS):
        obs, total = c.reset(seed), 0.0
        for _ in range(c.task.episode_length):
            x, _cos, sin, xd, thd = obs
            obs, reward, _ = c.step(np.clip(-K @ np.array([x, sin, xd, thd]), -1, 1))
            total += reward
        scores.append(total)
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "linear_cartpole.csv")
    write_csv(out, [{"controller": "LQR, linear in the observation", "resets": RESETS, "mean_return": f"{np.mean(scores):.1f}",
                     "min_return": f"{np.min(scores):.1f}", "gains_x_sin_xdot_thetadot": " ".join(f"{k:.3f}" for k in K[0])}])
    print(open(out).read())


if __name__ == "__main__":
    main()
