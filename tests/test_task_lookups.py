"""A task's name is resolved to its record at the edge, and code below asks the record (a test that reads the code,
with ast).

- No `isinstance` on a family: no isinstance(x, C) where C (or one of a tuple's) is a record class defined in
  envs/families/, and no comparison of a `.family`, outside envs/registry.py and envs/families/. Behaviour that
  differs by family is a method or field of the record (envs/families/record.py's TaskRecord).
- No module takes a task name below the command layer: calls of the registry's name lookups (LOOKUPS: envs.X(...),
  registry.X(...), mujoco_c.X(...), or X imported from envs, envs.registry or envs.mujoco_c) appear only in the
  command layer (gsa_jax/<command>.py, gsa_jax/commands/), in envs/registry.py, or in a module of ALLOWED, each
  with the reason it still looks a name up.
"""

import ast
import glob
import os

ROOT = os.path.join(os.path.dirname(__file__), "..")
FAMILY_MODULES = ("envs/registry.py", "envs/families/")
LOOKUP_MODULES = ("envs", "envs.registry", "envs.mujoco_c")
LOOKUPS = {"resolve", "task_record", "check_name", "check_task", "is_name", "resolve_task", "task_source",
           "has_c_backend", "default_episode_length", "max_return", "task_model", "action_size", "observation_size",
           "action_bounds", "control_range", "task_randomize", "make_c", "observation_layout"}
ALLOWED = {
    "gsa_jax/algorithm/ppo.py": "Config.__post_init__ and validate resolve cfg.env (Config move in progress, issue "
                                "74 item 4); make_train takes a name, a record or a Task (library API)",
    "envs/build.py": "envs.make / make_base / check_randomize / as_gymnasium take a name or a record (library API; "
                     "resolve() returns a record as it is)",
    "envs/mujoco_c.py": "make_c(name) and observation_layout(name): plain MuJoCo C by name (library API)",
    "envs/gymnasium_wrapper.py": "sizes read through the name helpers on the record it is given",
    "gsa_jax/running/spec.py": "a sweep's spec holds task names (sweep.json); its checks resolve them",
    "gsa_jax/running/single.py": "single.run resolves cfg.env for the run's records",
    "gsa_jax/running/sweeps.py": "a sweep's group resolves its cfg.env for the group's records",
    "gsa_jax/running/runinfo.py": "physics_record resolves cfg.env when no record is given",
    "gsa_jax/running/tuning.py": "a tuning file names its task",
    "gsa_jax/deployment/evaluation.py": "an exported controller names its task (config.json)",
    "gsa_jax/deployment/numpy_policy.py": "an exported controller names its task (config.json)",
    "gsa_jax/deployment/exporting.py": "an exported controller names its task (config.json)",
    "gsa_jax/verify/system.py": "an exported controller names its task (config.json)",
    "gsa_jax/deployment/shifts.py": "the 'simulator' shift maps a task's name to another task's (OTHER_SIMULATOR)",
    "gsa_jax/deployment/gymnasium_rollout.py": "gymnasium's env ids are checked against our ports by name (BRAX_PORTS)",
    "gsa_jax/analysis/controller_scores.py": "result rows name their task",
    "gsa_jax/analysis/answering.py": "result rows name their task",
    "gsa_jax/analysis/retention_eval.py": "result rows name their task",
    "gsa_jax/analysis/results.py": "result rows name their task",
    "gsa_jax/analysis/scoring.py": "result rows name their task",
    "gsa_jax/analysis/figures.py": "result rows name their task",
    "gsa_jax/analysis/retention.py": "result rows name their task",
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


def test_task_names_are_looked_up_only_at_the_edge():
    found = [f"{path}:{line} {name}" for path, source in sources().items() if not is_edge(path) and path not in ALLOWED
             for line, name in lookups(source)]
    assert not found, f"task names looked up below the command layer (pass the record down): {', '.join(found)}"
    stale = [path for path, source in sources().items() if path in ALLOWED and not lookups(source)]
    assert not stale, f"ALLOWED names modules that look no name up: {stale}"


def test_the_checks_see_what_they_look_for():
    assert family_checks("isinstance(r, registry.Definition)\nisinstance(r, (int, UserEnv))\n", {"Definition",
                                                                                               "UserEnv"}) == [1, 2]
    assert family_checks("r.family in ('brax',)\nx == r.family\nisinstance(r, int)\n", {"Definition"}) == [1, 2]
    source = "import envs\nfrom envs.registry import action_size as size\nenvs.resolve(n)\nsize(n)\nrecord.action_size()\n"
    assert sorted(lookups(source)) == [(3, "resolve"), (4, "size")]
    assert is_edge("gsa_jax/train.py") and is_edge("gsa_jax/commands/train.py") and not is_edge("gsa_jax/running/single.py")
