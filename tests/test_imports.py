"""The package's layers, as folders: every gsa_jax module imports only from its own layer or lower ones (the
user-error base class, gsa_jax/errors.py, below all of them; the commands, gsa_jax/commands/ with the entry point
and the `python -m` shims at the top level, above all of them; orchestration, what trains many runs as jobs, just
below them), no analysis module imports directly what trains (TRAINING), and the result-reading and deployment modules
load without JAX (reading results and running a controller must not pay JAX's import or need it installed as it
trains)."""

import ast
import glob
import os
import subprocess
import sys

ROOT = os.path.join(os.path.dirname(__file__), "..", "gsa_jax")
LAYERS = ("errors", "algorithm", "running", "deployment", "verify", "analysis", "benchmark", "orchestration",
          "commands")  # lowest first
# what trains or sets up training (the run driver, the programs, sweeps and single runs, their stores, workers, compile
# cache and tuning budgets, PPO itself): analysis reads and judges results and imports none of it directly (what it
# reaches through a lower layer's function-level import is that layer's); what trains many runs as jobs is orchestration's
TRAINING = ("running.driver", "running.programs", "running.single", "running.store", "running.supervise",
            "running.sweeps", "running.tuning", "running.xla_cache", "algorithm.ppo", "algorithm.ppo_update",
            "algorithm.run_parts")
JAX_FREE = ("algorithm.kinds", "algorithm.subpolicies", "algorithm.partitions", "deployment.numpy_policy", "deployment.cells", "deployment.export_onnx", "deployment.export_c", "deployment.gymnasium_rollout",
            "deployment.shifts", "deployment.evaluation", "running.runinfo", "running.metrics", "running.curve",
            "running.tensorboard", "analysis.sweeps.stats", "analysis.sweeps.results", "analysis.sweeps.tables",
            "analysis.sweeps.figures", "analysis.sweep_report", "analysis.verdicts.grid", "analysis.verdicts.answering", "analysis.robustness.retention",
            "analysis.robustness.retention_eval", "analysis.robustness.retention_stats", "analysis.robustness.retention_plots",
            "analysis.robustness.shift_rows", "analysis.robustness.paired", "analysis.robustness.fairness", "running.trained", "running.formats",
            "commands.plot",
            "commands.robustness", "commands.deploy", "plot", "robustness", "deploy", "cli", "errors")


def modules():
    """{dotted name below gsa_jax: path} of every module at any depth, commands (top level and inspect/) included."""
    paths = glob.glob(os.path.join(ROOT, "**", "*.py"), recursive=True)
    found = {}
    for p in paths:
        rel = os.path.relpath(p, ROOT)[:-3].replace(os.sep, ".")
        if not rel.endswith("__init__") and rel != "__main__":
            found[rel] = p
    return found


def layer(name):
    """A module's layer: its folder, 'errors' for gsa_jax/errors.py, or 'commands' for the rest of the top level and
    for a package's `python -m` shim (inspect/__main__, verify/__main__)."""
    head = name.split(".")[0]
    if name.endswith("__main__"):
        return "commands"
    return head if head in LAYERS and ("." in name or head == "errors") else "commands"


def gsa_imports(path):
    """The gsa_jax modules (dotted below gsa_jax) a file imports, anywhere in it ('module.name' for a name imported
    from a module)."""
    deps = set()
    for n in ast.walk(ast.parse(open(path).read())):
        if isinstance(n, ast.ImportFrom) and n.module and (n.module + ".").startswith("gsa_jax."):
            base = n.module[len("gsa_jax."):] if n.module != "gsa_jax" else ""
            deps.update(f"{base}.{a.name}".strip(".") for a in n.names)  # a module, or a name in one
        elif isinstance(n, ast.Import):
            deps.update(a.name[len("gsa_jax."):] for a in n.names if a.name.startswith("gsa_jax."))
    return deps


def test_every_module_lives_in_a_layer_folder_and_imports_only_downward():
    mods = modules()
    assert {layer(m) for m in mods} == set(LAYERS), sorted({layer(m) for m in mods})
    rank = {name: i for i, name in enumerate(LAYERS)}
    upward = [f"{m} ({layer(m)}) imports {d} ({layer(d)})" for m, p in sorted(mods.items())
              for d in sorted(gsa_imports(p)) if rank[layer(d)] > rank[layer(m)]]
    assert not upward, "; ".join(upward)
    unknown = sorted(d for p in mods.values() for d in gsa_imports(p)
                     if d not in mods and d not in LAYERS and d.rsplit(".", 1)[0] not in mods)
    assert not unknown, f"imports of modules that do not exist: {unknown}"


def test_envs_imports_nothing_of_gsa_jax():
    """envs/ sits below gsa_jax/: none of its modules imports gsa_jax (even inside a function); the user-error base
    both raise is envs/errors.py, which gsa_jax/errors.py re-exports, and importing it loads no other module of envs/."""
    root = os.path.join(os.path.dirname(__file__), "..", "envs")
    up = []
    for path in sorted(glob.glob(os.path.join(root, "**", "*.py"), recursive=True)):
        for n in ast.walk(ast.parse(open(path).read())):
            names = ([n.module or ""] if isinstance(n, ast.ImportFrom) else
                     [a.name for a in n.names] if isinstance(n, ast.Import) else [])
            up += [f"{os.path.relpath(path, root)} imports {m}" for m in names if m.split(".")[0] == "gsa_jax"]
    assert not up, "; ".join(up)
    code = ("import sys\nfrom gsa_jax.errors import UserError\nloaded = sorted(m for m in sys.modules if m.startswith('envs'))\n"
            "from envs.task import TaskError\nprint([loaded, issubclass(TaskError, UserError)])")
    assert imported(code) == [["envs", "envs.errors", "envs.mjx_import"], True]


def test_analysis_imports_nothing_that_trains():
    """analysis/ is statistics, tables and decisions: none of its modules imports directly (even inside a function)
    what trains a run (TRAINING); the answer loop that trains its rounds lives in orchestration/."""
    mods = modules()
    trains = lambda d: any(d == t or d.startswith(t + ".") for t in TRAINING)  # noqa: E731
    wrong = [f"{m} imports {d}" for m, p in sorted(mods.items()) if layer(m) == "analysis"
             for d in sorted(gsa_imports(p)) if trains(d)]
    assert not wrong, "; ".join(wrong)
    assert all(t in mods for t in TRAINING), [t for t in TRAINING if t not in mods]


def test_analysis_folders_import_only_sweeps_and_nothing_imports_the_sweep_report():
    """analysis/: sweeps/ (results and their statistics) at the bottom imports no other folder of analysis/; verdicts/,
    robustness/ and quoting/ import sweeps/ and not each other; sweep_report (every table and figure of a sweep) sits
    above them all."""
    mods = modules()
    folder = lambda name: name.split(".")[1] if name.startswith("analysis.") else None  # noqa: E731
    allowed = {"sweeps": set(), "verdicts": {"sweeps"}, "robustness": {"sweeps"}, "quoting": {"sweeps"}}
    wrong = [f"{m} imports {d}" for m, p in sorted(mods.items()) if folder(m) in allowed
             for d in sorted(gsa_imports(p)) if folder(d) not in (None, folder(m)) and folder(d) not in allowed[folder(m)]]
    assert not wrong, "; ".join(wrong)
    assert set(allowed) == {folder(m) for m in mods if m.count(".") == 2 and folder(m)}, "a folder of analysis/ not placed"


def test_reading_and_deployment_modules_import_without_jax():
    code = ("import sys; import " + ", ".join(f"gsa_jax.{m}" for m in JAX_FREE)
            + "; loaded = [m for m in ('jax', 'brax', 'mujoco.mjx') if m in sys.modules]; assert not loaded, loaded")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300)


def test_nothing_below_the_commands_names_a_command_module_and_cli_only_routes():
    """Below the command layer no module names a command's module in a string (a `python -m gsa_jax.sweep` spawn, an
    importlib load): worker processes run their own layer's entry points (gsa_jax.orchestration.sweep_job,
    gsa_jax.benchmark.workers); and gsa_jax/cli.py only routes a command line to a command (what the commands share
    is gsa_jax/commands/command_line.py)."""
    mods = modules()
    named = {f"gsa_jax.{m}" for m in mods if layer(m) == "commands"} | {"gsa_jax.commands"}
    wrong = [f"{m}: {n.value!r}" for m, p in sorted(mods.items()) if layer(m) != "commands"
             for n in ast.walk(ast.parse(open(p).read())) if isinstance(n, ast.Constant) and isinstance(n.value, str)
             and (n.value in named or n.value.startswith("gsa_jax.commands."))]
    assert not wrong, "; ".join(wrong)
    tree = ast.parse(open(os.path.join(ROOT, "cli.py")).read())
    defined = {n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    assert defined == {"summary_line", "usage", "main"}, defined


def imported(code: str, **environ) -> list:
    """The last line a fresh Python process running `code` (with `environ` added to its environment) prints, as a
    list (it prints one)."""
    out = subprocess.run([sys.executable, "-c", code], check=True, timeout=300, capture_output=True, text=True,
                         env={**os.environ, **environ}).stdout
    return eval(out.strip().splitlines()[-1])


def test_mjx_imports_without_its_warp_backend_and_warp_stays_importable():
    """envs/mjx_import.py: after `import envs`, mujoco.mjx loads as where warp-lang is not installed (no MuJoCo Warp
    module, WARP_INSTALLED False), the hook leaves sys.meta_path, and `import warp` itself still works where the
    playground extra installed it (the test extras do); a process that imported warp first, or that sets
    MJX_GPU_DEFAULT_WARP=true, keeps MJX's warp backend."""
    import importlib.util

    has_warp = importlib.util.find_spec("warp") is not None
    after_envs = imported(
        "import sys, importlib.util, envs, mujoco.mjx\nfrom mujoco.mjx import warp\n"
        "hooks = [f for f in sys.meta_path if type(f).__module__ == 'envs.mjx_import']\n"
        "w = importlib.util.find_spec('warp') is not None and __import__('warp').__name__\n"
        "print([warp.WARP_INSTALLED, 'mujoco.mjx.third_party.mujoco_warp' in sys.modules, len(hooks), w])")
    assert after_envs == [False, False, 0, "warp" if has_warp else False]
    if has_warp:
        first = imported("import warp, envs, mujoco.mjx\nfrom mujoco.mjx import warp as w\nprint([w.WARP_INSTALLED])")
        asked = imported("import envs, mujoco.mjx\nfrom mujoco.mjx import warp as w\nprint([w.WARP_INSTALLED])",
                         MJX_GPU_DEFAULT_WARP="true")
        assert first == [True] and asked == [True]
