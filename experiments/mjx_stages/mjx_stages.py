"""Where one MJX physics step goes: each stage of mjx.step timed as a prefix of the step (stages 1..k
applied in a lax.scan of N steps over a batch of hopper states with contacts, 1 process), so stage k
costs t(k) - t(k-1) inside one compiled program, without per-call overhead. With each line search.

    taskset -c 0 .venv/bin/python experiments/mjx_stages/mjx_stages.py --out experiments/mjx_stages/results
"""

import argparse
import json
import os
import sys
import time

import numpy as np


def stage_times(mode, batch=256, n=40, repeats=7):
    import jax
    from mujoco.mjx._src import collision_driver, constraint, forward, smooth, solver

    import envs
    from envs.physics import Physics, applied

    env = envs.make_base("hopper")
    m = env.sys
    st = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), batch))
    step = jax.jit(jax.vmap(env.step))
    a = jax.random.uniform(jax.random.PRNGKey(1), (batch, env.action_size), minval=-1, maxval=1)
    for _ in range(60):  # fall onto the floor: contacts for the solver
        st = step(st, a)
    d = st.pipeline_state
    def position_rest(d):  # subtree CoM, inertia and its factorization, collision, constraint rows
        d = smooth.tendon(m, smooth.camlight(m, smooth.com_pos(m, d)))
        d = smooth.factor_m(m, smooth.tendon_armature(m, smooth.crb(m, d)))
        return smooth.transmission(m, constraint.make_constraint(m, collision_driver.collision(m, d)))

    # stages small enough to be lost in fusion noise are grouped (a finer split gave negative differences)
    stages = [
        ("kinematics", lambda d: smooth.kinematics(m, d)),
        ("inertia, collision, constraint rows", position_rest),
        ("velocity, actuation, acceleration", lambda d: forward.fwd_acceleration(m, forward.fwd_actuation(m, forward.fwd_velocity(m, d)))),
        ("constraint solver", lambda d: solver.solve(m, d)),
        ("integration (euler)", lambda d: forward.euler(m, d)),
    ]

    def timed(fn):
        g = jax.jit(lambda d: jax.lax.scan(lambda c, _: (jax.vmap(fn)(c), None), d, None, length=n)[0])
        jax.block_until_ready(g(d))
        ts = []
        for _ in range(repeats):
            t = time.perf_counter()
            jax.block_until_ready(g(d))
            ts.append(time.perf_counter() - t)
        return float(np.median(ts)) / n / batch * 1e6  # us per env and physics step

    out, prev = {}, 0.0
    with applied(Physics(linesearch=mode), envs.mj_model(env)):
        for k in range(len(stages) + 1):
            def prefix(d, k=k):
                for _, f in stages[:k]:
                    d = f(d)
                return d
            t = timed(prefix)
            if k:
                out[stages[k - 1][0]] = t - prev
            prev = t
        out["mjx.step (whole)"] = timed(lambda d: forward.step(m, d))
    return out


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("--out", default="experiments/mjx_stages/results")
    args = p.parse_args(argv)
    from gsa_jax import run_metadata

    res = {"unit": "us per env per physics step, batch 256, 1 process", **run_metadata()}
    for mode in ("exact", "iterative"):
        res[mode] = stage_times(mode)
        print(mode, json.dumps({k: round(v, 2) for k, v in res[mode].items()}), flush=True)
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "stages.json"), "w") as f:
        json.dump(res, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
