"""`gsa verify CONTROLLER --pwa VERIFY_JSON`: a certificate of a linear-partition controller handed to the field's
verifiers, each file checked on the same points before it is written.

Writes into DIR/pwa/ (report.md: the checks in words): pwa.json (the PWA model of every piece around the certified fixed point, gsa_jax.verify.pwa,
with V, the level, k and rho), certificate.onnx with decrease.vnnlib and cells.vnnlib (gsa_jax.verify.vnnlib), and
checks.json: on POINTS uniform samples of E and on its boundary, (1) the PWA model's piece and action against the
NumPy controller's at the linearized observation, (2) onnxruntime's output against the NumPy one, (3) how many are
counterexamples of each property (0 where the certificate holds on the linearization), and (4) the exact one-step
image of E's bounding box under the PWA loop of all K pieces, a mixed-integer program (gsa_jax.verify.milp; HiGHS):
at most 1 where the box maps into itself in one control step, the pieces' switching included.
"""

import json
import os

import numpy as np

from gsa_jax.running.formats import FormatError, read_json
from gsa_jax.verify import certify, milp, pwa, roa, vnnlib
from gsa_jax.verify.report import pwa_lines
from gsa_jax.verify.system import System, VerifyError, equilibrium_guess

POINTS = 2000  # samples inside E, and as many on its boundary


def read_certificate(path: str) -> dict:
    """The certificate of a verify.json written by --certify; VerifyError (one line) where it has none."""
    try:
        doc = read_json(path, "verify")
    except (OSError, ValueError, FormatError) as e:
        raise VerifyError(f"cannot read {path!r}: {' '.join(str(e).split())}") from None
    cert = doc.get("certificate") if isinstance(doc, dict) else None
    if not cert or "P" not in cert:
        raise VerifyError(f"{path!r} has no certificate (write one with gsa verify CONTROLLER --certify)")
    if not cert.get("certified"):
        raise VerifyError(f"{path!r}'s certificate was not certified on the plant: nothing to hand on")
    return cert


def sample_points(cert: dict, seed: int) -> np.ndarray:
    """[2 POINTS, n] deviations uniform in E and on its boundary."""
    rng = np.random.default_rng(seed)
    P, n = np.asarray(cert["P"], np.float64), len(cert["P"])
    u = roa.ball(rng, POINTS, n)
    s = rng.normal(size=(POINTS, n))
    return certify.offsets(P, float(cert["level"]), np.concatenate([u, s / np.linalg.norm(s, axis=1, keepdims=True)]))


def onnx_outputs(model_bytes: bytes, d: np.ndarray) -> np.ndarray:
    """[N, width] onnxruntime's y at deviations d [N, n], one point per run (the graph's batch is 1)."""
    import onnxruntime

    sess = onnxruntime.InferenceSession(model_bytes, providers=["CPUExecutionProvider"])
    return np.concatenate([sess.run(["y"], {"d": row[None].astype(np.float32)})[0] for row in d]).astype(np.float64)


def provenance() -> dict:
    """The versions of what computed and checked the export, and the git commit."""
    from importlib import metadata

    from gsa_jax.running.runinfo import git_commit

    names = ("numpy", "scipy", "mujoco", "onnx", "onnxruntime")
    return {"versions": {n: metadata.version(n) for n in names}, "commit": git_commit()}


def checks(system: System, model: pwa.Pwa, arrays: dict, cert: dict, files: dict) -> dict:
    """The checks of the module docstring on the same sampled points."""
    d = sample_points(cert, 0)
    ours, theirs = vnnlib.outputs(arrays, d), onnx_outputs(files["certificate.onnx"], d)
    scale = np.maximum(np.abs(ours).max(axis=0), 1e-12)
    image = milp.decrease_bound(model.A, model.a, model.cells, milp.box_rows(cert["extent"]))
    return {"points": len(d), "controller": pwa.agreement(model, system.ctrl, d), **provenance(),
            "onnx_max_rel_diff": float((np.abs(ours - theirs) / scale).max()),
            "counterexamples": {name: int(vnnlib.counterexamples(text, d, ours).sum())
                                for name, text in files.items() if name.endswith(".vnnlib")},
            "box_image_milp": {"value": image.value, "at": image.d.tolist(), "piece": image.piece,
                               "programs": image.programs, "solver": "HiGHS (scipy.optimize.milp)",
                               "pwa_value_there": float(np.abs(milp.box_rows(cert["extent"])
                                                               @ pwa.step(model, image.d)[0]).max())}}


def shown_path(path: str) -> str:
    """A path as a record shows it: relative to the working directory where it lies below it."""
    rel = os.path.relpath(os.path.abspath(path))
    return path if rel.startswith("..") else rel


def export_pwa(system: System, cert_path: str, out: str) -> dict:
    """Write DIR/pwa/ (module docstring) for the certificate at cert_path; -> checks.json's record."""
    cert = read_certificate(cert_path)
    qref = equilibrium_guess(system.task)
    model = pwa.build(system, qref, certify.tangent_state(system.task, qref, cert["qpos"], cert["qvel"]))
    arrays = vnnlib.property_arrays(model, cert)
    files = {"certificate.onnx": vnnlib.build_graph(arrays).SerializeToString(), **vnnlib.properties(arrays, cert)}
    record = checks(system, model, arrays, cert, files)
    folder = os.path.join(out, "pwa")
    os.makedirs(folder, exist_ok=True)
    for name, content in files.items():
        with open(os.path.join(folder, name), "wb" if isinstance(content, bytes) else "w") as f:
            f.write(content)
    fields = {"controller": shown_path(system.path), "certificate": shown_path(cert_path), "piece": arrays["piece"],
              "k": arrays["k"], "rho": arrays["rho"], "level": arrays["level"], "P": cert["P"],
              "extent": cert["extent"], "coordinates": cert["coordinates"], **pwa.model_fields(model)}
    for name, doc in (("pwa.json", fields), ("checks.json", record)):
        with open(os.path.join(folder, name), "w") as f:
            json.dump(doc, f, indent=1)
    with open(os.path.join(folder, "report.md"), "w") as f:
        f.write("\n".join([f"# {os.path.basename(system.path)}: its certificate as a piecewise-affine closed loop", "",
                           *pwa_lines(record), ""]))
    return record
