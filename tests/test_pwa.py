"""A linear-partition controller's closed loop as a piecewise-affine model handed to the field's verifiers
(gsa_jax.verify.pwa, vnnlib, milp, pwa_export), on PointMass (tests/verify_tasks.py: exactly linear dynamics, so
the PWA model is the plant's closed loop): the model is the NumPy controller and MuJoCo's step, the ONNX graph
evaluates in onnxruntime to the NumPy outputs, the VNN-LIB properties have counterexamples exactly where the
certificate's claim fails, and the mixed-integer bound equals its analytic value on linear systems."""

import json

import numpy as np
import pytest
import scipy.linalg

from gsa_jax.verify import certify, milp, pwa, pwa_export, vnnlib
from gsa_jax.verify import linearize as lin
from gsa_jax.verify.system import VerifyError, load_system
from test_certify import IDP_FLAT, POINT_MASS
from verify_tasks import analytic_step, export, lqr_gain

SWITCH_X = 0.3  # m: piece 1 acts where x > SWITCH_X


@pytest.fixture(scope="module")
def system(tmp_path_factory):
    """K = 2 on PointMass with a linear partition: piece 0 the LQR gain, piece 1 half of it pushing left by 0.1,
    logits 0 and 5 (x - SWITCH_X)."""
    k = lqr_gain()[None]
    path = export(tmp_path_factory.mktemp("pwa") / "pair.npz", POINT_MASS, np.concatenate([-k, -0.5 * k]),
                  [[0.0], [-0.1]], [np.array([[0.0, 5.0], [0.0, 0.0]])], [np.array([0.0, -5.0 * SWITCH_X])],
                  partition="linear")
    return load_system(path)


@pytest.fixture(scope="module")
def model(system):
    return pwa.build(system, np.zeros(1), np.zeros(2))


def certificate_of(model, level):
    """A certificate record of piece 0 at the origin as certify writes one: P from the k-step Lyapunov equation at
    rho_P (certify.step_rule), so that V falls by rho^2 over k steps on the linear loop."""
    rho_a = max(abs(np.linalg.eigvals(model.A[0])))
    k, rho, rho_p = certify.step_rule(rho_a)
    Ak = np.linalg.matrix_power(model.A[0], k)
    P = scipy.linalg.solve_discrete_lyapunov(Ak.T / rho_p, np.eye(2))  # Ak' P Ak = rho_p^2 (P - I) < rho^2 P
    return {"certified": True, "piece": 0, "qpos": [0.0], "qvel": [0.0], "P": P.tolist(), "k": k, "rho": rho,
            "level": level, "coordinates": ["x (m)", "x velocity (m/s)"], **certify.ellipsoid_fields(P, level)}


def level_reaching(model, share):
    """The level whose ellipsoid reaches `share` of the way to the cell boundary x = SWITCH_X along x."""
    P = np.asarray(certificate_of(model, 1.0)["P"])
    return (share * SWITCH_X) ** 2 / np.linalg.inv(P)[0, 0]


def test_the_model_is_the_controller_and_the_plant(system, model):
    A, B = analytic_step()
    k = lqr_gain()
    for i, gain in enumerate((k, 0.5 * k)):  # the closed loop of each piece: exactly A - B K_i on this plant
        assert np.allclose(model.A[i], A - B @ gain, atol=1e-6)
    rng = np.random.default_rng(0)
    d = rng.uniform([-0.2, -0.5], [0.6, 0.5], size=(2000, 2))
    d = d[np.all(np.abs(pwa.action(model, d)) < 0.99, axis=1)]  # no action clip
    agree = pwa.agreement(model, system.ctrl, d)
    assert agree["same_piece"] == 1.0 and agree["action_max_abs_diff"] < 1e-5
    assert set(pwa.piece_of(model, d)) == {0, 1}
    jac = lambda obs: lin.piece_jacobian(system.ctrl, obs)
    plant = np.array([lin.closed_step(system.task, jac, np.zeros(1), x) for x in d[:50]])
    assert np.allclose(pwa.step(model, d[:50]), plant, atol=1e-6)


def test_a_boundary_point_takes_the_lower_piece(model):
    assert pwa.piece_of(model, np.array([[SWITCH_X, 0.0]]))[0] == 0
    assert pwa.piece_of(model, np.array([[SWITCH_X + 1e-9, 0.0]]))[0] == 1


def test_flat_ppo_and_mlp_partitions_are_refused(tmp_path):
    with pytest.raises(VerifyError, match="not piecewise affine"):
        pwa.require_pwa(load_system(IDP_FLAT).ctrl)
    k = lqr_gain()[None]
    mlp = export(tmp_path / "mlp.npz", POINT_MASS, np.concatenate([-k, -k]), [[0.0], [0.0]], partition="mlp")
    with pytest.raises(VerifyError, match="linear partition"):
        pwa.require_pwa(load_system(mlp).ctrl)


def onnx_ops(proto):
    return {node.op_type for node in proto.graph.node}


def test_the_onnx_graph_evaluates_to_numpy(system, model):
    cert = certificate_of(model, level_reaching(model, 0.9))
    arrays = vnnlib.property_arrays(model, cert)
    proto = vnnlib.build_graph(arrays)
    assert onnx_ops(proto) <= {"Constant", "MatMul", "Add", "Sub", "Mul", "Concat"}
    d = pwa_export.sample_points(cert, 1)
    ours, theirs = vnnlib.outputs(arrays, d), pwa_export.onnx_outputs(proto.SerializeToString(), d)
    assert np.max(np.abs(ours - theirs) / np.abs(ours).max(axis=0)) < 1e-5
    n, rows = 2, len(arrays["s"])
    obs = (model.obs + d @ model.C.T).astype(np.float32)
    free = np.all(np.abs(ours[:, 2 + rows + n:]) < 0.99, axis=1)  # where the action clip does not act
    assert free.mean() > 0.5
    assert np.allclose(theirs[free, 2 + rows + n:], system.ctrl.act(obs[free]), atol=1e-5)  # the controller's action
    assert np.allclose(theirs[:, 2 + rows: 2 + rows + n], pwa.step(model, d), atol=1e-6)  # the one-step map
    v = np.einsum("bi,ij,bj->b", d, np.asarray(cert["P"]), d)
    assert np.allclose(ours[:, 1], v - cert["level"])


def test_the_properties_find_counterexamples_where_the_claim_fails(model):
    inside = certificate_of(model, level_reaching(model, 0.9))
    d = pwa_export.sample_points(inside, 2)
    for cert, decrease, cells in ((inside, 0, 0),
                                  (dict(inside, rho=0.1), ">0", 0),  # a contraction the loop does not have
                                  (certificate_of(model, level_reaching(model, 1.5)), 0, ">0")):  # E crosses the cell
        arrays = vnnlib.property_arrays(model, cert)
        texts = vnnlib.properties(arrays, cert)
        points = pwa_export.sample_points(cert, 2) if cert is not inside else d
        y = vnnlib.outputs(arrays, points)
        found = {name: int(vnnlib.counterexamples(text, points, y).sum()) for name, text in texts.items()}
        assert (found["decrease.vnnlib"] > 0) == (decrease == ">0"), found
        assert (found["cells.vnnlib"] > 0) == (cells == ">0"), found
    lo, hi = vnnlib.box(inside)
    assert np.all((d >= lo - 1e-12) & (d <= hi + 1e-12))  # E inside the property's input box


def test_the_vnnlib_reader_knows_only_its_subset():
    text = vnnlib.property_text(np.zeros(1), np.ones(1), 2, ["(or (and (<= Y_0 0.0)) (and (>= Y_1 2.0)))"], "c")
    x = np.array([[0.5], [0.5], [2.0]])
    y = np.array([[-1.0, 0.0], [1.0, 0.0], [-1.0, 3.0]])
    assert vnnlib.counterexamples(text, x, y).tolist() == [True, False, False]  # the last is outside the box
    with pytest.raises(ValueError, match="not a VNN-LIB comparison"):
        vnnlib.counterexamples("(assert (< Y_0 1.0))", x[:1], y[:1])


def test_the_milp_bound_of_a_linear_system_is_its_analytic_value():
    rng = np.random.default_rng(3)
    A, a, none = rng.normal(size=(1, 3, 3)), 0.1 * rng.normal(size=(1, 3)), [np.zeros((0, 4))]
    assert milp.decrease_bound(A, np.zeros((1, 3)), none, np.eye(3)).value == pytest.approx(
        np.abs(A[0]).sum(axis=1).max(), rel=1e-9)  # the induced infinity norm
    assert milp.decrease_bound(A, a, none, np.eye(3)).value == pytest.approx(
        (np.abs(A[0]).sum(axis=1) + np.abs(a[0])).max(), rel=1e-9)
    lam = 1.0  # homogeneous: max over t in [0, 1] of t (||A|| - lam)
    assert milp.decrease_bound(A, np.zeros((1, 3)), none, np.eye(3), lam).value == pytest.approx(
        max(0.0, np.abs(A[0]).sum(axis=1).max() - lam), abs=1e-9)
    T = np.diag([2.0, 1.0, 0.5])  # a box of other widths: the norm of T A T^-1
    assert milp.decrease_bound(A, np.zeros((1, 3)), none, T).value == pytest.approx(
        np.abs(T @ A[0] @ np.linalg.inv(T)).sum(axis=1).max(), rel=1e-9)


def test_the_milp_bound_of_two_pieces_is_the_larger_cells_analytic_value():
    """Piece 0 on d_0 >= 0.5 of the unit box, piece 1 on d_0 <= 0.5: row q's max on a piece's slab of d_0 in
    [lo, hi] is max(s A_q0 lo, s A_q0 hi) + sum_j>0 |A_qj| over the signs s."""
    rng = np.random.default_rng(4)
    A = rng.normal(size=(2, 3, 3))
    cells = [np.array([[1.0, 0.0, 0.0, -0.5]]), np.array([[-1.0, 0.0, 0.0, 0.5]])]
    expect = max(max(s * A[i, q, 0] * x for s in (1, -1) for x in slab) + np.abs(A[i, q, 1:]).sum()
                 for i, slab in ((0, (0.5, 1.0)), (1, (-1.0, 0.5))) for q in range(3))
    bound = milp.decrease_bound(A, np.zeros((2, 3)), cells, np.eye(3))
    assert bound.value == pytest.approx(expect, rel=1e-9)
    step = A[bound.piece] @ bound.d
    assert np.abs(step).max() == pytest.approx(bound.value, rel=1e-7)  # attained at the reported point


def test_the_milp_refuses_bad_input():
    A, none = np.eye(2)[None], [np.zeros((0, 3))]
    with pytest.raises(VerifyError, match="unbounded"):
        milp.decrease_bound(A, np.zeros((1, 2)), none, np.array([[1.0, 0.0]]))
    with pytest.raises(VerifyError, match="lam must be"):
        milp.decrease_bound(A, np.zeros((1, 2)), none, np.eye(2), -1.0)
    with pytest.raises(VerifyError, match="needs A"):
        milp.decrease_bound(A, np.zeros((2, 2)), none, np.eye(2))


def test_the_export_writes_checked_files(system, model, tmp_path):
    cert_path = tmp_path / "verify.json"
    cert_path.write_text(json.dumps({"certificate": certificate_of(model, level_reaching(model, 0.9))}))
    record = pwa_export.export_pwa(system, str(cert_path), str(tmp_path / "out"))
    folder = tmp_path / "out" / "pwa"
    assert {p.name for p in folder.iterdir()} == {"pwa.json", "certificate.onnx", "decrease.vnnlib", "cells.vnnlib",
                                                 "checks.json", "report.md"}
    assert record["counterexamples"] == {"decrease.vnnlib": 0, "cells.vnnlib": 0}
    assert record["controller"]["same_piece"] == 1.0 and record["onnx_max_rel_diff"] < 1e-5
    box = record["box_image_milp"]
    assert box["pwa_value_there"] == pytest.approx(box["value"], rel=1e-6)
    assert json.loads((folder / "checks.json").read_text()) == record
    assert len(json.loads((folder / "pwa.json").read_text())["A"]) == 2


def test_a_file_without_a_certified_certificate_is_refused(tmp_path):
    path = tmp_path / "verify.json"
    path.write_text(json.dumps({"nominal": {}}))
    with pytest.raises(VerifyError, match="has no certificate"):
        pwa_export.read_certificate(str(path))
    path.write_text(json.dumps({"certificate": {"P": [[1.0]], "certified": False}}))
    with pytest.raises(VerifyError, match="not certified"):
        pwa_export.read_certificate(str(path))


def test_the_command_writes_the_export_and_refuses_a_missing_file(system, model, tmp_path, capsys):
    from gsa_jax.commands.verify import main

    cert_path = tmp_path / "verify.json"
    cert_path.write_text(json.dumps({"certificate": certificate_of(model, level_reaching(model, 0.9))}))
    assert main([system.path, "--pwa", str(cert_path), "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "decrease.vnnlib: 0 of 4000" in out and (tmp_path / "out" / "pwa" / "certificate.onnx").exists()
    assert main([system.path, "--pwa", str(tmp_path / "missing.json"), "--out", str(tmp_path / "x")]) == 2
    assert "cannot read" in capsys.readouterr().err
