import json, os, sys, time
from gsa_jax import bench
from gsa_jax.runinfo import run_metadata
out = sys.argv[1]; res = []
for rnd in range(2):
    for mode in ("shared", "each"):
        if mode == "each": os.environ["GSA_JAX_COMPILE_EACH"] = "1"
        else: os.environ.pop("GSA_JAX_COMPILE_EACH", None)
        t = time.time()
        r = bench.measure_sweep("hopper", "mixture", 256, 2, 2, run_batch=8)
        r.update(mode=mode, round=rnd, wall_s=time.time() - t); r.pop("chunk_s")
        print(json.dumps(r), flush=True); res.append(r)
        json.dump({"results": res, **run_metadata()}, open(out, "w"), indent=1)
