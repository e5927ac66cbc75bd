"""verify.json (schema: docs/verify.md), report.md and figures of one controller's verification."""

import json
import os
from typing import Any

import numpy as np

from gsa_jax.running.formats import FORMAT_VERSION
from gsa_jax.verify.analysis import Budget
from gsa_jax.verify.system import System

SCHEMA = 2


def public(obj: Any) -> Any:
    """obj without the private entries (keys starting with '_') the analyses pass between themselves."""
    if isinstance(obj, dict):
        return {k: public(v) for k, v in obj.items() if not str(k).startswith("_")}
    if isinstance(obj, list):
        return [public(v) for v in obj]
    return obj


def write_json(path: str, system: System, result: dict, budget: Budget, quick: bool) -> dict:
    import mujoco

    from gsa_jax.running.runinfo import git_commit

    doc = {"format_version": FORMAT_VERSION, "schema": SCHEMA, "controller": system.path, "env": system.env,
           "kind": system.ctrl.kind,
           "clusters": int(system.ctrl.num_clusters), "quick": bool(quick), "budget": budget._asdict(),
           "versions": {"mujoco": mujoco.__version__, "numpy": np.__version__}, "commit": git_commit(),
           **public(result)}
    with open(path, "w") as f:
        json.dump(doc, f, indent=1)
    return doc


def _fmt(x, digits=3):
    return f"{x:.{digits}g}" if isinstance(x, float) else str(x)


def local_lines(doc: dict) -> list:
    local = doc.get("local", {})
    if "note" in local:
        return [f"No local analysis: {local['note']}."]
    lines = ["| piece | fixed point | picked there | spectral radius | saturated | at a joint's limit | qpos | qvel |",
             "|---|---|---|---|---|---|---|---|"]
    for p in local["pieces"]:
        piece = "network" if p["piece"] is None else p["piece"]
        if not p["fixed_point_found"]:
            lines.append(f"| {piece} | none found (residual {_fmt(p['residual'])}) | | | | | | |")
            continue
        limit = ", ".join(p["at_limit"]) + " (kept out)" if p["at_limit"] else "no"
        lines.append(f"| {piece} | found | {p['picked_there']}{'' if p['own_region'] else ' (not its own)'} | "
                     f"{p['spectral_radius']:.4f} | {p['saturated']} | {limit} | {np.round(p['qpos'], 4).tolist()} | "
                     f"{np.round(p['qvel'], 4).tolist()} |")
    return lines + ["", f"Verdict: {fixed_point_verdict(local)}."]


def fixed_point_verdict(local: dict) -> str:
    fp = local["closed_loop_fixed_point"]
    if fp is None:
        return ("no piece's fixed point lies where the partition picks that piece, away from a joint's limit: the "
                "closed loop has no fixed point near the hold (it holds by switching, against a limit, or not at all)")
    where = "network" if fp["piece"] is None else f"piece {fp['piece']}"
    stable = "stable" if fp["spectral_radius"] < 1 else "unstable"
    return (f"the closed loop's fixed point nearest the hold is {where}'s at qpos {np.round(fp['qpos'], 4).tolist()}, "
            f"{stable} (spectral radius {fp['spectral_radius']:.4f})")


def roa_lines(name: str, r: "dict | None") -> list:
    if r is None:
        return []
    if "note" in r:
        return [f"- {name}: {r['note']} (volume 0)."]
    lyap = r.get("lyapunov")
    ly = "no quadratic Lyapunov function (no stable fixed point)"
    if lyap:
        ly = (f"quadratic Lyapunov level {lyap['level']:.3g} ({lyap['bounded_by']}), its ellipsoid "
              f"{lyap['ball_share']:.3g} of the ball of radius r_max")
    h, hold = r["horizon"], r["hold"]
    axis = "; ".join(f"{c} -{lo:.3g} to +{hi:.3g}" for c, (lo, hi) in zip(r["coordinates"], r["axis_radius_si"]))
    sampled = r["volume_fraction_sampled"]
    return [f"- {name}: radius min {r['radius_min']:.3g}, median {r['radius_median']:.3g} (scaled units; first "
            f"radius {r['r_max']}, grown up to {r['r_limit']:g}: {r['unbounded_directions']} of {len(r['radius'])} "
            f"directions without a boundary there), as large as a ball of radius {r['radius_equivalent']:.3g}",
            f"  - volume fraction of the ball of radius {r['r_max']}: {r['volume_fraction']:.3g} from the radii "
            f"(star-shaped), {'-' if sampled is None else f'{sampled:.3g}'} from {r['ball_samples']} uniform samples; "
            f"{r['not_star_shaped_directions']} of {len(r['radius'])} directions not star-shaped (a start below "
            f"the radius fails)",
            f"  - from the hold along each coordinate alone: {axis}",
            f"  - horizon {h['steps']} steps ({h['seconds']:.3g} s, set by {h['set_by']}); the hold's own excursion "
            f"{'within' if hold['within_tolerance'] else 'beyond'} the task's tolerance "
            f"{np.round(r['tolerance'], 4).tolist()}; {ly}"]


def certificate_lines(cert: dict) -> list:
    """The certificate (gsa_jax.verify.certify) in words, SI units per coordinate."""
    where = "the network" if cert["piece"] is None else f"piece {cert['piece']}"
    extent = ", ".join(f"{name} +-{e:.3g}" for name, e in zip(cert["coordinates"], cert["extent"]))
    rounds = rounds_text(cert["rounds"])
    verdict = ("certified: the confirmation round found no violation" if cert["certified"] else
               f"nothing certified: every one of {len(cert['rounds'])} rounds found violations")
    return [f"{cert['claim'][0].upper()}{cert['claim'][1:]}.", *held_lines(cert), *margin_flag_lines(cert),
            f"- fixed point: {where}'s at qpos {np.round(cert['qpos'], 4).tolist()}, qvel "
            f"{np.round(cert['qvel'], 4).tolist()}; spectral radius {cert['spectral_radius']:.4f}",
            f"- V(x) = (x - x*)' P (x - x*) falls by rho^2 over k = {cert['k']} control steps ({cert['k_seconds']:.3g} "
            f"s), rho = {cert['rho']:.4g} ({cert['rho_per_step']:.4g} per step); on the linearization "
            f"A^k' P A^k <= rho_P^2 P, rho_P = {cert['rho_linearization']:.4g}",
            f"- level {cert['level']:.4g} ({verdict}); {cert['level_linearization']:.4g} on the linearization, "
            f"bounded by {cert['bounded_by']}",
            f"- extent (each coordinate's largest excursion inside the set, in its units): {extent}; the semi-axes "
            "and the inscribed radius, which mix units, are in verify.json",
            f"- plant test ({cert['samples']} starts, each stepped k control steps in MuJoCo C with the exported "
            f"controller): {rounds}", *room_lines(cert), *between_lines(cert.get("between_instants")),
            *margin_lines(cert.get("margins"))]


def margin_flag_lines(cert: dict) -> list:
    """The headline's warning where a margin is below its threshold (gsa_jax.verify.margins)."""
    m = cert.get("margins")
    if not m or not m["flags"]:
        return []
    t = m["thresholds"]
    return [f"- **Low robustness margins**: {'; '.join(m['flags'])} (flagged below a gain margin of {t['gain']:g}x "
            f"either way, {t['delay_steps']} control step of delay, a disk margin of {t['disk']:g})."]


def plant_words(check: "dict | None", kind: str) -> str:
    """A margin's plant check in words (margins.checked_gain / checked_delay)."""
    if check is None:
        return "nothing to cross on the plant"
    if kind == "delay":
        a, b = check["holds_at"], check["holds_past"]
        said = (f"{check['at']} steps: {'holds' if a['holds'] else 'does not hold'}; {check['past']}: "
                f"{'holds' if b['holds'] else 'does not hold'}")
    else:
        a, b = check["holds_inside"], check["holds_outside"]
        said = (f"x{check['inside']:.4g}: {'holds' if a['holds'] else 'does not hold'} (growth {a['growth']:.3g}); "
                f"x{check['outside']:.4g}: {'holds' if b['holds'] else 'does not hold'} (growth {b['growth']:.3g})")
    return f"on the plant {said}: {'confirmed' if check['confirmed'] else '**not confirmed**'}"


def margin_lines(m: "dict | None") -> list:
    """The certificate's robustness margins (gsa_jax.verify.margins) with their plant checks."""
    if not m:
        return []
    disk, plant = m["disk"], m["plant"]
    return [f"- gain margins (every action channel scaled around the fixed point's action): lower {m['gain_lower']:.4g}x "
            f"({plant_words(plant['gain_lower'], 'gain')}), upper {m['gain_upper']:.4g}x "
            f"({plant_words(plant['gain_upper'], 'gain')})",
            f"- delay margin: {m['delay_steps']} control steps ({plant_words(plant['delay'], 'delay')})",
            f"- disk margin {disk['alpha']:.3g} (symmetric; gains {disk['gain_range'][0]:.3g}x to "
            f"{disk['gain_range'][1]:.3g}x and phase +-{disk['phase_deg']:.3g} degrees at once"
            + ("; with several action channels a lower bound for perturbations of all at once)"
               if m.get("channels", 2) > 1 else ")")]


def held_lines(cert: dict) -> list:
    """A warning where the certified fixed point is not the task's held equilibrium (certify.held_equilibrium); [] for
    a record without the check."""
    if "held_equilibrium" not in cert or cert["held_equilibrium"]:
        return []
    return [f"- **Not the held equilibrium: not counted as certified** ({cert['held_why']}); the set below is about "
            "that fixed point only."]


def rounds_text(rounds: list) -> str:
    """The plant test's rounds (gsa_jax.verify.certify.check_round) in words."""
    return "; ".join(f"level {r['level']:.4g}{' (confirmation)' if r.get('confirmation') else ''}: {r['samples']} "
                     f"samples inside, {r['boundary_samples']} on the boundary, {r['falsifier_episodes']} falsifier "
                     f"starts, {r['violations']} violations" for r in rounds)


def room_lines(rec: dict) -> list:
    """The certified level's room (certify.room_fields) in words; nothing for a record without it."""
    if "room" not in rec or not rec.get("level_clean"):
        return []
    first = rec["first_violating_v0"]
    where = ("no round found a violation" if first is None else
             f"the first violation found lies at V = {first:.4g}, {1 / rec['level_share_of_first_violation']:.3g}x "
             "the certified level")
    return [f"- room to spare: the level is {rec['room']:.3g} x the last clean level {rec['level_clean']:.4g}, confirmed "
            f"by a round of fresh samples; {where}"]


def between_lines(b: "dict | None") -> list:
    """V between the k-step instants and the convergence from E's boundary (gsa_jax.verify.boundary) in words."""
    if not b:
        return []
    inv = ("invariant at every step" if b["invariant"] else
           "not invariant between the k-step instants: V rises above the level before it falls")
    conv = (f"{b['converged']} of {b['starts']} starts on E's boundary settle within the task's convergence tolerance "
            f"in the horizon of {b['horizon_seconds']:.3g} s")
    if b["converged"]:
        conv += f" (median {b['seconds_median']:.3g} s, slowest {b['seconds_max']:.3g} s)"
    return [f"- between the instants: the set is {inv} (peak of V / level over the k steps {b['linearization_peak']:.3g} "
            f"on the linearization, at step {b['linearization_peak_step']}; {b['plant_peak']:.3g} over {b['starts']} "
            f"boundary starts on the plant); {conv}"]


def hold_set_lines(rec: dict) -> list:
    """The switching hold's invariant set (gsa_jax.verify.invariant) in words, SI units per coordinate."""
    lines = [f"{rec['claim'][0].upper()}{rec['claim'][1:]}.",
             f"- hold: pieces {rec['pieces']}, {rec['switches_per_second']:.3g} switches per second, centre x_c at qpos "
             f"{np.round(rec['qpos'], 4).tolist()}, qvel {np.round(rec['qvel'], 4).tolist()}; the pieces' closed loops "
             f"there have spectral radii {', '.join(f'{r:.4f}' for r in rec['spectral_radii'])}; cells "
             f"{rec['cells']}",
             f"- no fixed-point certificate: {rec['fixed_point']}" if rec.get("fixed_point") else
             "- the fixed point's certificate is reported beside it"]
    if "P" not in rec:
        return lines + [f"- nothing certified: {rec['reason']}"]
    extent = lambda key: ", ".join(f"{name} +-{e:.3g}" for name, e in zip(rec["coordinates"], rec[key]))
    verdict = ("certified: the confirmation round found no violation" if rec["certified"] else
               f"nothing certified: {rec['reason']}")
    k = rec.get("k", 1)
    steps = "one control step" if k == 1 else f"{k} control steps"
    program = [] if k == 1 else [
        f"- no one-step V: {rec['one_step_refusal']}; the set below is the k-step program's, fitted on "
        f"{rec['model_samples']} sampled runs of the piecewise-affine model from the box +-"
        f"{np.round(rec['sampled_box'], 4).tolist()} around x_c"]
    stays = "and stays" if k == 1 else f"at the {k}-step instants and stays there at those instants (between them V may rise)"
    return lines + program + [
        f"- V(x) = (x - x_c)' P (x - x_c): V(x_{k}) <= rho^2 V(x_0) + gamma over {steps} ({rec['k_seconds']:.3g} "
        f"s), rho = {rec['rho']:.4g}, gamma = {rec['gamma']:.4g}; on the {'linearization' if k == 1 else 'model samples'} "
        f"rho_P = {rec['rho_linearization']:.4g}",
        f"- level {rec['level']:.4g} ({verdict}); {rec['level_linearization']:.4g} on the linearization, bounded by "
        f"{rec['bounded_by']}; every start in the set enters the inner set V <= {rec['inner_level']:.4g} {stays}",
        f"- extent (each coordinate's largest excursion inside the set, in its units): {extent('extent')}; the inner "
        f"set's: {extent('inner_extent')}; the semi-axes and the inscribed radius, which mix units, are in verify.json",
        f"- plant test ({rec['samples']} starts, each stepped {steps} in MuJoCo C with the exported "
        f"controller): {rounds_text(rec['rounds'])}", *room_lines(rec)]


def push_text(push: "dict | None") -> str:
    if push is None:
        return "no push"
    return f"push {np.round(push['velocity_change'], 2).tolist()} m/s at step {push['step']}"


def searches(doc: dict) -> dict:
    """The falsification's searches by name (its rule aside)."""
    return {k: v for k, v in doc["falsification"].items() if k != "rule"}


def counterexample_line(c: dict, threshold: "float | None" = None, horizon: "int | None" = None) -> str:
    """One counterexample in words: below the failure threshold (the nominal episodes' worst return, stated) or not,
    and whether it terminated (an episode shorter than the task's horizon) or only scored less."""
    ended = "" if horizon is None else (f", terminated at step {c['steps']}" if c["steps"] < horizon else
                                        ", did not terminate")
    below = "below" if c["fails"] else "not below"
    bar = f"the failure threshold {threshold:.1f}" if threshold is not None else "the failure threshold"
    verdict = f"{below} {bar}{ended}" + ("; knife-edge, kept out of the worst return" if c["knife_edge"] else "")
    inherited = " (inherited)" if c["inherited"] else ""
    return (f"  - return {c['return']:.1f} in {c['steps']} steps from qpos {np.round(c['qpos'], 3).tolist()}, qvel "
            f"{np.round(c['qvel'], 3).tolist()}, {push_text(c['push'])}: {verdict}; neighbours failing "
            f"{c['neighbours_failing']:.2f}, robustness {c['robustness']:.3g}{inherited}")


def falsification_lines(doc: dict) -> list:
    n, rule = doc["nominal"], doc["falsification"]["rule"]
    lines = [f"Nominal (start law, {n['episodes']} episodes): mean return {n['return_mean']:.1f}, "
             f"5th percentile {n['return_p05']:.1f}, worst {n['return_min']:.1f}.", "",
             f"A counterexample counts as failing with {rule['failure']} (a score threshold: it need not terminate); "
             f"{rule['neighbours']} neighbours within "
             f"{rule['perturbation_scaled']:g} scaled units give the share that fail too, knife-edge below "
             f"{rule['knife_edge_share']:g}; robustness: {rule['robustness']}.", ""]
    for name, f in searches(doc).items():
        worst = "none" if f["worst_return"] is None else f"{f['worst_return']:.1f}"
        start = f", starting from {f['starts_from'].replace('_', ' ')}'s worst cases" if f["starts_from"] else ""
        lines.append(f"- {name.replace('_', ' ')}: {f['episodes']} episodes{start}, worst return {worst} "
                     f"({f['worst_return_with_knife_edges']:.1f} with {f['knife_edge_counterexamples']} knife-edge "
                     f"counterexamples; 5th percentile of the first iteration's draws {f['first_iteration_p05']:.1f})")
        lines += [counterexample_line(c, rule["failure_return"], rule.get("horizon")) for c in f["counterexamples"]]
    return lines


def lqr_weights_text(lqr: dict) -> str:
    """How the LQR beside the controller weights states and actions, in words."""
    w = lqr.get("weights", "Q = I on scaled states, R = I")
    if isinstance(w, str):
        return w
    return f"Q = diag({', '.join(f'{x:g}' for x in w['q'])}), R = diag({', '.join(f'{x:g}' for x in w['r'])}) in the task's units"


def write_markdown(path: str, doc: dict) -> None:
    s = doc["switching"]
    lines = [f"# Verification of `{doc['controller']}`", "",
             f"{doc['env']}, {doc['kind']} ({doc['clusters']} pieces){', quick budget' if doc['quick'] else ''}.", "",
             "## Local analysis per piece", "", *local_lines(doc), "", "## Region of attraction", ""]
    if "roa" in doc:
        lines += roa_lines("controller", doc["roa"]) + roa_lines(f"LQR on the same linearization ({lqr_weights_text(doc['lqr'])})",
                                                                 doc["lqr"].get("roa"))
        lines += [f"- LQR: {doc['lqr']['note']}."] if "note" in doc["lqr"] else []
    else:
        lines.append("None: no equilibrium declared.")
    if "certificate" in doc:
        lines += ["", "## Certified region of attraction", "", *certificate_lines(doc["certificate"]), "",
                  "Not proved on the plant: the decrease is tested at the samples and the falsifier's starts, not "
                  "between them; no disturbance, model error or sensor noise is part of it."]
    if "hold_set" in doc:
        lines += ["", "## Invariant set of the hold kept by switching", "", *hold_set_lines(doc["hold_set"])]
    risk = (f" (above {s['chatter_rate_limit']:g}: a hardware risk, chattering)" if s["chattering_risk"] else "")
    lines += ["", "## Falsification", "", *falsification_lines(doc), "", "## Switching", "",
              f"Switches per second {s['switches_per_second']:.3g} (second half of the episodes: "
              f"{s['switches_per_second_second_half']:.3g}{risk}); dwell {s['dwell_steps_mean']:.3g} steps on average "
              f"(median {s['dwell_steps_median']:.3g}); pieces used {s['pieces_used']} with shares "
              f"{np.round(s['piece_share'], 3).tolist()}; crossings {s['crossings']}.", "",
              f"Cost (s): {doc['cost_seconds']}.", "", "![figures](verify.png)", ""]
    with open(path, "w") as f:
        f.write("\n".join(lines))


def eigenvalue_panel(ax: "object", doc: dict) -> None:
    """Each piece's and the LQR's closed-loop eigenvalues around the unit circle, scaled to those of fixed points away
    from a joint's limit (those at one drawn hollow, off the scale where they fall outside it)."""
    t = np.linspace(0, 2 * np.pi, 200)
    ax.plot(np.cos(t), np.sin(t), "k:", lw=0.8)
    extent = 1.0
    for p in doc.get("local", {}).get("pieces", []):
        if "eigenvalues" in p:
            e = np.array(p["eigenvalues"])
            label = f"piece {p['piece']}" if p["piece"] is not None else "network"
            at_limit = bool(p["at_limit"])
            ax.plot(e[:, 0], e[:, 1], "o", ms=4, mfc="none" if at_limit else None,
                    label=label + (" (at a joint's limit)" if at_limit else ""))
            extent = extent if at_limit else max(extent, float(np.abs(e).max()))
    if "lqr" in doc and "eigenvalues" in doc["lqr"]:
        e = np.array(doc["lqr"]["eigenvalues"])
        ax.plot(e[:, 0], e[:, 1], "kx", label="LQR")
        extent = max(extent, float(np.abs(e).max()))
    ax.set(title="closed-loop eigenvalues", aspect="equal", xlim=(-1.1 * extent, 1.1 * extent),
           ylim=(-1.1 * extent, 1.1 * extent))


def write_figure(path: str, doc: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(13, 4))
    eigenvalue_panel(ax[0], doc)
    if len(ax[0].lines) > 1:
        ax[0].legend(fontsize=7)
    for name, r in (("controller", doc.get("roa")), ("LQR", doc.get("lqr", {}).get("roa"))):
        if r and r.get("radius"):
            ax[1].plot(np.sort(r["radius"]), label=name)
    ax[1].set(title="region of attraction: radius per direction (sorted)", ylabel="scaled radius")
    if ax[1].lines:
        ax[1].legend(fontsize=7)
    for name, f in searches(doc).items():
        ax[2].plot(f["best_by_iteration"], "o-", label=name)
    ax[2].axhline(doc["nominal"]["return_mean"], color="k", ls="--", label="nominal mean")
    ax[2].set(title="falsification: lowest return so far", xlabel="CEM iteration")
    ax[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_all(out_dir: str, system: System, result: dict, budget: Budget, quick: bool) -> dict:
    os.makedirs(out_dir, exist_ok=True)
    doc = write_json(os.path.join(out_dir, "verify.json"), system, result, budget, quick)
    write_markdown(os.path.join(out_dir, "report.md"), doc)
    write_figure(os.path.join(out_dir, "verify.png"), doc)
    return doc


def pwa_lines(check: dict) -> list:
    """The checks of a certificate's piecewise-affine export (gsa_jax.verify.pwa_export) as report lines."""
    c, box = check["controller"], check["box_image_milp"]
    found = ", ".join(f"{name}: {n} of {check['points']}" for name, n in check["counterexamples"].items())
    image = ("maps into itself" if box["value"] <= 1.0 else "does not map into itself")
    return [f"- The PWA model against the NumPy controller at the linearized observations ({c['points']} points in E "
            f"and on its boundary): the same piece at {100 * c['same_piece']:.2f}% of them, actions within "
            f"{c['action_max_abs_diff']:.3g}.",
            f"- onnxruntime's output against NumPy's on the same points: within {check['onnx_max_rel_diff']:.3g} "
            "of each output's largest value.",
            f"- Counterexamples of the VNN-LIB properties among those points (0: the certificate holds there on the "
            f"linearization): {found}.",
            f"- E's bounding box under one step of the PWA loop, every piece and its cell ({box['solver']}, "
            f"{box['programs']} mixed-integer programs, exact for the model): its image reaches {box['value']:.4g} "
            f"box widths (at most 1: the box maps into itself), so the box {image} in one control step; the model "
            f"stepped at the maximizer gives {box['pwa_value_there']:.4g}."]
