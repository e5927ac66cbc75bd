"""gsa_jax.deployment.shifts and gsa_jax.robustness: shifted tasks change what they say and nothing else, the nominal
evaluation equals the deployment runner's, the sensitivity equals finite differences, the CLI resumes."""

import csv
import json

import numpy as np
import pytest

from envs.mujoco_c import make_c, run_episodes
from gsa_jax.analysis.robustness.retention_eval import action_jacobian_norms
from gsa_jax.deployment import numpy_policy
from gsa_jax.deployment.shifts import DEFAULT_SHIFTS, Shift, run_shifted, shifted_task
from gsa_jax.robustness import main


def controller_arrays(kind, k=3, d_s=11, d_a=3, seed=0):
    """A small random exported controller of Hopper-v5 (gsa_jax.export's npz layout)."""
    rng = np.random.default_rng(seed)
    arrays = {"kind": np.array(kind), "obs_mean": rng.normal(0, 0.1, d_s).astype(np.float32),
              "obs_var": rng.uniform(0.5, 2.0, d_s).astype(np.float32), "obs_clip": np.array(10.0, np.float32),
              "config_json": np.array(json.dumps({"config": {"env": "Hopper-v5", "policy": kind}, "hparams": {"K": k},
                                                  "seed": seed}))}
    sizes = [d_s, 16, k] if kind == "mixture" else [d_s, 16, d_a]
    arrays["n_layers"] = np.array(len(sizes) - 1)
    for i in range(len(sizes) - 1):
        arrays[f"w{i}"] = rng.normal(0, 0.5, sizes[i:i + 2]).astype(np.float32)
        arrays[f"b{i}"] = rng.normal(0, 0.1, sizes[i + 1]).astype(np.float32)
    if kind == "mixture":
        arrays.update(subpolicy=np.array("linear"), partition=np.array("mlp"), L=rng.normal(0, 0.3, (k, d_a, d_s)).astype(np.float32),
                      b=rng.normal(0, 0.3, (k, d_a)).astype(np.float32))
    return arrays


def test_shifted_tasks_change_only_their_parameter_and_no_other_task():
    base = make_c("Hopper-v5").model
    heavy = shifted_task("Hopper-v5", Shift("mass", 1.25)).model
    np.testing.assert_allclose(heavy.body_mass, 1.25 * base.body_mass)
    np.testing.assert_allclose(heavy.body_inertia, 1.25 * base.body_inertia)
    np.testing.assert_array_equal(heavy.geom_friction, base.geom_friction)
    slippery = shifted_task("Hopper-v5", Shift("friction", 0.5)).model
    np.testing.assert_allclose(slippery.geom_friction[:, 0], 0.5 * base.geom_friction[:, 0])
    np.testing.assert_array_equal(slippery.geom_friction[:, 1:], base.geom_friction[:, 1:])
    weak = shifted_task("Hopper-v5", Shift("gear", 0.8)).model
    np.testing.assert_allclose(weak.actuator_gear[:, 0], 0.8 * base.actuator_gear[:, 0])
    np.testing.assert_array_equal(make_c("Hopper-v5").model.body_mass, base.body_mass)  # nothing patched
    assert shifted_task("Hopper-v5", Shift("simulator")).model.opt.integrator != base.opt.integrator  # Brax's Euler


@pytest.mark.parametrize("kind", ["mixture", "mlp"])
def test_nominal_and_zero_shifts_equal_the_deployment_runner(kind):
    """run_shifted under no shift (and under zero noise / no pushes / mass x 1) gives the returns of
    envs.mujoco_c's one-episode-at-a-time runner from the same starts (to float32 rounding: the controller
    runs on a batch of observations there, one at a time here)."""
    ctrl = numpy_policy.Controller(controller_arrays(kind))
    seeds = np.arange(3)
    ref, ref_len = run_episodes(make_c("Hopper-v5"), ctrl, 3, 1000, seed=0)
    for shift in (Shift("nominal"), Shift("obs_noise", 0.0), Shift("push", 0.0), Shift("mass", 1.0)):
        returns, lengths, _ = run_shifted(ctrl, "Hopper-v5", shift, seeds)
        np.testing.assert_allclose(returns, ref, rtol=1e-4, err_msg=shift.name)
        np.testing.assert_array_equal(lengths, ref_len)
    noisy, _, _ = run_shifted(ctrl, "Hopper-v5", Shift("obs_noise", 0.1), seeds)
    late, _, _ = run_shifted(ctrl, "Hopper-v5", Shift("action_delay", 1), seeds)
    assert np.abs(noisy - ref).max() > 1e-2 and np.abs(late - ref).max() > 1e-2


def test_sensitivity_is_the_active_piece_or_the_networks_jacobian():
    rng = np.random.default_rng(1)
    obs = rng.normal(0, 1, (5, 11)).astype(np.float32)
    mix = numpy_policy.Controller(controller_arrays("mixture"))
    np.testing.assert_array_equal(action_jacobian_norms(mix, obs), np.linalg.norm(mix.L[mix.cluster(obs)], axis=(1, 2)))
    mlp = numpy_policy.Controller(controller_arrays("mlp"))
    h = 1e-3
    for i, o in enumerate(obs.astype(np.float64)):
        z = (o - mlp.obs_mean) / mlp.obs_std
        cols = [(mlp._mlp((z + h * e).astype(np.float32)) - mlp._mlp((z - h * e).astype(np.float32))) / (2 * h)
                for e in np.eye(11)]
        assert action_jacobian_norms(mlp, obs[i:i + 1])[0] == pytest.approx(np.linalg.norm(np.array(cols)), rel=1e-2)


def test_cli_writes_tables_resumes_and_refuses_other_settings(tmp_path, capsys):
    for kind, seed in (("mixture", 0), ("mixture", 1), ("mlp", 0), ("mlp", 1)):
        np.savez(tmp_path / f"{kind}-{seed}.npz", **controller_arrays(kind, seed=seed))
    out = tmp_path / "rob"
    args = [str(tmp_path), "--out", str(out), "--episodes", "2", "--shifts", "gear,obs_noise", "--reps", "20"]
    assert main(args) == 0
    with open(out / "robustness.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4 * 4 and {r["shift"] for r in rows} == {"nominal", "gear", "obs_noise"}
    nominal = [r for r in rows if r["shift"] == "nominal"]
    assert all(float(r["retained_fraction"]) == 1.0 for r in nominal)
    with open(out / "aggregate.csv") as f:
        agg = list(csv.DictReader(f))
    assert {(r["policy"], r["K"], r["shift"]) for r in agg} >= {("mlp", "", "gear 0.8"), ("mixture", "3", "obs_noise 0.1")}
    assert all(r["p_retains_more_than_flat_ppo"] != "" for r in agg if r["policy"] == "mixture")
    assert (out / "robustness.png").stat().st_size > 10_000 and (out / "profile.png").exists()
    capsys.readouterr()
    assert main(args) == 0 and "[1/4]" not in capsys.readouterr().out  # nothing evaluated twice
    # the re-run with only the controllers and OUT continues with the recorded shifts and episodes
    assert main([str(tmp_path), "--out", str(out), "--reps", "20"]) == 0 and "[1/4]" not in capsys.readouterr().out
    with open(out / "robustness.csv") as f:
        assert len(list(csv.DictReader(f))) == 16
    assert main(args[:-4] + ["--shifts", "push", "--reps", "20"]) == 2
    assert "holds an evaluation with other settings" in capsys.readouterr().err
    assert main([str(tmp_path / "none"), "--out", str(out)]) == 2


def test_level_replaces_a_kinds_default_levels_and_bad_levels_are_one_line(tmp_path, capsys):
    from gsa_jax.commands.robustness import parse_levels, parse_shifts

    shifts = parse_shifts("push,gear", parse_levels(["push=0.5,1"]))
    assert [(s.kind, s.level) for s in shifts] == [("nominal", 0.0), ("push", 0.5), ("push", 1.0), ("gear", 0.8)]
    assert [s.name for s in parse_shifts("all")] == [s.name for s in DEFAULT_SHIFTS]
    np.savez(tmp_path / "c.npz", **controller_arrays("mlp", seed=0))
    for bad, message in (("push=0,1", "levels must be > 0"), ("simulator=1", "KIND must be one of"),
                         ("push=fast", "levels must be numbers")):
        assert main([str(tmp_path / "c.npz"), "--out", str(tmp_path / "o"), "--level", bad]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and message in err, err


def test_sensitivity_of_a_quadratic_mixture_is_its_pieces_jacobian_in_z():
    """d action / d z of the active piece, L_c d phi / d z, for a sub-policy class that is not linear: checked by
    central differences of L_c phi(z) + b_c in z (the cluster held)."""
    from gsa_jax.algorithm import subpolicies

    rng = np.random.default_rng(2)
    arrays = controller_arrays("mixture")
    quadratic = subpolicies.get("quadratic")
    arrays.update(subpolicy=np.array("quadratic"), L=rng.normal(0, 0.3, (3, 3, quadratic.size(11))).astype(np.float32))
    mix = numpy_policy.Controller(arrays)
    obs = rng.normal(0, 1, (4, 11)).astype(np.float32)
    norms = action_jacobian_norms(mix, obs)
    h = 1e-4
    for i, (z, c) in enumerate(zip(mix.normalize(obs).astype(np.float64), mix.cluster(obs))):
        piece = lambda x: mix.L[c].astype(np.float64) @ quadratic.features(x, np)  # noqa: E731
        cols = [(piece(z + h * e) - piece(z - h * e)) / (2 * h) for e in np.eye(11)]
        assert norms[i] == pytest.approx(np.linalg.norm(np.array(cols)), rel=1e-4)
