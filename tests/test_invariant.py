"""gsa verify --certify on a hold kept by switching: an invariant set, exact on the linearization and tested on the
plant (gsa_jax.verify.invariant)."""

import json
import os

import numpy as np
import pytest

from envs.task import TaskC
from gsa_jax.commands.verify import main as verify_main
from gsa_jax.deployment import cells
from gsa_jax.verify import analysis, certify, invariant, multistep, roa, simulate
from gsa_jax.verify import linearize as lin
from gsa_jax.verify.system import equilibrium_guess, load_system, state_scale
from verify_tasks import biased_pair, export, lqr_gain

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
POINT_MASS = os.path.join(ROOT, "tests", "verify_tasks.py") + ":PointMass"
CARTPOLE = os.path.join(ROOT, "experiments/partition/results/cartpole-balance/{0}/controllers",
                        "dmc.cartpole-balance-mixture-K4-partition={0}-lr_scale_partition=2.968-s2.npz")
BIAS = 0.2  # the biased pair's push: each piece's fixed point at x = -+0.07 m, in the other's cell
R0 = 0.3  # m: the planted piece acts beyond |x| = R0 + 0.011


def hold_of(system):
    task = system.task
    qref, scale = equilibrium_guess(task), state_scale(task)
    hold = roa.find_hold(task, simulate.controller_policy(system.ctrl), qref, scale, int(task.episode_length))
    return qref, scale, hold


def certify_system(system, budget=certify.QUICK):
    qref, scale, hold = hold_of(system)
    return invariant.certify_hold(system, qref, analysis.local_analysis(system, qref, scale, hold), hold, budget)


def planted_controller(path, r0):
    """K = 3 on PointMass: the biased pair's pieces 0 and 1 near x = 0, and piece 2, the LQR gain's opposite, picked
    beyond x = r0 + 0.011 and x = -r0 (tanh units h1 = tanh(50 x), h2 = tanh(50 (x - r0)), h3 = tanh(50 (-x - r0));
    logits 0, h1 and 2 + 2 h2 + 2 h3): every start where it acts with a velocity that does not point back
    diverges."""
    k = lqr_gain()[None]
    w = [np.array([[50.0, 50.0, -50.0], [0.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 2.0], [0.0, 0.0, 2.0]])]
    bw = [np.array([0.0, -50.0 * r0, -50.0 * r0]), np.array([0.0, 0.0, 2.0])]
    return load_system(export(path, POINT_MASS, np.concatenate([-k, -k, k]), [[BIAS], [-BIAS], [0.0]], w, bw))


def inside(rec, count, seed):
    """[count, 2] offsets from x_c uniform in {V <= level}, drawn otherwise than the certifier draws them (rejection
    from the cube around the unit ball, mapped by P's Cholesky factor; another seed)."""
    cube = np.random.default_rng(seed).uniform(-1.0, 1.0, (50 * count, 2))
    u = cube[np.linalg.norm(cube, axis=1) <= 1.0][:count]
    return np.sqrt(rec["level"]) * np.linalg.solve(np.linalg.cholesky(np.array(rec["P"])).T, u.T).T


def recheck(system, rec, seed, count=150, steps=150):
    """Starts uniform in the certified set (inside), each run `steps` control steps in plain MuJoCo C (TaskC, the
    controller's act on one observation): every step keeps V(x_1) <= rho^2 V(x_0) + gamma + DECREASE_TOL level, so
    no start leaves the set, and every run ends inside the inner set, V <= inner level (+ what rho^(2 steps) leaves
    of the level and the tolerance's sum)."""
    P, level, rho, gamma = np.array(rec["P"]), rec["level"], rec["rho"], rec["gamma"]
    q0, v0 = np.array(rec["qpos"]), np.array(rec["qvel"])
    V = lambda tc: (lambda d: d @ P @ d)(np.concatenate([tc.data.qpos - q0, tc.data.qvel - v0]))
    for d in inside(rec, count, seed):
        tc = TaskC(system.task)
        obs = tc.set_start(q0 + d[:1], v0 + d[1:])
        before = V(tc)
        for _ in range(steps):
            obs, _, done = tc.step(system.ctrl.act(obs.astype(np.float32)))
            after = V(tc)
            assert not done and after <= rho ** 2 * before + gamma + certify.DECREASE_TOL * level
            before = after
        slack = certify.DECREASE_TOL * level / (1.0 - rho ** 2)
        assert after <= rec["inner_level"] + slack + rho ** (2 * steps) * level


@pytest.mark.parametrize("partition", ["mlp", "linear"])
def test_a_biased_pair_gets_an_invariant_set_that_holds_on_an_independent_recheck(tmp_path, partition):
    """The biased pair (each piece stable, its fixed point in the other's cell, the loop chattering across x = 0)
    under either partition class: no fixed-point certificate, an invariant set certified with the inner level below
    the level; starts drawn otherwise, run in plain MuJoCo C, decrease at every step, never leave it and end in the
    inner set. The linear partition's cells enter exactly."""
    system = load_system(biased_pair(tmp_path / "c.npz", POINT_MASS, BIAS, partition))
    out = certify_system(system)
    assert set(out) == {"hold_set"}
    rec = out["hold_set"]
    assert rec["pieces"] == [0, 1] and rec["switches_per_second"] > 10 and rec["certified"], rec.get("reason")
    assert "no piece's fixed point lies in its own region" in rec["fixed_point"]
    assert rec["cells"].startswith("exact" if partition == "linear" else "linearized")
    assert max(rec["spectral_radii"]) < 1 and 0 < rec["inner_level"] < rec["level"] and rec["violations"][-1] == 0
    recheck(system, rec, seed=4321)


@pytest.mark.parametrize("r0", [0.2, 0.3])
def test_a_planted_unstable_piece_makes_it_refuse_or_shrink(tmp_path, r0):
    """planted_controller: the linearization at the hold does not see piece 2 (its logit's gradient there is nearly
    zero) and its set reaches where piece 2 acts; the plant test finds violations. Where piece 2 begins at |x| = 0.2
    the one-step set reaches diverging starts and shrinking it would reach the inner set: the one-step set is
    refused, and the k-step program's set, fitted on a box around the hold, is certified, reaches no diverging start
    and holds at its k-step instants on an independent recheck. Where it begins at 0.3 the certified set is smaller than the linearization's, reaches no
    diverging start (checked on its boundary: the set is convex and those starts are closed under growing |x|), and
    holds on an independent recheck."""
    system = planted_controller(tmp_path / "planted.npz", r0)
    rec = certify_system(system)["hold_set"]
    assert rec["pieces"] == [0, 1]
    t = np.linspace(0.0, 2 * np.pi, 20_000, endpoint=False)
    ring = np.stack([np.cos(t), np.sin(t)], axis=1)
    centre = np.array(rec["qpos"] + rec["qvel"])

    def diverging(level):
        x = centre + certify.offsets(np.array(rec["P"]), level, ring)
        return (system.ctrl.cluster(x.astype(np.float32)) == 2) & (x[:, 0] * x[:, 1] >= 0)

    if r0 == 0.2:  # the one-step set reaches diverging starts; the k-step program's smaller box does not
        assert rec["one_step_refusal"].startswith("the one-step set: plant falsified at level ")
        assert rec["program"].startswith("k steps") and rec["certified"] and not diverging(rec["level"]).any()
        recheck_instants(system, rec, seed=99, count=60)
    else:
        assert rec["violations"][0] > 0 and rec["program"].startswith("one step")
        assert rec["certified"] and rec["level"] < rec["level_linearization"] and not diverging(rec["level"]).any()
        recheck(system, rec, seed=99, count=60)


def test_a_strongly_biased_pair_says_why_nothing_is_certified(tmp_path):
    """Pushes of 0.5 put each piece's fixed point at the other piece's action clip: no quadratic invariant set lies
    inside the linearization's bounds, and the record says so (certified false, the LMI's reason)."""
    rec = certify_system(load_system(biased_pair(tmp_path / "c.npz", POINT_MASS, 0.5)))["hold_set"]
    assert not rec["certified"] and rec["level"] == 0.0
    assert rec["one_step_refusal"].startswith("the invariant-set LMI has no solution Clarabel finds at any rho_P of")
    # the k-step program fits the piecewise-affine model, whose clipped pieces the plant does not follow
    assert rec["program"].startswith("k steps") and rec["k"] > 1 and rec["violations"][0] > 0
    assert rec["reason"].startswith("plant falsified at level ") and "not above the inner level" in rec["reason"]


PENDULUM = os.path.join(ROOT, "experiments/atlas_dmc/results/pendulum-swingup/mixture/controllers",
                        "dmc.pendulum-swingup-mixture-K2-s0.npz")


def test_the_model_steps_each_state_with_the_piece_whose_cell_holds_it():
    """multistep.run_model against a loop over states: three 2-D pieces whose cells are the argmax of affine logits,
    each state stepped k times by the piece whose logit is largest there."""
    rng = np.random.default_rng(3)
    W, c = rng.normal(size=(3, 2)), rng.normal(size=3)
    rows = [np.array([np.append(W[i] - W[j], c[i] - c[j]) for j in range(3) if j != i]) for i in range(3)]
    F = rng.normal(scale=0.5, size=(3, 2, 3))
    d = rng.normal(size=(200, 2))
    out = multistep.run_model(F, rows, d, 4)
    for x, y in zip(d, out):
        for _ in range(4):
            i = int(np.argmax(W @ x + c))
            x = F[i, :, :2] @ x + F[i, :, 2]
        np.testing.assert_allclose(y, x, rtol=1e-12, atol=1e-12)


def test_a_sliding_pendulum_hold_is_certified_over_k_steps_and_holds_on_a_recheck():
    """dmc pendulum-swingup K = 2 seed 0 holds upright by sliding between two saturated pieces, each open-loop
    unstable there (spectral radii about 1.088): no one-step quadratic V exists, the k-step program's set is
    certified; starts drawn otherwise, run in plain MuJoCo C, keep V(x_k) <= rho^2 V(x_0) + gamma at each of three
    k-step instants and never terminate."""
    system = load_system(PENDULUM)
    rec = certify_system(system)["hold_set"]
    assert rec["program"].startswith("k steps") and rec["certified"] and rec["k"] > 1, rec.get("reason")
    assert rec["one_step_refusal"].startswith("the invariant-set LMI has no solution")
    assert min(rec["spectral_radii"]) > 1 and 0 < rec["inner_level"] < rec["level"]
    recheck_instants(system, rec, seed=2024, count=40)


def recheck_instants(system, rec, seed, count, instants=3):
    """Starts uniform in a k-step set (inside), each run `instants` x k control steps in plain MuJoCo C: V(x_k) <=
    rho^2 V(x_0) + gamma + DECREASE_TOL level at every k-step instant, and no run terminates."""
    P, level, rho, gamma, k = np.array(rec["P"]), rec["level"], rec["rho"], rec["gamma"], rec["k"]
    q0, v0 = np.array(rec["qpos"]), np.array(rec["qvel"])
    V = lambda tc: (lambda d: d @ P @ d)(np.concatenate([tc.data.qpos - q0, tc.data.qvel - v0]))
    for d in inside(rec, count, seed):
        tc = TaskC(system.task)
        obs = tc.set_start(q0 + d[:1], v0 + d[1:])
        before = V(tc)
        for _ in range(instants):
            for _ in range(k):
                obs, _, done = tc.step(system.ctrl.act(obs.astype(np.float32)))
                assert not done
            after = V(tc)
            assert after <= rho ** 2 * before + gamma + certify.DECREASE_TOL * level
            before = after


def random_cells(tmp_path, rng):
    """A K = 3 linear-partition controller on PointMass with a random W, c and normalizer."""
    w, c = rng.normal(size=(2, 3)), rng.normal(size=3)
    return load_system(export(tmp_path / "lin.npz", POINT_MASS, np.zeros((3, 1, 2)), np.zeros((3, 1)), [w], [c],
                              obs_var=(0.3, 2.0), obs_mean=(0.2, -0.1), partition="linear"))


def argmax_of_rows(rows, d):
    """[B] the piece whose cell's rows [m, n + 1] all hold at d [B, n] (-1: none)."""
    member = np.stack([np.all(d @ r[:, :-1].T + r[:, -1] >= 0, axis=1) for r in rows], axis=1)
    assert np.all(member.sum(1) <= 1)
    return np.where(member.any(1), np.argmax(member, axis=1), -1)


def test_linear_partition_cells_are_the_controllers_argmax(tmp_path):
    """For a linear partition, the S-procedure's cells (cell_rows through logit_rows: W and c with the normalization
    folded in, at any centre) are the controller's own argmax on random states, exactly; their rows are the cells
    `gsa inspect` prints (deployment.cells). The MLP partition's are flagged as a linearization."""
    rng = np.random.default_rng(7)
    system = random_cells(tmp_path, rng)
    ctrl = system.ctrl
    centre = rng.normal(size=2)
    pieces = invariant.Pieces([0, 1, 2], None, None, centre, np.eye(2))  # PointMass observes its state
    rows = invariant.cell_rows(ctrl, pieces)
    states = centre + 3.0 * rng.normal(size=(20_000, 2))
    np.testing.assert_array_equal(argmax_of_rows(rows, states - centre), ctrl.cluster(states.astype(np.float32)))
    for cell, r in zip(cells.cell_inequalities(ctrl), rows):
        np.testing.assert_allclose(r[:, :-1], cell.A, rtol=1e-12)
        np.testing.assert_allclose(r[:, -1], cell.A @ centre - cell.d, rtol=1e-9, atol=1e-12)
    qref, _, hold = hold_of(system)
    C = invariant.affine_pieces(system, qref, hold.x, [0, 1, 2]).C
    np.testing.assert_allclose(C, np.eye(2), atol=1e-8)  # the state's observation, by central differences
    assert lin.logit_rows(ctrl, centre)[2]


def test_a_committed_linear_partitions_cells_are_its_argmax():
    """cartpole-balance K = 4, seed 2, linear partition: the rows logit_rows gives in the observation (flagged exact)
    are the controller's argmax on random observations (within 2 std of the normalizer's mean), exactly; the MLP
    partition's seed 2 is flagged as a linearization."""
    system = load_system(CARTPOLE.format("linear"))
    ctrl, rng = system.ctrl, np.random.default_rng(3)
    obs = ctrl.obs_mean.astype(np.float64)
    logits, grad, exact = lin.logit_rows(ctrl, obs)
    s = obs + 2.0 * ctrl.obs_std * rng.normal(size=(20_000, len(obs)))
    assert exact and len(np.unique(ctrl.cluster(s.astype(np.float32)))) > 1
    np.testing.assert_array_equal(np.argmax(logits + (s - obs) @ grad.T, axis=1), ctrl.cluster(s.astype(np.float32)))
    mlp = load_system(CARTPOLE.format("mlp")).ctrl
    assert not lin.logit_rows(mlp, mlp.obs_mean.astype(np.float64))[2]


def test_certify_writes_the_hold_set_and_prints_it(tmp_path, capsys):
    """--certify --quick on the biased pair: verify.json's hold_set (P, rho, gamma, inner level, level, semi-axes,
    inscribed radius, samples and violations per round, the rule), report.md's section and the printed lines say what
    it is, in SI units; no fixed-point certificate beside it."""
    path = biased_pair(tmp_path / "c.npz", POINT_MASS, BIAS, "linear")
    assert verify_main([path, "--quick", "--certify", "--out", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    doc = json.load(open(tmp_path / "out" / "verify.json"))
    rec = doc["hold_set"]
    assert "certificate" not in doc and rec["certified"]
    assert {"P", "rho", "gamma", "inner_level", "level", "semi_axes", "inscribed_radius", "samples", "violations",
            "rule", "inner_extent", "cells"} <= set(rec)
    assert rec["coordinates"] == ["x (m)", "x velocity (m/s)"]
    report = (tmp_path / "out" / "report.md").read_text()
    for text in (printed, report):
        assert "Exact on the linearization, tested on the plant (not proved on it)." in text
        extent = ", ".join(f"{name} +-{e:.3g}" for name, e in zip(rec["coordinates"], rec["extent"]))
        assert f"in its units): {extent}" in text and "(SI units)" not in text  # per axis, each in its own units
        assert f"inner set V <= {rec['inner_level']:.4g}" in text


def test_a_piece_that_grows_far_from_the_hold_is_certified_inside_the_bounds():
    """1-D: piece 0 (d <= 0) d' = 1.1 d + 0.01 grows away from the hold beyond |d| = 0.1, piece 1 (d >= 0)
    d' = 0.5 d - 0.01 contracts; the hold chatters across 0. Asked on every whole cell the decrease fails along
    piece 0's growing mode at every rho_P; asked inside the validity bound |d| <= 0.05 only (the bounds' slabs among
    the S-procedure's rows), it holds, and V(d') <= rho_P^2 V(d) + gamma at every point of the set."""
    c = 0.01
    F = np.array([[[1.1, c]], [[0.5, -c]]])
    rows = [np.array([[-1.0, 0.0]]), np.array([[1.0, 0.0]])]
    H = np.array([[1 / 0.05]])
    assert all(invariant.invariant_shape(F, rows, H, 1.0 - gap) is None for gap in invariant.RHO_GAPS)
    shapes = invariant.grid_shapes(F, rows, H)
    assert shapes and all(s.within for s in shapes)
    best = invariant.least_gamma(F, rows, max(shapes, key=lambda s: s.radius), H)
    P = best.P[0, 0]
    d = np.linspace(-1.0, 1.0, 20_001) / np.sqrt(P)  # E at level 1
    f = np.where(d <= 0, 1.1 * d + c, 0.5 * d - c)
    assert np.all(P * f ** 2 <= best.rho_p ** 2 * P * d ** 2 + best.gamma + 1e-9)
    assert 1.0 / np.sqrt(P) <= 0.05 * (1 + 1e-6)  # inside the bound


def test_the_slab_rows_are_nonnegative_exactly_inside_the_bounds():
    H = np.array([[2.0, 0.0], [0.0, 0.5]])
    rows = invariant.slab_rows(H)
    inside, outside = np.array([0.4, -1.9, 1.0]), np.array([0.6, 0.0, 1.0])
    assert np.all(rows @ inside >= 0) and np.any(rows @ outside < 0)
