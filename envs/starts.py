"""A task's start-state law drawn in JAX (envs/task.py: noise, qpos_noise, vel_noise, qvel_noise): the same draws
from the same key on both backends (MJX: envs/task_mjx.py; MuJoCo C in the program: envs/c_backend.py). Imports
neither Brax nor MJX.
"""

import jax


def start_noise(rng, m, noise, law, vel_noise=None, qpos_law="uniform"):
    """(dq [nq], dv [nv]) of a reset drawn from rng: dq ~ U(-noise, noise) (qpos_law 'uniform') or noise * N(0, 1)
    ('normal'); dv ~ U(-s, s) (law 'uniform') or s * N(0, 1) ('normal') with s = vel_noise (None: noise); scales
    are scalars or per-coordinate arrays. The C backend's resets draw the same."""
    k_q, k_v = jax.random.split(rng)
    s = noise if vel_noise is None else vel_noise
    if qpos_law == "uniform":
        dq = jax.random.uniform(k_q, (m.nq,), minval=-noise, maxval=noise)
    else:
        dq = noise * jax.random.normal(k_q, (m.nq,))
    if law == "uniform":
        return dq, jax.random.uniform(k_v, (m.nv,), minval=-s, maxval=s)
    return dq, s * jax.random.normal(k_v, (m.nv,))


def task_start_noise(rng, task):
    """start_noise with a Task's (envs/task.py) start-state law."""
    return start_noise(rng, task.model, task.noise, task.qvel_noise, task.vel_noise, task.qpos_noise)
