"""The library's public functions and methods say their types: every function whose name does not start with '_'
(top level, or a method of a public class) annotates each parameter (self and cls aside) and its return."""

import ast
import glob
import os

ROOT = os.path.join(os.path.dirname(__file__), "..")
MODULES = ("gsa_jax/algorithm/*.py", "gsa_jax/deployment/*.py", "gsa_jax/analysis/*.py", "gsa_jax/analysis/*/*.py",
           "gsa_jax/inspect/*.py", "gsa_jax/commands/*.py", "gsa_jax/cli.py", "gsa_jax/errors.py",
           "gsa_jax/running/*.py", "gsa_jax/benchmark/*.py", "gsa_jax/orchestration/*.py", "gsa_jax/verify/*.py", "envs/dmc/*.py",
           "envs/__init__.py", "envs/registry.py", "envs/families/*.py", "envs/randomization.py", "envs/build.py",
           "envs/names.py", "envs/task.py", "envs/task_checks.py", "envs/physics.py", "envs/mujoco_c.py", "envs/c_backend.py",
           "envs/c_hosts.py", "envs/c_post_constraint.py",
           "envs/task_mjx.py")
NOT_YET = ()  # files of MODULES still to be annotated


def files():
    """The files MODULES names, less NOT_YET (paths relative to the repository root)."""
    found = sorted({os.path.relpath(p, ROOT) for m in MODULES for p in glob.glob(os.path.join(ROOT, m))})
    return [f for f in found if f.replace(os.sep, "/") not in NOT_YET]


def unannotated(source):
    """['name' or 'Class.name'] of the public functions of a module's source missing a parameter's or the return's
    annotation."""
    tree = ast.parse(source)
    out = []

    def visit(body, owner=None):
        for node in body:
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                visit(node.body, node.name)
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not node.name.startswith("_"):
                a = node.args
                params = a.posonlyargs + a.args + a.kwonlyargs + [p for p in (a.vararg, a.kwarg) if p]
                if owner and params and params[0].arg in ("self", "cls"):
                    params = params[1:]
                if node.returns is None or any(p.annotation is None for p in params):
                    out.append(f"{owner}.{node.name}" if owner else node.name)

    visit(tree.body)
    return out


def test_every_public_function_is_annotated():
    assert len(files()) > 20
    missing = {f: names for f in files() for names in [unannotated(open(os.path.join(ROOT, f)).read())] if names}
    assert not missing, "public functions without annotations: " + "; ".join(f"{f}: {', '.join(n)}" for f, n in missing.items())


def test_the_check_sees_a_missing_annotation():
    source = ("class A:\n    def f(self, x: int):\n        pass\n\n    def ok(self) -> None:\n        pass\n\n"
              "def g(y) -> int:\n    return y\n\ndef _h(z):\n    pass\n\ndef k(self, w: int) -> None:\n    pass\n")
    assert unannotated(source) == ["A.f", "g", "k"]
