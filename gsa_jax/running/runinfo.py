"""What every results file records: library versions, git commit, machine."""

import datetime
import json
import os
import platform
import shlex
import subprocess
import sys
from importlib import metadata
from typing import TYPE_CHECKING, Any

from envs.physics import record
from gsa_jax.errors import UserError

if TYPE_CHECKING:  # annotations only: this module loads without JAX
    from envs.families.record import TaskRecord
    from gsa_jax.algorithm.config import Config


def _version(dist):
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def git_commit() -> "str | None":
    """HEAD of the repository this package lives in, with '-dirty' if the tree has uncommitted changes."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=root, capture_output=True, text=True, timeout=10
        )
        return head.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def physics_record(cfg: "Config", task: "TaskRecord") -> dict:
    """Every physics option in force for a Config's task (envs.physics.record of the model of `task`, cfg's task
    record; no MJX env is built)."""
    return record(cfg.physics, task.model())


def run_metadata() -> dict:
    import jax

    from gsa_jax.running.xla_cache import once_options

    return {
        "versions": {
            "jax": jax.__version__,
            "jaxlib": _version("jaxlib"),
            "mujoco": _version("mujoco"),
            "mujoco_mjx": _version("mujoco-mjx"),
            "brax": _version("brax"),
            "numpy": _version("numpy"),
            "python": sys.version.split()[0],
        },
        "git_commit": git_commit(),
        "platform": platform.platform(),
        "devices": [str(d) for d in jax.devices()],
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "xla_compiler_options": {"init_and_evaluation": once_options() or {}},
        "started_at": datetime.datetime.now().isoformat(timespec="seconds"),
    }


def describe_changes(old: Any, new: Any, prefix: str = "") -> str:
    """'a.b: old -> new; ...' for every leaf that differs between two JSON-like dicts ('' if none)."""
    changes = []
    for k in sorted(set(old) | set(new), key=str):
        a, b = old.get(k, "(absent)"), new.get(k, "(absent)")
        if isinstance(a, dict) and isinstance(b, dict):
            inner = describe_changes(a, b, f"{prefix}{k}.")
            if inner:
                changes.append(inner)
        elif a != b:
            changes.append(f"{prefix}{k}: {json.dumps(a)} -> {json.dumps(b)}")
    return "; ".join(changes)


class ResumeRefused(UserError, ValueError):
    """A saved run or sweep differs from the one asked to continue it."""


def check_unchanged(old: dict, new: dict, force: bool, what: str, remedy: str) -> None:
    """The one resume check of runs and sweeps: raise ResumeRefused('<what> (<one-line diff>); <remedy>')
    if the saved record `old` differs from `new` (JSON-like dicts), unless force."""
    diff = describe_changes(old, json.loads(json.dumps(new)))
    if diff and not force:
        raise ResumeRefused(f"{what} ({diff}); {remedy}")


def resume_command(command: str, *flags: str) -> str:
    """The shell command that continues a run or sweep with its saved settings: `gsa <command> <flags>` with the
    `gsa` script installed beside this interpreter, else `<this interpreter> -m gsa_jax.<command> <flags>`; either
    relative to the working directory when it lies under it (e.g. .venv/bin/gsa)."""
    script = os.path.join(os.path.dirname(sys.executable), "gsa")
    words = [script, command] if os.path.isfile(script) else [sys.executable, "-m", f"gsa_jax.{command}"]
    rel = os.path.relpath(words[0])
    if not rel.startswith(".."):
        words[0] = rel if os.sep in rel else os.path.join(".", rel)
    return shlex.join([*words, *flags])


def cli_description(doc: str) -> str:
    """A command's --help description: the first paragraph of its module docstring, whole (a closing ':' that
    introduces the usage block below it becomes '.')."""
    text = " ".join(doc.split("\n\n")[0].split())
    return text[:-1] + "." if text.endswith(":") else text
