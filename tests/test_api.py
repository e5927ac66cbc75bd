"""The public API (gsa_jax/api.py, re-exported by gsa_jax): each function runs its command with the keyword options
as flags, a nonzero status is a UserError, `import gsa_jax` loads no JAX, and score_controller() is gsa score's
episodes."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import gsa_jax
import gsa_jax.train  # noqa: F401 - the commands' modules, imported before the API is used: their names are not its
import gsa_jax.verify.system  # noqa: F401
from gsa_jax.errors import UserError
from gsa_jax.running.formats import FORMAT_VERSION

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONTROLLER = os.path.join(ROOT, "tests", "golden", "controllers", "InvertedDoublePendulum-v5-K1-answer-export.npz")


def test_options_become_the_commands_flags():
    assert gsa_jax.options_argv({"clusters": 2, "steps": 1000, "quick": True, "force": False, "seed": None,
                                 "looks": (10, 20), "budget_minutes": 1.5}) == [
        "--clusters", "2", "--steps", "1000", "--quick", "--looks", "10,20", "--budget-minutes", "1.5"]


@pytest.mark.parametrize("name, command, module, attr, args, argv", [
    ("train_run", "train", "gsa_jax.commands.train", "train", ("dmc:cartpole-balance", "OUT"),
     ["--env", "dmc:cartpole-balance", "--out", "OUT", "--clusters", "2"]),
    ("run_sweep", "sweep", "gsa_jax.commands.sweep", "sweep", ("spec.toml", "OUT"),
     ["spec.toml", "--out", "OUT", "--clusters", "2"]),
    ("export_controller", "export", "gsa_jax.commands.export", "export_controller", ("RUN", "OUT"),
     ["RUN", "--out", "OUT", "--clusters", "2"]),
])
def test_each_function_runs_its_command_and_a_failure_is_a_user_error(monkeypatch, name, command, module, attr, args,
                                                                      argv):
    seen = []
    monkeypatch.setattr(f"{module}.{attr}", lambda a, *rest: seen.append(a) or 0)
    assert getattr(gsa_jax, name)(*args, clusters=2) == "OUT" and seen == [argv]
    monkeypatch.setattr(f"{module}.{attr}", lambda a, *rest: 2)
    with pytest.raises(UserError, match=f"gsa {command} ended with status 2"):
        getattr(gsa_jax, name)(*args)


def test_the_api_names_survive_importing_the_commands_modules():
    """gsa_jax.train and gsa_jax.verify are the `python -m` module and package (imported above): the API's functions
    have names of their own, so they stay callable whatever was imported first."""
    assert callable(gsa_jax.train_run) and callable(gsa_jax.verify_controller) and callable(gsa_jax.answer_task)
    assert not callable(gsa_jax.train) and not callable(gsa_jax.verify)


def test_answer_and_verify_return_their_records(monkeypatch, tmp_path):
    def write(name, record):
        def command(argv):
            out = argv[argv.index("--out") + 1]
            os.makedirs(out, exist_ok=True)
            with open(os.path.join(out, name), "w") as f:
                json.dump({"format_version": FORMAT_VERSION, "argv": argv, **record}, f)  # stamped as written
            return 0
        return command

    monkeypatch.setattr("gsa_jax.commands.answer.answer", write("answer.json", {"judged": {}}))
    monkeypatch.setattr("gsa_jax.commands.verify.verify_controller", write("verify.json", {"nominal": {}}))
    state = gsa_jax.answer_task("dmc:cartpole-balance", str(tmp_path / "a"), budget_minutes=3)
    assert state["argv"] == ["--env", "dmc:cartpole-balance", "--out", str(tmp_path / "a"), "--budget-minutes", "3"]
    doc = gsa_jax.verify_controller("c.npz", str(tmp_path / "v"), quick=True, certify=False)
    assert doc["argv"] == ["c.npz", "--out", str(tmp_path / "v"), "--quick"] and "nominal" in doc


def test_import_loads_no_jax_and_unknown_names_are_attribute_errors():
    code = ("import sys, gsa_jax; gsa_jax.load_controller; gsa_jax.cli\n"
            "print([m for m in ('jax', 'mujoco.mjx', 'brax') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True, timeout=300).stdout
    assert out.strip().splitlines()[-1] == "[]"
    with pytest.raises(AttributeError):
        gsa_jax.no_such_name  # noqa: B018


def test_score_and_load_controller_are_gsa_scores_episodes():
    from gsa_jax.analysis.sweeps import controller_scores

    scored = gsa_jax.score_controller(CONTROLLER, episodes=2, start_seed=20_000)
    _, returns, lengths = controller_scores.controller_episodes(CONTROLLER, 2, 20_000)
    assert scored["returns"] == [float(r) for r in returns] and scored["lengths"] == [int(n) for n in lengths]
    assert scored["sha256"] == controller_scores.file_sha256(CONTROLLER)
    ctrl = gsa_jax.load_controller(CONTROLLER)
    assert ctrl.act(np.zeros((3, ctrl.obs_mean.shape[-1]), np.float32)).shape[0] == 3


def test_run_metadata_is_what_results_record():
    from gsa_jax.running.runinfo import run_metadata

    meta = gsa_jax.run_metadata()
    assert set(meta) == set(run_metadata()) and meta["versions"] == run_metadata()["versions"]


def test_statistics_are_the_tables_rliable_numbers():
    """gsa_jax.iqm, iqm_ci and improvement_probability are the tables' own (analysis.sweeps.stats, rliable): the
    same numbers for the same seed, the tables' number of resamples by default."""
    from gsa_jax.analysis.sweeps import stats

    rng = np.random.default_rng(3)
    x, y = rng.normal(1.0, 1.0, (12, 1)), rng.normal(0.0, 1.0, (12, 1))
    assert gsa_jax.iqm(x) == stats.iqm(x)
    assert gsa_jax.iqm_ci({"x": x}, seed=1, reps=200) == stats.iqm_ci({"x": x}, 1, 200)
    assert gsa_jax.iqm_ci({"x": x}) == stats.iqm_ci({"x": x}, 0, stats.REPS)
    p = gsa_jax.improvement_probability({"p": (x, y)}, reps=200)["p"]
    assert p == stats.improvement_probability({"p": (x, y)}, 0, 200)["p"] and 0.5 < p[0] <= 1.0
