"""A task's name is resolved to its record at the edge, and code below asks the record (a test that reads the code,
with ast).

- No `isinstance` on a family: no isinstance(x, C) where C (or one of a tuple's) is a record class defined in
  envs/families/, and no comparison of a `.family`, outside envs/registry.py and envs/families/. Behaviour that
  differs by family is a method or field of the record (envs/families/record.py's TaskRecord).
- No module takes a task name below the command layer: calls of the registry's name lookups (LOOKUPS: envs.X(...),
  registry.X(...), mujoco_c.X(...), or X imported from envs, envs.registry or envs.mujoco_c) appear only in the
  command layer (gsa_jax/<command>.py, gsa_jax/commands/), in envs/registry.py, or in a module or folder of ALLOWED,
  each with the reason it still looks a name up.
"""

import ast
import glob
import os

ROOT = os.path.join(os.path.dirname(__file__), "..")
FAMILY_MODULES = ("envs/registry.py", "envs/families/")
LOOKUP_MODULES = ("envs", "envs.registry", "envs.mujoco_c")
LOOKUPS = {"resolve", "check_name", "check_task", "is_name", "resolve_task", "task_source",
           "has_c_backend", "default_episode_length", "max_return", "task_model", "action_size", "observation_size",
           "action_bounds", "control_range", "task_randomize", "make_c", "observation_layout"}
ALLOWED = {  # module -> why it still looks a name up: a library entry that takes a name, or the one reader of a kind
    # of file that names its task (where that name becomes the record code below is handed)
    "gsa_jax/running/tasks.py": "a Config names its task (config.json and experiment files write it so): task_of is "
                                "the running layer's one way from that name to the record the programs build their "
                                "environments from (the algorithm is handed the record or the environments)",
    "envs/build.py": "envs.make, make_base, check_backend, check_randomize, as_gymnasium: the library's entry, taking "
                     "a name or a record (resolve() returns a record as it is); make resolves once and passes it on",
    "envs/mujoco_c.py": "make_c(name), observation_layout(name): the library's entry to plain MuJoCo C by name",
    "gsa_jax/deployment/numpy_policy.py": "exported controller files name their task: controller_task(arrays) is where "
                                          "that name becomes the record (evaluation, export, verify, robustness ask "
                                          "it); load(path, task=NAME) is the library's entry",
    "gsa_jax/deployment/shifts.py": "the 'simulator' shift runs the same robot in the other family's task, named by "
                                    "OTHER_SIMULATOR",
    "gsa_jax/running/spec.py": "experiment files name their tasks: check_spec checks each name where the file is read",
    "gsa_jax/running/tuning.py": "tuning files name their task: checked where the file is read",
    "gsa_jax/analysis/sweeps/results.py": "result files (tidy CSV rows, sweep.json, answer.json) name their "
                                          "tasks: task_records is where analysis turns those names into records",
}


def sources() -> dict:
    """{path relative to the root: source} of every module of gsa_jax/ and envs/."""
    paths = glob.glob(os.path.join(ROOT, "gsa_jax", "**", "*.py"), recursive=True)
    paths += glob.glob(os.path.join(ROOT, "envs", "**", "*.py"), recursive=True)
    return {os.path.relpath(p, ROOT).replace(os.sep, "/"): open(p).read() for p in sorted(paths)}


def family_classes() -> set:
    """The names of the classes defined in envs/families/ (the records)."""
    return {node.name for path, source in sources().items() if path.startswith("envs/families/")
            for node in ast.walk(ast.parse(source)) if isinstance(node, ast.ClassDef)}


def tail(node: ast.AST) -> str:
    """The last part of a name or attribute (registry.Definition -> Definition), else ''."""
    return node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else ""


def family_checks(source: str, classes: set) -> list:
    """[line] of isinstance calls on a family's class and of comparisons of a `.family` in a module's source."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call) and tail(node.func) == "isinstance" and len(node.args) == 2:
            kinds = node.args[1].elts if isinstance(node.args[1], ast.Tuple) else [node.args[1]]
            if any(tail(k) in classes for k in kinds):
                out.append(node.lineno)
        elif isinstance(node, ast.Compare) and any(tail(x) == "family" and isinstance(x, ast.Attribute)
                                                   for x in [node.left, *node.comparators]):
            out.append(node.lineno)
    return out


def lookups(source: str) -> list:
    """[(line, name)] of the calls of a name lookup (LOOKUPS) in a module's source: envs.X(...), registry.X(...),
    mujoco_c.X(...), or X(...) where X was imported from one of LOOKUP_MODULES."""
    tree = ast.parse(source)
    imported = {a.asname or a.name for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
                and node.module in LOOKUP_MODULES for a in node.names if a.name in LOOKUPS}
    out = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Attribute) and f.attr in LOOKUPS and isinstance(f.value, ast.Name) \
                and f.value.id in ("envs", "registry", "mujoco_c"):
            out.append((node.lineno, f.attr))
        elif isinstance(f, ast.Name) and f.id in imported:
            out.append((node.lineno, f.id))
    return out


def is_edge(path: str) -> bool:
    """Whether a module is of the command layer (gsa_jax/<command>.py, gsa_jax/commands/) or the registry."""
    top = path.count("/") == 1 and path.startswith("gsa_jax/") and not path.endswith("__init__.py")
    return top or path.startswith("gsa_jax/commands/") or path == "envs/registry.py"


def test_no_isinstance_on_a_family_outside_the_registry():
    classes = family_classes()
    assert {"TaskRecord", "Definition", "BraxVariant", "PlaygroundAdapted", "UserEnv"} <= classes
    found = [f"{path}:{line}" for path, source in sources().items() if not path.startswith(FAMILY_MODULES)
             for line in family_checks(source, classes)]
    assert not found, f"family told apart outside the registry (ask the record instead): {', '.join(found)}"


def covers(key: str, path: str) -> bool:
    """Whether ALLOWED's key (a module, or a folder ending in '/') covers the module at path."""
    return path == key or (key.endswith("/") and path.startswith(key))


def test_task_names_are_looked_up_only_at_the_edge():
    below = {path: source for path, source in sources().items()
             if not is_edge(path) and not any(covers(key, path) for key in ALLOWED)}
    found = [f"{path}:{line} {name}" for path, source in below.items() for line, name in lookups(source)]
    assert not found, f"task names looked up below the command layer (pass the record down): {', '.join(found)}"
    looking = [path for path, source in sources().items() if lookups(source)]
    stale = [key for key in ALLOWED if not any(covers(key, path) for path in looking)]
    assert not stale, f"ALLOWED names places that look no name up: {stale}"


def test_the_checks_see_what_they_look_for():
    both = {"Definition", "UserEnv"}
    assert family_checks("isinstance(r, registry.Definition)\nisinstance(r, (int, UserEnv))\n", both) == [1, 2]
    assert family_checks("r.family in ('brax',)\nx == r.family\nisinstance(r, int)\n", both) == [1, 2]
    source = ("import envs\nfrom envs.registry import action_size as size\nenvs.resolve(n)\nsize(n)\n"
              "record.action_size()\n")
    assert sorted(lookups(source)) == [(3, "resolve"), (4, "size")]
    assert is_edge("gsa_jax/train.py") and is_edge("gsa_jax/commands/train.py")
    assert not is_edge("gsa_jax/running/single.py") and not is_edge("gsa_jax/__init__.py")
