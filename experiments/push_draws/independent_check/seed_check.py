# Monte Carlo spread of the two-way lower bound for the borderline cell Ant-v5 K=8 size 0.25 W=50
import numpy as np, pandas as pd, check_paired as cp
d = pd.read_csv(f"{cp.ROOT}/robustness/results/Ant-v5/pushes.csv.gz"); d = d[d["size"] == 0.25]
_, Cf, Ff = cp.matrices(d, "mlp", None); _, Cm, Fm = cp.matrices(d, "mixture", 8)
for s in range(5):
    cp.rng = np.random.default_rng(s); print(s, cp.boot(Cm, Fm, Cf, Ff, True))
