"""The package's layers: every gsa_jax module imports only from its own layer or lower ones, and the
result-reading and deployment modules load without JAX (reading results and running a controller must not
pay JAX's import or need it installed as it trains)."""

import ast
import glob
import os
import subprocess
import sys

ROOT = os.path.join(os.path.dirname(__file__), "..", "gsa_jax")
LAYERS = (  # lowest first
    ("foundation", {"metrics", "checkpoint", "runinfo", "runlock", "xla_cache", "nn", "optim", "normalize", "numpy_policy",
                    "curve", "tensorboard", "stats", "shifts"}),
    ("algorithm", {"episodes", "policies", "retrace", "ppo"}),
    ("running", {"driver", "programs", "spec", "supervise", "store"}),
    ("runs and deployment", {"inspection", "export_c", "export_onnx", "export", "gymnasium_task", "deploy", "render", "extract"}),
    ("tools", {"train", "sweep", "bench", "scoring", "plot", "robustness"}),
)
JAX_FREE = ("numpy_policy", "plot", "stats", "robustness", "deploy", "runinfo", "extract", "metrics", "curve", "export_onnx",
            "export_c", "gymnasium_task", "shifts", "tensorboard")


def gsa_imports(path):
    """The gsa_jax modules a file imports, anywhere in it."""
    deps = set()
    for n in ast.walk(ast.parse(open(path).read())):
        if isinstance(n, ast.ImportFrom) and n.module == "gsa_jax":
            deps.update(a.name for a in n.names)
        elif isinstance(n, ast.ImportFrom) and n.module and n.module.startswith("gsa_jax."):
            deps.add(n.module.split(".")[1])
        elif isinstance(n, ast.Import):
            deps.update(a.name.split(".")[1] for a in n.names if a.name.startswith("gsa_jax."))
    return deps


def test_every_module_imports_only_downward():
    level = {m: i for i, (_, mods) in enumerate(LAYERS) for m in mods}
    modules = {os.path.basename(p)[:-3] for p in glob.glob(os.path.join(ROOT, "*.py"))} - {"__init__", "__main__"}
    assert modules == set(level), f"place every module in a layer: missing {sorted(modules - set(level))}, gone {sorted(set(level) - modules)}"
    upward = [f"{m} ({LAYERS[level[m]][0]}) imports {d} ({LAYERS[level[d]][0]})"
              for m in sorted(modules) for d in sorted(gsa_imports(os.path.join(ROOT, m + ".py")) - {m}) if level[d] > level[m]]
    assert not upward, "; ".join(upward)


def test_reading_and_deployment_modules_import_without_jax():
    code = ("import sys; import " + ", ".join(f"gsa_jax.{m}" for m in JAX_FREE)
            + "; loaded = [m for m in ('jax', 'brax', 'mujoco.mjx') if m in sys.modules]; assert not loaded, loaded")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300)
