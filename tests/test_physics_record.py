"""The physics options as one record of Config (envs.physics.Physics), and the records written before, which kept
them as flat Config fields: experiment files, sweep.json, config.json and exported controllers read the same."""

import dataclasses
import json

import pytest

from envs.physics import Physics, make_physics, nest_physics, record_backend
from gsa_jax.algorithm.config import Config, config_defaults, config_record
from gsa_jax.running.formats import current
from gsa_jax.running.runinfo import ResumeRefused
from gsa_jax.running.single import check_resume_config
from gsa_jax.running.spec import SpecError, check_spec
from gsa_jax.running.sweeps import recorded_spec
from gsa_jax.running.tasks import task_of

FLAT = {"backend": "c", "physics_threads": 2, "num_envs": 16}  # a [config] table / config.json as written before
NESTED = {"physics": {"backend": "c", "threads": 2}, "num_envs": 16}


def test_flat_fields_move_into_the_physics_record():
    assert nest_physics(FLAT) == NESTED
    assert nest_physics(NESTED) == NESTED and nest_physics({"num_envs": 16}) == {"num_envs": 16}
    assert FLAT == {"backend": "c", "physics_threads": 2, "num_envs": 16}  # the input is left as it was
    assert record_backend(FLAT) == record_backend(NESTED) == "c" and record_backend({}) == "mjx"
    with pytest.raises(ValueError, match="backend is set both as a config field and as physics.backend"):
        nest_physics({"backend": "c", "physics": {"backend": "mjx"}})
    with pytest.raises(ValueError, match="unknown physics option 'thread'"):
        make_physics({"thread": 1})


def test_config_takes_the_record_or_a_dict_of_its_fields():
    a = Config(env="hopper", physics=Physics(backend="c", threads=2))
    assert Config(env="hopper", physics={"backend": "c", "threads": 2}) == a and hash(a) == hash(Config(**dataclasses.asdict(a)))
    assert dataclasses.asdict(a)["physics"] == dataclasses.asdict(Physics(backend="c", threads=2))
    assert not any(f.name in ("backend", "physics_threads", "solver_iterations") for f in dataclasses.fields(Config))


def test_an_old_config_json_reads_as_the_same_config():
    """config.json written with flat physics fields (and lacking fields added since) gives the Config it ran."""
    new = Config(env="hopper", num_envs=16, physics=Physics(backend="c", threads=2))
    old = {k: v for k, v in json.loads(json.dumps(dataclasses.asdict(new))).items() if k not in ("physics", "randomize")}
    old.update(backend="c", physics_threads=2, solver_iterations=None, linesearch="exact")
    record = config_record(current({"config": old}, "run", "config.json")["config"])  # read as running.formats does
    assert set(record) == set(config_defaults()) and record["randomize"] == ""
    assert Config(**{**record, "hidden": tuple(record["hidden"])}) == new


def test_resume_of_a_run_saved_with_flat_physics_fields():
    """A run saved before continues with the same settings; a changed physics option is still refused."""
    cfg = Config(env="hopper", physics=Physics(backend="c"))
    config = {"config": json.loads(json.dumps(dataclasses.asdict(cfg))), "seed": 0}
    old = {"config": {**{k: v for k, v in config["config"].items() if k != "physics"}, "backend": "c",
                      "physics_threads": 0}, "seed": 0}
    check_resume_config(current(old, "run", "config.json"), config, False, task_of(cfg).source())
    old["config"]["backend"] = "mjx"
    with pytest.raises(ResumeRefused, match=r"config.physics.backend: \"mjx\" -> \"c\""):
        check_resume_config(current(old, "run", "config.json"), config, False, task_of(cfg).source())


def test_experiment_files_and_sweep_json_in_either_layout():
    raw = {"envs": ["hopper"], "policies": ["mlp"], "seeds": 1, "steps": 100}
    flat, nested = check_spec({**raw, "config": FLAT}), check_spec({**raw, "config": NESTED})
    assert flat == nested and nested.to_json()["config"] == NESTED
    old = current({"spec": {**raw, "config": FLAT}}, "sweep", "sweep.json")  # a sweep.json written before resumes
    assert recorded_spec(old["spec"]) == nested.to_json() and old["runs_per_program"] == 0
    with pytest.raises(SpecError, match="unknown physics option 'threds'"):
        check_spec({**raw, "config": {"physics": {"threds": 1}}})
    with pytest.raises(SpecError, match="config.backnd"):
        check_spec({**raw, "config": {"backnd": "c"}})
