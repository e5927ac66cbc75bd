"""Retrace value targets (gsa_jax/algorithm/retrace.py): a NumPy reference with off-policy ratios, episode ends and
a truncation; GAE's targets on-policy; the buffer's ring of iterations; a Retrace run equal to a GAE run
when it keeps one iteration; a run with a full buffer killed and resumed equal to the uninterrupted run."""

import csv
import functools
import os
import signal
import subprocess
import sys
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from gsa_jax.algorithm.config import Config, make_hparams
from gsa_jax.algorithm.ppo import compute_gae, init_state, make_parts, run_chunk
from gsa_jax.algorithm.retrace import buffer_targets, init_buffer, retrace_targets, store

G, LAM = 0.9, 0.8
# one env, 6 steps: an episode terminated at t=2, one cut by the time limit at t=4 (done, not terminated)
R = np.array([1.0, -0.5, 2.0, 0.3, 1.5, -1.0], np.float32)
V = np.array([0.2, 0.4, -0.3, 1.0, 0.5, 0.1], np.float32)
NV = np.array([0.4, -0.3, 7.0, 0.5, 0.8, 0.6], np.float32)  # V(x'_t): x'_2 is terminal, x'_4 the cut-off state
TERM = np.array([0, 0, 1, 0, 0, 0], np.float32)
DONE = np.array([0, 0, 1, 0, 1, 0], np.float32)
RATIO = np.array([0.5, 2.0, 1.0, 0.2, 3.0, 0.9], np.float32)


def numpy_retrace(r, v, nv, term, done, ratio, g, lam):
    """v_t = V_t + sum_{s>=t} g^(s-t) (prod_{t<=i<s} lam min(1, ratio_i) (1 - done_i)) min(1, ratio_s) delta_s."""
    out = np.zeros_like(v)
    for t in range(len(r)):
        total, trace = 0.0, 1.0
        for s in range(t, len(r)):
            rho = min(1.0, ratio[s])
            total += trace * rho * (r[s] + g * (1 - term[s]) * nv[s] - v[s])
            trace *= g * lam * rho * (1 - done[s])
        out[t] = v[t] + total
    return out


def targets(ratio):
    return np.asarray(retrace_targets(*(jnp.asarray(x)[:, None] for x in (R, V, NV, TERM, DONE, ratio)), G, LAM))[:, 0]


def test_retrace_matches_numpy_with_off_policy_ratios_episode_ends_and_a_truncation():
    np.testing.assert_allclose(targets(RATIO), numpy_retrace(R, V, NV, TERM, DONE, RATIO, G, LAM), rtol=1e-6)
    # by hand: the last step is one truncated TD step; the terminal step t=2 ignores V(x'_2) = 7
    assert np.isclose(targets(RATIO)[5], 0.1 + 0.9 * (-1.0 + 0.9 * 0.6 - 0.1), rtol=1e-6)
    assert np.isclose(targets(RATIO)[2], -0.3 + 1.0 * (2.0 - (-0.3)), rtol=1e-6)
    # t=3 reaches t=4 (ratio 0.2: trace lam * 0.2) and stops at the cut; t=4 bootstraps from V(x'_4)
    d3, d4 = 0.3 + 0.9 * 0.5 - 1.0, 1.5 + 0.9 * 0.8 - 0.5
    assert np.isclose(targets(RATIO)[3], 1.0 + 0.2 * d3 + 0.9 * LAM * 0.2 * d4, rtol=1e-6)


def test_on_policy_retrace_is_gae():
    ones = np.ones_like(RATIO)
    _, gae_target = compute_gae(*(jnp.asarray(x)[:, None] for x in (R, V, NV, TERM, DONE)), G, LAM)
    np.testing.assert_allclose(targets(ones), np.asarray(gae_target)[:, 0], rtol=1e-6)


def test_buffer_keeps_the_last_iterations_and_scores_them_with_todays_functions():
    buf = init_buffer(2, 3, 1, obs_size=2, action_size=1)
    assert np.asarray(buf["filled"]).tolist() == [0.0, 0.0]
    rng = np.random.default_rng(0)

    def traj(i):
        return {"raw_obs": jnp.full((3, 1, 2), float(i)), "raw_next_obs": jnp.asarray(rng.normal(size=(3, 1, 2)), jnp.float32),
                "action": jnp.asarray(rng.normal(size=(3, 1, 1)), jnp.float32), "cluster": jnp.zeros((3, 1), jnp.int32),
                "logp": jnp.asarray(rng.normal(size=(3, 1)), jnp.float32), "reward": jnp.full((3, 1), float(i)),
                "term": jnp.zeros((3, 1)), "done": jnp.asarray([[0.0], [1.0], [0.0]])}

    buf = store(buf, traj(0), jnp.int32(0))
    assert np.asarray(buf["filled"]).tolist() == [1.0, 0.0]
    for i in (1, 2):
        buf = store(buf, traj(i), jnp.int32(i))
    assert np.asarray(buf["raw_obs"][:, 0, 0, 0]).tolist() == [2.0, 1.0]  # iteration 2 replaced the oldest
    obs, tgt, ratios = buffer_targets(buf, lambda x: 2.0 * x, lambda x: jnp.sum(x, -1),
                                      lambda o, a, c: a[:, 0] + 0.1, ret_scale=2.0, gamma=G, lam=LAM)
    b = jax.tree.map(np.asarray, buf)
    np.testing.assert_allclose(np.asarray(obs), 2.0 * b["raw_obs"])
    np.testing.assert_allclose(np.asarray(ratios), np.exp(b["action"][..., 0] + 0.1 - b["logp"]), rtol=1e-5)
    for n in range(2):
        ref = numpy_retrace(b["reward"][n, :, 0] / 2.0, 2.0 * b["raw_obs"][n, :, 0].sum(-1),
                            2.0 * b["raw_next_obs"][n, :, 0].sum(-1), b["term"][n, :, 0], b["done"][n, :, 0],
                            np.asarray(ratios)[n, :, 0], G, LAM)
        np.testing.assert_allclose(np.asarray(tgt)[n, :, 0], ref, rtol=1e-5, atol=1e-6)


class PointState(NamedTuple):
    obs: jax.Array
    reward: jax.Array
    done: jax.Array
    info: dict
    steps: jax.Array


class PointTask:
    """x' = x + a in 2-D, reward -|x'|^2; an episode ends when |x'| > 2 (terminated) or after 5 steps (cut)."""

    observation_size, action_size = 2, 2

    def reset(self, key):
        x = jax.random.uniform(key, (2,), minval=-1.0, maxval=1.0)
        z = jnp.zeros(())
        return PointState(x, z, z, {"final_obs": x, "truncation": z}, jnp.zeros((), jnp.int32))

    def step(self, s, a):
        x, steps = s.obs + a, s.steps + 1
        out = (jnp.sum(x * x) > 4.0).astype(jnp.float32)
        cut = (steps >= 5).astype(jnp.float32) * (1.0 - out)
        done = jnp.maximum(out, cut)
        start = self.reset(jax.random.PRNGKey(0) + steps.astype(jnp.uint32)).obs
        return PointState(jnp.where(done > 0, start, x), -jnp.sum(x * x), done, {"final_obs": x, "truncation": cut},
                          jnp.where(done > 0, 0, steps))


def test_retrace_over_one_iteration_trains_as_gae():
    """N = 1: the buffer holds only the iteration's own samples, whose ratios are 1: the same run as GAE
    (a mixture on a toy task with terminations and time limits, 4 iterations)."""
    hp = make_hparams(K=2, total_iterations=4)
    runs = {}
    for target in ("gae", "retrace"):
        cfg = Config(k_max=2, num_envs=4, unroll_length=8, num_minibatches=2, num_epochs=2, hidden=(8,),
                     value_target=target, retrace_iterations=1)
        p = make_parts(cfg, PointTask(), None)
        state = init_state(p, jax.random.PRNGKey(2), hp)
        final, runs[target] = jax.jit(functools.partial(run_chunk, p), static_argnums=2)(state, hp, 4)
        assert (final.buffer is None) == (target == "gae")
    assert float(np.min(runs["gae"]["episodes"])) > 0 and np.asarray(final.buffer["filled"]).tolist() == [1.0]
    for col in ("episode_return", "value_loss", "policy_loss", "approx_kl"):
        np.testing.assert_allclose(np.asarray(runs["retrace"][col]), np.asarray(runs["gae"][col]), rtol=1e-4, atol=1e-6,
                                   err_msg=col)


SMALL = ["--steps", "8192", "--num-envs", "16", "--unroll-length", "32", "--minibatches", "8", "--epochs", "2",
         "--episode-length", "200", "--chunk", "1", "--eval-every", "0", "--value-target", "retrace",
         "--retrace-iterations", "3", "--quiet"]


def train_cmd(out, *extra):
    return [sys.executable, "-m", "gsa_jax.train", *SMALL, "--out", str(out), *extra]


def saved_iteration(out):
    try:
        with np.load(out / "state.npz") as f:
            return int(f["__done__"])
    except (OSError, KeyError, ValueError):
        return 0


def read_rows(path):
    with open(path) as f:
        return [{k: v for k, v in r.items() if k != "wall_s"} for r in csv.DictReader(f)]


def test_kill9_with_a_full_buffer_then_resume_equals_uninterrupted(tmp_path):
    from gsa_jax.train import main

    assert main(SMALL + ["--out", str(tmp_path / "full")]) == 0
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(jax.config.jax_compilation_cache_dir),
               JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0.5")
    out = tmp_path / "killed"
    proc = subprocess.Popen(train_cmd(out), env=env, start_new_session=True)
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None and saved_iteration(out) < 5:  # 3 slots full, then more
        time.sleep(0.02)
    assert proc.poll() is None, "the run finished before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert 5 <= saved_iteration(out) < 16
    with np.load(out / "state.npz") as a:
        assert any("buffer" in k for k in a.files)  # the checkpoint holds the filled buffer
    assert main(SMALL + ["--out", str(out), "--resume"]) == 0  # in this process: the program compiled above
    assert read_rows(out / "metrics.csv") == read_rows(tmp_path / "full" / "metrics.csv")
    with np.load(out / "params.npz") as a, np.load(tmp_path / "full" / "params.npz") as b:
        for k in a.files:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
