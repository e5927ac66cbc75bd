"""What every command shares: its parser (one-line argparse errors, output paths checked before anything loads), the
option types people write, and options continued from a saved record. The commands of gsa_jax/commands/ build on it;
gsa_jax.cli only routes a command line to them."""

import argparse
import json
import os
from typing import Callable

from gsa_jax.errors import UserError


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


def read_saved(path: str, error: type, options_of: Callable = dict, kind: str | None = None) -> tuple:
    """(the settings a run, sweep or evaluation saved in the JSON file `path`, options_of(them)); a record of a
    versioned kind (running.formats.KINDS) read into the current layout. An unreadable record, or one options_of
    cannot read, is `error` (a UserError class) in one line; one of a newer format is a FormatError."""
    from gsa_jax.running.formats import read_json

    try:
        if kind is None:
            with open(path) as f:
                saved = json.load(f)
        else:
            saved = read_json(path, kind)
        return saved, options_of(saved)
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise error(f"{path} is not a gsa_jax record to continue ({type(e).__name__}: {e})") from None


def options_over_saved(parser: argparse.ArgumentParser, argv: list | None, path: str, options_of: Callable,
                       error: type, kind: str | None = None) -> tuple:
    """(argv parsed over the settings saved in the JSON file `path`, the saved record): options_of(record) gives
    option values (dest -> value) that replace the parser's defaults, so the options typed win and the rest
    continue as saved (read_saved: an unreadable record is `error` in one line)."""
    saved, defaults = read_saved(path, error, options_of, kind)
    parser.set_defaults(**defaults)
    return parser.parse_args(argv), saved
