"""A certificate's k-step decrease as an ONNX graph and VNN-LIB properties, the input format of the field's neural
network verifiers (alpha,beta-CROWN, NNV, Marabou; VNN-COMP's closed-loop Lyapunov benchmarks state theirs so).

The graph (onnx's own API, opset 17; MatMul, Add, Sub, Mul and Concat only: no ArgMax, Gather or comparison) takes
`d` float32 [1, n], the deviation from the certificate's fixed point x_c (tangent, SI units), and returns one output
`y` float32 [1, 2 + k (K - 1) + n + d_a] for the certified piece p of the PWA model (gsa_jax.verify.pwa), its images
d_j = M_j d + m_j (j = 0..k) composed exactly:
    y[0] = V(d_k) - rho^2 V(d) - tol level          (the decrease: the certificate says y[0] < 0 on E)
    y[1] = V(d) - level                             (in E = {V <= level} where y[1] <= 0)
    y[2 : 2 + k (K - 1)]  piece p's cell rows at d_0 .. d_{k-1}   (the k-step map is piece p's where all are >= 0)
    then d_1 [n] (the one-step map) and the controller's action f_p + F_p d [d_a],
with V(d) = d' P d. The two properties, each a counterexample over E's bounding box (x_c +- the extent per
coordinate, a box of linear input bounds, the form every VNN-COMP tool reads):
    decrease.vnnlib: y[1] <= 0 and y[0] >= 0                (a start in E whose V does not fall over k steps)
    cells.vnnlib:    y[1] <= 0 and some cell row <= 0        (a start in E that leaves piece p's cell within k steps,
                                                               where the composed map is not the PWA loop's)
Both unsatisfiable: the k-step decrease holds on E exactly for the PWA model. A boundary row = 0 counts as leaving
(conservative: there the lower piece acts).
"""

import re
from typing import TYPE_CHECKING

import numpy as np

from gsa_jax.verify import pwa

if TYPE_CHECKING:
    import onnx

OPSET = 17
IR_VERSION = 8
TOL = 1e-6  # x level: the decrease's tolerance, as certify.DECREASE_TOL


def property_arrays(model: pwa.Pwa, cert: dict) -> dict:
    """The graph's arrays (float64) for the certified piece: {'M_all' [n, k + 1, n] stacked images, 'm_all', 'P',
    'S' [n, k (K - 1)] / 's' the cell rows at d_0..d_{k-1}, 'F', 'f', 'level', 'rho', 'k', 'piece'}."""
    p, k = int(cert["piece"] or 0), int(cert["k"])
    M, m = pwa.images(model, p, k)
    rows = model.cells[p]
    S = np.concatenate([rows[:, :-1] @ M[j] for j in range(k)], axis=0) if len(rows) else np.zeros((0, M.shape[1]))
    s = np.concatenate([rows[:, :-1] @ m[j] + rows[:, -1] for j in range(k)]) if len(rows) else np.zeros(0)
    return {"M": M, "m": m, "P": np.asarray(cert["P"], np.float64), "S": S, "s": s, "F": model.F[p], "f": model.f[p],
            "level": float(cert["level"]), "rho": float(cert["rho"]), "k": k, "piece": p}


def outputs(arrays: dict, d: np.ndarray) -> np.ndarray:
    """[N, 2 + rows + n + d_a] the graph's output y at deviations d [N, n], in NumPy (float64)."""
    d = np.atleast_2d(np.asarray(d, np.float64))
    P, M, m, k = arrays["P"], arrays["M"], arrays["m"], arrays["k"]
    dk = d @ M[k].T + m[k]
    v0, vk = np.einsum("bi,ij,bj->b", d, P, d), np.einsum("bi,ij,bj->b", dk, P, dk)
    dec = vk - arrays["rho"] ** 2 * v0 - TOL * arrays["level"]
    return np.concatenate([dec[:, None], (v0 - arrays["level"])[:, None], d @ arrays["S"].T + arrays["s"],
                           d @ M[1].T + m[1], d @ arrays["F"].T + arrays["f"]], axis=1)


def _quadratic(nodes: list, const, x: str, P: np.ndarray, ones: str, name: str) -> str:
    """x' P x of x [1, n] as [1, 1]: MatMul, Mul, MatMul with a column of ones."""
    from onnx import helper

    nodes.append(helper.make_node("MatMul", [x, const(f"{name}_P", P)], [f"{name}_xP"]))
    nodes.append(helper.make_node("Mul", [f"{name}_xP", x], [f"{name}_terms"]))
    nodes.append(helper.make_node("MatMul", [f"{name}_terms", ones], [name]))
    return name


def _affine(nodes: list, const, x: str, W: np.ndarray, b: np.ndarray, name: str) -> str:
    """x W' + b of x [1, n] (W [m, n], b [m])."""
    from onnx import helper

    nodes.append(helper.make_node("MatMul", [x, const(f"{name}_w", W.T)], [f"{name}_mm"]))
    nodes.append(helper.make_node("Add", [f"{name}_mm", const(f"{name}_b", b[None, :])], [name]))
    return name


def build_graph(arrays: dict) -> "onnx.ModelProto":
    """The property's ONNX model (module docstring), float32."""
    from onnx import TensorProto, helper, numpy_helper

    nodes = []

    def const(name, value):
        nodes.append(helper.make_node("Constant", [], [name], value=numpy_helper.from_array(
            np.asarray(value, np.float32), name)))
        return name

    k, n = arrays["k"], arrays["P"].shape[0]
    ones = const("ones", np.ones((n, 1)))
    dk = _affine(nodes, const, "d", arrays["M"][k], arrays["m"][k], "d_k")
    vk, v0 = _quadratic(nodes, const, dk, arrays["P"], ones, "V_k"), _quadratic(nodes, const, "d", arrays["P"], ones, "V_0")
    nodes.append(helper.make_node("Mul", [v0, const("rho2", np.full((1, 1), arrays["rho"] ** 2))], ["rho2_V_0"]))
    nodes.append(helper.make_node("Sub", [vk, "rho2_V_0"], ["drop"]))
    dec = _affine(nodes, const, "drop", np.eye(1), np.array([-TOL * arrays["level"]]), "decrease")
    in_set = _affine(nodes, const, v0, np.eye(1), np.array([-arrays["level"]]), "in_set")
    parts = [dec, in_set, _affine(nodes, const, "d", arrays["S"], arrays["s"], "cell_rows"),
             _affine(nodes, const, "d", arrays["M"][1], arrays["m"][1], "d_1"),
             _affine(nodes, const, "d", arrays["F"], arrays["f"], "action")]
    nodes.append(helper.make_node("Concat", parts, ["y"], axis=1))
    width = 2 + len(arrays["s"]) + n + len(arrays["f"])
    graph = helper.make_graph(nodes, "certificate_decrease",
                              [helper.make_tensor_value_info("d", TensorProto.FLOAT, [1, n])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, width])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="gsa_jax")
    model.ir_version = IR_VERSION
    return model


def box(cert: dict) -> tuple:
    """(lo [n], hi [n]) E's bounding box in deviations: -+ the certificate's extent per coordinate."""
    e = np.asarray(cert["extent"], np.float64)
    return -e, e


def property_text(lo: np.ndarray, hi: np.ndarray, width: int, counterexample: list, comment: str) -> str:
    """A VNN-LIB property: inputs X_i in [lo_i, hi_i], outputs Y_0..Y_{width-1}; counterexample: its assertions
    on Y (SMT-LIB terms), the set a verifier shows empty."""
    lines = [f"; {line}" for line in comment.splitlines()]
    lines += [f"(declare-const X_{i} Real)" for i in range(len(lo))]
    lines += [f"(declare-const Y_{j} Real)" for j in range(width)]
    for i, (a, b) in enumerate(zip(lo, hi)):
        lines += [f"(assert (>= X_{i} {a:.17g}))", f"(assert (<= X_{i} {b:.17g}))"]
    lines += [f"(assert {term})" for term in counterexample]
    return "\n".join(lines) + "\n"


def properties(arrays: dict, cert: dict) -> dict:
    """{'decrease.vnnlib': text, 'cells.vnnlib': text} (module docstring)."""
    lo, hi = box(cert)
    rows = len(arrays["s"])
    width = 2 + rows + len(lo) + len(arrays["f"])
    head = (f"gsa_jax certificate: piece {arrays['piece']}, k = {arrays['k']} control steps, rho = "
            f"{arrays['rho']:.17g}, level = {arrays['level']:.17g}\ninputs: the deviation from the fixed point "
            "(tangent, SI units) over E's bounding box; outputs: the ONNX model's y (gsa_jax.verify.vnnlib)")
    out = {"decrease.vnnlib": property_text(lo, hi, width, ["(<= Y_1 0.0)", "(>= Y_0 0.0)"],
                                            head + "\ncounterexample: in E and V does not fall over k steps")}
    if rows:
        leaves = " ".join(f"(and (<= Y_{2 + r} 0.0))" for r in range(rows))
        out["cells.vnnlib"] = property_text(lo, hi, width, ["(<= Y_1 0.0)", f"(or {leaves})"],
                                            head + "\ncounterexample: in E and leaves piece's cell within k steps")
    return out


_ATOM = re.compile(r"\((<=|>=) ([XY])_(\d+) (\S+?)\)")


def _holds(term: str, x: np.ndarray, y: np.ndarray) -> bool:
    """One assertion (our subset: comparisons of one variable with a number, 'and' / 'or' of them) at (x, y)."""
    term = term.strip()
    if term.startswith("(or ") or term.startswith("(and "):
        op, body = term[1:].split(" ", 1)
        parts, depth, start = [], 0, None
        for i, ch in enumerate(body[:-1]):
            depth += ch == "("
            if ch == "(" and depth == 1:
                start = i
            depth -= ch == ")"
            if ch == ")" and depth == 0:
                parts.append(body[start:i + 1])
        values = [_holds(p, x, y) for p in parts]
        return any(values) if op == "or" else all(values)
    m = _ATOM.fullmatch(term)
    if m is None:
        raise ValueError(f"not a VNN-LIB comparison this reader knows: {term!r}")
    v = (x if m.group(2) == "X" else y)[int(m.group(3))]
    return bool(v <= float(m.group(4)) if m.group(1) == "<=" else v >= float(m.group(4)))


def counterexamples(text: str, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """[N] bool: which points (x [N, n], y [N, width]) satisfy every assertion of a property (are counterexamples)."""
    terms = [line[len("(assert "):-1] for line in text.splitlines() if line.startswith("(assert ")]
    return np.array([all(_holds(t, xi, yi) for t in terms) for xi, yi in zip(x, y)])
