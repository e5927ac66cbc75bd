"""Numbers in Markdown pages quoted from the committed tables, so that they cannot drift from them
(`gsa quote PAGE.md [PAGE.md ...] [--check]`).

Each span `<!-- quote KIND FILE [column=value ...] [option=value ...] -->TEXT<!-- /quote -->` has its
TEXT rewritten from FILE (a CSV path relative to the page: final_returns.csv, per_run_scores.csv,
aggregate.csv, ... as gsa_jax.plot writes them), over the rows whose columns equal the given values (a
value "a,b" matches either; quote a value with spaces: config="K = 0.5 d_a"). KIND:
  value      one row's `col` (exactly one row must match); with pm=COLUMN "col ± pm", with ci=LOW,HIGH
             "col [low, high]"
  text       one row's `col` as written, 'none' where empty (a verdict, a list of K)
  scores     every row's `col`, ascending (order=file: as the rows come), joined by " / "
  range      "min-max" of the rows' `col`          min, max: one end; median: the rows' median
  spread     "mean ± std" over the rows' `col` (std with ddof 0, as CleanRL's tables give it)
  table      the rows of a final_returns.csv as Figure 1's Markdown table (a block: put the markers on
             their own lines)
  aggregate  the rows of an aggregate.csv as the normalized-score table (a block)
  reach      from the tidy metrics under FILE (directories, comma-separated), per cell: how many runs'
             deterministic controllers reached `threshold` and the median env step where they first did
Options: col (default final_score), pm, ci, digits (default 0; thousands are separated by commas),
threshold, order. Tables give half-widths under 10 with one decimal.
"""

import math
import os
import re
import shlex
from decimal import ROUND_HALF_UP, Decimal
from typing import Sequence

import numpy as np

from gsa_jax.algorithm.kinds import MIXTURE, MLP
from gsa_jax.analysis.sweeps import columns as C
from gsa_jax.analysis.sweeps.results import read_csv
from gsa_jax.errors import UserError

SPAN = re.compile(r"<!-- quote (?P<args>.*?) -->(?P<text>.*?)<!-- /quote -->", re.S)
OPTIONS = ("col", "pm", "ci", "digits", "threshold", "order")


class QuoteError(UserError, ValueError):
    """A quote span the tables cannot fill (a bad argument, a missing file or column, no matching row)."""


def fmt(x: float | str, digits: int = 0) -> str:
    """A number as the pages write it: thousands separated by commas, `digits` decimals, halves rounded away
    from zero as the table prints them (0.205 -> 0.21)."""
    if x == "" or not math.isfinite(float(x)):
        return "n/a"
    exact = Decimal(repr(float(x))).quantize(Decimal(1).scaleb(-int(digits)), rounding=ROUND_HALF_UP)
    return f"{exact:,.{int(digits)}f}"


def parse_args(args: str) -> tuple:
    """(kind, file, {column: [values]}, {option: value}) of a span's argument string."""
    try:
        words = shlex.split(args)
    except ValueError as e:
        raise QuoteError(f"'quote {args}': {e}") from None
    if len(words) < 2:
        raise QuoteError(f"'quote {args}': expected KIND FILE [column=value ...]")
    filters, options = {}, {}
    for w in words[2:]:
        key, eq, value = w.partition("=")
        if not eq:
            raise QuoteError(f"'quote {args}': {w!r} is not column=value")
        (options if key in OPTIONS else filters)[key] = value if key in OPTIONS else value.split(",")
    return words[0], words[1], filters, options


def read_rows(path: str, filters: dict) -> list:
    """The rows of a CSV file whose columns hold one of the given values."""
    if not os.path.exists(path):
        raise QuoteError(f"{path}: no such file")
    rows = read_csv(path)
    missing = [c for c in filters if rows and c not in rows[0]]
    if missing:
        raise QuoteError(f"{path} has no column {missing[0]!r}")
    return [r for r in rows if all(r[c] in values for c, values in filters.items())]


def values(rows: list, col: str, path: str) -> list:
    """The rows' `col` as floats (NaN where empty)."""
    if not rows:
        raise QuoteError(f"{path}: no row matches")
    if col not in rows[0]:
        raise QuoteError(f"{path} has no column {col!r}")
    return [float(r[col]) if r[col] != "" else math.nan for r in rows]


def interval(row: dict, point: str, low: str, high: str, digits: int = 0) -> str:
    """'point [low, high]' of a row's columns ('' where the point is empty)."""
    if row.get(point, "") == "":
        return ""
    return f"{fmt(row[point], digits)} [{fmt(row[low], digits)}, {fmt(row[high], digits)}]"


def cell_name(row: dict) -> str:
    """A final_returns.csv row's configuration: flat PPO, or K with its ratio to the action dimension."""
    if row["policy"] == MLP:
        return "flat PPO (MLP 64x64)"
    ratio = float(row[C.K_OVER_ACTION_DIM]) if row.get(C.K_OVER_ACTION_DIM, "") != "" else math.nan
    return f"K = {row['K']}" + (f" ({round(ratio, 2):g} d_a)" if math.isfinite(ratio) else "")


def halfwidth(x: float | str) -> str:
    """A table's ± half-width: one decimal under 10 (cells at a task's ceiling), none above."""
    return fmt(x, 1 if x != "" and abs(float(x)) < 10 else 0)


def cell_markdown(rows: list) -> str:
    """Figure 1's per-task Markdown table of final_returns.csv rows (one task)."""
    mixture = [r for r in rows if r["policy"] == MIXTURE and r.get(C.K_OVER_ACTION_DIM, "") != ""]
    d_a = f" (d_a = {round(float(mixture[0]['K']) / float(mixture[0][C.K_OVER_ACTION_DIM]))})" if mixture else ""
    lines = [f"| {rows[0]['env']}{d_a} | deterministic: mean ± 95% CI | IQM [95% CI] | P(> flat PPO) [95% CI] "
             "| training return | learning speed IQM |", "|---|---|---|---|---|---|"]
    for r in rows:
        (mean, half), (train, train_half) = ((r[c] for c in cols) for cols in (C.MEAN_CI, C.TRAINING_CI))
        lines.append(f"| {cell_name(r)} | {fmt(mean)} ± {halfwidth(half)} | {interval(r, *C.IQM_CI)} "
                     f"| {interval(r, *C.P_FLAT_CI, 2)} | {fmt(train)} ± {halfwidth(train_half)} | {fmt(r[C.CURVE_CI[0]])} |")
    return "\n".join(lines)


def aggregate_markdown(rows: list) -> str:
    """The Markdown table of aggregate.csv rows (normalized IQM and P(> flat PPO) per configuration)."""
    lines = ["| configuration | normalized IQM [95% CI] | P(> flat PPO) [95% CI] |", "|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['config']} | {interval(r, *C.NORMALIZED_IQM_CI, 2)} | {interval(r, *C.P_FLAT_CI, 2)} |")
    return "\n".join(lines)


def reach(dirs: Sequence[str], filters: dict, threshold: float) -> str:
    """'flat PPO 10/10 at 358k, K = 2 8/10 at 532k, ...': per cell of the sweeps' tidy metrics (cells whose
    columns hold the filters' values), the runs whose deterministic return reached `threshold` at an
    evaluation, and the median env step of their first such evaluation."""
    from gsa_jax.analysis.sweeps.results import drop_failed, load_failed, load_sweeps
    from gsa_jax.analysis.sweeps.tables import cell_order

    data, _ = drop_failed(load_sweeps(dirs), [f for d in dirs for f in load_failed(d)])
    keep = [c for c in sorted(data, key=cell_order)
            if all(str(c.columns().get(k, "")) in v for k, v in filters.items())]
    if not keep:
        raise QuoteError(f"{', '.join(dirs)}: no cell matches")
    parts = []
    for cell in keep:
        firsts = [s["env_steps"][np.flatnonzero(s["eval_return"] >= threshold)[0]] for s in data[cell].values()
                  if np.any(s["eval_return"] >= threshold)]
        at = f" at {round(float(np.median(firsts)) / 1000)}k" if firsts else ""
        parts.append(f"{'flat PPO' if cell.policy == MLP else f'K = {cell.k}'} {len(firsts)}/{len(data[cell])}{at}")
    return ", ".join(parts)


def render(args: str, page_dir: str) -> str:
    """The text a span's arguments give."""
    kind, name, filters, options = parse_args(args)
    if kind == "reach":
        if "threshold" not in options:
            raise QuoteError(f"'quote {args}': reach needs threshold=")
        return reach([os.path.join(page_dir, d) for d in name.split(",")], filters, float(options["threshold"]))
    path = os.path.join(page_dir, name)
    rows = read_rows(path, filters)
    digits = options.get("digits", 0)
    if kind in ("table", "aggregate"):
        if not rows:
            raise QuoteError(f"{path}: no row matches")
        return "\n\n" + (cell_markdown(rows) if kind == "table" else aggregate_markdown(rows)) + "\n\n"
    if kind == "text":  # one row's column as it is written ('none' where empty): verdicts, K lists
        col = options.get("col", "final_score")
        if len(rows) != 1 or col not in rows[0]:
            raise QuoteError(f"'quote {args}': {len(rows)} rows match, not one" if len(rows) != 1 else f"{path} has no column {col!r}")
        return rows[0][col] or "none"
    xs = values(rows, options.get("col", "final_score"), path)
    if kind == "value":
        if len(xs) != 1:
            raise QuoteError(f"'quote {args}': {len(xs)} rows match, not one")
        pm = f" ± {fmt(values(rows, options['pm'], path)[0], digits)}" if "pm" in options else ""
        ends = [fmt(values(rows, c, path)[0], digits) for c in options["ci"].split(",")] if "ci" in options else []
        return fmt(xs[0], digits) + pm + (f" [{', '.join(ends)}]" if ends else "")
    finite = sorted(x for x in xs if math.isfinite(x))
    if kind == "scores":  # ascending, unscored runs (NaN) last as n/a; order=file: in the file's (seed) order
        ordered = xs if options.get("order") == "file" else finite + [x for x in xs if not math.isfinite(x)]
        return " / ".join(fmt(x, digits) for x in ordered)
    if not finite:
        raise QuoteError(f"{path}: no finite value in the matching rows")
    if kind in ("range", "min", "max", "median"):
        ends = {"range": f"{fmt(finite[0], digits)}-{fmt(finite[-1], digits)}", "min": fmt(finite[0], digits),
                "max": fmt(finite[-1], digits), "median": fmt(float(np.median(finite)), digits)}
        return ends[kind]
    if kind == "spread":
        mean = sum(finite) / len(finite)
        std = math.sqrt(sum((x - mean) ** 2 for x in finite) / len(finite))
        return f"{fmt(mean, digits)} ± {fmt(std, digits)}"
    raise QuoteError(f"'quote {args}': unknown kind {kind!r}")


def requote(text: str, page_dir: str) -> tuple:
    """(the page with every span's TEXT rewritten, [(arguments, old TEXT, new TEXT)] of the spans that changed)."""
    changed = []

    def one(m):
        new = render(m["args"], page_dir)
        if new != m["text"]:
            changed.append((" ".join(m["args"].split()), m["text"], new))
        return f"<!-- quote {m['args']} -->{new}<!-- /quote -->"

    return SPAN.sub(one, text), changed
