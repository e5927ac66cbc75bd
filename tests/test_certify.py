"""gsa verify --certify: a certified region of attraction, exact on the linearization and tested on the plant."""

import json
import os
import sys

import numpy as np
import pytest
import scipy.linalg

from envs.task import TaskC
from gsa_jax.commands.verify import main as verify_main
from gsa_jax.verify import analysis, certify, roa, simulate
from gsa_jax.verify.boundary import settle_steps
from gsa_jax.verify.system import equilibrium_guess, load_system, state_scale
from verify_tasks import analytic_step, export, lqr_gain

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
POINT_MASS = os.path.join(ROOT, "tests", "verify_tasks.py") + ":PointMass"
HOPPER = os.path.join(ROOT, "experiments/fig1_v5/results/fig1_v5_Hopper-v5/controllers",
                      "Hopper-v5-mixture-K2-s5.npz")
IDP_FLAT = os.path.join(ROOT, "experiments/fig1_v5/results/fig1_v5_InvertedDoublePendulum-v5/controllers",
                        "InvertedDoublePendulum-v5-mlp-s0.npz")
LEVEL_TOL = 1e-6  # relative: verify's A (mjd_transitionFD, central differences of a linear step) vs the formula
R0 = 0.1  # m: the planted controller's piece changes at |x| = R0


def lqr_controller(path):
    return load_system(export(path, POINT_MASS, -lqr_gain()[None] * np.sqrt(1.0 + 1e-8), [[0.0]]))


def planted_controller(path):
    """K = 2 on PointMass: piece 0 the LQR gain, piece 1 its opposite, picked where |x| > R0 (tanh units
    h1 = tanh(50 (x - R0)), h2 = tanh(50 (-x - R0)); logit 1 = h1 + h2 + 1 > 0 exactly there). Piece 1 pushes away:
    where x > R0 and v >= 0 (or x < -R0 and v <= 0) the action is positive (negative), so x and v only grow and
    every start there diverges."""
    k = lqr_gain()[None] * np.sqrt(1.0 + 1e-8)
    w = [np.array([[50.0, -50.0], [0.0, 0.0]]), np.array([[0.0, 1.0], [0.0, 1.0]])]
    bw = [np.full(2, -50.0 * R0), np.array([0.0, 1.0])]
    return load_system(export(path, POINT_MASS, np.concatenate([-k, k]), [[0.0], [0.0]], w, bw))


def certify_system(system, budget=certify.QUICK):
    task = system.task
    qref, scale = equilibrium_guess(task), state_scale(task)
    hold = roa.find_hold(task, simulate.controller_policy(system.ctrl), qref, scale, int(task.episode_length))
    return certify.certificate(system, qref, analysis.local_analysis(system, qref, scale, hold), budget)


def boundary(cert, level, count=20_000):
    """[count, 2] points on the boundary of {x' P x <= level} (x* = 0 here)."""
    t = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    return certify.offsets(np.array(cert["P"]), level, np.stack([np.cos(t), np.sin(t)], axis=1))


def recheck(system, cert, seed, count=400):
    """Starts uniform in the certified set drawn otherwise than the certifier draws them (rejection from the cube
    around the unit ball, mapped by P's Cholesky factor; another seed), each stepped k control steps in plain MuJoCo C
    (TaskC, the controller's act on one observation): none terminates, V(x_k) <= rho^2 V(x_0) + DECREASE_TOL level for
    every one."""
    P, level, k, rho = np.array(cert["P"]), cert["level"], cert["k"], cert["rho"]
    q0, v0, nv = np.array(cert["qpos"]), np.array(cert["qvel"]), system.task.model.nv
    assert system.task.model.nq == nv  # hinges and slides: qpos = q* + dq
    cube = np.random.default_rng(seed).uniform(-1.0, 1.0, (50 * count, len(P)))
    u = cube[np.linalg.norm(cube, axis=1) <= 1.0][:count]
    assert len(u) == count
    starts = np.sqrt(level) * np.linalg.solve(np.linalg.cholesky(P).T, u.T).T  # d' P d = level |u|^2
    for d in starts:
        tc = TaskC(system.task)
        obs = tc.set_start(q0 + d[:nv], v0 + d[nv:])
        for _ in range(k):
            obs, _, done = tc.step(system.ctrl.act(obs.astype(np.float32)))
            assert not done
        dk = np.concatenate([tc.data.qpos - q0, tc.data.qvel - v0])
        assert dk @ P @ dk <= rho ** 2 * (d @ P @ d) + certify.DECREASE_TOL * level


def test_lqr_on_a_linear_task_gets_the_largest_ellipsoid_of_its_p(tmp_path):
    """An LQR gain as a K = 1 controller on an exactly linear task (PointMass): P satisfies the decrease LMI on the
    analytic closed loop over k steps (k by the rule), the certified level equals the analytic largest level of that
    P (the ellipsoid and its images over the k steps inside |gain x| <= 1, the action clip, and the normalizer's
    clip) within LEVEL_TOL, the plant test finds no violation, and an independent recheck finds none either."""
    system = lqr_controller(tmp_path / "lqr.npz")
    cert = certify_system(system)
    A, B = analytic_step()
    gain = system.ctrl.L[0].astype(np.float64) / system.ctrl.obs_std  # d action / d obs = d action / dx
    a_cl = A + B @ gain
    rho_a = np.abs(np.linalg.eigvals(a_cl)).max()
    assert cert["k"] == int(np.ceil(np.log(0.5) / np.log(rho_a))) and rho_a ** cert["k"] <= 0.5
    P, k = np.array(cert["P"]), cert["k"]
    rho_p = certify.contraction(np.linalg.matrix_power(a_cl, k), P)
    assert rho_p <= cert["rho_linearization"] * (1 + LEVEL_TOL) and cert["rho_linearization"] < cert["rho"] < 1
    rows = np.concatenate([gain, np.eye(2) / system.ctrl.obs_clip])  # |row x| <= 1
    images = np.concatenate([rows @ np.linalg.matrix_power(a_cl, j) for j in range(k)])
    analytic = 1.0 / np.einsum("mi,ij,mj->m", images, np.linalg.inv(P), images).max()
    assert cert["level_clean"] == cert["level_linearization"] and cert["level"] == certify.ROOM * cert["level_clean"]
    assert abs(cert["level_clean"] - analytic) <= LEVEL_TOL * analytic
    assert cert["bounded_by"] == "action 0's clip at step 0"
    assert cert["certified"] and cert["violations"] == [0, 0] and cert["samples"] == 2 * (500 + 500 + 32 * 4)
    assert [r["confirmation"] for r in cert["rounds"]] == [False, True] and cert["first_violating_v0"] is None
    between = cert["between_instants"]  # exactly linear: no boundary start exceeds the linearization's peak
    peaks = [scipy.linalg.eigh(np.linalg.matrix_power(a_cl, j).T @ P @ np.linalg.matrix_power(a_cl, j), P,
                               eigvals_only=True).max() for j in range(1, k + 1)]
    assert between["linearization_peak"] == pytest.approx(max(peaks), rel=1e-9)
    assert between["linearization_peak_step"] == int(np.argmax(peaks)) + 1
    assert between["plant_peak"] <= between["linearization_peak"] * (1 + 1e-6)
    assert between["converged"] == between["starts"] and between["invariant"] == (max(peaks) <= 1.0)
    axes = np.sqrt(cert["level"] / np.linalg.eigvalsh(P))
    np.testing.assert_allclose(cert["semi_axes"], axes, rtol=1e-12)  # largest first
    assert cert["inscribed_radius"] == pytest.approx(axes.min(), rel=1e-12)
    recheck(system, cert, seed=12345)


def test_planted_instability_is_certified_no_further_than_its_radius(tmp_path):
    """The planted controller (planted_controller) diverges from every start beyond |x| = R0 whose velocity does not
    point back. The linearization sees none of it (the partition's boundary has zero gradient at x*) and its level
    reaches there; the plant test finds violations, shrinks the level, and the certified set reaches no such start
    (checked on its boundary: the set is convex and those starts are closed under growing |x|). An independent
    recheck finds no violation. With one round only, its violations leave nothing certified."""
    system = planted_controller(tmp_path / "planted.npz")
    cert = certify_system(system)
    unstable = lambda x: ((x[:, 0] > R0) & (x[:, 1] >= 0)) | ((x[:, 0] < -R0) & (x[:, 1] <= 0))
    assert unstable(boundary(cert, cert["level_linearization"])).any()
    assert cert["violations"][0] > 0 and cert["violations"][-1] == 0 and cert["certified"]
    assert not unstable(boundary(cert, cert["level"])).any()
    assert cert["level"] < cert["level_linearization"] and cert["inscribed_radius"] > 0.1 * R0
    recheck(system, cert, seed=54321)
    one_round = certify_system(system, certify.QUICK._replace(rounds=1))  # violations in its only round
    assert not one_round["certified"] and one_round["level"] == 0.0 and one_round["inscribed_radius"] == 0.0
    assert one_round["between_instants"] is None and one_round["level_clean"] is None


def test_the_room_fields_name_the_clean_level_and_the_first_violation():
    """room_fields: the certified level's last clean level is the round before the confirmation; the first
    violation is the smallest V(x_0) of a violation over every round, the level's share of it beside it."""
    r = lambda level, bad, v0=None, confirmation=False: {"level": level, "violations": bad,
                                                         "smallest_violating_v0": v0, "confirmation": confirmation}
    rounds = [r(1.0, 3, 0.5), r(0.45, 0), r(0.36, 0, None, True)]
    got = certify.room_fields(rounds, 0.36)
    assert got["level_clean"] == 0.45 and got["room"] == pytest.approx(0.8) and got["first_violating_v0"] == 0.5
    assert got["level_share_of_first_violation"] == pytest.approx(0.72)
    nothing = certify.room_fields([r(1.0, 3, 0.5)], 0.0)
    assert nothing["level_clean"] is None and nothing["level_share_of_first_violation"] is None


def test_the_spare_level_keeps_its_room_above_the_floor():
    assert certify.spare_level(1.0, 0.0) == certify.ROOM
    assert certify.spare_level(1.0, 0.9) == pytest.approx(0.95)  # ROOM x 1 would reach the inner level 0.9


def test_the_settling_step_is_the_first_after_the_last_step_outside():
    ok = np.array([[0, 0, 1, 0], [1, 0, 1, 1], [0, 1, 1, 1], [1, 1, 1, 0]], bool)  # [T + 1 = 4, B = 4]
    alive = np.array([True, True, True, True])
    assert settle_steps(ok, alive).tolist() == [3, 2, 0, -1]  # the last ends outside: none
    assert settle_steps(ok, np.array([True, False, True, True])).tolist() == [3, -1, 0, -1]


def test_a_committed_controllers_certificate_holds_on_an_independent_recheck():
    """InvertedDoublePendulum-v5's flat PPO seed 0 (a stable fixed point, spectral radius 0.948): the plant test finds
    violations at the linearization's level and certifies a smaller one; 1000 starts drawn otherwise, stepped in plain
    MuJoCo C, find no violation in it."""
    system = load_system(IDP_FLAT)
    cert = certify_system(system)
    assert cert["violations"][0] > 0 and cert["violations"][-1] == 0 and cert["certified"]
    assert 0 < cert["level"] < cert["level_linearization"] and cert["k"] == 14
    recheck(system, cert, seed=777, count=1000)


def test_certify_writes_its_record_and_prints_it(tmp_path, capsys):
    """--certify --quick on the LQR controller: verify.json's certificate (P, rho, k, level, semi-axes, inscribed
    radius, samples and violations per round, the rule), report.md's section and the printed certificate say
    exactly what it is: exact on the linearization, tested on the plant (not proved on it)."""
    path = export(tmp_path / "lqr.npz", POINT_MASS, -lqr_gain()[None] * np.sqrt(1.0 + 1e-8), [[0.0]])
    assert verify_main([path, "--quick", "--certify", "--out", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    doc = json.load(open(tmp_path / "out" / "verify.json"))
    cert = doc["certificate"]
    assert {"P", "rho", "k", "level", "semi_axes", "inscribed_radius", "samples", "violations", "rule"} <= set(cert)
    assert cert["claim"] == "exact on the linearization, tested on the plant (not proved on it)"
    assert cert["coordinates"] == ["x (m)", "x velocity (m/s)"] and "certificate" in doc["cost_seconds"]
    assert cert["held_equilibrium"] and cert["counted"] and cert["held_why"] == ""  # the LQR holds x = 0 itself
    report = (tmp_path / "out" / "report.md").read_text()
    for text in (printed, report):
        assert "Exact on the linearization, tested on the plant (not proved on it)." in text
        extent = ", ".join(f"{name} +-{e:.3g}" for name, e in zip(cert["coordinates"], cert["extent"]))
        assert f"in its units): {extent}" in text and "(SI units)" not in text  # per axis, each in its own units
    recheck(load_system(path), cert, seed=2024)


def test_a_certificate_away_from_the_held_equilibrium_is_never_counted():
    """dmc:pendulum-swingup declares the pendulum upright: a certified fixed point hanging down (3.058 rad, as
    committed seed 1 of K = 1 was) is not the held equilibrium, whether or not the closed loop holds upright; one at the
    hold it keeps upright is."""
    import envs

    task = envs.resolve_task("dmc:pendulum-swingup")
    qref = equilibrium_guess(task)
    down = {"qpos": [3.058], "qvel": [0.0], "certified": True}
    at_down, upright = (certify.tangent_state(task, qref, q, [0.0]) for q in ([3.058], [0.01]))
    for hold_x, holds in ((at_down, False), (upright, True), (upright, False)):
        rec = certify.held_equilibrium(task, qref, hold_x, holds, down)
        assert not rec["held_equilibrium"] and not rec["counted"] and rec["held_why"]
    # upright, but the closed loop does not hold the equilibrium (as InvertedDoublePendulum-v5's flat PPO seed 1)
    rec = certify.held_equilibrium(task, qref, upright, False, {**down, "qpos": [0.01]})
    assert not rec["counted"] and rec["held_why"] == "the closed loop does not hold the task's equilibrium from it"
    rec = certify.held_equilibrium(task, qref, upright, True, {**down, "qpos": [0.0]})
    assert rec["held_equilibrium"] and rec["counted"] and rec["held_offset"] < 1.0
    assert not certify.held_equilibrium(task, qref, upright, True, {**down, "qpos": [0.0], "certified": False})["counted"]


def test_the_committed_certified_tables_count_only_the_held_equilibrium():
    """experiments/verify/results/certified/: summary.csv and per_controller.csv are what summarize_certified.py
    computes from the committed verify.json files, and the certificates around another fixed point (the pendulum
    hanging down, or a closed loop that does not hold the equilibrium: InvertedDoublePendulum-v5's flat PPO seed 1)
    are counted apart, not as certified."""
    import csv
    import importlib.util

    path = os.path.join(ROOT, "experiments", "verify", "summarize_certified.py")
    spec = importlib.util.spec_from_file_location("summarize_certified", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    import glob

    rows = [mod.row(p) for p in sorted(glob.glob(os.path.join(mod.RESULTS, "*", "*", "verify.json")))]
    elsewhere = sorted(r["controller"] for r in rows if r["certified_not_held"])
    assert elsewhere == ["InvertedDoublePendulum-v5-mlp-s1", "dmc.pendulum-swingup-mixture-K1-s1",
                         "dmc.pendulum-swingup-mixture-K1-s3", "dmc.pendulum-swingup-mixture-K1-s7",
                         "dmc.pendulum-swingup-mixture-K1-s8", "dmc.pendulum-swingup-mixture-K4-s8",
                         "dmc.pendulum-swingup-mlp-s8"]
    assert not any(r["fixed_point_certified"] for r in rows if r["certified_not_held"])
    text = lambda rs: [{k: str(v) for k, v in r.items()} for r in rs]  # noqa: E731 - as csv reads them back
    for name, table in (("summary.csv", mod.summary(rows)), ("per_controller.csv", rows)):
        with open(os.path.join(mod.RESULTS, name), newline="") as f:
            assert text(table) == list(csv.DictReader(f)), name


@pytest.mark.parametrize("case, expect", [
    ("no_extra", ["--certify needs cvxpy and Clarabel, the optional extra verify: pip install 'gsa_jax[verify]'"]),
    ("unstable", ["is unstable, spectral radius 1."]),
    ("no_hold", ["nothing to certify: no fixed point found near the hold (Newton's residual",
                 "; the closed loop does not hold the equilibrium (its run from there terminates, moves away or falls"]),
    ("no_equilibrium", ["'Hopper-v5' declares no equilibrium"]),
])
def test_certify_one_line_errors(tmp_path, monkeypatch, capsys, case, expect):
    """--certify without the extra (its import hidden), with an unstable fixed point (PointMass with the LQR gain's
    opposite, resting at it), with no hold (a constant push: no fixed point, and the run leaves the equilibrium; the
    line says both), a task without an equilibrium: exit code 2, one line."""
    path = {"unstable": lambda: export(tmp_path / "c.npz", POINT_MASS, lqr_gain()[None], [[0.0]]),
            "no_hold": lambda: export(tmp_path / "c.npz", POINT_MASS, np.zeros((1, 1, 2)), [[0.5]]),
            "no_equilibrium": lambda: HOPPER,
            "no_extra": lambda: export(tmp_path / "c.npz", POINT_MASS, -lqr_gain()[None], [[0.0]])}[case]()
    if case == "no_extra":
        monkeypatch.setitem(sys.modules, "cvxpy", None)
    assert verify_main([path, "--quick", "--certify", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert all(e in err for e in expect) and err.count("\n") == 1 and "Traceback" not in err, err
    assert not (tmp_path / "out").exists()
