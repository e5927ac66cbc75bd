import json
import os
import sys
import time

from gsa_jax.benchmark import measure
from gsa_jax import run_metadata

out = sys.argv[1]; res = []
FLAG = "--xla_cpu_multi_thread_eigen=false"
for rnd in range(2):
    for mode in ("default", "eigen_single_thread"):
        # the workers run single-threaded by default now (gsa_jax.running.supervise.worker_env): ask for threads explicitly
        os.environ["XLA_FLAGS"] = "--xla_cpu_multi_thread_eigen=true" if mode == "default" else FLAG
        for kind in ("raw", "mixture"):
            t = time.time()
            r = measure.measure_raw("hopper", 256, 2, 3) if kind == "raw" else measure.measure_sweep(measure.SweepCell("hopper", "mixture", 256, 2, run_batch=8), 2)
            r.update(mode=mode, xla_flags=os.environ.get("XLA_FLAGS", ""), round=rnd, wall_s=time.time() - t); r.pop("chunk_s")
            print(json.dumps(r), flush=True); res.append(r)
            json.dump({"results": res, **run_metadata()}, open(out, "w"), indent=1)
