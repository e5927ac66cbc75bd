"""Robustness margins of every committed certificate (results/certified/, `run.py --certify`), without certifying
again: `.venv/bin/python experiments/verify/margins_of_certified.py`

For each verify.json with a fixed-point certificate, its margins as `gsa verify --certify` records them, or for a file
written before, gsa_jax.verify.margins at its fixed point (qpos, qvel, piece), each margin checked on the plant in
MuJoCo C with the committed controller, as `gsa verify --certify` computes them. Writes results/certified/margins.csv (one row per certificate: whether it counts at the held equilibrium, the
gain, delay and disk margins, each plant check's verdict and growths, the flags) and margins_summary.csv (per task
and class: certificates, counted ones, medians of the margins, flagged and plant-confirmed counts).
"""

import glob
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from summarize_certified import RESULTS, cls, held_of, median  # noqa: E402

from gsa_jax import write_csv  # noqa: E402
from gsa_jax.verify import margins  # noqa: E402
from gsa_jax.verify.system import equilibrium_guess, load_system  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(HERE))


def plant_columns(plant: dict) -> dict:
    """Each margin's plant check as columns: confirmed (True/False, '' where there is nothing to cross) and growths."""
    out = {}
    for name, check in plant.items():
        if check is None:
            out.update({f"{name}_confirmed": "", f"{name}_growth_inside": "", f"{name}_growth_outside": ""})
            continue
        inside, outside = ((check["holds_at"], check["holds_past"]) if name == "delay"
                           else (check["holds_inside"], check["holds_outside"]))
        out.update({f"{name}_confirmed": check["confirmed"], f"{name}_growth_inside": inside["growth"],
                    f"{name}_growth_outside": outside["growth"]})
    return out


def row(path: str) -> "dict | None":
    with open(path) as f:
        doc = json.load(f)
    cert = doc.get("certificate")
    if not cert:
        return None
    m = cert.get("margins")  # recorded by gsa verify --certify; computed here for a file written before
    if m is None:
        controller = doc["controller"] if os.path.isabs(doc["controller"]) else os.path.join(ROOT, doc["controller"])
        system = load_system(controller)
        m = margins.certificate_margins(system, equilibrium_guess(system.task), cert, seed=0)
    group = os.path.basename(os.path.dirname(os.path.dirname(path)))
    held = held_of(doc)
    return {"task": group[:-4] if group.endswith("-lqr") else group,
            "class": "lqr" if group.endswith("-lqr") else cls(doc), "controller": os.path.basename(os.path.dirname(path)),
            "certified": bool(cert["certified"]), "counted": bool(held.get("counted")),
            "nominal_return": doc["nominal"]["return_mean"], "gain_lower": round(m["gain_lower"], 5),
            "gain_upper": round(m["gain_upper"], 5), "delay_steps": m["delay_steps"],
            "disk_alpha": round(m["disk"]["alpha"], 5), "disk_phase_deg": round(m["disk"]["phase_deg"], 3),
            "flagged": bool(m["flags"]), "flags": "; ".join(m["flags"]), **plant_columns(m["plant"])}


def summary(rows: list) -> list:
    out = []
    for key in sorted({(r["task"], r["class"]) for r in rows}):
        rs = [r for r in rows if (r["task"], r["class"]) == key]
        counted = [r for r in rs if r["counted"]]
        out.append({"task": key[0], "class": key[1], "certificates": len(rs), "counted": len(counted),
                    "gain_upper_median": median([r["gain_upper"] for r in counted]),
                    "gain_lower_median": median([r["gain_lower"] for r in counted]),
                    "delay_steps_median": median([r["delay_steps"] for r in counted]),
                    "disk_alpha_median": median([r["disk_alpha"] for r in counted]),
                    "flagged": sum(r["flagged"] for r in counted),
                    "gain_upper_confirmed": sum(r["gain_upper_confirmed"] is True for r in counted),
                    "delay_confirmed": sum(r["delay_confirmed"] is True for r in counted)})
    return out


def main() -> None:
    rows = [r for r in (row(p) for p in sorted(glob.glob(os.path.join(RESULTS, "*", "*", "verify.json")))) if r]
    write_csv(os.path.join(RESULTS, "margins.csv"), rows)
    write_csv(os.path.join(RESULTS, "margins_summary.csv"), summary(rows))
    print(f"{len(rows)} certificates -> {RESULTS}/margins.csv, margins_summary.csv")


if __name__ == "__main__":
    main()
