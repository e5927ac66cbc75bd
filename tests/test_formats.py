"""Versioned records (gsa_jax.running.formats): every writer stamps format_version, and an older file of every kind
still reads, into the current layout. The fixtures in tests/fixtures/formats/ are committed results copied as they
were written (format_version 0: no field): a run's config.json, two sweep.json (pad_runs; flat physics options), an
answer.json from before futility stopping, an MLP and a mixture controller from before partition classes and task
records, and a verify.json."""

import json
import os

import numpy as np
import pytest

from gsa_jax.algorithm.config import Config, config_defaults, config_record
from gsa_jax.deployment import numpy_policy
from gsa_jax.running.formats import FORMAT_VERSION, STEPS, FormatError, current, read_controller, read_json, stamped

FIX = os.path.join(os.path.dirname(__file__), "fixtures", "formats")


def fixture(name: str) -> str:
    return os.path.join(FIX, name)


def test_the_fixtures_are_older_files_of_every_kind():
    names = sorted(os.listdir(FIX))
    for name in names:
        if name.endswith(".json"):
            with open(fixture(name)) as f:
                assert "format_version" not in json.load(f), name
        else:
            with np.load(fixture(name)) as f:
                assert "format_version" not in f.files, name
    kinds = {n.split(".")[0].split("-")[0] for n in names}
    assert kinds == set(STEPS) == {"run", "sweep", "controller", "answer", "verify"}


def test_an_older_run_config_reads_as_the_settings_it_ran():
    record = read_json(fixture("run-config.v0.json"), "run")
    assert record["format_version"] == FORMAT_VERSION and record["eval_seed"] == 0 and record["tensorboard"] is True
    config = config_record(record["config"])
    assert set(config) == set(config_defaults()) and config["physics"] == config_defaults()["physics"]
    assert Config(**{**config, "hidden": tuple(config["hidden"])}).env == "hopper"
    from gsa_jax.commands.train import saved_options

    opts = saved_options(record)
    assert (opts["eval_seed"], opts["tensorboard"], opts["chunk"]) == (0, True, 10)
    assert opts["steps"] == record["iterations"] * config["num_envs"] * config["unroll_length"]


def test_an_older_sweep_json_resumes_with_its_runs_per_program_and_physics():
    from gsa_jax.commands.sweep import saved_options
    from gsa_jax.running.formats import GROUP_COLUMNS
    from gsa_jax.running.spec import GROUP_AXES, check_spec
    from gsa_jax.running.sweeps import recorded_spec

    padded = read_json(fixture("sweep-pad_runs.v0.json"), "sweep")
    assert "pad_runs" not in padded and padded["runs_per_program"] == 10
    assert saved_options(padded, "d", None)["runs_per_program"] == 10
    flat = read_json(fixture("sweep-flat-physics.v0.json"), "sweep")
    assert flat["runs_per_program"] == 0 and flat["spec"]["config"]["physics"] == {"backend": "c"}
    assert "backend" not in flat["spec"]["config"] and check_spec(flat["spec"]).config["physics"]["backend"] == "c"
    assert recorded_spec(flat["spec"]) == check_spec(flat["spec"]).to_json()
    assert GROUP_COLUMNS == ("env", "policy", *(c for _, c, _, _ in GROUP_AXES))  # how pad_runs' groups are counted
    with open(fixture("sweep-pad_runs.v0.json")) as f:
        raw = json.load(f)
    raw["runs"] = raw["runs"] + [{**raw["runs"][0], "seed": 99}]  # a group larger than pad_runs: trained whole then
    assert current(raw, "sweep", "sweep.json")["trained_whole"] == 11  # read; its resume is refused (test_sweep.py)


def test_an_older_answer_reads_with_its_settings_and_times():
    from gsa_jax.analysis.verdicts.answer_report import rounds_text

    state = read_json(fixture("answer.v0.json"), "answer")
    assert state["setup"]["futility"] == 0.0 and state["setup"]["max_steps"] is None and state["before_futility"]
    sweeps = [s for r in state["rounds"] for s in r["sweeps"].values()]
    assert sweeps and all(s["compile_wall_s"] == s["compile_s"] for s in sweeps)
    table, share = rounds_text(state)
    assert table.count("\n") == 1 + len(state["rounds"]) and 0 < share < 1
    with open(fixture("answer.v0.json")) as f:
        raw = json.load(f)
    assert "steps" not in raw and "compile_wall_s" not in json.dumps(raw)  # truly older: read as the report reads it
    step = {"steps": 1000, "enough": True, "sweep": {"seconds": 9.0, "compile_s": 2.0, "runs": 10}}
    older = current({**raw, "steps": {"calibration": [step]}}, "answer", "answer.json")  # a step budget's record
    assert older["steps"]["calibration"][0]["candidate"] is True
    assert older["steps"]["calibration"][0]["sweep"]["compile_wall_s"] == 2.0 and "candidate" not in step  # no change


def test_an_older_run_config_with_flat_physics_reads_nested():
    record = current({"config": {"env": "hopper", "backend": "c", "physics_threads": 2}, "iterations": 1}, "run", "c")
    assert record["config"] == {"env": "hopper", "physics": {"backend": "c", "threads": 2}}
    with pytest.raises(FormatError, match="backend is set both as a config field and as physics.backend"):
        current({"config": {"backend": "c", "physics": {"backend": "mjx"}}}, "run", "config.json")


def test_older_controllers_act_as_they_did(tmp_path):
    """A mixture from before partition classes reads as the mlp class with the linear sub-policy; both controllers
    name no task record ('') and act on their task's observations."""
    mixture = numpy_policy.load(fixture("controller-mixture.v0.npz"))
    assert (mixture.partition, mixture.subpolicy, mixture.num_clusters) == ("mlp", "linear", 2)
    assert str(mixture.arrays["task"]) == "" and numpy_policy.stored_sha256(mixture.arrays) is None
    mlp = numpy_policy.load(fixture("controller-mlp.v0.npz"))
    for ctrl in (mixture, mlp):
        assert int(ctrl.arrays["format_version"]) == FORMAT_VERSION
        obs = np.random.default_rng(0).normal(size=(5, ctrl.obs_mean.shape[0])).astype(np.float32)
        action = ctrl.act(obs)
        assert action.shape == (5, ctrl.action_size) and np.all(np.abs(action) <= 1.0)
    with np.load(fixture("controller-mixture.v0.npz")) as f:  # the same arrays as stored, and nothing dropped
        stored = {k: f[k] for k in f.files}
    read = read_controller(fixture("controller-mixture.v0.npz"))
    assert set(read) - set(stored) == {"format_version", "partition", "task", "task_sha256"}
    assert all(np.array_equal(read[k], v) for k, v in stored.items())
    path = tmp_path / "no-subpolicy.npz"  # exported before sub-policy classes: linear
    np.savez(path, **{k: v for k, v in stored.items() if k != "subpolicy"})
    assert numpy_policy.load(str(path)).subpolicy == "linear"


def test_an_older_verify_json_reads_and_a_current_record_reads_unchanged():
    doc = read_json(fixture("verify.v0.json"), "verify")
    assert doc["format_version"] == FORMAT_VERSION and doc["schema"] == 2
    for kind, name in (("run", "run-config.v0.json"), ("sweep", "sweep-pad_runs.v0.json"), ("answer", "answer.v0.json"),
                       ("verify", "verify.v0.json")):
        once = read_json(fixture(name), kind)
        assert current(json.loads(json.dumps(once)), kind, name) == once  # stamped: read as it is
        unstamped = {k: v for k, v in json.loads(json.dumps(once)).items() if k != "format_version"}
        assert current(unstamped, kind, name) == once  # the steps leave a record of the current layout unchanged


def test_a_newer_or_unreadable_version_is_one_line(tmp_path):
    with pytest.raises(FormatError, match=r"written by a newer gsa_jax \(format_version 2; this one reads up to 1\)"):
        current({"format_version": FORMAT_VERSION + 1}, "run", "config.json")
    for bad in ("1", 1.5, True, -1, np.bool_(True), [1]):
        with pytest.raises(FormatError, match="not a version number"):
            current({"format_version": bad}, "sweep", "sweep.json")
    path = tmp_path / "newer.npz"
    np.savez(path, **{**read_controller(fixture("controller-mlp.v0.npz")), "format_version": np.array(2)})
    with pytest.raises(FormatError, match="newer gsa_jax"):
        numpy_policy.load(str(path))
    (tmp_path / "list.json").write_text("[]")
    with pytest.raises(FormatError, match="not a gsa_jax record"):
        read_json(str(tmp_path / "list.json"), "answer")
    assert stamped({"a": 1, "format_version": 0}) == {"format_version": FORMAT_VERSION, "a": 1}
    with pytest.raises(FormatError, match="not a gsa_jax answer record of format_version 0 .KeyError: 'setup'"):
        current({"judged": {}}, "answer", "answer.json")
