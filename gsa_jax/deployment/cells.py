"""A linear partition's cells in the task's own units, from an exported controller (NumPy only): the inequalities
`gsa inspect` prints and the figure of the cells on two coordinates.

The linear partition's logits are W z + c on the normalized observation z = (s - mean) / std (W [d_s, K], c [K]),
so cluster i acts on the convex polyhedron {s : (w_i - w_j) . (s - mean) / std + c_i - c_j >= 0 for every active
j != i}, written here A_i s >= d_i with A_i [K - 1, d_s] in 1 / (the observation's unit) and d_i [K - 1]. Exact
where the normalizer's clip does not act (|s - mean| <= obs_clip std in every coordinate; outside, a state is in
the cell of its clipped point). On a shared boundary the controller takes the lower cluster (the first maximum).
A single piece (K = 1, exported with no partition) has one cell, every state: logits 0, no inequality.
"""

from typing import NamedTuple

import numpy as np

from gsa_jax.algorithm import partitions
from gsa_jax.algorithm.kinds import MIXTURE
from gsa_jax.deployment.numpy_policy import Controller


class Cell(NamedTuple):
    """Where cluster `cluster` acts: {s : A s >= d}, one row per other active cluster."""

    cluster: int
    others: list  # the other cluster of each row
    A: np.ndarray  # [K - 1, d_s]
    d: np.ndarray  # [K - 1]


def raw_logits(ctrl: Controller) -> tuple:
    """(W_raw [d_s, K], c_raw [K]) float64: the linear partition's logits s @ W_raw + c_raw on the raw observation s
    (the normalization folded in; a single piece's: zeros, one cell); ValueError for a controller without a linear
    partition."""
    if ctrl.single_piece:
        return np.zeros((ctrl.obs_mean.shape[0], 1)), np.zeros(1)
    if ctrl.kind != MIXTURE or not partitions.get(ctrl.partition).polyhedral:
        raise ValueError("the controller has no linear partition: its cells are not polyhedra")
    (w, c), k = ctrl.layers[0], ctrl.num_clusters
    w_raw = np.asarray(w, np.float64)[:, :k] / np.asarray(ctrl.obs_std, np.float64)[:, None]
    return w_raw, np.asarray(c, np.float64)[:k] - np.asarray(ctrl.obs_mean, np.float64) @ w_raw


def cell_inequalities(ctrl: Controller) -> list:
    """[Cell] of each of the K active clusters, in raw observation units."""
    w_raw, c_raw = raw_logits(ctrl)
    cells = []
    for i in range(ctrl.num_clusters):
        others = [j for j in range(ctrl.num_clusters) if j != i]
        cells.append(Cell(i, others, (w_raw[:, [i]] - w_raw[:, others]).T, c_raw[others] - c_raw[i]))
    return cells


def cells_text(ctrl: Controller, names: list) -> str:
    """The cells as text: per cell, one line 'vs j:  <coefficient> <name>  ...  >= <d>' per other cluster, every
    observation's coefficient in the order of `names` [d_s], separated by two spaces."""
    exact = f"exact while every |obs - mean| <= {ctrl.obs_clip:g} std" if np.isfinite(ctrl.obs_clip) else "exact"
    lines = [(f"Cells of the linear partition ({ctrl.num_clusters} clusters): cluster i acts where each of its rows "
              f"holds, in the task's units ({exact}; on a boundary the lower cluster acts).")]
    for cell in cell_inequalities(ctrl):
        lines.append(f"cell {cell.cluster}:" + ("" if cell.others else " every state (one cluster)"))
        for j, row, bound in zip(cell.others, cell.A, cell.d):
            lines.append(f"  vs {j}:  " + "  ".join(f"{a:+.6g} {n}" for a, n in zip(row, names)) + f"  >= {bound:+.6g}")
    return "\n".join(lines) + "\n"


def informative_coordinates(ctrl: Controller, n: int = 2) -> list:
    """The n observation coordinates along which the logits part the clusters most: the largest spread (std over
    the K active clusters) of W's row, the logits' change per observation std [the indices, most first]."""
    w = np.asarray(ctrl.layers[0][0], np.float64)[:, : ctrl.num_clusters]
    return [int(i) for i in np.argsort(-w.std(axis=1), kind="stable")[:n]]


def plot_cells(ctrl: Controller, names: list, path: str, visited: np.ndarray | None = None, grid: int = 300) -> None:
    """The cells on the two informative coordinates (informative_coordinates; d_s >= 2), over mean +- 3 std of each,
    the other coordinates at their mean: each point coloured by the controller's own cluster (a cell's centroid in
    the slice labelled with it); visited states [n, d_s] (projected, their other coordinates free) as grey dots."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    p, q = informative_coordinates(ctrl)
    k = ctrl.num_clusters
    axes = [ctrl.obs_mean[i] + ctrl.obs_std[i] * np.linspace(-3.0, 3.0, grid) for i in (p, q)]
    x, y = np.meshgrid(*axes)
    obs = np.tile(ctrl.obs_mean, (grid * grid, 1))
    obs[:, p], obs[:, q] = x.ravel(), y.ravel()
    cluster = ctrl.cluster(obs).reshape(grid, grid)
    colours = ListedColormap([plt.cm.tab10(i % 10) for i in range(k)])
    fig, ax = plt.subplots(figsize=(6.4, 5))
    ax.pcolormesh(x, y, cluster, cmap=colours, vmin=-0.5, vmax=k - 0.5, alpha=0.45, shading="auto")
    w_raw, c_raw = raw_logits(ctrl)
    logits = obs.astype(np.float64) @ w_raw + c_raw  # [grid^2, K]
    for i, j in zip(*np.triu_indices(k, 1)):  # the boundary of cells i and j: where they are the two best
        between = np.ma.masked_where(~np.isin(cluster, (i, j)), (logits[:, i] - logits[:, j]).reshape(grid, grid))
        if between.count():
            ax.contour(x, y, between, levels=[0.0], colors="k", linewidths=0.8)
    if visited is not None and len(visited):
        ax.scatter(visited[:, p], visited[:, q], s=2, color="0.3", alpha=0.3, label="visited states (projected)")
        ax.legend(fontsize=8, markerscale=4, loc="upper right")
    for i in np.unique(cluster):
        ys, xs = np.nonzero(cluster == i)
        ax.text(x[0, int(xs.mean())], y[int(ys.mean()), 0], str(i), ha="center", va="center", fontsize=12)
    ax.set_xlim(axes[0][0], axes[0][-1])
    ax.set_ylim(axes[1][0], axes[1][-1])
    ax.set_xlabel(names[p])
    ax.set_ylabel(names[q])
    ax.set_title("linear partition's cells (other observations at their mean)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
