"""A single run's learning curve (curve.png of `gsa train`), apart from the sweep figures so
that training does not import the sweep-analysis stack. matplotlib is imported when a curve is drawn, not at
import: selecting its non-interactive backend is process-wide, which importing this module must not do."""

import math


def plot_curve(rows: list, path: str, title: str = "") -> None:
    """A single run's learning curve: rows are metrics.csv rows as dicts. Training return per iteration
    (with a trailing mean), deterministic evaluation returns as markers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def col(name):
        pts = [(float(r["env_steps"]), float(r[name])) for r in rows if r.get(name, "") not in ("", None)]
        pts = [p for p in pts if not math.isnan(p[1])]
        return zip(*pts) if pts else ((), ())

    fig, ax = plt.subplots(figsize=(7, 4.2))
    xs, ys = col("episode_return")
    ax.plot(xs, ys, lw=0.8, alpha=0.35, color="C0", label="training episodes (stochastic policy)")
    if len(ys) >= 10:  # few episodes end per iteration late in training: show a trailing mean too
        w = max(5, len(ys) // 30)
        trailing = [sum(ys[max(0, i - w + 1):i + 1]) / len(ys[max(0, i - w + 1):i + 1]) for i in range(len(ys))]
        ax.plot(xs, trailing, lw=1.8, color="C0", label=f"  trailing mean over {w} iterations")
    xs, ys = col("eval_return")
    ax.plot(xs, ys, "o-", ms=4, lw=1, color="C1", label="evaluation (deterministic controller)")
    ax.set(xlabel="environment steps", ylabel="episode return", title=title)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
