"""Independent re-implementation of P(mixture falls less than flat PPO) and its
controllers-only / two-way (controllers x events) percentile bootstrap intervals.
Reads only pushes.csv.gz and the committed paired_pushes.csv / draws.csv."""
import numpy as np
import pandas as pd

import os

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # experiments/
W = 50
B = 2000
rng = np.random.default_rng(20240611)


def matrices(d, policy, K):
    """(counted, fell) arrays of shape (controllers, events), events ordered by (start_seed, event)."""
    sel = d[(d.policy == policy) & ((d.K == K) if K is not None else d.K.isna())]
    c = sel.pivot_table(index="seed", columns=["start_seed", "event"], values=f"counted_W{W}", aggfunc="first")
    f = sel.pivot_table(index="seed", columns=["start_seed", "event"], values=f"fell_W{W}", aggfunc="first")
    f = f.reindex_like(c)
    assert not c.isna().any().any() and not f.isna().any().any()
    return c.columns, c.to_numpy(float), (f.to_numpy(float) * c.to_numpy(float))


def fall_prob(C, F, w):
    n = C @ w
    k = F @ w
    with np.errstate(invalid="ignore", divide="ignore"):
        p = k / n
    return p[n > 0]


def pairP(pm, pf):
    if len(pm) == 0 or len(pf) == 0:
        return np.nan
    a = pm[:, None]
    b = pf[None, :]
    return float(np.mean((a < b) + 0.5 * (a == b)))


def boot(Cm, Fm, Cf, Ff, events):
    n_ev = Cm.shape[1]
    out = np.empty(B)
    for i in range(B):
        if events:
            w = np.bincount(rng.integers(0, n_ev, n_ev), minlength=n_ev).astype(float)
        else:
            w = np.ones(n_ev)
        im = rng.integers(0, Cm.shape[0], Cm.shape[0])
        jf = rng.integers(0, Cf.shape[0], Cf.shape[0])
        out[i] = pairP(fall_prob(Cm[im], Fm[im], w), fall_prob(Cf[jf], Ff[jf], w))
    return np.nanpercentile(out, [2.5, 97.5])


def verdict(lo, hi):
    return "less" if lo > 0.5 else ("more" if hi < 0.5 else "not shown")


rows = []
for env in ["Ant-v5", "Walker2d-v5"]:
    d = pd.read_csv(f"{ROOT}/robustness/results/{env}/pushes.csv.gz")
    com = pd.read_csv(f"{ROOT}/robustness/results/{env}/paired_pushes.csv")
    for size in sorted(d["size"].unique()):
        ds = d[d["size"] == size]
        evf, Cf, Ff = matrices(ds, "mlp", None)
        w1 = np.ones(Cf.shape[1])
        for K in sorted(ds.loc[ds.policy == "mixture", "K"].unique()):
            evm, Cm, Fm = matrices(ds, "mixture", K)
            assert list(evm) == list(evf), "event sets differ between configurations"
            P = pairP(fall_prob(Cm, Fm, w1), fall_prob(Cf, Ff, w1))
            ev_lo, ev_hi = boot(Cm, Fm, Cf, Ff, True)
            co_lo, co_hi = boot(Cm, Fm, Cf, Ff, False)
            r = com[(com.policy == "mixture") & (com.K == K) & (com["size"] == size) & (com.window == W)].iloc[0]
            rows.append(dict(env=env, K=int(K), size=size, P_com=r.p_falls_less_than_flat_ppo, P_mine=round(P, 4),
                             ev_com=(r.p_fall_events_ci_low, r.p_fall_events_ci_high),
                             ev_mine=(round(ev_lo, 3), round(ev_hi, 3)),
                             co_com=(r.p_fall_ci_low, r.p_fall_ci_high), co_mine=(round(co_lo, 3), round(co_hi, 3)),
                             maxdiff=round(max(abs(ev_lo - r.p_fall_events_ci_low), abs(ev_hi - r.p_fall_events_ci_high)), 3),
                             maxdiff_co=round(max(abs(co_lo - r.p_fall_ci_low), abs(co_hi - r.p_fall_ci_high)), 3),
                             w_ev=ev_hi - ev_lo, w_co=co_hi - co_lo,
                             v_com=verdict(r.p_fall_events_ci_low, r.p_fall_events_ci_high), v_mine=verdict(ev_lo, ev_hi)))

res = pd.DataFrame(rows)
pd.set_option("display.width", 250)
pd.set_option("display.max_columns", 30)
print(res.drop(columns=["w_ev", "w_co"]).to_string(index=False))
print("point estimates max |diff|:", (res.P_com - res.P_mine).abs().max())
print("max events-CI bound diff:", res.maxdiff.max(), " mean:", res.maxdiff.mean().round(3))
print("max controllers-only bound diff vs committed:", res.maxdiff_co.max())
print("mean width events:", res.w_ev.mean().round(3), " controllers-only:", res.w_co.mean().round(3),
      " cells where events narrower:", int((res.w_ev < res.w_co - 1e-9).sum()), "of", len(res))
print("verdict mismatches:", res[res.v_com != res.v_mine][["env", "K", "size", "ev_com", "ev_mine", "v_com", "v_mine"]].to_string(index=False))

# Claim check: Ant-v5 K=8 size 0.5 W=50
r = res[(res.env == "Ant-v5") & (res.K == 8) & (res["size"] == 0.5)].iloc[0]
dr = pd.read_csv(f"{ROOT}/push_draws/results/draws.csv")
dr = dr[(dr.env == "Ant-v5") & (dr.K == 8) & (dr["size"] == 0.5) & (dr.window == 50)]
vals = list(dr.p_falls_less_than_flat_ppo) + [0.58]
for name, (lo, hi) in [("committed events CI", r.ev_com), ("my events CI", r.ev_mine),
                       ("committed controllers-only CI", r.co_com), ("my controllers-only CI", r.co_mine)]:
    print(f"{name} [{lo}, {hi}] contains", {v: bool(lo <= v <= hi) for v in vals})
