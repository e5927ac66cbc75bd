"""Per-group learning rates and the equal-budget tuning protocol (gsa_jax.tune): every group at scale 1 is the
one-lr update bit for bit, a group at scale 0 stays put, a bad tuning file is one line before anything
compiles, the draws are reproducible and in range, and a configuration trained in the vmapped tuning sweep
equals the same configuration trained alone."""

import csv
import glob
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsa_jax.algorithm.config import Config, make_hparams
from gsa_jax.algorithm.optim import adam_step, init_adam
from gsa_jax.running.tasks import trainer_for
from gsa_jax.algorithm.ppo_update import group_learning_rates
from gsa_jax.running.spec import SpecError
from gsa_jax.running.tuning import check_tuning, draw_configurations
from gsa_jax.tune import main

SMALL = {"num_envs": 16, "unroll_length": 32, "num_minibatches": 8, "num_epochs": 2, "episode_length": 200}


def params_like():
    k = jax.random.split(jax.random.PRNGKey(0), 4)
    return {"policy": {"partition": [{"w": jax.random.normal(k[0], (3, 4)), "b": jnp.zeros(4)}],
                       "L": jax.random.normal(k[1], (2, 1, 3)), "b": jnp.ones((2, 1)), "log_sigma": jnp.zeros((2, 1))},
            "value": [{"w": jax.random.normal(k[2], (3, 1)), "b": jnp.zeros(1)}]}


def test_group_rates_at_scale_one_are_the_one_lr_update_bit_for_bit_and_scale_zero_freezes_a_group():
    params = params_like()
    grads = jax.tree.map(lambda x: jnp.sin(x) + 0.3, params)
    lr = jnp.float32(3e-4)
    one, _ = adam_step(params, grads, init_adam(params), lr)
    grouped, _ = adam_step(params, grads, init_adam(params), group_learning_rates(params, make_hparams(), lr))
    for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(grouped)):
        assert np.array_equal(np.asarray(a), np.asarray(b))
    hp = make_hparams(lr_scale_L=0.0, lr_scale_critic=2.0)
    moved, _ = adam_step(params, grads, init_adam(params), group_learning_rates(params, hp, lr))
    np.testing.assert_array_equal(moved["policy"]["L"], params["policy"]["L"])
    step = lambda t: np.asarray(t["value"][0]["w"] - params["value"][0]["w"])  # noqa: E731
    np.testing.assert_allclose(step(moved), 2 * step(one), rtol=1e-3)  # float32 differences of parameters
    np.testing.assert_array_equal(moved["policy"]["b"], one["policy"]["b"])


TUNING = {"name": "t", "env": "inverted_double_pendulum", "configurations": 2, "draw_seed": 3, "tuning_seeds": [5],
          "tuning_steps": 1536, "evaluation_seeds": [0], "evaluation_steps": 1024, "config": {**SMALL, "eval_envs": 4},
          "classes": {"mix": {"policy": "mixture", "clusters": 3,
                              "knobs": {"lr_scale_L": [0.3, 3.0, "log"], "eps_init": [0.0, 0.3], "lr": [1e-4, 1e-3, "log"]}}}}


@pytest.mark.parametrize("change, message", [
    ({"classes": {"mix": {"policy": "mixture", "clusters": 2, "knobs": {"lr_scale_Q": [1, 2]}}}}, "unknown knob"),
    ({"classes": {"mix": {"policy": "mixture", "clusters": 2, "knobs": {"lr": [1e-3, 1e-3]}}}}, "is empty"),
    ({"classes": {"mix": {"policy": "mixture", "clusters": 2, "knobs": {"lr": [0, 1e-3, "log"]}}}}, "needs low > 0"),
    ({"classes": {"f": {"policy": "mlp", "knobs": {"lr_scale_L": [1, 2]}}}}, "acts on mixture policies only"),
    ({"evaluation_seeds": [0, 5]}, "also tuning seeds"),
    ({"tuning_seeds": []}, "non-empty list"),
    ({"budget": 3}, "unknown field"),
    ({"env": "Walker2d-v9"}, "Walker2d-v5"),
])
def test_a_bad_tuning_file_is_one_line(change, message):
    with pytest.raises(SpecError) as e:
        check_tuning({**TUNING, **change})
    assert message in str(e.value) and "\n" not in str(e.value), str(e.value)


def test_draws_are_reproducible_in_range_and_start_from_the_defaults():
    spec = check_tuning({**TUNING, "configurations": 40})
    sets = draw_configurations(spec, "mix")
    assert sets == draw_configurations(spec, "mix") and len(sets) == 40
    assert sets[0] == {"lr_scale_L": 1.0, "eps_init": 0.2, "lr": 3e-4}
    lrs = np.array([s["lr"] for s in sets[1:]])
    assert lrs.min() >= 1e-4 and lrs.max() <= 1e-3 and np.median(lrs) < 5.5e-4  # log-uniform: median near 3.2e-4
    assert all(0.0 <= s["eps_init"] <= 0.3 for s in sets)


def test_tuning_selects_evaluates_and_a_vmapped_configuration_equals_it_alone(tmp_path, capsys):
    spec_path = tmp_path / "t.toml"
    spec_path.write_text(
        'name = "t"\nenv = "InvertedDoublePendulum-v5"\nconfigurations = 2\ndraw_seed = 3\ntuning_seeds = [5]\n'
        "tuning_steps = 1536\nevaluation_seeds = [0]\nevaluation_steps = 1024\n[config]\n"
        + "".join(f"{k} = {v}\n" for k, v in {**SMALL, "eval_envs": 4}.items())
        + '[config.physics]\nbackend = "c"\n'  # MuJoCo C in the program (the protocol is under test, not MJX)
        + '[classes.mix]\npolicy = "mixture"\nclusters = 3\nknobs.lr_scale_L = [0.3, 3.0, "log"]\n'
          'knobs.eps_init = [0.0, 0.3]\nknobs.lr = [1e-4, 1e-3, "log"]\n')
    out = tmp_path / "tune"
    args = [str(spec_path), "--out", str(out), "--reps", "20", "--sweep-args", "--no-tensorboard --no-watchdog --local-processes 1 --quiet"]
    assert main(args) == 0
    with open(out / "mix" / "selection.csv") as f:
        selection = list(csv.DictReader(f))
    assert sorted(int(r["hparam_set"]) for r in selection) == [0, 1] and selection[0]["rank"] == "1"
    assert float(selection[0]["tuning_iqm"]) >= float(selection[1]["tuning_iqm"])
    with open(out / "tuning.csv") as f:
        (row,) = list(csv.DictReader(f))
    assert row["class"] == "mix" and row["K"] == "3" and int(row["chosen_set"]) == int(selection[0]["hparam_set"])
    assert json.loads(row["chosen"]) == {k: float(selection[0][k]) for k in ("lr_scale_L", "eps_init", "lr")}
    # the drawn configuration (set 1) in the vmapped tuning sweep equals it trained alone
    drawn = draw_configurations(check_tuning(TUNING), "mix")[1]
    tr = trainer_for(Config(env="InvertedDoublePendulum-v5", policy="mixture", k_max=3, physics={"backend": "c"}, **SMALL))
    hp = make_hparams(K=3, total_iterations=3, **drawn)
    _, m = jax.jit(tr.run_chunk, static_argnums=2)(jax.jit(tr.init)(jax.random.PRNGKey(5), hp), hp, 3)
    rows = []
    for path in glob.glob(str(out / "mix" / "tuning" / "**" / "metrics.csv"), recursive=True):
        with open(path) as f:
            rows += [r for r in csv.DictReader(f) if r["hparam_set"] == "1"]
    rows.sort(key=lambda r: int(r["iteration"]))
    for col in ("policy_loss", "value_loss", "approx_kl"):
        np.testing.assert_allclose([float(r[col]) for r in rows], np.asarray(m[col], np.float64), rtol=2e-3, atol=1e-5, err_msg=col)
    capsys.readouterr()
    assert main(args) == 0 and "chose configuration" in capsys.readouterr().out  # a re-run trains nothing again
    # the rank check: both configurations on the tuning seed for the evaluation's env steps
    assert main(args + ["--phase", "rank", "--rank-check", "1,2,7"]) == 0
    with open(out / "mix" / "ranking.csv") as f:
        ranking = list(csv.DictReader(f))
    assert [r["hparam_set"] for r in ranking] == [r["hparam_set"] for r in selection]  # rank 7 does not exist
    assert (out / "mix" / "ranking" / "sweep.json").exists()
    assert "seeds = [5]\nsteps = 1024" in (out / "mix" / "ranking.toml").read_text()
    with open(out / "ranking.csv") as f:
        (summary,) = list(csv.DictReader(f))
    assert summary["class"] == "mix" and summary["configurations"] == "2" and abs(float(summary["spearman"])) == 1.0
    assert main(args + ["--phase", "rank", "--rank-check", "x"]) == 2


def test_a_configuration_of_a_set_is_named_by_its_index():
    from gsa_jax.running.trained import run_label

    row = {"env": "Walker2d-v5", "policy": "mixture", "K": 6, "seed": 1000, "run": 0, "gamma": 0.99, "hparam_set": 3,
           **{f"lr_scale_{g}": 2.0 for g in ("partition", "L", "b", "log_sigma", "critic")}}
    assert run_label(row) == "Walker2d-v5-mixture-K6-gamma=0.99-hparam_set=3-s1000"
