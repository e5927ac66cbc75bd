"""Learning-curve plots (matplotlib, headless)."""

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def plot_curve(rows, path, title=""):
    """rows: metrics.csv rows as dicts. Training return per iteration, deterministic eval return as markers."""
    def col(name):
        out = []
        for r in rows:
            v = r.get(name, "")
            x = float(r["env_steps"])
            y = float(v) if v not in ("", None) else math.nan
            if not math.isnan(y):
                out.append((x, y))
        return zip(*out) if out else ((), ())

    fig, ax = plt.subplots(figsize=(7, 4.2))
    xs, ys = col("episode_return")
    ax.plot(xs, ys, lw=1.5, label="training episodes (stochastic policy)")
    xs, ys = col("eval_return")
    ax.plot(xs, ys, "o-", ms=4, lw=1, label="evaluation (deterministic controller)")
    ax.set_xlabel("environment steps")
    ax.set_ylabel("episode return")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
