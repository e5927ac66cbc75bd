"""The certified region of attraction (`gsa verify --certify`) of every committed controller of one cell per partition
class of a task, in SI units: per controller its fixed point's piece, spectral radius, certified level, inscribed
radius and per-coordinate extent, or why none was certified (a one-line refusal: no stable fixed point, no hold,
...); and where the hold switches between pieces, its invariant set's (the active pieces, the certified level and
inner level, inscribed radius and extent, or why none). Exact on the linearization, tested on the plant
(docs/verify.md).

    .venv/bin/python experiments/partition/certify_regions.py experiments/partition/results/cartpole-balance 4 2.968 [SEEDS]
writes certified_regions.csv in that directory (row by row; SEEDS: the first that many seeds per class, default all).
"""

import csv
import glob
import json
import os
import subprocess
import sys
import tempfile

COLUMNS = ("partition", "K", "lr_scale_partition", "seed", "certified", "piece", "spectral_radius", "level",
           "inscribed_radius", "extent", "violations", "refused", "hold_pieces", "hold_certified", "hold_level",
           "hold_inner_level", "hold_inscribed_radius", "hold_extent", "hold_reason")


def extent(c: dict) -> str:
    return "; ".join(f"{name} +-{v:.3g}" for name, v in zip(c["coordinates"], c["extent"]))


def fixed_point_fields(c: dict) -> dict:
    return {"certified": c["certified"], "piece": c["piece"], "spectral_radius": round(c["spectral_radius"], 5),
            "level": round(c["level"], 5), "inscribed_radius": round(c["inscribed_radius"], 5), "extent": extent(c),
            "violations": sum(r["violations"] for r in c["rounds"])}


def hold_fields(h: dict) -> dict:
    out = {"hold_pieces": " ".join(map(str, h["pieces"])), "hold_certified": h["certified"],
           "hold_level": round(h["level"], 5), "hold_reason": h["reason"] or ""}
    if h["certified"]:
        out.update({"hold_inner_level": round(h["inner_level"], 5),
                    "hold_inscribed_radius": round(h["inscribed_radius"], 5), "hold_extent": extent(h)})
    return out


def certify(path: str, budget: str) -> dict:
    """The certificates' fields of one controller (verify --certify at `budget`), or its refusal."""
    with tempfile.TemporaryDirectory() as out:
        done = subprocess.run([sys.executable, "-m", "gsa_jax", "verify", path, f"--{budget}", "--certify", "--out", out],
                              capture_output=True, text=True)
        if done.returncode != 0:
            return {"refused": done.stderr.strip().splitlines()[-1] if done.stderr.strip() else f"exit {done.returncode}"}
        doc = json.load(open(os.path.join(out, "verify.json")))
    return {**(fixed_point_fields(doc["certificate"]) if "certificate" in doc else {}),
            **(hold_fields(doc["hold_set"]) if "hold_set" in doc else {})}


def write_rows(path: str, rows: list) -> None:
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)


def controller_path(task_dir: str, partition: str, k: str, lr: str, seed: int) -> "str | None":
    """The committed controller of one run (any task family's label: dmc.<task>-..., Hopper-v5-..., ...), or None."""
    found = glob.glob(os.path.join(task_dir, partition, "controllers",
                                   f"*-mixture-K{k}-partition={partition}-lr_scale_partition={lr}-s{seed}.npz"))
    return found[0] if len(found) == 1 else None


def main(task_dir: str, k: str, lr: str, seeds: str = "0", budget: str = "quick") -> int:
    rows, out = [], os.path.join(task_dir, "certified_regions.csv")
    for seed in range(int(seeds) or 10 ** 6):
        for partition in ("linear", "mlp"):
            path = controller_path(task_dir, partition, k, lr, seed)
            if path is None:
                return 0
            rows.append({"partition": partition, "K": k, "lr_scale_partition": lr, "seed": seed, **certify(path, budget)})
            print(rows[-1], flush=True)
            write_rows(out, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
