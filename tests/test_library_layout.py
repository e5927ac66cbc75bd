"""docs/library.md's layout names every module of the package and of envs/, and names no module that is gone."""

import glob
import os
import re

ROOT = os.path.join(os.path.dirname(__file__), "..")


def layout() -> str:
    """The layout block of docs/library.md: the fenced block that starts with the package folder."""
    lines = open(os.path.join(ROOT, "docs", "library.md")).read().split("\n")
    fences = [i for i, line in enumerate(lines) if line.startswith("```")]
    blocks = ["\n".join(lines[a + 1:b]) for a, b in zip(fences[::2], fences[1::2])]
    return next(b for b in blocks if b.startswith("gsa_jax/"))


def modules() -> list:
    """Paths (relative to the root) of the modules of gsa_jax/ and envs/, __init__.py aside."""
    paths = glob.glob(os.path.join(ROOT, "gsa_jax", "**", "*.py"), recursive=True)
    paths += glob.glob(os.path.join(ROOT, "envs", "**", "*.py"), recursive=True)
    return sorted(os.path.relpath(p, ROOT).replace(os.sep, "/") for p in paths if not p.endswith("__init__.py"))


def named(block: str) -> set:
    """The file and folder names a layout block mentions ('spec.py', 'sweeps/', '__main__.py', ...)."""
    return set(re.findall(r"(?<![/\w.])[A-Za-z_][A-Za-z0-9_]*(?:\.py|/)", block))


def test_the_layout_names_every_module_and_folder():
    names = named(layout())
    missing = [m for m in modules() if os.path.basename(m) not in names
               or any(f"{d}/" not in names for d in m.split("/")[1:-1])]
    assert not missing, f"docs/library.md's layout does not name: {', '.join(missing)}"


def test_the_layout_names_no_module_that_is_gone():
    files = {os.path.basename(m) for m in modules()} | {"__init__.py", "__main__.py"}
    gone = sorted(n for n in named(layout()) if n.endswith(".py") and n not in files)
    assert not gone, f"docs/library.md's layout names modules that do not exist: {', '.join(gone)}"


def test_the_check_sees_a_missing_module():
    assert named("  running/  spec.py (specs) verdicts/ x.py\n") == {"running/", "spec.py", "verdicts/", "x.py"}
