"""`gsa`: one entry point lists every command; each command's --help and its `python -m gsa_jax.X` shim work, every
option has a help text, and no help loads JAX, MuJoCo or Matplotlib; a bad option of any command is one line and exit
status 2; counts are written as people write them (1e6)."""

import argparse
import importlib
import os
import subprocess
import sys
import tomllib

import pytest

from gsa_jax import cli
from gsa_jax.cli import COMMANDS
from gsa_jax.commands.command_line import whole_number

ROOT = os.path.join(os.path.dirname(__file__), "..")
SHIMS = {  # python -m <module> -> the command it runs
    **{f"gsa_jax.{name}": name for name in ("train", "sweep", "answer", "score", "plot", "export", "deploy",
                                             "robustness", "tune", "bench", "render", "extract", "quote", "published")},
    "gsa_jax.inspect": "inspect", "gsa_jax.verify": "verify",
}


def test_gsa_help_lists_every_command_with_one_line(capsys):
    """`gsa --help` names every command of gsa_jax/commands/ once (command_line: what they share), each with a line of words."""
    modules = {n[:-3] for n in os.listdir(os.path.join(ROOT, "gsa_jax", "commands")) if n.endswith(".py")} - {"__init__", "command_line"}
    assert set(COMMANDS.values()) == modules
    assert cli.main(["--help"]) == 0
    lines = capsys.readouterr().out.splitlines()
    for name in COMMANDS:
        line = next(row for row in lines if row.split()[:1] == [name])
        assert len(line.split()) >= 4 and len(line) < 120, line


def test_the_console_script_is_the_front_door():
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        target = tomllib.load(f)["project"]["scripts"]["gsa"]
    module, _, name = target.partition(":")
    assert getattr(importlib.import_module(module), name) is cli.main


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_command_has_help(name, capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main([name, "--help"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: gsa {name} ")


def test_every_option_of_every_command_has_a_help_text():
    """Each command's parser (the module's build_parser, as `gsa NAME` builds it): every option but -h says what it
    does (a worker-only option hidden with argparse.SUPPRESS counts as said), and the help formats (%(default)s)."""
    missing = []
    for name, module in COMMANDS.items():
        parser = importlib.import_module(f"gsa_jax.commands.{module}").build_parser()
        parser.format_help()
        missing += [f"gsa {name} {'/'.join(a.option_strings) or a.dest}" for a in parser._actions
                    if not isinstance(a, argparse._HelpAction) and not (a.help or "").strip()]
    assert not missing, f"options without a help text: {', '.join(missing)}"


def test_no_help_loads_jax_mujoco_or_matplotlib():
    """`gsa --help` and every `gsa COMMAND --help`, in one fresh process: none of them imports JAX, MuJoCo, Matplotlib,
    SciPy or Brax (a command imports them past its parser), and each exits 0."""
    code = ("import contextlib, io, sys\nfrom gsa_jax import cli\nstatus = {}\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    status['gsa'] = cli.main(['--help'])\n"
            "    for name in cli.COMMANDS:\n"
            "        try:\n"
            "            cli.main([name, '--help'])\n"
            "        except SystemExit as stop:\n"
            "            status[name] = stop.code\n"
            "print([m for m in ('jax', 'mujoco', 'matplotlib', 'scipy', 'brax') if m in sys.modules],"
            " {k: v for k, v in status.items() if v != 0}, len(status))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["[]", "{}", str(len(COMMANDS) + 1)], done.stdout


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_bad_option_of_every_command_is_one_line_and_exit_2(name, capsys):
    assert cli.main([name, "--no-such-option"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"gsa {name}: error: ") and f"gsa {name} --help" in err, err


def test_an_unknown_command_is_one_line_and_exit_2(capsys):
    assert cli.main(["trian"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown command 'trian'" in err and "train" in err


@pytest.mark.parametrize("module", sorted(m for m in SHIMS if m not in ("gsa_jax.inspect", "gsa_jax.verify")))
def test_every_python_m_shim_runs_its_command(module):
    assert importlib.import_module(module).main is importlib.import_module(f"gsa_jax.commands.{COMMANDS[SHIMS[module]]}").main


@pytest.mark.parametrize("argv", [["gsa_jax", "--help"], ["gsa_jax.cli", "export", "--help"], ["gsa_jax.export", "--help"],
                                  ["gsa_jax.inspect", "--help"], ["gsa_jax.verify", "--help"]])
def test_python_m_forms_in_a_new_process(argv):
    done = subprocess.run([sys.executable, "-m", *argv], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert done.returncode == 0, done.stderr
    name = argv[1] if argv[0] == "gsa_jax.cli" else SHIMS.get(argv[0])
    assert done.stdout.startswith(f"usage: gsa {name} " if name else "usage: gsa COMMAND"), done.stdout[:200]


def test_a_count_is_written_as_people_write_it():
    assert whole_number("1e6") == whole_number("1_000_000") == whole_number("1000000") == 1_000_000
    assert whole_number("2.5e3") == 2500
    for text in ("1.5e0", "ten", "nan", "inf"):
        with pytest.raises(argparse.ArgumentTypeError, match="is not a whole number"):
            whole_number(text)


@pytest.mark.parametrize("name", ["train", "answer"])
def test_steps_take_1e6_and_refuse_a_fraction_in_one_line(name, capsys):
    module = importlib.import_module(f"gsa_jax.commands.{name}")
    required = ["--env", "hopper"] if name == "answer" else []
    assert module.build_parser().parse_args(required + ["--steps", "1e6"]).steps == 1_000_000
    assert module.main(required + ["--steps", "1.5e0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'1.5e0' is not a whole number" in err, err


def test_the_physics_option_has_one_name_in_every_command():
    """train, answer, bench and profile call the physics backend --physics; none calls it --backend."""
    for name in COMMANDS:
        options = {o for a in importlib.import_module(f"gsa_jax.commands.{COMMANDS[name]}").build_parser()._actions
                   for o in a.option_strings}
        assert "--backend" not in options, name
        if name in ("train", "answer", "bench", "profile"):
            assert "--physics" in options, name


def test_the_wrapper_maps_errors_and_interrupts_to_exit_statuses(capsys):
    """A UserError is its exit status and one line naming the command; Ctrl-C is 130; any other error is not
    swallowed (a traceback, as for a bug)."""
    from gsa_jax.errors import run_command
    from gsa_jax.errors import UserError

    def fail(error):
        def body():
            raise error
        return body

    assert run_command("train", fail(UserError("bad --steps"))) == 2
    assert capsys.readouterr().err == "gsa train: error: bad --steps\n"
    assert run_command("sweep", fail(UserError("the disk is full", exit_status=4))) == 4
    assert capsys.readouterr().err == "gsa sweep: error: the disk is full\n"
    assert run_command("answer", fail(KeyboardInterrupt())) == 130
    assert capsys.readouterr().err == "gsa answer: interrupted\n"
    with pytest.raises(ZeroDivisionError):
        run_command("plot", fail(ZeroDivisionError()))
    assert run_command("score", lambda: 0) == 0


def test_render_says_in_one_line_what_mujocos_renderer_refuses(monkeypatch, tmp_path, capsys):
    """MuJoCo's renderer refuses an unknown camera or a size beyond its framebuffer with a ValueError: one line and
    exit 2, as every other bad input (the renderer itself stands in here: it needs an OpenGL library)."""
    from gsa_jax.commands import render

    def refuse(*args):
        raise ValueError("The camera 'nosuch' does not exist.")

    monkeypatch.setattr(render, "render_scene", refuse)
    assert render.main(["inverted_double_pendulum", "--out", str(tmp_path / "x.png"), "--camera", "nosuch"]) == 2
    err = capsys.readouterr().err
    assert err == "gsa render: error: The camera 'nosuch' does not exist.\n"


def test_train_on_a_cpu_names_the_faster_physics_where_the_task_has_it(capsys):
    """MJX stays the default backend; on a CPU, for a task MuJoCo C steps, gsa train says --physics c is the fast
    path (and nothing for a task MuJoCo C does not step, or for the C backend itself)."""
    import envs
    from envs.physics import Physics
    from gsa_jax.algorithm.config import Config
    from gsa_jax.commands.train import note_physics

    note_physics(Config(env="Hopper-v5"), envs.resolve("Hopper-v5"))
    assert "--physics c steps this task in MuJoCo C" in capsys.readouterr().err
    for cfg in (Config(env="inverted_double_pendulum"), Config(env="Hopper-v5", physics=Physics(backend="c"))):
        note_physics(cfg, envs.resolve(cfg.env))
        assert capsys.readouterr().err == ""
