"""MJX's constraint solver as we run it (envs/linesearch.py): the exact line search finds the minimiser
of the piecewise-quadratic line cost (against a float64 NumPy reference) and steps hopper as MJX's
iterative search does to float32 precision; MJX's iterative search as a while loop gives the same
iterates as MJX's scan, bitwise; the solver-iterations option changes the MJX model only, says so,
and rejects bad values."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mujoco.mjx._src import solver

import envs
from envs import linesearch
from envs.physics import Physics


def test_while_loop_has_the_scan_contract_under_vmap():
    """Per batch element: body applied while cond holds, at most max_iter times -- envs that converge
    early keep their value while the others go on, as in MJX's scan of conds."""
    cond = lambda c: c["x"] < c["limit"]
    body = lambda c: {"x": c["x"] + 1.0, "limit": c["limit"]}
    init = {"x": jnp.zeros(5), "limit": jnp.array([0.0, 1.0, 3.0, 7.0, 50.0])}
    for impl in (linesearch.while_loop, linesearch._ORIGINAL):
        out = jax.jit(jax.vmap(lambda c: impl(cond, body, c, 6)))(init)
        np.testing.assert_array_equal(np.asarray(out["x"]), [0.0, 1.0, 3.0, 6.0, 6.0])


def line_cost(a, jaref, jv, efc_d, always, g1, g2):
    """f(a) of linesearch.line_minimum in float64 NumPy; a: [n] points."""
    x = jaref[None] + a[:, None] * jv[None]
    act = always[None] | (x < 0)
    return g1 * a + g2 * a * a + np.sum(act * 0.5 * efc_d * x * x, 1)


def reference_minimum(jaref, jv, efc_d, always, g1, g2):
    """min f over every breakpoint and every piece's own minimiser (f is convex and quadratic on each piece)."""
    has_b = (jv != 0) & ~always
    b = np.sort(-jaref[has_b] / jv[has_b])
    edges = np.concatenate(([-np.inf], b, [np.inf]))
    cands = list(b) + [0.0]
    for lo, hi in zip(edges[:-1], edges[1:]):
        t = 0.5 * (lo + hi) if np.isfinite(lo) and np.isfinite(hi) else (hi - 1 if np.isfinite(hi) else (lo + 1 if np.isfinite(lo) else 0.0))
        act = always | (jaref + t * jv < 0)
        a2, a1 = g2 + np.sum(act * 0.5 * efc_d * jv * jv), g1 + np.sum(act * efc_d * jv * jaref)
        if a2 > 0:
            cands.append(np.clip(-a1 / (2 * a2), lo, hi))
    cands = np.asarray(cands)
    return cands[np.argmin(line_cost(cands, jaref, jv, efc_d, always, g1, g2))]


def test_exact_line_minimum_matches_float64_reference():
    rng = np.random.default_rng(0)
    n, probs = 11, 400
    jaref = rng.normal(size=(probs, n))
    jv = rng.normal(size=(probs, n)) * (rng.random((probs, n)) > 0.15)  # some rows do not move
    efc_d = rng.uniform(0.2, 3.0, (probs, n)) * (rng.random((probs, n)) > 0.1)  # some padding rows
    always = np.zeros((probs, n), bool)
    always[::3, :2] = True  # equality rows in a third of the problems
    g1, g2 = rng.normal(size=probs) * 3, rng.uniform(0.05, 2.0, probs)
    g1[-1], g2[-1], jv[-1] = 0.0, 0.0, 0.0  # a zero search direction: stay
    args = [x.astype(np.float32) for x in (jaref, jv, efc_d)] + [always] + [x.astype(np.float32) for x in (g1, g2)]
    alpha, change = jax.device_get(jax.jit(jax.vmap(linesearch.line_minimum))(*args))
    args64 = [a.astype(np.float64) if a.dtype != bool else a for a in args]
    worse, moves = [], 0
    for i in range(probs):
        p = [a[i] for a in args64]
        best = reference_minimum(*p)
        f_best, f_ours, f0 = line_cost(np.array([best, alpha[i]], np.float64), *p).tolist() + line_cost(np.zeros(1), *p).tolist()
        worse.append((f_ours - f_best) / (1.0 + abs(f_best)))
        np.testing.assert_allclose(change[i], f_ours - f0, rtol=1e-3, atol=1e-4)
        moves += abs(best) > 1e-3
    assert max(worse) < 1e-5, max(worse)
    assert moves > probs // 2  # the problems do move
    assert alpha[-1] == 0.0 and change[-1] == 0.0


def test_exact_line_search_applies_to_pyramidal_cones_only():
    import copy

    import mujoco

    from envs.physics import Physics, exact_applies, linesearch_in_force

    model = envs.task_model("hopper")
    assert exact_applies(model)
    elliptic = copy.deepcopy(model)
    elliptic.opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    assert not exact_applies(elliptic)
    assert linesearch_in_force(Physics(), elliptic) == "iterative"
    assert envs.solver_settings(envs.make_base("hopper"))["linesearch_in_force"] == "exact"
    # ls_iterations is a parameter of MJX's search, which it then uses
    assert linesearch_in_force(Physics(ls_iterations=50), model) == "iterative"
    assert linesearch_in_force(Physics(linesearch="iterative"), model) == "iterative"


def test_physics_options_apply_only_while_the_task_runs():
    """Making a task patches nothing; its step routes MJX's solver and the Cholesky while it runs and
    restores them after, also after an error."""
    import jax.scipy.linalg as jsl

    from envs import linalg
    from envs.physics import Physics, applied

    before = (solver._linesearch, solver._while_loop_scan, jsl.cho_factor)
    envs.make_base("hopper")
    assert (solver._linesearch, solver._while_loop_scan, jsl.cho_factor) == before
    model = envs.task_model("hopper")
    with applied(Physics(), model):
        assert solver._linesearch is linesearch.exact_linesearch and solver._while_loop_scan is linesearch.while_loop
        assert jsl.cho_factor is linalg.cho_factor
        with applied(Physics(linesearch="iterative", search_loop="scan", cholesky="lapack"), model):
            assert solver._linesearch is linesearch._ORIGINAL_LINESEARCH and solver._while_loop_scan is linesearch._ORIGINAL
            assert jsl.cho_factor is linalg._ORIGINAL["cho_factor"]
        assert solver._linesearch is linesearch.exact_linesearch
    with pytest.raises(RuntimeError):
        with applied(Physics(), model):
            raise RuntimeError
    assert (solver._linesearch, solver._while_loop_scan, jsl.cho_factor) == before
    with pytest.raises(ValueError, match="linesearch must be one of exact, iterative"):
        Physics(linesearch="bisect").validate()


@pytest.fixture(scope="module")
def hopper():
    env = envs.make_base("hopper", Physics(ls_iterations=50))  # the task's settings through MJX's iterative search
    assert envs.solver_settings(env)["linesearch_in_force"] == "iterative"
    s0 = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 4))
    acts = jax.random.uniform(jax.random.PRNGKey(1), (12, 4, env.action_size), minval=-1, maxval=1)
    return env, s0, acts


def roll(env, s0, acts):
    """A new function per call: a fresh trace (jit caches by function)."""
    def body(s, a):
        s = jax.vmap(env.step)(s, a)
        return s, (s.pipeline_state.qpos, s.pipeline_state.qvel, s.pipeline_state.qfrc_constraint)

    return jax.device_get(jax.jit(lambda s: jax.lax.scan(body, s, acts)[1])(s0))


def test_while_line_search_is_bitwise_mjx_scan(hopper):
    env, s0, acts = hopper
    ours = roll(env, s0, acts)
    assert np.abs(ours[2]).max() > 1.0  # the foot is on the floor: the constraint solver works
    scan = envs.make_base("hopper", Physics(ls_iterations=50, search_loop="scan"))
    theirs = roll(scan, s0, acts)
    for a, b in zip(ours, theirs):
        np.testing.assert_array_equal(a, b)


def test_exact_line_search_steps_hopper_as_the_iterative_one(hopper):
    """Same solver, same cost, the line minimum found exactly: 12 steps with contacts agree with MJX's
    iterative search to float32 solver precision."""
    env, s0, acts = hopper
    exact = envs.make_base("hopper")
    assert envs.solver_settings(exact)["linesearch_in_force"] == "exact"
    ours, theirs = roll(exact, s0, acts), roll(env, s0, acts)
    assert np.abs(ours[2]).max() > 1.0
    np.testing.assert_allclose(ours[0], theirs[0], atol=1e-4)  # qpos
    np.testing.assert_allclose(ours[1], theirs[1], atol=2e-2)  # qvel (m/s, rad/s) after contact events


def test_solver_option_changes_mjx_only(hopper):
    env, s0, acts = hopper
    fast = envs.make_base("hopper", Physics(solver_iterations=1, ls_iterations=4))
    assert envs.solver_settings(fast) == {"solver_iterations": 1, "ls_iterations": 4, "linesearch": "exact",
                                          "search_loop": "while", "cholesky": "unrolled", "backend": "mjx", "threads": 0,
                                          "linesearch_in_force": "iterative",
                                          "iterations_in_force": 1, "task_iterations": 4, "task_ls_iterations": 50}
    assert envs.solver_settings(env)["iterations_in_force"] == 4 and envs.mj_model(fast).opt.ls_iterations == 50
    assert envs.make("hopper", physics=Physics(solver_iterations=2)).unwrapped.sys.opt.iterations == 2
    q_task, q_fast = roll(env, s0, acts[:3])[0], roll(fast, s0, acts[:3])[0]
    diff = np.abs(q_task - q_fast).max()
    assert 0.0 < diff < 0.05, diff  # a different, nearby simulator over 3 steps


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "4"])
def test_solver_option_rejects_bad_values(bad):
    with pytest.raises(ValueError, match="solver_iterations must be an integer >= 1"):
        Physics(solver_iterations=bad).validate()
    with pytest.raises(ValueError, match="ls_iterations must be an integer >= 1"):
        Physics(ls_iterations=bad).validate()
    from gsa_jax.algorithm.config import Config
    from gsa_jax.running.tasks import config_for

    with pytest.raises(ValueError, match="ls_iterations"):
        config_for(Config(env="hopper", physics=Physics(ls_iterations=bad)))
