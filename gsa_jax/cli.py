"""`gsa COMMAND [options]`: the project's commands behind one entry point. Each command is one module of
gsa_jax/commands/ (its docstring's first line is its line in `gsa --help`); `python -m gsa_jax.X` runs the same
(`profile` aside: a module of that name would shadow the standard library's).

Exit status: 0 done, 2 bad input (one line on stderr, `gsa COMMAND: error: ...`), 130 interrupted; a command's
own further statuses are in its --help."""

import argparse
import ast
import importlib.util
import json
import os
import sys
from typing import Callable

from gsa_jax.errors import EXIT_DISK_FULL, UserError

COMMANDS = {  # command -> its module under gsa_jax.commands
    "train": "train", "sweep": "sweep", "answer": "answer", "score": "score", "plot": "plot", "inspect": "inspect_run",
    "export": "export", "deploy": "deploy", "verify": "verify", "robustness": "robustness", "tune": "tune",
    "bench": "bench", "profile": "profile_parts", "render": "render", "extract": "extract", "quote": "quote",
    "published": "published",
}


class CommandParser(argparse.ArgumentParser):
    """An argument parser whose errors are one UserError line (argparse prints its usage block otherwise), and which
    checks the output paths it parsed (`outputs`: the dests of the options naming what the command writes) with
    check_output, so every command that writes follows one rule before it loads or compiles anything. A command that
    runs JAX programs sets `runs_jax`: a command line parsed (not --help, which exits first) then loads from a
    compilation cache the user set (JAX_COMPILATION_CACHE_DIR) quietly (gsa_jax.running.xla_cache; the command
    imports JAX itself only past its parser, so that --help loads no JAX)."""

    outputs: tuple = ("out",)
    runs_jax: bool = False

    def error(self, message: str) -> None:
        raise UserError(f"{message} (see {self.prog} --help)")

    def parse_known_args(self, args: "list | None" = None, namespace: "argparse.Namespace | None" = None) -> tuple:
        parsed, rest = super().parse_known_args(args, namespace)
        for dest in self.outputs:  # as typed: a default (runs/...) is the command's own to create
            if getattr(parsed, dest, None) != self.get_default(dest):
                check_output(getattr(parsed, dest, None), "--" + dest.replace("_", "-"))
        if self.runs_jax and os.environ.get("JAX_COMPILATION_CACHE_DIR"):
            from gsa_jax.running import xla_cache

            xla_cache.quiet_cache_loads()
        return parsed, rest


def check_output(path: str | None, flag: str) -> None:
    """UserError (one line) where an output path typed on a command line lies in a folder that does not exist outside
    the working directory: a command never creates a mistyped tree of folders (at the root, say). Missing folders
    inside the working directory (runs/ in a fresh clone) are created here, for every command alike."""
    if path is None:
        return
    parent, here = os.path.dirname(os.path.abspath(path)), os.path.abspath(os.getcwd())
    if os.path.isdir(parent):
        return
    if os.path.commonpath([parent, here]) != here:
        raise UserError(f"{flag} {path!r} is in a folder that does not exist ({parent}); create it first or choose "
                        "another (only folders inside the working directory are created)")
    try:
        os.makedirs(parent, exist_ok=True)
    except OSError as e:
        raise UserError(f"{flag} {path!r}: its folder {parent} cannot be created ({e.strerror or e})") from None


def whole_number(text: str) -> int:
    """An option's integer as people write counts: 1000000, 1_000_000 or 1e6 (argparse type; 1.5e0 is refused)."""
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text.replace("_", ""))
    except ValueError:
        value = float("nan")
    if not value.is_integer():
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number (write e.g. 1000000, 1_000_000 or 1e6)")
    return int(value)


def command_parser(name: str, doc: str) -> CommandParser:
    """The parser of `gsa NAME`: its description is the first paragraph of the command's docstring."""
    from gsa_jax.running.runinfo import cli_description

    return CommandParser(prog=f"gsa {name}", description=cli_description(doc))


def read_saved(path: str, error: type, options_of: Callable = dict) -> tuple:
    """(the settings a run, sweep or evaluation saved in the JSON file `path`, options_of(them)); an unreadable
    record, or one options_of cannot read, is `error` (a UserError class) in one line."""
    try:
        with open(path) as f:
            saved = json.load(f)
        return saved, options_of(saved)
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise error(f"{path} is not a gsa_jax record to continue ({type(e).__name__}: {e})") from None


def options_over_saved(parser: argparse.ArgumentParser, argv: list | None, path: str, options_of: Callable,
                       error: type) -> tuple:
    """(argv parsed over the settings saved in the JSON file `path`, the saved record): options_of(record) gives
    option values (dest -> value) that replace the parser's defaults, so the options typed win and the rest
    continue as saved (read_saved: an unreadable record is `error` in one line)."""
    saved, defaults = read_saved(path, error, options_of)
    parser.set_defaults(**defaults)
    return parser.parse_args(argv), saved


def disk_full(e: OSError, intact: str) -> UserError:
    """A full disk (running/checkpoint.py's DiskFullError) as a command's one-line error with exit status 4, naming
    the checkpoint left intact."""
    return UserError(e.describe(intact), exit_status=EXIT_DISK_FULL)


def run_command(name: str, body: Callable[[], int]) -> int:
    """Run a command's body and return its exit status: a UserError is one line on stderr and its status, an
    interrupt 130."""
    try:
        return body()
    except UserError as e:
        print(f"gsa {name}: error: {e}", file=sys.stderr)
        return e.exit_status
    except KeyboardInterrupt:
        print(f"gsa {name}: interrupted", file=sys.stderr)
        return 130


def summary_line(name: str) -> str:
    """A command's line in `gsa --help`: its module docstring's opening words, up to its usage in parentheses or
    the first sentence's end. The docstring is read from the module's source, not imported: `gsa --help` loads no
    command (their imports are JAX's, MuJoCo's, ...)."""
    from gsa_jax.running.runinfo import cli_description

    with open(importlib.util.find_spec(f"gsa_jax.commands.{COMMANDS[name]}").origin, encoding="utf-8") as f:
        text = cli_description(ast.get_docstring(ast.parse(f.read()), clean=False))
    for stop in (" (`gsa ", ". ", ": "):
        text = text.split(stop)[0]
    return text.rstrip(".")


def usage() -> str:
    """`gsa --help`: every command with its line."""
    width = max(map(len, COMMANDS))
    rows = [f"  {name:<{width}}  {summary_line(name)}" for name in COMMANDS]
    return "usage: gsa COMMAND [options]   (gsa COMMAND --help: its options)\n\ncommands:\n" + "\n".join(rows) + "\n"


def main(argv: list | None = None) -> int:
    """`gsa COMMAND ...`: run COMMAND's main on the rest of the command line."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage(), end="")
        return 0 if argv else 2
    if argv[0] not in COMMANDS:
        print(f"gsa: error: unknown command {argv[0]!r}; choose one of {', '.join(COMMANDS)} (see gsa --help)",
              file=sys.stderr)
        return 2
    module = importlib.import_module(f"gsa_jax.commands.{COMMANDS[argv[0]]}")
    return module.main(argv[1:])


if __name__ == "__main__":
    sys.exit(main())
