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
    ax.plot(xs, ys, lw=0.8, alpha=0.35, color="C0", label="training episodes (stochastic policy)")
    if len(ys) >= 10:  # few episodes end per iteration late in training: show a trailing mean too
        w = max(5, len(ys) // 30)
        smooth = [sum(ys[max(0, i - w + 1):i + 1]) / len(ys[max(0, i - w + 1):i + 1]) for i in range(len(ys))]
        ax.plot(xs, smooth, lw=1.8, color="C0", label=f"  trailing mean over {w} iterations")
    xs, ys = col("eval_return")
    ax.plot(xs, ys, "o-", ms=4, lw=1, color="C1", label="evaluation (deterministic controller)")
    ax.set_xlabel("environment steps")
    ax.set_ylabel("episode return")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
