"""The atlas's cartpole LQR as an exported K = 1 controller: `.venv/bin/python experiments/verify/lqr_controller.py`

`../atlas_dmc/linear_cartpole.py` designs a discrete LQR for dm_control's cartpole (Q = diag(1, 10, 0.1, 0.1) on cart
position, pole angle and their velocities, R = 0.1) and applies it as a linear function of the observation (cart x,
sin of the pole angle, their velocities; zero weight on the cosine), clipped to [-1, 1]. This writes that very
controller as a controller file (results/certified/lqr/dmc.cartpole-balance-lqr.npz) in the format `gsa export` writes
(the committed K = 1 controller's file with its one piece's L and b replaced: u = L (obs - mean) / std + b equals
-K [x, sin, xdot, thetadot]), so `gsa verify --certify` and experiments/verify/run.py analyse it like any trained
controller, and checks that it acts as linear_cartpole.py's law on the task's resets.
"""

import importlib.util
import os

import numpy as np
import scipy.linalg as sla

import envs
import gsa_jax
from gsa_jax.deployment import numpy_policy
from gsa_jax.running.checkpoint import save_npz_atomic

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
TEMPLATE = os.path.join(ROOT, "experiments/atlas_dmc/results/cartpole-balance/mixture/controllers/"
                              "dmc.cartpole-balance-mixture-K1-s0.npz")
OUT = os.path.join(HERE, "results", "certified", "lqr", "dmc.cartpole-balance-lqr.npz")


def atlas_gain() -> np.ndarray:
    """[4] the atlas's LQR gain on (x, sin theta, xdot, thetadot): u = -K s (linear_cartpole.py's design)."""
    spec = importlib.util.spec_from_file_location("linear_cartpole", os.path.join(ROOT, "experiments/atlas_dmc/linear_cartpole.py"))
    lc = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(lc)
    A, B = lc.linearize(envs.resolve("dmc:cartpole-balance").make_c().model)
    P = sla.solve_discrete_are(A, B, lc.Q, lc.R)
    return np.linalg.solve(lc.R + B.T @ P @ B, B.T @ P @ A)[0]


def write_controller() -> np.ndarray:
    """Write OUT from TEMPLATE with the LQR as its piece -> the gain on the raw observation [5]."""
    arrays = gsa_jax.read_record(TEMPLATE, "controller")  # in the current layout, stamped with its format_version
    k = atlas_gain()
    g = -np.array([k[0], 0.0, k[1], k[2], k[3]])  # on (x, cos, sin, xdot, thetadot)
    std = np.sqrt(arrays["obs_var"].astype(np.float64))
    arrays["L"] = (g * std)[None, None].astype(np.float32)
    arrays["b"] = np.array([[g @ arrays["obs_mean"].astype(np.float64)]], np.float32)
    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    save_npz_atomic(OUT, **arrays)
    return g


def check(g: np.ndarray, resets: int = 5) -> float:
    """The largest difference between the file's actions and the law's, over the task's first `resets` episodes."""
    ctrl, task = numpy_policy.load(OUT), envs.resolve("dmc:cartpole-balance").make_c()
    worst = 0.0
    for seed in range(resets):
        obs = task.reset(seed)
        for _ in range(200):
            a = ctrl.act(obs)
            worst = max(worst, float(np.abs(a - np.clip(g @ obs, -1, 1)).max()))
            obs, _, _ = task.step(a)
    return worst


if __name__ == "__main__":
    gain = write_controller()
    print(f"wrote {os.path.relpath(OUT, ROOT)}; largest action difference from the law: {check(gain):.2e}")
