"""The linear partition (gsa_jax/algorithm/partitions.py): its K = 4 run inside a K_max = 16 program is the K = 4
program's; its exported cells are the trained policy's argmax in NumPy, ONNX and C; inspect's printed inequalities
pick the controller's cell; the class is recorded, checked in one line and absent from old files (mlp).

One tiny trained run (inverted_double_pendulum, a few iterations) serves the export and inspect tests."""

import json
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_export import COMMITTED, ROOT, run_c_header

from gsa_jax.algorithm.config import Config, make_hparams
from gsa_jax.algorithm.normalize import normalize
from gsa_jax.algorithm.ppo import schedule
from gsa_jax.running.tasks import trainer_for
from gsa_jax.deployment import numpy_policy
from gsa_jax.running.formats import FORMAT_VERSION
from gsa_jax.deployment.cells import cell_inequalities, informative_coordinates
from gsa_jax.export import main as export_main

K = 3
TRAIN = ["--env", "inverted_double_pendulum", "--partition", "linear", "-K", str(K), "--k-max", "5", "--steps", "2048",
         "--num-envs", "8", "--unroll-length", "32", "--minibatches", "4", "--epochs", "2", "--episode-length", "50",
         "--chunk", "1", "--eval-every", "0", "--eval-envs", "2", "--lr", "3e-3", "--quiet", "--no-tensorboard"]
TINY = {"env": "InvertedDoublePendulum-v5", "partition": "linear", "num_envs": 4, "unroll_length": 16,
        "num_minibatches": 2, "num_epochs": 1, "hidden": (16,), "episode_length": 30, "eval_envs": 1,
        "physics": {"backend": "c"}}  # MuJoCo C in the program: the masking is under test, not MJX


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A trained linear-partition run directory (K = 3 padded to K_max = 5)."""
    from gsa_jax.train import main

    out = tmp_path_factory.mktemp("partition") / "run"
    assert main(TRAIN + ["--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def states(run):
    """(observations [n, d_s] spread over the normalizer's range, inside its clip; the trained policy's argmax
    there in JAX [n]; the exported NumPy controller; its float64 logits [n, K])."""
    from gsa_jax.deployment.inspection import load_run

    trainer, params, obs_stats, hp, _ = load_run(str(run))
    npz = run.parent / "controller.npz"
    assert export_main([str(run), "--out", str(npz)]) == 0
    ctrl = numpy_policy.load(str(npz))
    rng = np.random.default_rng(0)
    obs = (ctrl.obs_mean + ctrl.obs_std * rng.normal(scale=2.0, size=(3000, ctrl.obs_mean.shape[0]))).astype(np.float32)
    mode = jax.jit(jax.vmap(trainer.policy.mode, in_axes=(None, 0, None)))
    _, c_jax = mode(params["policy"], normalize(obs_stats, jnp.asarray(obs)), schedule(hp, jnp.int32(8)))
    w, b = (np.asarray(x, np.float64) for x in ctrl.layers[0])
    return obs, np.asarray(c_jax), ctrl, ctrl.normalize(obs).astype(np.float64) @ w + b


def clear(logits, gap=1e-5):
    """States whose best logit leads the second by more than `gap` (float32 rounding cannot swap them) [n] bool."""
    top = np.sort(logits, axis=1)
    return top[:, -1] - top[:, -2] > gap


def test_linear_partition_k4_inside_k16_program_equals_k4_program():
    """A run of K = 4 in a K_max = 16 program trains as the K = 4 program (same seed, 3 iterations): the same
    episodes and cluster counts, its other metrics and active parameters (the partition's first K logits among
    them) equal to float rounding (bit for bit where the two programs' reductions round alike, as on XLA:CPU), and
    the 12 masked logits' weights exactly zero (uniform init, zero gradients)."""
    hp = make_hparams(K=4, total_iterations=3)
    out = {}
    for k_max in (4, 16):
        tr = trainer_for(Config(k_max=k_max, **TINY))
        state, metrics = jax.jit(tr.run_chunk, static_argnums=2)(jax.jit(tr.init)(jax.random.PRNGKey(3), hp), hp, 3)
        out[k_max] = jax.device_get(state.params["policy"]), jax.device_get(metrics)
    (p4, m4), (p16, m16) = out[4], out[16]
    for name in ("episodes", "clusters_used", "env_steps"):
        np.testing.assert_array_equal(m16[name], m4[name], err_msg=name)
    for name in ("episode_return", "policy_loss", "value_loss", "approx_kl", "partition_entropy", "grad_norm"):
        np.testing.assert_allclose(m16[name], m4[name], rtol=1e-5, atol=1e-7, err_msg=name)
    (layer4,), (layer16,) = p4["partition"], p16["partition"]
    d_s = layer4["w"].shape[0]
    assert layer16["w"].shape == (d_s, 16) and layer4["w"].shape == (d_s, 4)  # one affine layer, no hidden one
    assert not np.any(layer16["w"][:, 4:]) and not np.any(layer16["b"][4:])
    for got, want in ((layer16["w"][:, :4], layer4["w"]), (layer16["b"][:4], layer4["b"]), (p16["L"][:4], p4["L"])):
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)


def test_the_export_records_the_class_and_numpy_picks_the_trained_argmax(run, states):
    obs, c_jax, ctrl, logits = states
    assert json.loads((run / "config.json").read_text())["config"]["partition"] == "linear"
    assert ctrl.partition == "linear" and len(ctrl.layers) == 1 and ctrl.num_clusters == K
    assert str(ctrl.arrays["partition"]) == "linear" and ctrl.layers[0][0].shape == (obs.shape[1], K)
    ok = clear(logits)
    assert ok.mean() > 0.99 and len(np.unique(c_jax)) > 1, (ok.mean(), np.unique(c_jax))
    np.testing.assert_array_equal(ctrl.cluster(obs)[ok], c_jax[ok])


def test_onnx_picks_the_trained_argmax(run, states, tmp_path):
    ort = pytest.importorskip("onnxruntime")
    obs, c_jax, _, logits = states
    path = tmp_path / "controller.onnx"
    assert export_main([str(run), "--out", str(path)]) == 0
    _, cluster, _ = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(None, {"obs": obs})
    np.testing.assert_array_equal(cluster[clear(logits)], c_jax[clear(logits)])


def test_the_c_header_picks_the_trained_argmax(run, states, tmp_path, capsys):
    """The header holds one affine layer (no tanhf), compiles warning-free and picks the trained argmax."""
    obs, c_jax, ctrl, logits = states
    assert export_main([str(run), "--out", str(tmp_path / "controller.h")]) == 0
    assert "linear partition" in capsys.readouterr().out
    header = (tmp_path / "controller.h").read_text()
    assert "linear partition, logits = W z + c" in header and "gsa_w1" not in header and "0 tanhf" in header
    _, _, cluster = run_c_header(tmp_path, obs, ctrl.action_size)
    np.testing.assert_array_equal(cluster[clear(logits)], c_jax[clear(logits)])


def parse_cells(text, names):
    """{cluster: (A [K - 1, d_s], d [K - 1])} of inspect's printed cells."""
    cells, current = {}, None
    for line in text.splitlines():
        if m := re.match(r"cell (\d+):", line):
            current = cells.setdefault(int(m.group(1)), ([], []))
        elif m := re.match(r"  vs \d+:  (.*)  >= (\S+)$", line):
            terms = m.group(1).split("  ")
            assert [t.split(" ", 1)[1] for t in terms] == names
            current[0].append([float(t.split(" ", 1)[0]) for t in terms])
            current[1].append(float(m.group(2)))
    return {i: (np.array(a), np.array(d)) for i, (a, d) in cells.items()}


def test_inspect_prints_cells_that_pick_the_controllers_cluster(run, states, tmp_path, capsys):
    """inspect prints each cell's inequalities in the task's units, named by its observation layout: evaluated on
    states, the one cell whose rows all hold is the controller's cluster (states clear of every boundary by more
    than the print's 6 digits can move them); summary.json's A, d are cells.py's; cells.png is written."""
    import envs
    from gsa_jax.commands.inspect_run import main as inspect_main

    obs, _, ctrl, _ = states
    assert inspect_main([str(run), "--out", str(tmp_path), "--episodes", "2"]) == 0
    names = envs.resolve("inverted_double_pendulum").observation_layout()
    cells = parse_cells(capsys.readouterr().out, names)
    assert sorted(cells) == list(range(K)) and all(a.shape == (K - 1, len(names)) for a, _ in cells.values())
    x, rows = obs.astype(np.float64), [cells[i] for i in range(K)]
    slack = np.stack([np.min(x @ a.T - d, axis=1) for a, d in rows], axis=1)  # [n, K]: a cell's tightest row
    scale = np.stack([np.max(np.abs(x) @ np.abs(a).T + np.abs(d), axis=1) for a, d in rows], axis=1)
    sure = np.all(np.abs(slack) > 1e-5 * scale, axis=1)
    assert sure.mean() > 0.99
    assert np.all(np.sum(slack[sure] >= 0, axis=1) == 1)
    np.testing.assert_array_equal(np.argmax(slack[sure] >= 0, axis=1), ctrl.cluster(obs)[sure])
    summary = json.loads((tmp_path / "summary.json").read_text())
    for saved, cell in zip(summary["cells"], cell_inequalities(ctrl)):
        assert saved["versus"] == cell.others
        np.testing.assert_array_equal(saved["A"], cell.A)
        np.testing.assert_array_equal(saved["d"], cell.d)
    assert (tmp_path / "cells.png").stat().st_size > 10_000
    assert len(set(informative_coordinates(ctrl))) == 2


def test_an_old_controller_reads_as_mlp_and_an_unknown_class_is_one_line(tmp_path, capsys):
    path = f"{ROOT}/{COMMITTED['Ant-v5']}"  # exported before the partition class was stored (format_version 0)
    with np.load(path) as f:
        assert "partition" not in f.files and "format_version" not in f.files
    old = numpy_policy.load(path)
    assert old.arrays["partition"] == "mlp" and old.partition == "mlp" and len(old.layers) == 3
    assert int(old.arrays["format_version"]) == FORMAT_VERSION
    for bad, message in (("cubic", "unknown partition class 'cubic'; this version knows mlp, linear"),
                         ("linear", "names partition class 'linear' but its layers have sizes")):
        path = tmp_path / f"{bad}.npz"
        np.savez(path, **{**old.arrays, "partition": np.array(bad)})
        with pytest.raises(numpy_policy.ControllerClassError, match=message):
            numpy_policy.load(str(path))
        assert export_main([str(path), "--format", "c", "--out", str(tmp_path / "c.h")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err


def test_an_unknown_partition_in_an_experiment_file_is_one_line():
    from gsa_jax.running.spec import SpecError, build_grid, check_spec, group_config

    spec = {"envs": ["hopper"], "policies": ["mixture"], "clusters": [2], "steps": 10}
    with pytest.raises(SpecError, match=r"field 'config'.*unknown partition 'cubic'; choose one of mlp, linear"):
        check_spec({**spec, "config": {"partition": "cubic"}}, source="x.toml")
    linear = check_spec({**spec, "config": {"partition": "linear"}}, source="x.toml")
    assert group_config(linear, build_grid(linear)[0]).partition == "linear"
