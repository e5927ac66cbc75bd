"""Robustness margins of a certificate's fixed point (gsa_jax.verify.margins): on a discretized double integrator
(PointMass, tests/verify_tasks.py) and an open-loop unstable step under their LQR gains the gain margins equal their
analytic values (Jury's test on the characteristic polynomial), the delay margin and the disk margin equal independent
computations, the disk's phase is a guaranteed margin, and the plant check holds inside each margin and fails past
it."""

import math

import numpy as np
import pytest

from gsa_jax.verify import margins
from gsa_jax.verify.system import load_system
from verify_tasks import analytic_step, export, lqr_gain
from test_certify import POINT_MASS


def double_integrator() -> margins.Loop:
    A, B = analytic_step()
    return margins.Loop(A, B, -lqr_gain())


def jury_margins(loop: margins.Loop) -> tuple:
    """(lower, upper): the interval of g around 1 where z^2 - tr z + det of A + g b m is stable, each coefficient
    affine in g (b m has rank one): |det| < 1, 1 - tr + det > 0, 1 + tr + det > 0."""
    A, bm = loop.A, loop.Bu @ loop.M
    tr0, tr1 = np.trace(A), np.trace(bm)
    det0 = np.linalg.det(A)
    det1 = np.linalg.det(A + bm) - det0  # det(A + g b m) = det0 + g det1 for a rank-one b m
    conditions = [(1 - det0, -det1), (1 + det0, det1), (1 - tr0 + det0, -tr1 + det1), (1 + tr0 + det0, tr1 + det1)]
    lower, upper = 0.0, math.inf  # each c0 + c1 g > 0, true at g = 1
    for c0, c1 in conditions:
        assert c0 + c1 > 0
        root = -c0 / c1 if c1 != 0 else None
        if root is not None and root > 1:
            upper = min(upper, root)
        elif root is not None and root < 1:
            lower = max(lower, root)
    return lower, upper


def unstable_plant() -> margins.Loop:
    """An open-loop unstable linear step (eigenvalues 1 +- 0.032) under its discrete LQR gain: its lower gain margin is
    positive (without enough feedback it diverges)."""
    import scipy.linalg

    A, B = np.array([[1.0, 0.02], [0.05, 1.0]]), np.array([[0.0], [0.02]])
    P = scipy.linalg.solve_discrete_are(A, B, np.eye(2), np.eye(1))
    return margins.Loop(A, B, -np.linalg.solve(np.eye(1) + B.T @ P @ B, B.T @ P @ A))


def test_gain_margins_equal_jurys_analytic_interval():
    loop = unstable_plant()
    lower, upper = margins.gain_margins(loop)
    want = jury_margins(loop)
    assert 0.01 < want[0] < 1 < want[1] < margins.GAIN_MAX
    assert lower == pytest.approx(want[0], rel=1e-9, abs=0) and upper == pytest.approx(want[1], rel=1e-9, abs=0)
    # the damped double integrator keeps an integrator: marginal without feedback, its lower margin 0
    di = double_integrator()
    assert margins.gain_margins(di)[0] == 0.0 and jury_margins(di)[0] < margins.MARGINAL
    assert margins.gain_margins(di)[1] == pytest.approx(jury_margins(di)[1], rel=1e-9, abs=0)
    unstable = margins.Loop(loop.A, loop.Bu, 2 * want[1] * loop.M)  # its g = 1 is the first loop's 2 x upper
    assert all(math.isnan(g) for g in margins.gain_margins(unstable)) and margins.delay_margin(unstable) == -1


def grows(loop: margins.Loop, d: int, steps: int = 20_000) -> bool:
    """Whether x_{t+1} = A x_t + B_u M x_{t-d}, simulated from a random history, grows."""
    rng = np.random.default_rng(d)
    hist = [rng.standard_normal(len(loop.A)) for _ in range(d + 1)]
    for _ in range(steps):
        hist.append(loop.A @ hist[-1] + loop.Bu @ (loop.M @ hist[-1 - d]))
        hist.pop(0)
    return bool(np.linalg.norm(hist[-1]) > 1.0)


def test_delay_margin_equals_the_simulated_recursion():
    loop = double_integrator()
    d = margins.delay_margin(loop)
    assert 0 <= d < margins.DELAY_MAX
    assert not any(grows(loop, k) for k in range(d + 1)) and grows(loop, d + 1)


def test_disk_margin_equals_a_fine_sweep_and_lies_inside_the_gain_margins():
    loop = double_integrator()
    disk = margins.disk_margin(loop)
    A, b, m = loop.A, loop.Bu[:, 0], loop.M[0]
    w = np.linspace(0.0, np.pi, 200_001)
    z = np.exp(1j * w)
    det = z ** 2 - np.trace(A) * z + np.linalg.det(A)  # (zI - A)^-1 = adj(zI - A) / det(zI - A)
    L = np.array([-(m @ (np.array([[zi - A[1, 1], A[0, 1]], [A[1, 0], zi - A[0, 0]]]) @ b)) for zi in z]) / det
    alpha = 1.0 / np.max(np.abs(1.0 / (1.0 + L) - 0.5))
    assert disk["alpha"] == pytest.approx(alpha, rel=1e-3)
    lower, upper = margins.gain_margins(loop)
    assert lower <= disk["gain_range"][0] < 1 < disk["gain_range"][1] <= upper
    assert 0 < disk["phase_deg"] < 90


@pytest.mark.parametrize("loop", [double_integrator(), unstable_plant()], ids=["double_integrator", "unstable"])
def test_the_disk_margins_phase_is_a_guaranteed_margin(loop):
    """A phase shift e^{j phi} on the action, |phi| at 0.9 of the disk margin's phase margin, keeps the loop stable
    (the disk's phase is a guaranteed margin, so also a check of L's and S's signs)."""
    phi = 0.9 * np.radians(margins.disk_margin(loop)["phase_deg"])
    for sign in (1, -1):
        assert margins.spectral_radius(loop.A + np.exp(1j * sign * phi) * loop.Bu @ loop.M) < 1.0


def test_the_plant_check_holds_inside_each_margin_and_fails_past_it(tmp_path):
    """PointMass in MuJoCo C under the exported LQR controller: the loop holds at 0.9 of the upper gain margin's
    distance from 1 and at the delay margin, and does not at 1.1 of it or one step past the delay margin."""
    system = load_system(export(tmp_path / "lqr.npz", POINT_MASS, -lqr_gain()[None], [[0.0]]))
    cert = {"qpos": [0.0], "qvel": [0.0], "piece": 0}
    m = margins.certificate_margins(system, np.zeros(1), cert)
    want = jury_margins(double_integrator())
    assert m["gain_lower"] == 0.0 and m["plant"]["gain_lower"] is None  # an integrator: nothing to cross
    assert m["gain_upper"] == pytest.approx(want[1], rel=1e-4)
    for name in ("gain_upper", "delay"):
        check = m["plant"][name]
        assert check is not None and check["confirmed"], (name, check)
    assert m["flags"] == [] and m["channels"] == 1  # 9x, 0x, 5 steps, disk 1.47: none below its threshold


def test_the_committed_margin_summary_is_its_rows_summary():
    """experiments/verify/results/certified/margins_summary.csv is margins_of_certified.summary of margins.csv (the
    per-certificate rows the README's class medians and counts quote)."""
    import csv
    import importlib.util
    import os

    here = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "experiments", "verify")
    spec = importlib.util.spec_from_file_location("margins_of_certified", os.path.join(here, "margins_of_certified.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    booleans = ("certified", "counted", "flagged", "gain_upper_confirmed", "gain_lower_confirmed", "delay_confirmed")
    with open(os.path.join(mod.RESULTS, "margins.csv"), newline="") as f:
        rows = [{k: {"True": True, "False": False}.get(v, v) if k in booleans else v for k, v in r.items()}
                for r in csv.DictReader(f)]
    with open(os.path.join(mod.RESULTS, "margins_summary.csv"), newline="") as f:
        assert [{k: str(v) for k, v in r.items()} for r in mod.summary(rows)] == list(csv.DictReader(f))
