"""The deployed controller in plain NumPy (no JAX needed): load(path).act(obs), .cluster(obs).

A mixture controller is piecewise simple: normalize the observation, pick the most probable
cluster of the partition network (eps-uniform exploration does not change the argmax), apply
that cluster's L_c phi(z) + b_c, where phi is the sub-policy class: [] (constant), z (linear),
[z, z_i z_j for i <= j] (quadratic). An MLP controller applies its tanh MLP to the normalized observation.
Actions are what the policy outputs; the environment clips them to its action range [-1, 1].

File format (written by `python -m gsa_jax.export`): kind ('mixture'|'mlp'), obs_mean, obs_var,
obs_clip, n_layers, w{i}/b{i} for i < n_layers (partition or policy MLP), and for mixtures subpolicy
('constant'|'linear'|'quadratic'; absent = linear), L [K, d_a, d_phi], b [K, d_a] of the K active clusters.
"""

import numpy as np


class Controller:
    def __init__(self, arrays):
        self.kind = str(arrays["kind"])
        self.obs_mean = np.asarray(arrays["obs_mean"], np.float32)
        self.obs_std = np.sqrt(np.asarray(arrays["obs_var"], np.float32) + np.float32(1e-8))
        self.obs_clip = float(arrays["obs_clip"])
        n = int(arrays["n_layers"])
        self.layers = [(np.asarray(arrays[f"w{i}"], np.float32), np.asarray(arrays[f"b{i}"], np.float32)) for i in range(n)]
        if self.kind == "mixture":
            self.subpolicy = str(arrays["subpolicy"]) if "subpolicy" in arrays else "linear"
            if self.subpolicy not in ("constant", "linear", "quadratic"):
                raise ValueError(f"unknown sub-policy class {self.subpolicy!r}")
            self.L = np.asarray(arrays["L"], np.float32)
            self.b = np.asarray(arrays["b"], np.float32)
        elif self.kind != "mlp":
            raise ValueError(f"unknown controller kind {self.kind!r}")

    @property
    def num_clusters(self):
        return self.L.shape[0] if self.kind == "mixture" else 1

    def normalize(self, obs):
        return np.clip((np.asarray(obs, np.float32) - self.obs_mean) / self.obs_std, -self.obs_clip, self.obs_clip)

    def _mlp(self, x):
        for i, (w, b) in enumerate(self.layers):
            x = x @ w + b
            if i < len(self.layers) - 1:
                x = np.tanh(x)
        return x

    def features(self, z):
        """phi(z) [..., d_phi] of normalized observations z [..., d_s]."""
        if self.subpolicy == "constant":
            return z[..., :0]
        if self.subpolicy == "linear":
            return z
        i, j = np.triu_indices(z.shape[-1])
        return np.concatenate([z, z[..., i] * z[..., j]], axis=-1)

    def cluster(self, obs):
        """Active cluster for obs [..., d_s] -> int array [...] (0 for an MLP controller)."""
        z = self.normalize(obs)
        if self.kind == "mlp":
            return np.zeros(z.shape[:-1], np.int64)
        return np.argmax(self._mlp(z)[..., : self.num_clusters], axis=-1)

    def act(self, obs):
        """Deterministic action for obs [..., d_s] -> [..., d_a]."""
        z = self.normalize(obs)
        if self.kind == "mlp":
            return self._mlp(z)
        c = self.cluster(obs)
        if self.L.shape[-1] == 0:  # constant sub-policies (an empty contraction can come back uninitialized)
            return self.b[c].copy()
        return np.einsum("...ij,...j->...i", self.L[c], self.features(z)) + self.b[c]


def load(path):
    with np.load(path, allow_pickle=False) as f:
        return Controller({k: f[k] for k in f.files})
