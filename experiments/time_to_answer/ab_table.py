"""The first answer's wall and compile times before and after a change, from interleaved cold answers
(`run.py --cold-only --checkout <worktree>` per side and round, both sides in each round): each round's summary.csv and
sweeps.csv under results/<ab>/<side>-round<r>/ -> results/<ab>/ab.csv (a row per side and round, then each side's
median: wall, compile or load, its share, the calibration sweep's and the first round's mixture sweep's compile or
load seconds; a side's first calibration sweep where it ran several).

    .venv/bin/python experiments/time_to_answer/ab_table.py results/2026-12-02-init-draw-ab
"""

import csv
import glob
import os
import re
import statistics
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
COLUMNS = ["side", "round", "commit", "wall_s", "compile_or_load_s", "compile_share", "calibration_compile_s",
           "round1_mixture_compile_s"]


def read_round(path: str) -> dict:
    """One side's answer of one round: summary.csv's row and the two sweeps' compile or load seconds."""
    side, r = re.fullmatch(r"(\w+)-round(\d+)", os.path.basename(path)).groups()
    with open(os.path.join(path, "summary.csv")) as f:
        s = next(csv.DictReader(f))
    with open(os.path.join(path, "sweeps.csv")) as f:
        sweeps = {row["sweep"]: float(row["compile_or_load_s"]) for row in csv.DictReader(f)}
    pick = lambda prefix: next(v for k, v in sweeps.items() if k.startswith(prefix))  # noqa: E731
    return {"side": side, "round": int(r), "commit": s["commit"], "wall_s": float(s["wall_s"]),
            "compile_or_load_s": float(s["compile_or_load_s"]), "compile_share": float(s["compile_share"]),
            "calibration_compile_s": pick("calibrate-"), "round1_mixture_compile_s": pick("round1-mixture-")}


def medians(rows: list) -> list:
    """A 'median' row per side, in the order the sides first appear."""
    out = []
    for side in dict.fromkeys(r["side"] for r in rows):
        mine = [r for r in rows if r["side"] == side]
        out.append({"side": side, "round": "median", "commit": mine[0]["commit"],
                    **{c: round(statistics.median(r[c] for r in mine), 3) for c in COLUMNS[3:]}})
    return out


def main(ab: str) -> None:
    root = ab if os.path.isabs(ab) else os.path.join(HERE, ab)
    rows = sorted((read_round(p) for p in glob.glob(os.path.join(root, "*-round*"))),
                  key=lambda r: (r["round"], r["side"] != "before"))
    with open(os.path.join(root, "ab.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, COLUMNS)
        w.writeheader()
        w.writerows(rows + medians(rows))
    print(open(os.path.join(root, "ab.csv")).read())


if __name__ == "__main__":
    main(sys.argv[1])
