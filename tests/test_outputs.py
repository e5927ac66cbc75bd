"""One rule for what every command writes: an output path in a folder that does not exist outside the working directory
is one line before anything loads or compiles, and one inside it has its folders made (gsa_jax.commands.command_line.CommandParser.outputs,
check_output)."""

import argparse
import importlib
import os

import pytest

from gsa_jax.cli import COMMANDS
from gsa_jax.commands.command_line import CommandParser
from gsa_jax.errors import UserError


def parser_of(name: str) -> CommandParser:
    return importlib.import_module(f"gsa_jax.commands.{COMMANDS[name]}").build_parser()


def minimal_argv(parser: argparse.ArgumentParser) -> list:
    """Placeholders for the parser's positional arguments and required options (the rule is checked on parsing)."""
    argv = []
    for action in parser._actions:  # argparse keeps them here
        if not action.option_strings and action.dest != "help":
            argv.append("x")
        elif action.required and action.dest not in parser.outputs:
            argv += [action.option_strings[0], "x"]
    return argv


WRITERS = [name for name in COMMANDS if any(a.dest in parser_of(name).outputs and a.option_strings
                                              for a in parser_of(name)._actions)]


def test_the_commands_that_write_are_all_under_the_rule():
    assert set(WRITERS) >= {"train", "sweep", "answer", "verify", "inspect", "export", "deploy", "robustness", "tune",
                            "plot", "render", "published", "bench", "profile", "extract"}, WRITERS


@pytest.mark.parametrize("name", WRITERS)
def test_an_output_in_a_missing_folder_is_one_line(name, tmp_path):
    parser = parser_of(name)
    dest = next(d for d in parser.outputs if any(a.dest == d for a in parser._actions))
    flag = "--" + dest.replace("_", "-")
    missing = tmp_path / "no" / "such" / "out"
    with pytest.raises(UserError, match=f"{flag} .* is in a folder that does not exist"):
        parser.parse_args(minimal_argv(parser) + [flag, str(missing)])
    assert not (tmp_path / "no").exists()
    parsed = parser.parse_args(minimal_argv(parser) + [flag, str(tmp_path / "out")])  # its last part is created later
    assert getattr(parsed, dest) == str(tmp_path / "out")


@pytest.mark.parametrize("name", WRITERS)
def test_missing_folders_inside_the_working_directory_are_created(name, tmp_path, monkeypatch):
    """runs/ does not exist in a fresh clone: `--out runs/x/out` works there, its folders made before anything runs."""
    parser = parser_of(name)
    dest = next(d for d in parser.outputs if any(a.dest == d for a in parser._actions))
    monkeypatch.chdir(tmp_path)
    parser.parse_args(minimal_argv(parser) + ["--" + dest.replace("_", "-"), os.path.join("runs", "x", "out")])
    assert (tmp_path / "runs" / "x").is_dir() and not (tmp_path / "runs" / "x" / "out").exists()


def test_train_refuses_a_missing_folder_before_it_creates_anything(tmp_path, capsys):
    from gsa_jax.commands.train import main

    assert main(["--out", str(tmp_path / "no" / "run"), "--steps", "1000"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is in a folder that does not exist" in err, err
    assert not (tmp_path / "no").exists()
