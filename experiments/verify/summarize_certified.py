"""Tables of the certified runs (results/certified/, `run.py --certify`): `.venv/bin/python experiments/verify/summarize_certified.py`

Writes results/certified/per_controller.csv (one row per controller: nominal return, the fixed-point certificate,
counted only at the task's held equilibrium, one that is not counted apart; the switching hold's invariant set, the region of attraction at the task's one convergence rule, the LQR's beside it,
the falsification's knife-edge counts) and results/certified/summary.csv (per task and class: how many controllers
got each certificate, the certified sets' median inscribed radius in SI units, the regions' medians).
"""

import glob
import json
import os

import numpy as np

from gsa_jax import write_csv

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results", "certified")


def cls(doc: dict) -> str:
    return "flat_ppo" if doc["kind"] == "mlp" else f"K{doc['clusters']}"


def held_of(doc: dict) -> dict:
    """certify.held_equilibrium's record of the document's certificate: its own where verify wrote it, else computed
    from the certificate's fixed point and the region's hold (both in verify.json); {} without a certificate."""
    c = doc.get("certificate") or {}
    if not c or "held_equilibrium" in c:
        return c
    import envs
    from gsa_jax.verify import certify
    from gsa_jax.verify.system import equilibrium_guess

    task = envs.resolve_task(doc["env"])
    qref, hold = equilibrium_guess(task), doc["roa"]["hold"]
    return certify.held_equilibrium(task, qref, certify.tangent_state(task, qref, hold["qpos"], hold["qvel"]),
                                    bool(hold["holds"]), c)


def certificate_part(doc: dict) -> dict:
    """The fixed-point certificate's and the hold set's columns: certified (and counted) only at the task's held
    equilibrium (certify.held_equilibrium); a certificate that is not (its fixed point elsewhere, or the closed loop
    not holding the equilibrium: not_held_why says which) is counted apart."""
    c, h, held = doc.get("certificate") or {}, doc.get("hold_set") or {}, held_of(doc)
    return {"fixed_point_certified": bool(held.get("counted")),
            "certified_not_held": bool(c.get("certified") and not held.get("held_equilibrium")),
            "not_held_why": held.get("held_why", ""), "cert_level": c.get("level", ""),
            "cert_inscribed_radius_si": c.get("inscribed_radius", "") if held.get("counted") else "",
            "cert_extent_si": " ".join(f"{x:.4g}" for x in c.get("extent", [])) if held.get("counted") else "",
            "cert_rho_per_step": c.get("rho_per_step", ""), "hold_set_applies": bool(h),
            "hold_set_certified": bool(h.get("certified")),
            "hold_set_inscribed_radius_si": h.get("inscribed_radius", "") if h.get("certified") else "",
            "hold_set_reason": (h.get("reason") or "")[:160], "hold_set_within_bounds": h.get("within_bounds", ""),
            "hold_set_k": h.get("k", "") if "P" in h else "", "hold_set_program": h.get("program", ""),
            "hold_set_extent_si": " ".join(f"{x:.4g}" for x in h.get("extent", [])) if h.get("certified") else "",
            "refused": (doc.get("certify_refused") or "")[:160], **room_part(c if held.get("counted") else {})}


def room_part(c: dict) -> dict:
    """A counted certificate's room (its level's share of the last clean level and of the first violation found)
    and its behaviour between the k-step instants and from its boundary (gsa_jax.verify.boundary); blank where the
    file has none (written before they were recorded) or nothing is counted."""
    b = c.get("between_instants") or {}
    return {"cert_room": c.get("room", ""), "cert_share_of_first_violation": c.get("level_share_of_first_violation") or "",
            "between_invariant": b.get("invariant", ""), "between_peak_linearization": b.get("linearization_peak", ""),
            "between_peak_plant": b.get("plant_peak", ""),
            "boundary_converged": f"{b['converged']}/{b['starts']}" if b else "",
            "boundary_settle_median_s": b.get("seconds_median", "") if b else ""}


def region_part(doc: dict) -> dict:
    """The region of attraction's columns (scaled units: 1 = the start law's spread per coordinate) and the LQR's."""
    roa, lqr = doc.get("roa") or {}, (doc.get("lqr") or {}).get("roa") or {}
    return {"tolerance": " ".join(f"{x:.4g}" for x in roa.get("tolerance", [])), "horizon_s": roa.get("horizon", {}).get("seconds", ""),
            "holds": (roa.get("hold") or {}).get("holds", ""), "roa_radius_min": roa.get("radius_min", ""),
            "roa_radius_median": roa.get("radius_median", ""), "roa_radius_equivalent": roa.get("radius_equivalent", ""),
            "roa_volume_sampled": roa.get("volume_fraction_sampled", ""),
            "not_star_shaped_directions": roa.get("not_star_shaped_directions", ""),
            "lqr_roa_radius_median": lqr.get("radius_median", "")}


def old_region(group: str, controller: str) -> dict:
    """The same controller's region from results/<group>/ (the earlier rule: a tolerance per controller, radii capped
    at r_max, the episode's horizon), where it was verified there."""
    path = os.path.join(HERE, "results", group, controller, "verify.json")
    if not os.path.exists(path):
        return {"old_roa_radius_median": "", "old_roa_volume": ""}
    with open(path) as f:
        roa = json.load(f).get("roa") or {}
    return {"old_roa_radius_median": roa.get("radius_median", ""), "old_roa_volume": roa.get("volume_fraction", "")}


def row(path: str) -> dict:
    with open(path) as f:
        doc = json.load(f)
    fals = doc["falsification"]
    knife = sum(bool(c.get("knife_edge")) for s in ("start_law", "twice_the_spread", "start_law_and_pushes")
                for c in fals[s].get("counterexamples", []))  # listed ones (a search's count also holds those it inherits)
    total = sum(len(fals[s].get("counterexamples", [])) for s in ("start_law", "twice_the_spread", "start_law_and_pushes"))
    group = os.path.basename(os.path.dirname(os.path.dirname(path)))
    lqr = group.endswith("-lqr")  # the atlas's LQR as a controller file (lqr_controller.py)
    return {"task": group[:-4] if lqr else group, "class": "lqr" if lqr else cls(doc),
            "controller": os.path.basename(os.path.dirname(path)), "nominal_return": doc["nominal"]["return_mean"],
            "switches_per_second": doc["switching"]["switches_per_second_second_half"],
            "chattering_risk": doc["switching"].get("chattering_risk", ""),
            **certificate_part(doc), **region_part(doc),
            **old_region(group, os.path.basename(os.path.dirname(path))), "counterexamples": total, "knife_edge": knife,
            "worst_return_start_law": fals["start_law"].get("worst_return", "")}


def median(values: list) -> "float | str":
    v = [float(x) for x in values if x not in ("", None)]
    return round(float(np.median(v)), 4) if v else ""


def summary(rows: list) -> list:
    out = []
    for key in sorted({(r["task"], r["class"]) for r in rows}):
        rs = [r for r in rows if (r["task"], r["class"]) == key]
        out.append({"task": key[0], "class": key[1], "controllers": len(rs),
                    "nominal_return_median": median([r["nominal_return"] for r in rs]),
                    "fixed_point_certified": sum(r["fixed_point_certified"] for r in rs),
                    "certified_not_held": sum(r["certified_not_held"] for r in rs),
                    "cert_inscribed_radius_si_median": median([r["cert_inscribed_radius_si"] for r in rs]),
                    "hold_set_applies": sum(r["hold_set_applies"] for r in rs),
                    "hold_set_certified": sum(r["hold_set_certified"] for r in rs),
                    "hold_set_certified_k_step": sum(r["hold_set_certified"] and r["hold_set_k"] not in ("", 1)
                                                     for r in rs),
                    "invariant_between_instants": sum(r["between_invariant"] is True for r in rs),
                    "between_peak_linearization_median": median([r["between_peak_linearization"] for r in rs]),
                    "boundary_all_converged": sum(bool(r["boundary_converged"]) and r["boundary_converged"].split("/")[0]
                                                  == r["boundary_converged"].split("/")[1] for r in rs),
                    "refused": sum(bool(r["refused"]) for r in rs),
                    "roa_radius_median_median": median([r["roa_radius_median"] for r in rs]),
                    "roa_volume_sampled_median": median([r["roa_volume_sampled"] for r in rs]),
                    "not_star_shaped_controllers": sum(1 for r in rs if (r["not_star_shaped_directions"] or 0) > 0),
                    "lqr_roa_radius_median_median": median([r["lqr_roa_radius_median"] for r in rs]),
                    "old_roa_radius_median_median": median([r["old_roa_radius_median"] for r in rs]),
                    "old_roa_volume_median": median([r["old_roa_volume"] for r in rs]),
                    "counterexamples": sum(r["counterexamples"] for r in rs),
                    "knife_edge": sum(r["knife_edge"] for r in rs),
                    "tolerances": len({r["tolerance"] for r in rs})})
    return out


def main() -> None:
    rows = [row(p) for p in sorted(glob.glob(os.path.join(RESULTS, "*", "*", "verify.json")))]
    write_csv(os.path.join(RESULTS, "per_controller.csv"), rows)
    write_csv(os.path.join(RESULTS, "summary.csv"), summary(rows))
    print(f"{len(rows)} controllers -> {RESULTS}/per_controller.csv, summary.csv")


if __name__ == "__main__":
    main()
