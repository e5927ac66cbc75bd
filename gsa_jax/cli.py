"""`gsa COMMAND [options]`: the project's commands behind one entry point. Each command is one module of
gsa_jax/commands/ (its docstring's first line is its line in `gsa --help`); `python -m gsa_jax.X` runs the same
(`profile` aside: a module of that name would shadow the standard library's).

Exit status: 0 done, 2 bad input (one line on stderr, `gsa COMMAND: error: ...`), 130 interrupted; a command's
own further statuses are in its --help."""

import ast
import importlib.util
import sys

COMMANDS = {  # command -> its module under gsa_jax.commands
    "train": "train", "sweep": "sweep", "answer": "answer", "score": "score", "plot": "plot", "inspect": "inspect_run",
    "export": "export", "deploy": "deploy", "verify": "verify", "robustness": "robustness", "tune": "tune",
    "bench": "bench", "profile": "profile_parts", "render": "render", "extract": "extract", "quote": "quote",
    "published": "published",
}


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
