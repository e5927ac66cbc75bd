"""The partition classes of a mixture, one `PartitionClass` entry each: the network whose logits over the K active
clusters pick the cluster (its softmax in training, its argmax in the deterministic controller), on the normalized
observation z [d_s].

Every class is a stack of affine layers with tanh between them (gsa_jax.algorithm.nn: a list of {'w', 'b'}), so
the policy in training, the deployed NumPy controller, the ONNX and C exporters and the verifier evaluate every class
alike; an entry says which layers it has. `mlp` is the paper's (hidden layers of Config.hidden); `linear` is one
affine layer, logits = W z + c, whose cells {z : argmax = i} are convex polyhedra (gsa inspect writes their
inequalities). No JAX: the deployment modules load it without JAX.
"""

from collections.abc import Callable
from typing import NamedTuple


class PartitionClass(NamedTuple):
    """One partition class."""

    name: str
    rule: str  # the logits' formula, as reports and exported files write it
    sizes: Callable[[int, tuple, int], tuple]  # (d_s, hidden widths, K_max) -> layer sizes (d_s, ..., K_max)
    polyhedral: bool  # logits affine in z: every cell is a convex polyhedron


MLP = PartitionClass("mlp", "logits = tanh-MLP(z)", lambda d_s, hidden, k_max: (d_s, *hidden, k_max), False)
LINEAR = PartitionClass("linear", "logits = W z + c", lambda d_s, hidden, k_max: (d_s, k_max), True)

PARTITIONS = {p.name: p for p in (MLP, LINEAR)}  # in the order errors list them
DEFAULT = MLP.name  # a mixture's class where a config or an exported file names none


def get(name: str) -> PartitionClass:
    """The entry of a partition class; ValueError naming the known ones."""
    if name not in PARTITIONS:
        raise ValueError(f"unknown partition {name!r}; choose one of {', '.join(PARTITIONS)}")
    return PARTITIONS[name]
