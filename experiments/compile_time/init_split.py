"""XLA's compile of the demo's init program and of its policy's init alone, in one or more checkouts.

    .venv/bin/python experiments/compile_time/init_split.py --checkout loop_init=. --checkout unrolled_init=/tmp/wt
    [--rounds 3]

Per round and checkout, a fresh process (this venv's Python, in the checkout's directory so its gsa_jax is imported)
builds the demo's run (`make demo`'s arguments) and compiles, as `gsa train` compiles init (jax.jit with
xla_cache.once_options, no XLA_FLAGS, no persistent cache): the policy's init (its partition network's and
controllers' parameters) and the whole init (the policy's and the value network's parameters, the optimizer's
state and the envs' reset). A row per program goes to
results/init_split.csv: label, round, commit, program, XLA compile seconds (lowered.compile()), the StableHLO
dot_general count of the lowered program, and the load average before the process.
"""

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from demo_compile import DEMO, append, commit_of  # noqa: E402

RESULTS = os.path.join(HERE, "results", "init_split.csv")
COLUMNS = ("label", "round", "commit", "program", "compile_s", "dot_ops", "load_before")
CHILD = r"""
import json, sys, time
import jax
from gsa_jax.algorithm.config import make_hparams
from gsa_jax.algorithm.ppo import make_run_parts
from gsa_jax.commands.train import build_parser, resolve
from gsa_jax.running import xla_cache
from gsa_jax.running.tasks import trainer_for

plan = resolve(build_parser().parse_args(sys.argv[1].split()))
parts, trainer = make_run_parts(plan.cfg, plan.task), trainer_for(plan.cfg, plan.task)
hp, key, once = make_hparams(**plan.hp), jax.random.PRNGKey(0), xla_cache.once_options()
programs = [("policy_init", lambda k, h: parts.policy.init(k, h)),
            ("init", trainer.init)]
for name, fn in programs:
    lowered = jax.jit(fn, compiler_options=once).lower(key, hp)
    t0 = time.perf_counter()
    lowered.compile()
    print(json.dumps({"program": name, "compile_s": round(time.perf_counter() - t0, 3),
                      "dot_ops": lowered.as_text().count("stablehlo.dot_general")}), flush=True)
"""


def measure(label: str, path: str, rnd: int) -> list:
    """One fresh process in checkout `path` -> its rows."""
    env = dict(os.environ)
    for name in ("XLA_FLAGS", "JAX_COMPILATION_CACHE_DIR"):
        env.pop(name, None)
    load = round(os.getloadavg()[0], 2)
    out = subprocess.run([sys.executable, "-c", CHILD, " ".join(DEMO)], cwd=path, env=env, check=True, capture_output=True,
                         text=True).stdout
    base = {"label": label, "round": rnd, "commit": commit_of(path, RESULTS), "load_before": load}
    return [dict(base, **json.loads(line)) for line in out.splitlines() if line.startswith("{")]


def main() -> None:
    """Each checkout in turn, --rounds times; rows appended to RESULTS."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkout", action="append", required=True, help="LABEL=PATH of a checkout")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    for rnd in range(1, args.rounds + 1):
        for label, path in (c.split("=", 1) for c in args.checkout):
            rows = measure(label, os.path.abspath(path), rnd)
            append(rows, RESULTS, COLUMNS)
            print("\n".join(json.dumps(r) for r in rows), flush=True)


if __name__ == "__main__":
    main()
