"""The command-line options generated from the configuration's fields (gsa_jax/algorithm/config.py): what a command
line sets, and the option values that give back a saved run's Config and Hparams. No compiling."""

import argparse
import dataclasses
import json

from gsa_jax.algorithm.config import (
    CONFIG_OPTIONS, HPARAM_OPTIONS, UNFLAGGED, Config, add_options, config_record, flag_names, options_config,
    options_hparams, saved_option_values,
)

ARGV = ["--env", "hopper", "--policy", "mlp", "--num-envs", "8", "--epochs", "3", "--no-normalize-reward",
        "--physics", "c", "--physics-threads", "2", "--randomize", "mass=0.9:1.1", "--eval-randomized",
        "-K", "3", "--clip", "0.1", "--no-anneal-lr", "--lr-scale-L", "0.5"]


def parser():
    p = argparse.ArgumentParser()
    add_options(p)
    return p


def test_a_command_line_sets_its_fields():
    args = parser().parse_args(ARGV)
    cfg = options_config(args, k_max=3)
    assert (cfg.env, cfg.policy, cfg.num_envs, cfg.num_epochs, cfg.normalize_reward) == ("hopper", "mlp", 8, 3, False)
    assert (cfg.physics.backend, cfg.physics.threads, cfg.eval_randomized, cfg.k_max) == ("c", 2, True, 3)
    assert cfg.randomize == "mass=0.9:1.1" and cfg.hidden == Config.hidden
    hp = options_hparams(args)
    assert (hp["K"], hp["clip_eps"], hp["anneal_lr"], hp["lr_scale_L"], hp["lr"]) == (3, 0.1, 0.0, 0.5, 3e-4)
    assert options_hparams(parser().parse_args([]))["anneal_lr"] == 1.0


def test_the_options_of_a_saved_run_give_it_back():
    """A saved run's records (as config.json holds them) -> option defaults -> the same Config and Hparams, the
    fields no option sets included."""
    p = parser()
    args = p.parse_args(ARGV)
    cfg = dataclasses.replace(options_config(args, k_max=3), hidden=(32,), normalize_obs=False)
    hp = options_hparams(args)
    saved = json.loads(json.dumps({"config": dataclasses.asdict(cfg), "hparams": hp}))
    p.set_defaults(**saved_option_values(config_record(saved["config"]), saved["hparams"]))
    again = p.parse_args([])
    assert options_config(again) == cfg and options_hparams(again) == hp


def test_every_field_has_one_option_or_none():
    fields = [o.field for o in CONFIG_OPTIONS] + list(UNFLAGGED)
    assert sorted(fields) == sorted({*(f.name for f in dataclasses.fields(Config) if f.name != "physics"),
                                     *(f"physics.{f.name}" for f in dataclasses.fields(Config().physics))})
    assert UNFLAGGED == ("hidden", "normalize_obs", "physics.search_loop")
    assert [o.field for o in HPARAM_OPTIONS if o.inverted] == ["anneal_lr"]


def test_errors_name_the_flag():
    assert flag_names("num_epochs must be >= 1, got 0") == "--epochs must be >= 1, got 0"
    assert flag_names("backend must be one of mjx, c") == "--physics must be one of mjx, c"
    assert flag_names("unknown policy 'x'") == "unknown policy 'x'"
