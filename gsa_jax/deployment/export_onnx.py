"""The deterministic controller as one ONNX graph, built with the `onnx` package's own API.

Input `obs` float32 [N, d_s]; outputs `action` float32 [N, d_a] (inside the task's action bounds, as
numpy_policy's act), `cluster` int64 [N] (0 for an MLP controller) and `raw_action` float32 [N, d_a] (before the
bounds, as act(obs, clip=False)); the bounds are also in its metadata (action_low, action_high), with what it was
trained on (task, obs_size, task_sha256: the npz's, docs/deploy.md). The graph:
normalize (subtract the running mean, divide by the std, clip), then for a mixture: the partition's layers (a tanh
MLP; one affine layer W z + c for the linear partition class) -> logits of the K active clusters -> ArgMax (first maximum, as NumPy's) -> gather that cluster's L_c, b_c -> L_c phi(z) + b_c; for
a single piece (K = 1) no partition: one Gemm phi(z) L_0^T + b_0 (a constant piece: b_0 expanded), cluster 0; for
an MLP controller its tanh MLP; then Max / Min with the bounds.
Needs the optional `deploy` extra (`pip install gsa_jax[deploy]`).
"""

import json
from typing import TYPE_CHECKING, Mapping

import numpy as np

from gsa_jax.algorithm import subpolicies
from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.deployment.numpy_policy import SINGLE, Controller

if TYPE_CHECKING:
    import onnx

OPSET = 17
IR_VERSION = 8  # the IR of opset 17: readable by every onnxruntime that runs opset 17


def _const(nodes, name, value):
    from onnx import helper, numpy_helper

    nodes.append(helper.make_node("Constant", [], [name], value=numpy_helper.from_array(np.asarray(value), name)))
    return name


def _mlp(nodes, x, layers, prefix):
    """Tanh MLP on tensor name x; the last layer is linear. Returns the output's name."""
    from onnx import helper

    for i, (w, b) in enumerate(layers):
        mm = f"{prefix}{i}_matmul"
        nodes.append(helper.make_node("MatMul", [x, _const(nodes, f"{prefix}{i}_w", w)], [mm]))
        x = f"{prefix}{i}_pre" if i < len(layers) - 1 else f"{prefix}_out"
        nodes.append(helper.make_node("Add", [mm, _const(nodes, f"{prefix}{i}_b", b)], [x]))
        if i < len(layers) - 1:
            nodes.append(helper.make_node("Tanh", [x], [f"{prefix}{i}_h"]))
            x = f"{prefix}{i}_h"
    return x


def _normalize(nodes, ctrl):
    from onnx import helper

    nodes.append(helper.make_node("Sub", ["obs", _const(nodes, "obs_mean", ctrl.obs_mean)], ["centred"]))
    nodes.append(helper.make_node("Div", ["centred", _const(nodes, "obs_std", ctrl.obs_std)], ["scaled"]))
    lo, hi = (np.float32(-ctrl.obs_clip), np.float32(ctrl.obs_clip))
    nodes.append(helper.make_node("Clip", ["scaled", _const(nodes, "clip_lo", lo), _const(nodes, "clip_hi", hi)], ["z"]))
    return "z"


def _features(nodes, ctrl, z):
    """phi(z): the nodes of the sub-policy class's ONNX emitter (gsa_jax.algorithm.subpolicies); phi's name."""
    from onnx import helper

    def node(op, inputs, outputs, **attributes):
        nodes.append(helper.make_node(op, inputs, outputs, **attributes))

    emit = subpolicies.SUBPOLICIES[ctrl.subpolicy].onnx
    return emit(node, lambda name, value: _const(nodes, name, value), z, ctrl.obs_mean.shape[0])


def _zero_cluster(nodes):
    """Nodes writing 'cluster': int64 zeros [N] (one piece) and 'batch' ([N], obs's first dimension)."""
    from onnx import TensorProto, helper

    nodes.append(helper.make_node("Shape", ["obs"], ["batch"], start=0, end=1))
    nodes.append(helper.make_node("ConstantOfShape", ["batch"], ["cluster"],
                                  value=helper.make_tensor("zero", TensorProto.INT64, [1], [0])))


def _single_piece(nodes, ctrl, z):
    """Nodes of a K = 1 mixture (no partition): 'raw_action' = phi(z) L_0^T + b_0 (one Gemm; b_0 expanded to [N, d_a]
    for a constant piece), 'cluster' = 0."""
    from onnx import helper

    _zero_cluster(nodes)
    if ctrl.L.shape[-1] == 0:
        d_a = _const(nodes, "action_dim", np.array([ctrl.action_size], np.int64))
        nodes.append(helper.make_node("Concat", ["batch", d_a], ["action_shape"], axis=0))
        nodes.append(helper.make_node("Expand", [_const(nodes, "b", ctrl.b[0]), "action_shape"], ["raw_action"]))
        return
    phi = _features(nodes, ctrl, z)
    nodes.append(helper.make_node("Gemm", [phi, _const(nodes, "L", ctrl.L[0]), _const(nodes, "b", ctrl.b[0])],
                                  ["raw_action"], transB=1))


def _mixture(nodes, ctrl, z):
    """Nodes of the mixture's deterministic controller; writes 'raw_action' and 'cluster'."""
    from onnx import helper

    if ctrl.single_piece:
        return _single_piece(nodes, ctrl, z)
    k = ctrl.num_clusters
    layers = list(ctrl.layers[:-1]) + [(ctrl.layers[-1][0][:, :k], ctrl.layers[-1][1][:k])]  # the K active logits
    logits = _mlp(nodes, z, layers, "partition")
    nodes.append(helper.make_node("ArgMax", [logits], ["cluster"], axis=1, keepdims=0, select_last_index=0))
    nodes.append(helper.make_node("Gather", [_const(nodes, "b", ctrl.b), "cluster"], ["b_c"], axis=0))
    if ctrl.L.shape[-1] == 0:  # constant sub-policies: the cluster's action
        nodes.append(helper.make_node("Identity", ["b_c"], ["raw_action"]))
        return
    phi = _features(nodes, ctrl, z)
    nodes.append(helper.make_node("Gather", [_const(nodes, "L", ctrl.L), "cluster"], ["L_c"], axis=0))
    axes = _const(nodes, "axis2", np.array([2], np.int64))
    nodes.append(helper.make_node("Unsqueeze", [phi, axes], ["phi_col"]))
    nodes.append(helper.make_node("MatMul", ["L_c", "phi_col"], ["Lphi_col"]))
    nodes.append(helper.make_node("Squeeze", ["Lphi_col", axes], ["Lphi"]))
    nodes.append(helper.make_node("Add", ["Lphi", "b_c"], ["raw_action"]))


def _bound(nodes, ctrl):
    """action = min(max(raw_action, action_low), action_high), per action (ONNX's Clip takes scalar bounds only)."""
    from onnx import helper

    low, high = ctrl.bounds()
    nodes.append(helper.make_node("Max", ["raw_action", _const(nodes, "action_low", low)], ["above_low"]))
    nodes.append(helper.make_node("Min", ["above_low", _const(nodes, "action_high", high)], ["action"]))


def build_model(arrays: Mapping, layout: list | None = None) -> "onnx.ModelProto":
    """onnx.ModelProto of the controller in `arrays` (the export's arrays, see numpy_policy)."""
    import onnx
    from onnx import TensorProto, helper

    ctrl = Controller(arrays)
    d_s, d_a = ctrl.obs_mean.shape[0], ctrl.action_size
    nodes = []
    z = _normalize(nodes, ctrl)
    if ctrl.kind == MIXTURE:
        _mixture(nodes, ctrl, z)
    else:
        out = _mlp(nodes, z, ctrl.layers, "mlp")
        nodes.append(helper.make_node("Identity", [out], ["raw_action"]))
        _zero_cluster(nodes)
    _bound(nodes, ctrl)
    graph = helper.make_graph(
        nodes, "gsa_jax_controller",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["N", d_s])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["N", d_a]),
         helper.make_tensor_value_info("cluster", TensorProto.INT64, ["N"]),
         helper.make_tensor_value_info("raw_action", TensorProto.FLOAT, ["N", d_a])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="gsa_jax")
    model.ir_version = IR_VERSION
    model.doc_string = describe(arrays)
    meta = {"config_json": str(arrays["config_json"]) if "config_json" in arrays else "{}"}
    meta.update({k: str(arrays[k]) for k in ("task", "obs_size", "task_sha256") if k in arrays})
    meta.update(action_low=json.dumps(ctrl.action_low.tolist()), action_high=json.dumps(ctrl.action_high.tolist()))
    if ctrl.action_space == "controls":  # the action is the actuators' controls (the task's own action space)
        meta.update(action_space="controls")
    elif ctrl.ctrl_range is not None:  # the task maps the action onto its controls: low + (a + 1) (high - low) / 2
        meta.update(ctrl_low=json.dumps(ctrl.ctrl_range[0].tolist()), ctrl_high=json.dumps(ctrl.ctrl_range[1].tolist()))
    if layout:
        meta["observation_layout"] = json.dumps(layout)
    helper.set_model_props(model, meta)
    onnx.checker.check_model(model, full_check=True)
    return model


def describe(arrays: Mapping) -> str:
    """One line saying what the controller is."""
    meta = json.loads(str(arrays["config_json"])) if "config_json" in arrays else {}
    cfg = meta.get("config", {})
    kind = str(arrays["kind"])
    what = "tanh MLP (mean action)"
    if kind == MIXTURE:
        sub, part = str(arrays["subpolicy"]), str(arrays["partition"])
        what = (f"mixture of K={np.asarray(arrays['L']).shape[0]} {sub} controllers (most probable cluster, mean "
                f"action), {'no' if part == SINGLE else part} partition")
    return (f"gsa_jax deterministic controller: {what}; task {cfg.get('env', '?')}, seed {meta.get('seed', '?')}, "
            f"commit {meta.get('git_commit') or '?'}")


def to_bytes(arrays: Mapping, layout: list | None = None) -> bytes:
    """The serialized, checked ONNX model of the controller."""
    return build_model(arrays, layout).SerializeToString()
