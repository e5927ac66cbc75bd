"""Switching along trajectories: which pieces the closed loop uses, how long it stays in one (dwell), how often it
changes piece (switches per second, over whole episodes and over their second half, where an equilibrium task
holds), and between which pieces it crosses the partition's boundaries. A rate above CHATTER_RATE over the second
half is flagged as a hardware risk: an actuator asked to change its control law that often (chattering)."""

import numpy as np

from gsa_jax.deployment.numpy_policy import Controller

CHATTER_RATE = 10.0  # switches per second over the second half of the episodes: above it, a hardware risk


def piece_sequence(ctrl: Controller, obs: np.ndarray) -> np.ndarray:
    """[T, B] the piece the partition picks at each recorded observation obs [T, B, d_s] (0 for flat PPO)."""
    return ctrl.cluster(obs.astype(np.float32))


def dwell_times(seq: np.ndarray) -> np.ndarray:
    """Run lengths (steps) of one episode's piece sequence [T]."""
    change = np.flatnonzero(np.diff(seq) != 0)
    edges = np.concatenate([[0], change + 1, [len(seq)]])
    return np.diff(edges)


def switching_stats(ctrl: Controller, obs: np.ndarray, lengths: np.ndarray, dt: float) -> dict:
    """Switches per second (all steps; second half), dwell times, pieces' shares and the crossings' counts, over
    episodes obs [T + 1, B, d_s] that last lengths [B] steps."""
    seq = piece_sequence(ctrl, obs)
    k = ctrl.num_clusters
    counts, crossings, dwells, sw_all, sw_half, steps_all, steps_half = np.zeros(k), {}, [], 0, 0, 0, 0
    for b, n in enumerate(np.asarray(lengths)):
        s = seq[:n, b]
        counts += np.bincount(s, minlength=k)
        changes = np.flatnonzero(np.diff(s) != 0)
        sw_all, steps_all = sw_all + len(changes), steps_all + n
        sw_half, steps_half = sw_half + int(np.sum(changes >= n // 2)), steps_half + n - n // 2
        dwells.extend(dwell_times(s).tolist())
        for i in changes:
            key = f"{int(s[i])}->{int(s[i + 1])}"
            crossings[key] = crossings.get(key, 0) + 1
    d = np.asarray(dwells, float)
    half = sw_half / max(steps_half * dt, 1e-12)
    return {"switches_per_second": sw_all / max(steps_all * dt, 1e-12),
            "switches_per_second_second_half": half, "chatter_rate_limit": CHATTER_RATE,
            "chattering_risk": bool(half > CHATTER_RATE),
            "dwell_steps_mean": float(d.mean()), "dwell_steps_median": float(np.median(d)),
            "piece_share": [float(c) for c in counts / max(counts.sum(), 1)],
            "pieces_used": [int(i) for i in np.flatnonzero(counts)],
            "crossings": dict(sorted(crossings.items(), key=lambda kv: -kv[1]))}
