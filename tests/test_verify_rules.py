"""gsa verify's rules: one convergence tolerance per task, the horizon a slow mode needs, wider searches no less bad,
pushes only within their episode, fixed points at a joint's limit flagged, a changed task refused."""

import hashlib
import json
import os
import shutil

import numpy as np
import pytest

from gsa_jax.commands import verify as verify_command
from gsa_jax.verify import analysis, falsify, report, roa, simulate
from gsa_jax.verify.system import equilibrium_guess, load_system, state_scale
from verify_tasks import PointMass, export, lqr_gain

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TASKS = os.path.join(ROOT, "tests", "verify_tasks.py")
POINT_MASS, RAIL = TASKS + ":PointMass", TASKS + ":RailPointMass"
IDP = os.path.join(ROOT, "experiments/fig1_v5/results/fig1_v5_InvertedDoublePendulum-v5/controllers",
                   "InvertedDoublePendulum-v5-mlp-s0.npz")
TINY = analysis.QUICK._replace(nominal_episodes=4, roa_directions=6, roa_bisections=3, roa_growths=1, roa_inside=1,
                               roa_samples=4, population=8, iterations=2, counterexamples=2, neighbours=4)
SLOW = analysis.LqrWeights((0.01, 1.0), (1.0,))  # PointMass's position mode: a 10 s time constant, episodes of 6 s


def region(system, policy, a_cl=None, budget=TINY):
    """verify's region record of a policy on the system's task (a_cl: the closed loop's Jacobian, scaled)."""
    task = system.task
    return analysis.roa_of(system, policy, equilibrium_guess(task), state_scale(task), budget, a_cl)


def test_two_controllers_of_one_task_share_its_convergence_tolerance(tmp_path):
    """An LQR and a K = 2 controller that holds PointMass by switching pieces (its hold chatters) are judged by the
    same tolerance, the task's: 0.1 x its start law's spread per coordinate, whatever the hold's own excursion."""
    k = lqr_gain()[None]
    w = [np.array([[50.0, 0.0], [0.0, 0.0]]), np.array([[0.0, 1.0], [0.0, 0.0]])]
    pair = export(tmp_path / "pair.npz", POINT_MASS, np.concatenate([-k, -k]), [[0.5], [-0.5]], w,
                  [np.zeros(2), np.zeros(2)])
    records = [region(s, simulate.controller_policy(s.ctrl), budget=TINY._replace(roa_directions=2, roa_growths=0,
                                                                                  roa_samples=0, roa_inside=0))
               for s in (load_system(export(tmp_path / "lqr.npz", POINT_MASS, -k, [[0.0]])), load_system(pair))]
    assert records[0]["tolerance"] == records[1]["tolerance"] == (0.1 * np.array([0.5, 0.5])).tolist()
    assert records[0]["hold"]["excursion"] != records[1]["hold"]["excursion"]
    assert records[0]["tolerance_rule"] == records[1]["tolerance_rule"]


def test_a_slow_mode_gets_its_horizon_and_the_lqrs_region(tmp_path):
    """A K = 1 controller whose gain is the LQR's beside it (SLOW weights: a position mode of about 10 s on 6 s
    episodes) converges from starts that an episode's length does not settle; judged over 5 time constants, its
    region is no smaller than that LQR's in any direction, and beyond the start law's size."""
    probe = load_system(export(tmp_path / "probe.npz", POINT_MASS, -lqr_gain()[None], [[0.0]]))
    task = probe.task
    qref, scale = equilibrium_guess(task), state_scale(task)
    summary, lqr_policy = analysis.lqr_design(probe, qref, scale, np.zeros(2), SLOW)
    system = load_system(export(tmp_path / "slow.npz", POINT_MASS, -np.array(summary["gain"])[None], [[0.0]]))
    hold = roa.find_hold(task, simulate.controller_policy(system.ctrl), qref, scale, task.episode_length)
    a_cl = analysis.local_analysis(system, qref, scale, hold)["_a_cl"] / scale[:, None] * scale[None, :]
    mine = region(system, simulate.controller_policy(system.ctrl), a_cl)
    lqr = region(system, lqr_policy, summary["_a_cl"])
    h = mine["horizon"]
    assert h["steps"] == lqr["horizon"]["steps"] and h["set_by"] == "5 time constants of the slowest mode"
    assert h["time_constant_seconds"] > task.episode_length * task.dt and h["steps"] > task.episode_length
    assert np.all(np.array(mine["radius"]) >= np.array(lqr["radius"])) and mine["radius_min"] > 1.0
    assert mine["tolerance"] == lqr["tolerance"]
    start = np.array([[1.0, 0.0]])  # scaled: the start law's edge along x
    trial = roa.Trial(task, simulate.controller_policy(system.ctrl), qref, roa.find_hold(
        task, simulate.controller_policy(system.ctrl), qref, scale, h["steps"]), scale, np.array(mine["tolerance"]),
        h["steps"])
    assert roa.converged(trial, start)[0] and not roa.converged(trial._replace(horizon=task.episode_length), start)[0]


def test_a_wider_search_is_at_least_as_bad_as_the_narrower(tmp_path):
    """The searches over twice the start law's spread and with pushes start from the start law's worst cases: their
    worst returns, with and without knife-edge counterexamples, are at most its (an LQR on PointMass)."""
    system = load_system(export(tmp_path / "lqr.npz", POINT_MASS, -lqr_gain()[None], [[0.0]]))
    result = analysis.falsification(system, TINY._replace(nominal_episodes=2))
    narrow = result["start_law"]
    for name in ("twice_the_spread", "start_law_and_pushes"):
        wide = result[name]
        assert wide["starts_from"] == "start_law" and wide["episodes"] > TINY.population * TINY.iterations
        assert wide["worst_return"] <= narrow["worst_return"]
        assert wide["worst_return_with_knife_edges"] <= narrow["worst_return_with_knife_edges"]
        assert any(c["inherited"] for c in wide["counterexamples"]) or \
            wide["counterexamples"][0]["search_return"] <= narrow["counterexamples"][0]["search_return"]
    assert result["start_law_and_pushes"]["push_axes"] == ["x"]  # along its slide only
    for c in (c for name, part in result.items() if name != "rule" for c in part["counterexamples"]):
        assert c["push"] is None or c["push"]["step"] < c["steps"]


def test_a_push_after_the_episode_ends_is_not_recorded_and_pushes_follow_the_free_axes():
    """A start that falls within a few steps, pushed late in the episode and at its first step: only the first push
    is recorded (and is replayed as recorded). A body on an x slide is pushed along x only, planar or not."""
    system = load_system(IDP)
    task = system.task
    qpos = np.array([[0.0, 0.6, 0.0], [0.0, 0.6, 0.0]])
    force = simulate.push_impulse(task, 0.5) * np.array([[1.0, 0.0], [1.0, 0.0]])
    pushes = simulate.Push(np.array([task.episode_length - 10, 0]), force)
    judge = falsify.Judge(0.0, state_scale(task), neighbours=2)
    late, early = falsify.examine(task, system.ctrl, task.episode_length, judge, qpos, np.zeros((2, 3)), pushes)
    assert late["steps"] < task.episode_length - 10 and late["push"] is None
    assert early["push"] is not None and early["push"]["step"] == 0 < early["steps"]
    assert falsify.push_axes(task) == [0]
    not_planar = PointMass()
    not_planar.planar = False
    assert falsify.push_axes(not_planar) == [0]


def test_a_fixed_point_at_a_rail_end_is_flagged_and_kept_out(tmp_path):
    """A K = 1 controller that pushes the point mass against its rail's end: its fixed point there is flagged, is
    not the closed loop's (nor its stability verdict's), and its eigenvalues do not set the plot's scale."""
    system = load_system(export(tmp_path / "push.npz", RAIL, np.zeros((1, 1, 2)), [[1.0]]))
    task = system.task
    qref, scale = equilibrium_guess(task), state_scale(task)
    hold = roa.find_hold(task, simulate.controller_policy(system.ctrl), qref, scale, task.episode_length)
    local = analysis.local_analysis(system, qref, scale, hold)
    piece = local["pieces"][0]
    assert piece["fixed_point_found"] and piece["own_region"] and piece["at_limit"] == ["x"]
    assert local["closed_loop_fixed_point"] is None and not local["has_fixed_point"]
    assert "away from a joint's limit" in report.fixed_point_verdict(local)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    far = {"piece": 0, "eigenvalues": [[40.0, 0.0]], "at_limit": ["x"]}
    near = {"piece": 1, "eigenvalues": [[0.5, 0.2]], "at_limit": []}
    fig, ax = plt.subplots()
    report.eigenvalue_panel(ax, {"local": {"pieces": [far, near]}})
    assert ax.get_xlim() == pytest.approx((-1.1, 1.1))
    plt.close(fig)


def changed_task_controller(tmp_path):
    """(controller path, task file) of a PointMass controller trained on a copy of tests/verify_tasks.py, with the
    copy's sha256 recorded as export records it."""
    mine = tmp_path / "my_tasks.py"
    shutil.copy(TASKS, mine)
    name = f"{mine}:PointMass"
    path = export(tmp_path / "c.npz", name, -lqr_gain()[None], [[0.0]])
    with np.load(path) as f:
        arrays = {k: f[k] for k in f.files}
    arrays.update(task=np.array(name), task_sha256=np.array(hashlib.sha256(mine.read_bytes()).hexdigest()))
    np.savez(path, **arrays)
    return path, mine


def test_a_controller_whose_task_changed_is_refused_in_one_line_unless_forced(tmp_path, capsys, monkeypatch):
    """verify refuses a controller whose task file changed since it was trained, in one line (deploy's check and its
    flag), and --force verifies it."""
    path, mine = changed_task_controller(tmp_path)
    load_system(path)  # unchanged: accepted
    mine.write_text(mine.read_text() + "\n# an edit\n")
    assert verify_command.main([path, "--quick", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "changed since" in err and "--force" in err and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()
    monkeypatch.setattr(analysis, "QUICK", TINY._replace(nominal_episodes=2, roa_directions=2))
    assert verify_command.main([path, "--quick", "--force", "--out", str(tmp_path / "out")]) == 0
    assert json.load(open(tmp_path / "out" / "verify.json"))["env"] == f"{mine}:PointMass"


def test_committed_knife_edge_counterexamples_are_kept_out_of_the_worst_return():
    """In every committed certified run (experiments/verify/results/certified/): a search's worst return is at most
    every counterexample it lists that is not knife-edge, and its worst return with knife-edges at most every one it
    lists; in at least one run a knife-edge counterexample lies below the worst return (it was kept out)."""
    import glob
    import math

    seen_below = False
    paths = glob.glob(os.path.join(ROOT, "experiments/verify/results/certified/*/*/verify.json"))
    assert paths
    for path in paths:
        with open(path) as f:
            fals = json.load(f)["falsification"]
        for name in ("start_law", "twice_the_spread", "start_law_and_pushes"):
            s, ce = fals[name], fals[name]["counterexamples"]
            clear = [c["search_return"] for c in ce if not c["knife_edge"]]
            knife = [c["search_return"] for c in ce if c["knife_edge"]]
            if s["worst_return"] is not None and clear:
                assert s["worst_return"] <= min(clear) + 1e-9
            assert s["worst_return_with_knife_edges"] <= min([c["search_return"] for c in ce] + [math.inf]) + 1e-9
            seen_below |= any(k < (s["worst_return"] or -math.inf) for k in knife)
    assert seen_below
