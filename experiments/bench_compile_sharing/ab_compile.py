import json
import sys
import time

from gsa_jax.benchmark import measure
from gsa_jax import run_metadata

out = sys.argv[1]; res = []
for rnd in range(2):
    for mode in ("shared", "each"):
        t = time.time()
        r = measure.measure_sweep(measure.SweepCell("hopper", "mixture", 256, 2, run_batch=8), 2, compile_each=mode == "each")
        r.update(mode=mode, round=rnd, wall_s=time.time() - t); r.pop("chunk_s")
        print(json.dumps(r), flush=True); res.append(r)
        json.dump({"results": res, **run_metadata()}, open(out, "w"), indent=1)
