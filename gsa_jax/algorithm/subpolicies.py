"""The sub-policy classes of a mixture (the paper's second complexity knob), one `SubpolicyClass` entry each:
cluster c acts a = L_c phi(z) + b_c on the normalized observation z [d_s], and the class is its feature map phi.

Every place that needs phi reads the entry: the policy in training (gsa_jax.algorithm.policies, jax.numpy), the
deployed NumPy controller (gsa_jax.deployment.numpy_policy), the ONNX and C exporters, the inspection report and
the verifier's linearization. Adding a class is one new entry in SUBPOLICIES (`register` for one defined outside
the package). No JAX at module level: the deployment modules load it without JAX.
"""

from typing import Any, Callable, NamedTuple

import numpy as np


class SubpolicyClass(NamedTuple):
    """One sub-policy class. d_s: observation size; d_phi = size(d_s); z: normalized observations [..., d_s]."""

    name: str
    rule: str  # the action's formula, as the inspection report writes it
    size: Callable[[int], int]  # d_s -> d_phi
    features: Callable[[Any, Any], Any]  # (z [..., d_s], xp: numpy or jax.numpy) -> phi [..., d_phi]
    names: Callable[[list], list]  # observation names [d_s] -> feature names [d_phi]
    jacobian: Callable[[np.ndarray], np.ndarray]  # one z [d_s] -> d phi / d z [d_phi, d_s]
    onnx: Callable[..., str]  # (node, const, z, d_s) -> the name of phi [N, d_phi] (see _quadratic_onnx)
    c: Callable[[int], tuple]  # d_s -> (C statements computing phi from z [d_s], phi's array name)
    madds: Callable[[int], int]  # d_s -> multiply-adds phi costs (the C header's cost line)


def _no_onnx_nodes(node: Callable, const: Callable, z: str, d_s: int) -> str:
    """phi = z (linear), or unused (constant: d_phi = 0): no nodes."""
    return z


def _no_c_code(d_s: int) -> tuple:
    """phi = z (linear), or unused (constant: d_phi = 0): no statements."""
    return [], "z"


def _quadratic_features(z: Any, xp: Any = np) -> Any:
    """[z, z_i z_j for i <= j (row-major upper triangle)] [..., d_s + d_s (d_s + 1) / 2]."""
    i, j = np.triu_indices(z.shape[-1])
    return xp.concatenate([z, z[..., i] * z[..., j]], axis=-1)


def _quadratic_jacobian(z: np.ndarray) -> np.ndarray:
    """d phi / d z [d_phi, d_s] of the quadratic features at z [d_s]."""
    i, j = np.triu_indices(len(z))
    eye = np.eye(len(z))
    return np.concatenate([eye, eye[i] * z[j][:, None] + eye[j] * z[i][:, None]])


def _quadratic_names(obs_names: list) -> list:
    i, j = np.triu_indices(len(obs_names))
    return list(obs_names) + [f"{obs_names[a]}*{obs_names[b]}" for a, b in zip(i, j)]


def _quadratic_onnx(node: Callable, const: Callable, z: str, d_s: int) -> str:
    """Nodes of phi from tensor z [N, d_s]: node(op, inputs, outputs, **attributes) adds one, const(name, array)
    adds a constant and returns its name."""
    i, j = np.triu_indices(d_s)
    node("Gather", [z, const("quad_i", i.astype(np.int64))], ["z_i"], axis=1)
    node("Gather", [z, const("quad_j", j.astype(np.int64))], ["z_j"], axis=1)
    node("Mul", ["z_i", "z_j"], ["z_ij"])
    node("Concat", [z, "z_ij"], ["phi"], axis=1)
    return "phi"


def _quadratic_c(d_s: int) -> tuple:
    """C99 statements filling float phi[d_phi] from float z[d_s] (int i in scope)."""
    return ([f"float phi[{d_s + d_s * (d_s + 1) // 2}];", "int j, n = 0;",
             f"for (i = 0; i < {d_s}; ++i) phi[n++] = z[i];",
             f"for (i = 0; i < {d_s}; ++i) for (j = i; j < {d_s}; ++j) phi[n++] = z[i] * z[j];"], "phi")


CONSTANT = SubpolicyClass(
    "constant", "a = b_c", size=lambda d_s: 0, features=lambda z, xp=np: z[..., :0], names=lambda obs_names: [],
    jacobian=lambda z: np.zeros((0, len(z))), onnx=_no_onnx_nodes, c=_no_c_code, madds=lambda d_s: 0)
LINEAR = SubpolicyClass(
    "linear", "a = L_c z + b_c", size=lambda d_s: d_s, features=lambda z, xp=np: z, names=list,
    jacobian=lambda z: np.eye(len(z)), onnx=_no_onnx_nodes, c=_no_c_code, madds=lambda d_s: 0)
QUADRATIC = SubpolicyClass(
    "quadratic", "a = L_c [z, z_i z_j (i <= j)] + b_c", size=lambda d_s: d_s + d_s * (d_s + 1) // 2,
    features=_quadratic_features, names=_quadratic_names, jacobian=_quadratic_jacobian, onnx=_quadratic_onnx,
    c=_quadratic_c, madds=lambda d_s: d_s * (d_s + 1) // 2)

SUBPOLICIES = {s.name: s for s in (CONSTANT, LINEAR, QUADRATIC)}  # in the order errors list them
DEFAULT = LINEAR.name  # a mixture's class where a config or an exported file names none
SUBPOLICY_KINDS = SUBPOLICIES.keys()  # the sub-policy classes' names, registered ones included


def register(entry: SubpolicyClass) -> None:
    """Add a sub-policy class (its name must be new) for this process."""
    if entry.name in SUBPOLICIES:
        raise ValueError(f"sub-policy class {entry.name!r} exists")
    SUBPOLICIES[entry.name] = entry


def get(name: str) -> SubpolicyClass:
    """The entry of a sub-policy class; ValueError naming the known ones."""
    if name not in SUBPOLICIES:
        raise ValueError(f"unknown subpolicy {name!r}; choose one of {', '.join(SUBPOLICIES)}")
    return SUBPOLICIES[name]
