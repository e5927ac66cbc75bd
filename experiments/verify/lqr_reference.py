"""The atlas's committed cartpole LQR as verify's reference: `.venv/bin/python experiments/verify/lqr_reference.py`

verify's LQR beside each controller weights scaled states (Q = I, R = I). The atlas designed its own for
dm_control's cartpole (`../atlas_dmc/linear_cartpole.py`: Q = diag(1, 10, 0.1, 0.1) on cart position, pole angle and
their velocities, R = 0.1). This runs `python -m gsa_jax.verify --quick --lqr-q 1,10,0.1,0.1 --lqr-r 0.1` on
one committed controller (the LQR's region does not depend on the controller beside it; the same quick budget as
run.py) and writes results/lqr_reference.csv: the gain verify designs (equal to linear_cartpole.csv's, from an
independent linearization), its spectral radius and region of attraction, beside verify's default-weight LQR's
from results/cartpole-balance/ (the same linearization and search).
"""

import csv
import json
import os

import numpy as np

from gsa_jax import write_csv
from gsa_jax.verify.__main__ import main as verify_main
from gsa_jax.verify.analysis import state_scale
from gsa_jax.verify.system import load_system

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
NAME = "dmc.cartpole-balance-mlp-s0"
CONTROLLER = f"experiments/atlas_dmc/results/cartpole-balance/flat_ppo/controllers/{NAME}.npz"
Q, R = "1,10,0.1,0.1", "0.1"


def row(label, lqr):
    roa = lqr["roa"]
    """K of u = -K (x, theta, xdot, thetadot), as linear_cartpole.csv prints it, and the region it holds."""
    return {"lqr": label, "gain_x_theta_xdot_thetadot": " ".join(f"{g:.3f}" for g in np.ravel(lqr["gain"])),
            "spectral_radius": f"{lqr['spectral_radius']:.4f}", "roa_volume": f"{roa['volume_fraction']:.3f}",
            "roa_radius_min": f"{roa['radius_min']:.3f}", "roa_radius_median": f"{roa['radius_median']:.3f}",
            "no_boundary_in_range": roa["no_boundary_in_range"]}


def main():
    out = os.path.join(HERE, "results", "lqr_reference", "cartpole-balance", NAME)  # not one of summarize.py's groups
    verify_main([os.path.join(ROOT, CONTROLLER), "--quick", "--lqr-q", Q, "--lqr-r", R, "--out", out])
    with open(os.path.join(out, "verify.json")) as f:
        committed = json.load(f)["lqr"]
    with open(os.path.join(HERE, "results", "cartpole-balance", NAME, "verify.json")) as f:
        default = json.load(f)["lqr"]
    scale = state_scale(load_system(os.path.join(ROOT, CONTROLLER)).task)
    default.setdefault("gain", (np.asarray(default["gain_scaled"]) / scale[None, :]).tolist())  # verify.json before 'gain'
    with open(os.path.join(ROOT, "experiments/atlas_dmc/results/linear_cartpole.csv")) as f:
        atlas_gain = next(csv.DictReader(f))["gains_x_sin_xdot_thetadot"]
    diff = np.abs(np.ravel(committed["gain"]) - np.array(atlas_gain.split(), float)).max()
    rows = [{**row("committed", committed), "weights": f"Q = diag({Q}); R = {R} (the task's units)",
             "atlas_gain": atlas_gain, "max_abs_diff_from_atlas_gain": f"{diff:.4f}"},
            {**row("default", default), "weights": "Q = I on scaled states; R = I", "atlas_gain": "",
             "max_abs_diff_from_atlas_gain": ""}]
    write_csv(os.path.join(HERE, "results", "lqr_reference.csv"), rows)
    print(open(os.path.join(HERE, "results", "lqr_reference.csv")).read())


if __name__ == "__main__":
    main()
