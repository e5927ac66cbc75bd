"""The experiments' scripts use the public API (`import gsa_jax`, `from gsa_jax import <gsa_jax.API name>`); a script
that imports a module of gsa_jax by name measures that internal part and is listed in INTERNAL with the reason. A
listed script that is gone or no longer imports an internal module fails too, so the list stays the true one."""

import ast
import os

import gsa_jax

ROOT = os.path.join(os.path.dirname(__file__), "..")
PUBLIC = set(gsa_jax.API) | {"__version__"}

VERDICTS = "re-judges committed results with the verdict rules themselves (gsa_jax.analysis.verdicts)"
VERIFY = "research on the verifier's parts (the system model, the LMI and ROA steps) beyond gsa verify's record"
INTERNAL = {
    "atlas_dmc/atlas.py": "quotes the verdicts' margins (MARGINS) beside the atlas rows",
    "bench_c_backend/run_batch_ab.py": "times the sweep programs (running.programs) of one spec, A against B",
    "bench_c_backend/update_cost.py": "times one PPO update's parts (networks, optimizer) apart from the physics",
    "bench_compile_sharing/ab_compile.py": "drives gsa_jax.benchmark's A/B timing of whole commands",
    "bench_eigen_threads/ab_eigen.py": "drives gsa_jax.benchmark's A/B timing of whole commands",
    "compile_time/measure.py": "times the compile of the training program's parts (config, train command internals)",
    "constructive/answers.py": VERDICTS,
    "constructive/fresh_episodes.py": "scores controllers' fresh episodes with the deployment and selection parts",
    "deploy_gymnasium/deploy_gymnasium.py": "compares the exported C and ONNX controllers with the rollout parts",
    "deploy_hopper/deploy_hopper.py": "steps a controller in MJX and MuJoCo C side by side (deployment.evaluation)",
    "partition/compare.py": VERDICTS,
    "partition/constructive.py": VERDICTS,
    "profile_program/tables.py": "tabulates the program's parts as gsa profile measures them (benchmark.parts)",
    "push_draws/push_draws.py": "draws pushes with the robustness evaluation's own parts, paired",
    "sb3_your_task/sb3_your_task.py": "exports a controller into SB3's gymnasium loop (deployment.gymnasium_rollout)",
    "solver_hopper/rescoring.py": "re-scores runs with the training program's episode and normalization parts",
    "time_to_answer/rejudge_budget.py": "re-judges the step budget rule (analysis.verdicts.step_budget)",
    "verdicts/answer_speed.py": VERDICTS,
    "verdicts/error_rates.py": "simulates the verdict rules' error rates under failing seeds and ties",
    "verdicts/fresh_scores.py": "compares selection and fresh scores (analysis.sweeps.controller_scores)",
    "verdicts/regenerate_answers.py": VERDICTS,
    "verdicts/rejudge.py": VERDICTS,
    "verdicts/tuned_references.py": VERDICTS,
    "verify/lqr_controller.py": "writes the LQR gain as a controller file (checkpoint and deployment formats)",
    "verify/lqr_reference.py": VERIFY,
    "verify/margins_of_certified.py": VERIFY,
    "verify/run.py": "verifies every committed controller with the verifier's budgets (gsa verify's parts, in-process)",
    "verify/summarize_certified.py": VERIFY,
}


def internal_imports(source: str) -> set:
    """The gsa_jax modules a script imports by name (anywhere in it): import gsa_jax.x, from gsa_jax.x import y,
    from gsa_jax import <not a public name>."""
    found = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("gsa_jax.")}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module.startswith("gsa_jax."):
                found.add(node.module)
            elif node.module == "gsa_jax":
                found |= {f"gsa_jax.{a.name}" for a in node.names if a.name not in PUBLIC}
    return found


def scripts() -> dict:
    """{path under experiments/: source} of every experiment script."""
    base = os.path.join(ROOT, "experiments")
    out = {}
    for folder, dirs, names in os.walk(base):
        dirs[:] = sorted(d for d in dirs if d not in ("__pycache__", "results"))
        for name in sorted(n for n in names if n.endswith(".py")):
            path = os.path.join(folder, name)
            with open(path) as f:
                out[os.path.relpath(path, base).replace(os.sep, "/")] = f.read()
    return out


def test_experiments_use_the_public_api_but_the_listed_few():
    using = {name for name, source in scripts().items() if internal_imports(source)}
    unlisted = sorted(using - set(INTERNAL))
    assert not unlisted, f"these scripts import gsa_jax modules by name; use gsa_jax's API or list why: {unlisted}"


def test_every_listed_script_exists_and_imports_an_internal_module():
    using = {name for name, source in scripts().items() if internal_imports(source)}
    stale = sorted(set(INTERNAL) - using)
    assert not stale, f"listed in INTERNAL but gone or using the public API only: {stale}"


def test_the_check_sees_internal_imports_anywhere_and_passes_public_ones():
    source = ("import gsa_jax\nfrom gsa_jax import iqm, write_csv\n"
              "def f():\n    from gsa_jax.analysis.sweeps import stats\n    from gsa_jax import deployment\n")
    assert internal_imports(source) == {"gsa_jax.analysis.sweeps", "gsa_jax.deployment"}
    assert internal_imports("import gsa_jax.verify.system as s\n") == {"gsa_jax.verify.system"}
    assert internal_imports("import gsa_jax\nfrom gsa_jax import load_sweep\n") == set()
