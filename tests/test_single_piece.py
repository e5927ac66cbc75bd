"""A K = 1 mixture exports as one affine (or quadratic, or constant) law with no partition network, in npz, ONNX and C,
acting as the trained controller; `gsa inspect` prints every piece as u = u0 + K (x - x*) in the task's units, and
that printed law is the controller's raw action. Committed controllers only: no JAX program is compiled."""

import json
import os
import re

import numpy as np
import pytest

from gsa_jax.commands.inspect_run import main as inspect_main
from gsa_jax.deployment import cells, export_c, numpy_policy
from gsa_jax.deployment.exporting import load_arrays
from gsa_jax.export import main as export_main
from gsa_jax.running.formats import read_controller
from tests.test_docs import python_blocks
from tests.test_export import assert_same_controller, run_c_header, test_observations

ROOT = os.path.join(os.path.dirname(__file__), "..")
IDP = os.path.join(ROOT, "experiments", "fig1_v5", "results", "fig1_v5_InvertedDoublePendulum-v5", "controllers")
K1 = os.path.join(IDP, "InvertedDoublePendulum-v5-mixture-K1-s0.npz")  # exported with its unused 64x64 network
K4 = os.path.join(IDP, "InvertedDoublePendulum-v5-mixture-K4-s0.npz")


def old_file(tmp_path, subpolicy):
    """The committed K = 1 file (its 3 partition layers kept), or the same with random pieces of another class."""
    if subpolicy == "linear":
        return K1
    with np.load(K1) as f:
        arrays = {k: f[k] for k in f.files}
    d_s = arrays["obs_mean"].shape[0]
    d_phi = {"constant": 0, "quadratic": d_s + d_s * (d_s + 1) // 2}[subpolicy]
    rng = np.random.default_rng(3)
    arrays.update(subpolicy=np.array(subpolicy), L=rng.normal(scale=0.3, size=(1, 1, d_phi)).astype(np.float32),
                  b=rng.normal(size=(1, 1)).astype(np.float32))
    path = tmp_path / f"old-{subpolicy}.npz"
    np.savez(path, **arrays)
    return str(path)


def exported(tmp_path, subpolicy, suffix):
    """(the old file's Controller, the path of its export with `suffix`, its text where it is a header)."""
    old = old_file(tmp_path, subpolicy)
    out = tmp_path / f"k1-{subpolicy}{suffix}"
    assert export_main([old, "--out", str(out)]) == 0
    return numpy_policy.load(old), str(out), out.read_text() if suffix == ".h" else None


@pytest.mark.parametrize("subpolicy", ["linear", "constant", "quadratic"])
def test_the_npz_has_no_network_and_acts_exactly_as_the_old_file(tmp_path, subpolicy):
    old, path, _ = exported(tmp_path, subpolicy, ".npz")
    assert len(old.layers) == 3 and old.partition == "mlp"
    with np.load(path) as f:
        assert int(f["n_layers"]) == 0 and str(f["partition"]) == "single" and not {"w0", "b0"} & set(f.files)
    new = numpy_policy.load(path)
    assert new.layers == [] and new.single_piece and new.partition == numpy_policy.SINGLE
    obs = test_observations(old)
    np.testing.assert_array_equal(new.act(obs), old.act(obs))
    np.testing.assert_array_equal(new.act(obs, clip=False), old.act(obs, clip=False))
    np.testing.assert_array_equal(new.cluster(obs), np.zeros(len(obs), np.int64))
    np.testing.assert_array_equal(old.cluster(obs), new.cluster(obs))
    documented = {}  # docs/deploy.md's evaluator, as written, reads the file too (n_layers 0: cluster 0)
    exec(next(b for b in python_blocks("deploy.md") if "def evaluate(" in b), documented)
    action, cluster = documented["evaluate"](path, obs)
    np.testing.assert_array_equal(cluster, new.cluster(obs))
    np.testing.assert_allclose(action, new.act(obs), rtol=1e-6, atol=1e-6)
    w_raw, c_raw = cells.raw_logits(new)  # one cell, every state: no inequality
    assert not w_raw.any() and not c_raw.any() and cells.cell_inequalities(new)[0].A.shape == (0, len(obs[0]))


@pytest.mark.parametrize("subpolicy", ["linear", "constant", "quadratic"])
def test_the_c_header_is_the_affine_law_alone(tmp_path, subpolicy, capsys):
    old, path, src = exported(tmp_path, subpolicy, ".h")
    assert "tanhf(" not in src and "gsa_w" not in src and "gsa_layer" not in src and "first maximum" not in src
    d_s, d_a, d_phi = old.obs_mean.shape[0], old.action_size, old.L.shape[-1]
    consts = 2 * d_s + 2 * d_a + d_a * d_phi + d_a  # normalizer, bounds, L_0, b_0 (linear: 30, the 4,895 before)
    madds = d_s + d_a * d_phi + (d_s * (d_s + 1) // 2 if subpolicy == "quadratic" else 0)  # linear: 18 (4,754)
    assert (f"C controller: {consts} float constants ({4 * consts / 1024:.1f} KiB); per call {madds} multiply-adds, "
            f"0 tanhf, {2 * d_s + 2 * d_a} compares") in capsys.readouterr().out
    assert "tanhf(" not in export_c.to_source(old.arrays)  # handed the old arrays themselves: no network either
    (tmp_path / "controller.h").write_text(src)
    obs = test_observations(old)
    action, raw, cluster = run_c_header(tmp_path, obs, d_a)
    assert_same_controller(old, obs, action, cluster)
    assert_same_controller(old, obs, raw, cluster, clip=False)


@pytest.mark.parametrize("subpolicy", ["linear", "constant", "quadratic"])
def test_the_onnx_graph_is_the_affine_law_alone(tmp_path, subpolicy):
    onnx = pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    old, path, _ = exported(tmp_path, subpolicy, ".onnx")
    model = onnx.load(path)
    ops = [n.op_type for n in model.graph.node]
    assert not {"Tanh", "ArgMax"} & set(ops) and ops.count("MatMul") == 0
    assert ops.count("Gemm") == (subpolicy != "constant")
    assert ops.count("Gather") == (2 if subpolicy == "quadratic" else 0)  # the quadratic features' z_i, z_j only
    obs = test_observations(old)
    action, cluster, raw = ort.InferenceSession(path, providers=["CPUExecutionProvider"]).run(None, {"obs": obs})
    assert cluster.dtype == np.int64 and not cluster.any()
    assert_same_controller(old, obs, action, cluster)
    assert_same_controller(old, obs, raw, cluster, clip=False)


def test_partition_single_is_checked_and_verify_reads_it_exactly(tmp_path):
    """'single' needs no layers and K = 1, and no layers need 'single' (one line each); verify's logits of a single
    piece are one exact 0."""
    from gsa_jax.verify.linearize import logit_rows

    arrays, four = read_controller(K1), read_controller(K4)  # the committed files in the current layout
    no_layers = {"n_layers": np.array(0), "partition": np.array("single")}
    for bad, message in (({**arrays, "partition": np.array("single")}, "names partition class 'single' but has 3"),
                         ({**four, **no_layers}, "but has 0 partition layers and K = 4"),
                         ({**arrays, "n_layers": np.array(0)}, "names partition class 'mlp' but has 0")):
        with pytest.raises(numpy_policy.ControllerClassError, match=message):
            numpy_policy.Controller(bad)
    ctrl = numpy_policy.Controller(load_arrays(K1))
    logits, rows, exact = logit_rows(ctrl, ctrl.obs_mean + 20 * ctrl.obs_std)  # beyond the clip too
    assert exact and logits.tolist() == [0.0] and rows.shape == (1, ctrl.obs_mean.shape[0]) and not rows.any()


def parse_laws(text):
    """(x* [d_s], [(u0 [d_a], K [d_a, d_s], Q {(action, i, j): q})] per piece, observation names, action names) of
    inspect's printed laws."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("x* = "))
    x_lines = [line for line in lines[start + 1:] if line.startswith("  [")]
    obs_names = [line.split("] ", 1)[1].rsplit(" = ", 1)[0] for line in x_lines]
    x_star = np.array([float(line.rsplit(" = ", 1)[1]) for line in x_lines])
    terms = lambda s: [(float(t.split(" ", 1)[0]), t.split(" ", 1)[1])  # noqa: E731
                       for t in re.split(r"  (?=[+-][0-9]|[+-]inf)", s)]  # a name may hold two spaces
    pieces, part = [], None
    for line in lines:
        if line.startswith("piece "):
            pieces.append({"K": [], "Q": []})
        elif line.startswith("  u0 (the raw action at x*):  "):
            u0 = terms(line.split(":  ", 1)[1])
            pieces[-1]["u0"], act_names = np.array([v for v, _ in u0]), [n for _, n in u0]
        elif line.startswith("  K ") or line.startswith("  Q "):
            part = line[2]
        elif line.startswith("    ") and pieces:
            row = terms(line.split(":  ", 1)[1])
            pieces[-1][part].append([v for v, _ in row])
            if part == "K":
                assert [n for _, n in row] == obs_names
    laws = [(p["u0"], np.array(p["K"]).reshape(len(p["u0"]), -1), np.array(p["Q"])) for p in pieces]
    return x_star, laws, obs_names, act_names


ANT = os.path.join(ROOT, "experiments", "fig1_v5", "results", "fig1_v5_Ant-v5_seeds_0_4", "controllers",
                   "Ant-v5-mixture-K4-s0.npz")  # a task without an equilibrium: x* is the normalization mean


@pytest.mark.parametrize("source", ["linear", "quadratic", "K4", "Ant"])
def test_the_printed_law_is_the_controllers_raw_action_inside_the_clip(tmp_path, source, capsys):
    """u0 + K (x - x*) (+ Q's terms), as inspect prints them for an exported file (6 digits), is act(x, clip=False) at
    points inside the observation clip, for the piece the controller picks there, named by the task's layout and
    actuators; x* is the task's equilibrium observation (InvertedDoublePendulum: cart centred, poles upright, at
    rest), else the normalization mean."""
    import envs

    path = {"K4": K4, "Ant": ANT}.get(source) or old_file(tmp_path, source)
    ctrl = numpy_policy.load(path)
    assert inspect_main([path, "--out", str(tmp_path / "out")]) == 0
    text = capsys.readouterr().out
    x_star, laws, obs_names, act_names = parse_laws(text)
    record = envs.resolve(numpy_policy.task_name(ctrl.arrays))
    assert obs_names == record.observation_layout()
    assert act_names == (["slide"] if source != "Ant" else [f"{p}_{i}" for i in (4, 1, 2, 3) for p in ("hip", "ankle")])
    if source == "Ant":
        np.testing.assert_allclose(x_star, ctrl.obs_mean, rtol=1e-5, atol=1e-12)
    else:
        np.testing.assert_array_equal(x_star, [0, 0, 0, 1, 1, 0, 0, 0, 0])
    assert len(laws) == ctrl.num_clusters and ("acts on every state" in text) == (ctrl.num_clusters == 1)
    rng = np.random.default_rng(5)
    x = ctrl.obs_mean + ctrl.obs_std * rng.uniform(-9.9, 9.9, size=(3000, len(x_star)))
    x = x.astype(np.float32).astype(np.float64)
    c, i, j = ctrl.cluster(x.astype(np.float32)), *np.triu_indices(len(x_star))
    dx = x - x_star
    u, scale = np.zeros((len(x), ctrl.action_size)), np.zeros((len(x), ctrl.action_size))
    for p, (u0, K, Q) in enumerate(laws):
        at = c == p
        quad = (dx[at][:, i] * dx[at][:, j]) @ Q.T if Q.size else 0.0
        u[at] = u0 + dx[at] @ K.T + quad
        scale[at] = np.abs(u0) + (np.abs(dx[at]) + np.abs(x_star)) @ np.abs(K).T + np.abs(quad) + 1e-3
    assert len(set(np.unique(c))) == ctrl.num_clusters  # every piece's law is checked
    err = np.abs(u - ctrl.act(x.astype(np.float32), clip=False)) / scale
    assert err.max() < 2e-5, err.max()
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())["pieces"]
    np.testing.assert_allclose(np.array([p["K"] for p in summary["pieces"]]), [K for _, K, _ in laws], rtol=1e-5)
    table = (tmp_path / "out" / "controllers.md").read_text()
    assert table.count("## cluster") == len(laws) and all(f"| {n} |" in table for n in act_names)
    assert all(n in table for n in obs_names)


def test_inspect_reads_an_answers_controller(capsys):
    """A K = 1 controller.npz as gsa answer exported it before K = 1 dropped its network (kept in tests/golden/controllers)
    is inspected: one piece on every state."""
    path = os.path.join(ROOT, "tests", "golden", "controllers", "InvertedDoublePendulum-v5-K1-answer-export.npz")
    assert inspect_main([path]) == 0
    out = capsys.readouterr().out
    assert "1 linear piece," in out and "piece 0: acts on every state" in out and "slide:  " in out
