"""The test suite's wall time and the summed time of its tests, read from a `make test` run's output and its JUnit
XML, one row per run: what the suite's compile flags (tests/conftest.py) cost or save.

    .venv/bin/python -m pytest -q tests -m "not benchmark" -n auto --maxprocesses 4 --dist loadfile \\
        --junitxml=/tmp/junit.xml > /tmp/suite.log 2>&1
    .venv/bin/python experiments/compile_time/suite_time.py --label L --commit C --xla-flags="FLAGS" --log /tmp/suite.log \\
        --junit /tmp/junit.xml

Row: label, commit (what ran, '+' where the working tree had changes beside it), the XLA flags the suite compiled
with, tests passed and failed, pytest's wall seconds, the tests' summed seconds (both workers), the three test files
with the most summed seconds. Appended to results/suite_time.csv.
"""

import argparse
import collections
import csv
import os
import re
import xml.etree.ElementTree as ET

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results", "suite_time.csv")
FIELDS = ["label", "commit", "xla_flags", "passed", "failed", "wall_s", "summed_test_s", "slowest_files"]


def read_log(path: str) -> dict:
    """passed, failed and wall seconds from pytest's last summary line ('712 passed, 5 warnings in 976.43s')."""
    line = [ln for ln in open(path).read().splitlines() if re.search(r" in [\d.]+s", ln)][-1]
    count = lambda word: int(m.group(1)) if (m := re.search(rf"(\d+) {word}", line)) else 0  # noqa: E731
    return {"passed": count("passed"), "failed": count("failed"), "wall_s": float(re.search(r" in ([\d.]+)s", line).group(1))}


def read_junit(path: str) -> dict:
    """The tests' summed seconds and the three files with the most."""
    files = collections.Counter()
    for case in ET.parse(path).iter("testcase"):
        files[case.get("classname")] += float(case.get("time"))
    top = "; ".join(f"{name} {s:.0f}" for name, s in files.most_common(3))
    return {"summed_test_s": round(sum(files.values()), 1), "slowest_files": top}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--label", required=True)
    ap.add_argument("--commit", required=True)
    ap.add_argument("--xla-flags", required=True, help="the flags tests/conftest.py set in that run")
    ap.add_argument("--log", required=True)
    ap.add_argument("--junit", required=True)
    args = ap.parse_args()
    row = {"label": args.label, "commit": args.commit, "xla_flags": args.xla_flags, **read_log(args.log),
           **read_junit(args.junit)}
    new = not os.path.exists(RESULTS)
    with open(RESULTS, "a", newline="") as f:
        w = csv.DictWriter(f, FIELDS)
        if new:
            w.writeheader()
        w.writerow(row)
    print(row)


if __name__ == "__main__":
    main()
