"""python -m gsa_jax.verify: the closed loop of an exported controller analysed in its task's MuJoCo C twin."""

import json
import os
import subprocess
import sys

import mujoco
import numpy as np
import pytest

from envs.task import TaskC
from gsa_jax.running.checkpoint import save_npz_atomic
from gsa_jax.verify import analysis
from gsa_jax.verify.system import load_system
from verify_tasks import analytic_step, export, lqr_gain

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
POINT_MASS = os.path.join(ROOT, "tests", "verify_tasks.py") + ":PointMass"
IDP = os.path.join(ROOT, "experiments/fig1_v5/results/fig1_v5_InvertedDoublePendulum-v5/controllers",
                   "InvertedDoublePendulum-v5-mixture-K4-s0.npz")
EIG_TOL = 1e-6  # finite differences (eps 1e-6, central) of an exactly linear step: exact to rounding


def test_linear_task_eigenvalues_match_the_analytic_ones_and_its_roa_has_no_boundary(tmp_path):
    """An LQR gain as a K = 1 controller on an exactly linear task: the closed-loop eigenvalues verify computes
    (mjd_transitionFD over the frame skip, the exact controller Jacobian) equal eig(A - B K L/std) within EIG_TOL,
    and every sampled start converges, in every direction out to the largest radius the search grows to."""
    system = load_system(export(tmp_path / "lqr.npz", POINT_MASS, -lqr_gain()[None] * np.sqrt(1.0 + 1e-8), [[0.0]]))
    result = analysis.verify(system, analysis.QUICK)
    A, B = analytic_step()
    gain = system.ctrl.L[0].astype(np.float64) / system.ctrl.obs_std  # d action / d obs, as stored (float32)
    expected = np.linalg.eigvals(A + B @ gain)
    piece = result["local"]["pieces"][0]
    got = np.array([complex(*e) for e in piece["eigenvalues"]])
    assert piece["fixed_point_found"] and piece["own_region"]
    assert np.abs(np.sort_complex(got) - np.sort_complex(expected)).max() < EIG_TOL
    assert abs(piece["spectral_radius"] - np.abs(expected).max()) < EIG_TOL
    roa = result["roa"]
    assert roa["hold"]["holds"] and roa["no_boundary_in_range"] and roa["volume_fraction"] == 1.0
    assert roa["volume_fraction_sampled"] == 1.0 and roa["not_star_shaped_directions"] == 0
    assert roa["r_limit"] == roa["r_max"] * 2 ** analysis.QUICK.roa_growths > roa["r_max"]
    assert min(roa["radius"]) == roa["radius_equivalent"] == roa["r_limit"]
    assert roa["unbounded_directions"] == analysis.QUICK.roa_directions
    # every sampled start converged: each coordinate's reach and axis radii (the task's units) are r_limit's
    scale = analysis.state_scale(system.task)
    assert roa["scale"] == scale.tolist()
    np.testing.assert_allclose(roa["reach"], roa["r_limit"] * scale, rtol=1e-12)
    np.testing.assert_allclose(roa["axis_radius_si"], roa["r_limit"] * np.stack([scale, scale], 1), rtol=1e-12)


def test_lqr_with_given_weights_is_the_analytic_design(tmp_path):
    """--lqr-q/--lqr-r weights in the task's units: verify's LQR gain on PointMass (exactly linear) is scipy's
    discrete LQR on the analytic step with those weights (Q = diag(10, 1), R = 1), and its weights are recorded."""
    system = load_system(export(tmp_path / "lqr.npz", POINT_MASS, -lqr_gain()[None], [[0.0]]))
    scale = analysis.state_scale(system.task)
    summary, policy = analysis.lqr_design(system, analysis.equilibrium_guess(system.task), scale, np.zeros(2),
                                          analysis.LqrWeights((10.0, 1.0), (1.0,)))
    assert policy is not None and summary["weights"] == {"q": [10.0, 1.0], "r": [1.0]}
    np.testing.assert_allclose(summary["gain"], lqr_gain(), rtol=1e-5)
    default, _ = analysis.lqr_design(system, analysis.equilibrium_guess(system.task), scale, np.zeros(2))
    assert default["weights"] == "Q = I on scaled states, R = I" and not np.allclose(default["gain"], lqr_gain())


def quadrant_controller(path):
    """K = 2 on PointMass: piece 0 the LQR gain, piece 1 its opposite (diverges); the partition picks piece 1 where
    x > 0 and v > 0 (the quadrant), through tanh(50 z) units: logit 1 = h_x + h_v - 1.5."""
    k = lqr_gain()[None] * np.sqrt(1.0 + 1e-8)
    w = [50.0 * np.eye(2), np.array([[0.0, 1.0], [0.0, 1.0]])]
    return export(path, POINT_MASS, np.concatenate([-k, k]), [[0.0], [0.0]], w, [np.zeros(2), np.array([0.0, -1.5])])


def test_falsification_finds_a_planted_failure_quadrant(tmp_path):
    """Within the quick budget the search's worst start lies in the quadrant where the controller diverges, far
    below the worst the same search finds for the LQR alone."""
    planted = load_system(quadrant_controller(tmp_path / "planted.npz"))
    lqr = load_system(export(tmp_path / "lqr.npz", POINT_MASS, -lqr_gain()[None] * np.sqrt(1.0 + 1e-8), [[0.0]]))
    budget = analysis.QUICK._replace(neighbours=4)
    f = analysis.falsification(planted, budget)["start_law"]
    g = analysis.falsification(lqr, budget)["start_law"]
    worst = f["counterexamples"][0]
    assert worst["qpos"][0] > 0 and worst["qvel"][0] > 0
    assert f["episodes"] == g["episodes"] == analysis.QUICK.population * analysis.QUICK.iterations
    assert worst["return"] < 100 * g["worst_return"] < 0


def replay_in_mujoco_c(task, ctrl, example):
    """(return, steps) of a counterexample in plain MuJoCo C, written here: one MjData, mj_step frame_skip times
    per control step, the push as xfrc_applied on its body during its step."""
    tc = TaskC(task)
    obs = tc.set_start(np.array(example["qpos"]), np.array(example["qvel"]))
    push, total = example["push"], 0.0
    for t in range(task.episode_length):
        if push is not None:
            body = mujoco.mj_name2id(task.model, mujoco.mjtObj.mjOBJ_BODY, push["body"])
            tc.data.xfrc_applied[body, :2] = push["force"] if t == push["step"] else 0.0
        obs, r, done = tc.step(ctrl.act(obs.astype(np.float32)))
        total += r
        if done:
            return total, t + 1
    return total, task.episode_length


def test_counterexamples_replay_in_plain_mujoco_c_to_their_return():
    """Every counterexample of a small search on a committed InvertedDoublePendulum-v5 controller, pushes included,
    replays to its reported return and steps; the batched search's own return agrees."""
    system = load_system(IDP)
    budget = analysis.QUICK._replace(population=8, iterations=2, counterexamples=2, neighbours=4)
    result = analysis.falsification(system, budget)
    examples = [c for name, part in result.items() if name != "rule" for c in part["counterexamples"]]
    assert any(c["push"] is not None for c in examples)
    for c in examples:
        ret, steps = replay_in_mujoco_c(system.task, system.ctrl, c)
        assert steps == c["steps"] and ret == pytest.approx(c["return"], rel=1e-9, abs=1e-9)
        assert c["search_return"] == pytest.approx(c["return"], rel=1e-6)


def run_cli(*args):
    env = {**os.environ, "PYTHONPATH": ROOT}
    return subprocess.run([sys.executable, "-m", "gsa_jax.verify", *args], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=120)


def rewrite_env(src, dst, env):
    with np.load(src) as f:
        arrays = {k: f[k] for k in f.files}
    arrays["config_json"] = np.array(json.dumps({"config": {"env": env}}))
    save_npz_atomic(str(dst), **arrays)
    return str(dst)


@pytest.mark.parametrize("case, expect", [
    ("not_npz", "is not an exported controller"),
    ("npz_without_fields", "is not an exported controller"),
    ("no_twin", "has no MuJoCo C twin verify can step; these have one: gymnasium's v5 tasks"),
    ("obs_size", "takes observations of size 9 but its task 'dmc:cartpole-balance' observes 5"),
    ("lqr_q_length", "--lqr-q needs 6 weights >= 0"),
    ("lqr_r_alone", "--lqr-q and --lqr-r go together"),
])
def test_one_line_errors(tmp_path, case, expect):
    """Bad input: exit code 2 and one line on stderr, no traceback."""
    path, extra = tmp_path / "c.npz", {"lqr_q_length": ["--lqr-q", "1,2", "--lqr-r", "1"], "lqr_r_alone": ["--lqr-r", "1"]}
    if case in extra:
        path = IDP
    elif case == "not_npz":
        path.write_text("not a controller")
    elif case == "npz_without_fields":
        np.savez(path, x=np.zeros(3))
    else:
        rewrite_env(IDP, path, "inverted_double_pendulum" if case == "no_twin" else "dmc:cartpole-balance")
    p = run_cli(str(path), "--out", str(tmp_path / "out"), *extra.get(case, []))
    assert p.returncode == 2 and expect in p.stderr, p.stderr
    assert p.stderr.count("\n") == 1 and "Traceback" not in p.stderr


def test_quick_run_writes_json_report_and_figure(tmp_path):
    """The CLI on a K = 2 controller of the linear task: verify.json, report.md and the figure, with each part's
    cost; the diverging piece's fixed point (the origin, where the partition picks the LQR piece) is not the closed
    loop's."""
    path = quadrant_controller(tmp_path / "planted.npz")
    p = run_cli(path, "--quick", "--out", str(tmp_path / "out"))
    assert p.returncode == 0, p.stderr
    doc = json.load(open(tmp_path / "out" / "verify.json"))
    assert doc["schema"] == 2 and doc["clusters"] == 2 and doc["quick"]
    assert set(doc["cost_seconds"]) == {"nominal_and_switching", "local", "roa", "lqr", "falsification"}
    assert doc["local"]["has_fixed_point"] and doc["lqr"]["spectral_radius"] < 1
    lqr_piece, diverging = doc["local"]["pieces"]
    assert lqr_piece["own_region"] and lqr_piece["spectral_radius"] < 1
    assert not diverging["own_region"] and diverging["picked_there"] == 0 and diverging["spectral_radius"] > 1
    assert doc["local"]["closed_loop_fixed_point"]["piece"] == 0
    assert (tmp_path / "out" / "verify.png").stat().st_size > 0
    assert "## Falsification" in (tmp_path / "out" / "report.md").read_text()
