"""Find the start pose of the Allegro cylinder task and write it into envs/assets/allegro_cylinder.xml.

    python experiments/fig3_allegro/allegro_grasp.py [--seed 0]
    python experiments/fig3_allegro/allegro_grasp.py --pairs   # which geoms can touch: the MJCF's <contact> pairs

How the asset's object placement and keyframe "grasp" were made (run once; the result is committed):
1. sample index-finger and thumb configurations (middle 70% of each joint range), pair them, and keep
   the pair whose fingertip spheres can touch a 25 mm cylinder from opposite sides: the tips'
   separation across the cylinder axis (parallel to the index flexion axis) is 2 * (25 + 12) mm,
   both finger pads face the axis, the cylinder is in front of the palm, the joints are far from
   their limits;
2. refine both fingers by damped least squares so each tip sphere just touches the cylinder;
3. set the PD targets 2 mm further into the object ("squeeze") and let MuJoCo C settle for 0.5 s;
   the settled joint positions and the squeezed targets are the keyframe.
"""

import argparse
import re
from pathlib import Path

import mujoco
import numpy as np

ASSET = Path(__file__).resolve().parents[2] / "envs" / "assets" / "allegro_cylinder.xml"
R_OBJ, R_TIP = 0.025, 0.012
SQUEEZE = 0.002
FINGERS = {"ff": ("ff_j0", "ff_j1", "ff_j2", "ff_j3"), "th": ("th_j0", "th_j1", "th_j2", "th_j3")}


def _quat_rotate(q, v):
    res = np.zeros(3)
    mujoco.mju_rotVecQuat(res, np.asarray(v, float), np.asarray(q, float))
    return res


def object_axis():
    """Index flexion axis at ff_j0 = 0: the ff_base frame's y axis, in the palm (= world) frame."""
    return _quat_rotate([0.999048, -0.0436194, 0, 0], [0, 1, 0])


def _finger_samples(m, d, finger, n, rng):
    jids = [m.joint(j).id for j in FINGERS[finger]]
    lo, hi = m.jnt_range[jids].T
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    qs = mid + rng.uniform(-0.7, 0.7, size=(n, 4)) * half
    tips, pads = np.zeros((n, 3)), np.zeros((n, 3))
    site, body = m.site(f"{finger}_tip").id, m.body(f"{finger}_dist").id
    for i, q in enumerate(qs):
        d.qpos[[m.jnt_qposadr[j] for j in jids]] = q
        mujoco.mj_kinematics(m, d)
        tips[i] = d.site_xpos[site]
        pads[i] = d.xmat[body].reshape(3, 3)[:, 0]  # flexion turns +z toward +x: the pad faces +x
    return qs, tips, pads, (qs - mid) / half


def choose_pair(m, u, n=2500, seed=0):
    """The (index, thumb) configuration pair that best pinches a cylinder with axis u."""
    rng = np.random.default_rng(seed)
    d = mujoco.MjData(m)
    qa, ta, pa, za = _finger_samples(m, d, "ff", n, rng)
    qb, tb, pb, zb = _finger_samples(m, d, "th", n, rng)
    diff = ta[:, None, :] - tb[None, :, :]  # (n, n, 3)
    along = diff @ u
    perp = diff - along[..., None] * u
    sep = np.linalg.norm(perp, axis=-1)
    normal = perp / np.maximum(sep, 1e-9)[..., None]  # from thumb tip toward index tip, across the axis
    centre = (ta[:, None, :] + tb[None, :, :]) / 2
    pad_a = -(pa[:, None, :] * normal).sum(-1)  # index pad faces the axis: along -normal
    pad_b = (pb[None, :, :] * normal).sum(-1)
    cost = (
        ((sep - 2 * (R_OBJ + R_TIP)) / 0.002) ** 2
        + (along / 0.01) ** 2
        + 400 * (np.clip(0.8 - pad_a, 0, None) ** 2 + np.clip(0.8 - pad_b, 0, None) ** 2)
        + 100 * np.clip(0.011 + R_OBJ + 0.01 - centre[..., 0], 0, None) ** 2 / 1e-4
        + 0.5 * ((za**2).sum(-1)[:, None] + (zb**2).sum(-1)[None, :])
    )
    i, j = np.unravel_index(np.argmin(cost), cost.shape)
    return qa[i], qb[j], centre[i, j], normal[i, j], float(cost[i, j])


def solve_tip(m, finger, q0, target, iters=200):
    """Damped least squares: joints of `finger` that put its tip-sphere centre at `target`."""
    d = mujoco.MjData(m)
    jids = [m.joint(j).id for j in FINGERS[finger]]
    adr = [m.jnt_qposadr[j] for j in jids]
    dofs = [m.jnt_dofadr[j] for j in jids]
    site = m.site(f"{finger}_tip").id
    q = np.array(q0, float)
    jac = np.zeros((3, m.nv))
    for _ in range(iters):
        d.qpos[adr] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        err = target - d.site_xpos[site]
        if np.linalg.norm(err) < 1e-6:
            break
        mujoco.mj_jacSite(m, d, jac, None, site)
        J = jac[:, dofs]
        q = q + J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(3), err)
        q = np.clip(q, *m.jnt_range[jids].T)
    return q, float(np.linalg.norm(err))


def sample_joints(m, n, rng):
    """n configurations of the 8 finger joints (n, 8): each joint at its lower limit, its upper limit or
    uniform in between, with probability 1/4, 1/4, 1/2 (contacts happen at the limits)."""
    lo, hi = m.jnt_range[:8].T
    u = rng.uniform(lo, hi, size=(n, 8))
    pick = rng.integers(0, 4, size=(n, 8))
    return np.where(pick == 0, lo, np.where(pick == 1, hi, u))


def candidate_pairs(m):
    """Geom pairs of different bodies that are neither welded together nor parent and child (the object's
    visual marker aside)."""
    marker = [g for g in range(m.ngeom) if m.geom_bodyid[g] == m.body("object").id and m.geom(g).name != "object"]
    geoms = [g for g in range(m.ngeom) if g not in marker]
    body, weld, parent = m.geom_bodyid, m.body_weldid, m.body_parentid
    return [(a, b) for i, a in enumerate(geoms) for b in geoms[i + 1:]
            if weld[body[a]] != weld[body[b]] and parent[body[a]] != body[b] and parent[body[b]] != body[a]]


def reachable_pairs(m, n=20000, seed=0, cutoff=0.05):
    """{(geom1 name, geom2 name): (smallest distance [m], fraction of configurations in overlap)} over n
    sampled finger configurations (sample_joints), for every candidate pair (distances capped at cutoff).
    A pair that can touch has a smallest distance <= 0; one in overlap in every configuration is two
    shapes sharing a joint, not a contact."""
    d = mujoco.MjData(m)
    pairs = candidate_pairs(m)
    dist = np.zeros((n, len(pairs)))
    fromto = np.zeros(6)
    for i, q in enumerate(sample_joints(m, n, np.random.default_rng(seed))):
        d.qpos[:8] = q
        mujoco.mj_kinematics(m, d)
        dist[i] = [mujoco.mj_geomDistance(m, d, a, b, cutoff, fromto) for a, b in pairs]
    name = lambda g: m.geom(g).name or m.body(m.geom_bodyid[g]).name  # noqa: E731
    return {(name(a), name(b)): (float(dist[:, j].min()), float(np.mean(dist[:, j] < 0))) for j, (a, b) in enumerate(pairs)}


def report_pairs(m, paired):
    """Print reachable_pairs, closest first, marking the pairs the MJCF collides."""
    got = reachable_pairs(m)
    print(f"{'geom pair':>24} {'closest (mm)':>13} {'overlap':>8}  paired in the MJCF")
    for (a, b), (dmin, frac) in sorted(got.items(), key=lambda kv: kv[1][0]):
        print(f"{a:>11} {b:>12} {dmin * 1e3:13.1f} {frac:8.3f}  {'yes' if {a, b} in paired else ''}")


def _set_object(xml, pos, quat, half):
    xml = re.sub(r'(<body name="object" pos=")[^"]*(" quat=")[^"]*(")',
                 lambda g: f'{g[1]}{" ".join(f"{x:.6f}" for x in pos)}{g[2]}{" ".join(f"{x:.6f}" for x in quat)}{g[3]}', xml)
    xml = re.sub(r'(type="capsule" size="0.025 )[^"]*(")', lambda g: f"{g[1]}{half:.4f}{g[2]}", xml)
    return re.sub(r'(size="0.0035 0.0035 )[^"]*(")', lambda g: f"{g[1]}{half:.4f}{g[2]}", xml)


def _set_keyframe(xml, qpos, ctrl):
    fmt = lambda a: " ".join(f"{x:.6f}" for x in a)  # noqa: E731
    key = f'  <keyframe>\n    <key name="grasp" qpos="{fmt(qpos)}" ctrl="{fmt(ctrl)}"/>\n  </keyframe>'
    return re.sub(r"  <keyframe>.*?</keyframe>", key, xml, flags=re.S)


def main(argv=None):
    p = argparse.ArgumentParser(prog="python experiments/fig3_allegro/allegro_grasp.py",
                                description=__doc__.split("\n")[0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--pairs", action="store_true", help="report which geoms can touch (nothing is written)")
    args = p.parse_args(argv)

    xml = ASSET.read_text()
    m = mujoco.MjModel.from_xml_string(xml)
    if args.pairs:
        name = lambda g: m.geom(g).name  # noqa: E731
        return report_pairs(m, [{name(m.pair_geom1[i]), name(m.pair_geom2[i])} for i in range(m.npair)])
    u = object_axis()
    qa, qb, centre, normal, cost = choose_pair(m, u, seed=args.seed)
    print(f"pair cost {cost:.3f}, centre {np.round(centre, 4)}")
    touch = R_OBJ + R_TIP
    qa, ea = solve_tip(m, "ff", qa, centre + touch * normal)
    qb, eb = solve_tip(m, "th", qb, centre - touch * normal)
    ca, _ = solve_tip(m, "ff", qa, centre + (touch - SQUEEZE) * normal)
    cb, _ = solve_tip(m, "th", qb, centre - (touch - SQUEEZE) * normal)
    print(f"touch IK residuals: index {ea * 1e3:.3f} mm, thumb {eb * 1e3:.3f} mm")

    # object frame: capsule axis (local z) along u, centred between the tips along u
    z = u / np.linalg.norm(u)
    x = normal - (normal @ z) * z
    x /= np.linalg.norm(x)
    mat = np.stack([x, np.cross(z, x), z], axis=1)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, mat.ravel())
    half = 0.045
    xml = _set_object(xml, centre, quat, half)

    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qpos[:4], d.qpos[4:8] = qa, qb
    d.ctrl[:4], d.ctrl[4:8] = ca, cb
    mujoco.mj_step(m, d, nstep=int(round(0.5 / m.opt.timestep)))
    forces = np.zeros(2)
    for i in range(d.ncon):
        f = np.zeros(6)
        mujoco.mj_contactForce(m, d, i, f)
        geoms = {d.contact.geom1[i], d.contact.geom2[i]}
        forces[0 if m.geom("ff_tip").id in geoms else 1] += f[0]
    print(f"after 0.5 s: {d.ncon} contacts, tip normal forces index {forces[0]:.2f} N, thumb {forces[1]:.2f} N, "
          f"object speed {d.qvel[8]:.4f} rad/s")
    if d.ncon != 2:
        raise SystemExit("the settled grasp lost a contact; try another --seed")
    qpos = d.qpos.copy()
    qpos[8] = 0.0
    ASSET.write_text(_set_keyframe(xml, qpos, d.ctrl))
    print(f"wrote {ASSET}")


if __name__ == "__main__":
    main()
