"""Paired pushes (gsa_jax.deployment.pushes, gsa_jax.analysis.robustness.paired) and the fair comparisons under persistent
shifts (gsa_jax.analysis.robustness.fairness): which pushes count, known fall times give the stated probabilities, a pushed
copy differs from its control by the push only, the line and the partial correlation against references."""

import csv
import json
import types

import numpy as np
import pytest

from gsa_jax.analysis.robustness.fairness import fair_rows, leave_out_residuals, partial_spearman, verdict
from gsa_jax.analysis.robustness.paired import aggregate_pushes, crossed_interval, per_controller
from gsa_jax.analysis.robustness.shift_rows import cells
from gsa_jax.deployment import numpy_policy
from gsa_jax.deployment.pushes import PushPlan, evaluate_pushes, push_events, window_outcomes
from gsa_jax.robustness import main
from tests.test_robustness import controller_arrays


def test_which_pushes_count_and_which_make_the_robot_fall():
    windows = (5, 20)
    # the control never falls; the copy falls 10 steps after the push: counted for both, a fall within 20 only
    assert [list(x) for x in window_outcomes(None, 10, 100, 1000, windows)] == [[True, True], [False, True]]
    # the control falls 12 steps after the push: the 20-step window does not count (the fall is not the push's)
    assert [list(x) for x in window_outcomes(12, 3, 100, 1000, windows)] == [[True, False], [True, False]]
    # the control ended before the push (its fall 30 steps earlier): never counted
    assert [list(x) for x in window_outcomes(-30, None, 100, 1000, windows)] == [[False, False], [False, False]]
    # a window running past the episode's end does not count; a fall on the window's last step does
    assert [list(x) for x in window_outcomes(None, 5, 990, 1000, windows)] == [[True, False], [True, False]]


def test_push_times_and_directions_depend_on_the_start_alone():
    a, b = push_events(7, 10, 900, planar=True), push_events(7, 10, 900, planar=True)
    assert a == b and a != push_events(8, 10, 900, planar=True)
    assert all(0 <= t <= 900 for t, _ in a) and {d for _, d in a} <= {(1.0, 0.0), (-1.0, 1.2246467991473532e-16)}
    assert all(abs(np.hypot(*d) - 1) < 1e-12 for _, d in push_events(7, 10, 900, planar=False))
    # another draw: other times and directions from the same start; draw 0 is the committed experiment's
    assert push_events(7, 10, 900, True, draw=0) == a and push_events(7, 10, 900, False, draw=1) != push_events(7, 10, 900, False)
    assert push_events(7, 10, 900, False, draw=1) == push_events(7, 10, 900, False, draw=1)


class FakeTask:
    """A task with known fall times: the control falls at step `fall_at` (None: never); after a push (a
    nonzero force on body 1) it falls `ctrl_delay` steps later, where the controller's action sets the delay
    (0: it never falls from a push)."""

    def __init__(self, fall_at):
        self.fall_at, self.model = fall_at, types.SimpleNamespace(body_mass=np.array([0.0, 2.0]), opt=types.SimpleNamespace(timestep=0.01))
        self.n_frames = 2
        self.data = types.SimpleNamespace(xfrc_applied=np.zeros((2, 6)), t=0, pushed_at=None)

    def reset(self, seed):
        self.data.t, self.data.pushed_at = 0, None
        return np.zeros(1)

    def step(self, action):
        d = self.data
        if d.xfrc_applied[1, :2].any():
            d.pushed_at = d.t
        d.t += 1
        delay = int(action[0])
        fell = (self.fall_at is not None and d.t - 1 >= self.fall_at) or (
            d.pushed_at is not None and delay > 0 and d.t - d.pushed_at >= delay)
        return np.zeros(1), 1.0, fell


class ConstantController:
    def __init__(self, delay):
        self.delay = delay

    def act(self, obs):
        return np.full(obs.shape[:-1] + (1,), float(self.delay))


def fake_events(delay, seed, fall_at=None, windows=(5, 20)):
    rows, nominal = evaluate_pushes(ConstantController(delay), "fake", [0, 1],
                                    PushPlan(sizes=(0.5,), windows=windows, per_episode=6, length=200),
                                    make_task=lambda: FakeTask(fall_at))
    return [{"env": "fake", "policy": "mlp" if delay == 10 else "mixture", "K": "" if delay == 10 else "2", "seed": seed,
             **r} for r in rows], nominal


def test_known_fall_times_give_the_stated_probabilities():
    """Flat 'PPO' falls 10 steps after every push, the 'mixture' never: P(fall) 0 and 1 within 20 steps, 0 and
    0 within 5; P(mixture falls less) 1 and 0.5 (ties count half); a never-falling controller scores 0."""
    events = []
    for seed in range(3):
        events += fake_events(10, seed)[0] + fake_events(0, seed)[0]
    per = per_controller(events, (5, 20))
    assert {v[0] for v in per.values()} == {12} and {k[-1]: v[1] for k, v in per.items() if k[1] == "mlp"} == {5: 0.0, 20: 1.0}
    rows = {(r["policy"], r["window"]): r for r in aggregate_pushes(events, (5, 20), reps=50)}
    assert rows[("mixture", 20)]["fall_iqm"] == 0 and rows[("mlp", 20)]["fall_iqm"] == 1
    assert rows[("mixture", 20)]["p_falls_less_than_flat_ppo"] == 1 and rows[("mixture", 5)]["p_falls_less_than_flat_ppo"] == 0.5
    assert rows[("mixture", 20)]["lost_iqm"] == 0 and rows[("mlp", 20)]["lost_iqm"] == 10  # 10 of 20 rewards of 1 lost


def event_matrix(fell):
    """[n, E, 3] (counted, fell, lost) of n controllers over E counted events: fell [n, E] 0/1, lost = 5 per fall."""
    fell = np.asarray(fell, float)
    return np.stack([np.ones_like(fell), fell, 5 * fell], -1)


def test_resampling_push_events_changes_nothing_where_the_events_do_not_differ():
    """Every controller meets each event alike: the interval over 12 events equals the one over 1 event, i.e.
    the controllers-only bootstrap (the event weights are drawn after the controllers)."""
    rng = np.random.default_rng(3)
    x, y = rng.random(8) < 0.3, rng.random(8) < 0.6
    one = crossed_interval(event_matrix(x[:, None]), event_matrix(y[:, None]), reps=400)
    many = crossed_interval(event_matrix(np.repeat(x[:, None], 12, 1)), event_matrix(np.repeat(y[:, None], 12, 1)), reps=400)
    assert one == many and one[0] < one[1]


def test_resampling_push_events_covers_other_draws_of_them():
    """Controllers alike within each configuration, events of two kinds (the mixture falls after the 'left'
    pushes, flat PPO after the 'right' ones): P varies only with how many of each kind a draw holds. A
    controllers-only interval is one point; resampling the events too covers most independent draws' P."""
    rng = np.random.default_rng(0)

    def draw():
        left = rng.random(20) < 0.5
        return event_matrix(np.tile(left, (6, 1))), event_matrix(np.tile(~left, (6, 1)))

    x, y = draw()
    fall_low, fall_high, lost_low, lost_high = crossed_interval(x, y, reps=1000)
    points = []
    for _ in range(40):
        a, b = draw()
        pa, pb = a[0, :, 1].mean(), b[0, :, 1].mean()
        points.append(float(pa < pb) + 0.5 * float(pa == pb))
    inside = np.mean([fall_low <= p <= fall_high for p in points])
    assert fall_low == 0.0 and fall_high == 1.0 and inside == 1.0 and (lost_low, lost_high) == (fall_low, fall_high)
    p = {(r["policy"], r["window"]): r for r in aggregate_pushes(events_of(x, y), (5,), reps=200)}[("mixture", 5)]
    assert p["p_fall_ci_low"] == p["p_fall_ci_high"] and p["p_fall_events_ci_low"] < p["p_fall_ci_low"] <= p["p_fall_events_ci_high"]


def events_of(x, y):
    """pushes.csv.gz rows of event matrices x (a K = 2 mixture's controllers) and y (flat PPO's), window 5."""
    rows = []
    for m, policy, k in ((x, "mixture", "2"), (y, "mlp", "")):
        for seed, ctrl in enumerate(m):
            for e, (counted, fell, lost) in enumerate(ctrl):
                rows.append({"env": "T", "policy": policy, "K": k, "seed": str(seed), "start_seed": e // 5, "event": e % 5,
                             "time": 10, "size": 0.5, "counted_W5": int(counted), "fell_W5": int(fell), "lost_W5": lost})
    return rows


def test_a_push_after_the_control_has_fallen_is_not_counted():
    rows, nominal = fake_events(10, 0, fall_at=50)
    assert nominal["mean_length"] == 51 and nominal["full_length_fraction"] == 0
    for r in rows:
        if r["time"] >= 50:  # the control ended (or terminates at the push's own step)
            assert r["counted_W5"] == r["counted_W20"] == 0 and r["branch_fall"] == ""
        assert r["counted_W20"] == int(r["time"] + 20 <= 50)


def test_a_pushed_copy_differs_from_its_control_by_the_push_only():
    """On Hopper-v5 in MuJoCo C: a push of size 0 never makes the robot fall and costs exactly nothing (the copy
    continues the control's MjData bit for bit); a real push changes the return."""
    ctrl = numpy_policy.Controller(controller_arrays("mlp", seed=3))
    rows, nominal = evaluate_pushes(ctrl, "Hopper-v5", [10_000],
                                    PushPlan(sizes=(0.0, 1.0), windows=(10, 30), per_episode=3, length=120))
    zero = [r for r in rows if r["size"] == 0.0 and r["counted_W10"]]
    assert zero and all(r["lost_W10"] == 0.0 and r["fell_W10"] == 0 and r["branch_fall"] in ("", None) for r in zero)
    hard = [r for r in rows if r["size"] == 1.0 and r["counted_W10"]]
    assert any(r["lost_W10"] != 0.0 for r in hard)


def shift_rows():
    """Tidy robustness rows: 'flat' and K = 2 lie on shifted = 0.5 nominal + 10; K = 3 lies 7 above it."""
    rows = []
    for policy, k, lift in (("mlp", "", 0.0), ("mixture", "2", 0.0), ("mixture", "3", 7.0)):
        for seed in range(4):
            nom = 100.0 + 20 * seed + (5 if k == "2" else 0)
            for shift, score in (("nominal", nom), ("mass", 0.5 * nom + 10 + lift)):
                rows.append({"env": "T", "policy": policy, "K": k, "seed": str(seed), "shift": shift, "level": 1.25 if shift == "mass" else 0.0,
                             "score": score, "nominal_score": nom, "random_score": 0.0, "retained_fraction": score / nom})
    return rows


def test_the_line_the_other_configurations_set():
    by = cells(shift_rows())
    res, in_range = leave_out_residuals(by, "T", "mass 1.25", ("mixture", "3"))
    np.testing.assert_allclose(res, 7.0, atol=1e-9)
    assert in_range == 1.0
    nominal = [{"env": "T", "policy": p, "K": k, "seed": str(s), "full_length_fraction": 1.0 if s < 3 else 0.5}
               for p, k in (("mlp", ""), ("mixture", "2"), ("mixture", "3")) for s in range(4)]
    fair = {(r["K"], r["shift"]): r for r in fair_rows(shift_rows(), nominal, reps=50)}
    assert fair[("3", "mass 1.25")]["residual_iqm"] == pytest.approx(7.0) and fair[("3", "mass 1.25")]["line_says"] == "more"
    assert fair[("3", "mass 1.25")]["full_length_runs"] == 3
    assert fair[("3", "mass 1.25")]["p_nominal_above_flat_ppo"] == 0.5  # the same nominal scores as flat PPO's
    assert fair[("3", "mass 1.25")]["p_score_above_flat_ppo"] == 0.625  # 10 of 16 pairs higher (7 above, 10 apart)


def test_partial_rank_correlation_equals_the_textbook_formula():
    from scipy.stats import spearmanr

    rng = np.random.default_rng(0)
    z = rng.normal(size=40)
    x, y = z + rng.normal(size=40), z + 0.5 * rng.normal(size=40)
    rxy, rxz, ryz = spearmanr(x, y)[0], spearmanr(x, z)[0], spearmanr(y, z)[0]
    expected = (rxy - rxz * ryz) / np.sqrt((1 - rxz ** 2) * (1 - ryz ** 2))
    rho, p = partial_spearman(x, y, z)
    assert rho == pytest.approx(expected, abs=1e-12) and 0 < p <= 1
    assert verdict(0.9, 0.7, 1.0) == "more" and verdict(0.2, 0.0, 0.45) == "less" and verdict(0.6, 0.3, 0.8) == "no difference"


def test_cli_adds_paired_pushes_to_an_evaluation_made_without_them(tmp_path, capsys):
    for kind, seed in (("mixture", 0), ("mlp", 0), ("mixture", 1), ("mlp", 1)):
        np.savez(tmp_path / f"{kind}-{seed}.npz", **controller_arrays(kind, seed=seed))
    out = tmp_path / "rob"
    base = [str(tmp_path), "--out", str(out), "--episodes", "2", "--shifts", "gear", "--reps", "20"]
    assert main(base + ["--pushes-per-episode", "0"]) == 0
    assert not (out / "pushes.csv.gz").exists() and "paired_pushes" not in json.loads((out / "robustness.json").read_text())
    capsys.readouterr()
    assert main(base + ["--windows", "5,10", "--pushes-per-episode", "3"]) == 0
    log = capsys.readouterr().out
    assert "paired pushes" in log and "mean retained fraction" not in log  # the shifts were not evaluated again
    saved = json.loads((out / "robustness.json").read_text())
    assert saved["paired_pushes"] == {"sizes": [0.25, 0.5, 1.0], "windows": [5, 10], "per_episode": 3} and "paired_pushes" in saved["added"]
    with open(out / "paired_pushes.csv") as f:
        agg = list(csv.DictReader(f))
    assert len(agg) == 2 * 3 * 2 and (out / "pushes.png").exists() and (out / "fair.csv").exists()
    assert main(base + ["--windows", "5,20"]) == 2 and "other settings" in capsys.readouterr().err
    for flags, message in ((["--windows", "0,5"], "must be > 0"), (["--push-sizes", "big"], "comma-separated"),
                           (["--pushes-per-episode", "-1"], "must be >= 0")):
        assert main(base + flags) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and message in err, err


def test_a_push_acts_on_the_body_the_task_names():
    """step_task pushes the task definition's push_body (envs/task.py; here the example's forearm, by name) during
    the step only; a task's `planar` decides the directions (the example: any horizontal angle)."""
    from envs.task import TaskC
    from examples.reacher import Reacher
    from gsa_jax.deployment.shifts import is_planar, step_task

    class Forearm(Reacher):
        push_body = "forearm"

    task = TaskC(Forearm())
    task.reset(0)
    seen = []
    inner = task.step
    task.step = lambda a: (seen.append(task.data.xfrc_applied.copy()), inner(a))[1]
    step_task(task, np.zeros(2), np.array([0.5, -0.25]))
    forearm = task.model.body("forearm").id
    assert seen[0][forearm, :2].tolist() == [0.5, -0.25] and np.count_nonzero(seen[0]) == 2
    assert not task.data.xfrc_applied.any() and not is_planar(task)
