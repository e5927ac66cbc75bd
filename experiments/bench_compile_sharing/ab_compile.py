import json, sys, time
from gsa_jax import bench
from gsa_jax.runinfo import run_metadata
out = sys.argv[1]; res = []
for rnd in range(2):
    for mode in ("shared", "each"):
        t = time.time()
        r = bench.measure_sweep(bench.SweepCell("hopper", "mixture", 256, 2, run_batch=8), 2, compile_each=mode == "each")
        r.update(mode=mode, round=rnd, wall_s=time.time() - t); r.pop("chunk_s")
        print(json.dumps(r), flush=True); res.append(r)
        json.dump({"results": res, **run_metadata()}, open(out, "w"), indent=1)
