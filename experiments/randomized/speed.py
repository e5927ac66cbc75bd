"""results/speed.csv from the benchmark's bench.json files under results/ (python -m gsa_jax.bench --randomize ...):
per machine, backend and run count, the nominal and randomized sweeps' env-steps/s and their ratio.

    .venv/bin/python experiments/randomized/speed.py
"""

import csv
import glob
import json
import os

HERE = os.path.dirname(os.path.abspath(__file__))


def rows_of(path):
    """The nominal/randomized pairs of one bench.json."""
    report = json.load(open(path))
    machine = os.path.basename(os.path.dirname(os.path.dirname(path)))
    out = []
    nominal = {}
    for s in report["sweeps"]:
        key = (s["backend"], s["policy"], s["runs"], s["processes"])
        if not s.get("randomize"):
            nominal[key] = s
        elif key in nominal:
            n = nominal[key]
            out.append({"machine": machine, "env": report["env"], "backend": key[0], "policy": key[1], "runs": key[2],
                        "processes": key[3], "nominal_steps_per_s": round(n["env_steps_per_s"]),
                        "randomized_steps_per_s": round(s["env_steps_per_s"]),
                        "ratio": round(s["env_steps_per_s"] / n["env_steps_per_s"], 3), **in_run(n, s),
                        "randomize": s["randomize"], "timed_chunks": report["repeats"]})
    return out


def in_run(nominal, randomized):
    """Backend 'c': each sweep's in-run split (MuJoCo C's microseconds per env step and worker, the other host calls'
    and the program's shares of the time); empty on MJX."""
    out = {}
    for name, s in (("nominal", nominal), ("randomized", randomized)):
        split = s.get("in_run")
        if split:
            out[f"{name}_mujoco_c_us"] = round(split["mujoco_c_us_per_env_step"], 1)
            out[f"{name}_host_other_share"] = round(split["fractions"]["host_other"], 3)
            out[f"{name}_program_share"] = round(split["fractions"]["program"], 3)
    return out


def main():
    rows = [r for p in sorted(glob.glob(os.path.join(HERE, "results", "*", "*", "bench.json"))) for r in rows_of(p)]
    with open(os.path.join(HERE, "results", "speed.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote results/speed.csv ({len(rows)} rows)")


if __name__ == "__main__":
    main()
