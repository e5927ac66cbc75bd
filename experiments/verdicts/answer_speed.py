"""How much training does a decided answer take, against the fixed 10-seed grid? `.venv/bin/python experiments/verdicts/answer_speed.py`

Runs are deterministic in their seed (a sweep's runs train bit for bit the same alone or in any batch), so
gsa_jax.answer's loop from scratch can be replayed on runs already trained: each round takes the planned seeds'
committed controller scores instead of training them, and stops where it would need a seed nobody trained. Per task:
the default design (looks at 10, 20, 40 seeds), the runs it trains, the seeds per cell, the verdicts and the
answer, beside the fixed grid (10 seeds per cell, one look); and the minutes those runs cost at the seconds per
run that the task's own answer rounds measured (answers/<task>/answer.json, this machine, shared). Writes
results/answer_speed.csv.
"""

import glob
import json
import os
import tempfile

from gsa_jax.analysis.sweeps import controller_scores
from gsa_jax import write_csv
from gsa_jax.analysis.verdicts import answering as A
from gsa_jax.analysis.verdicts import verdict
from gsa_jax.orchestration import answer_loop as L

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..")
TASKS = {  # task: (K ladder, directories whose controller_scores.csv hold its runs)
    "dmc:cartpole-swingup": ((1, 2, 4), ["atlas_dmc/results/cartpole-swingup", "verdicts/answers/cartpole-swingup"]),
    "dmc:reacher-hard": ((1, 2, 4, 8), ["atlas_dmc/results/reacher-hard", "verdicts/answers/reacher-hard"]),
    "InvertedDoublePendulum-v5": ((1, 2, 4), ["fig1_v5/results/fig1_v5_InvertedDoublePendulum-v5"]),
}


class NotTrained(Exception):
    pass


def pool(env, dirs):
    """{FLAT or K: {seed: score}} of every scored run of the task under the directories."""
    out = {}
    for d in dirs:
        for path in glob.glob(os.path.join(ROOT, d, "**", controller_scores.FILE), recursive=True):
            for r in controller_scores.read_scores(path).values():
                if r["env"] == env:
                    out.setdefault(A.FLAT if r["policy"] == "mlp" else int(r["K"]), {})[int(r["seed"])] = float(r["controller_score"])
    return out


def replay_trainer(env, scores):
    """A round's 'training' that writes the planned runs' committed scores (NotTrained where one is missing)."""
    def train(out, name, spec, log, **options):
        rows = {}
        for k in spec.get("clusters") or [A.FLAT]:
            for seed in spec["seeds"]:
                if seed not in scores.get(k, {}):
                    raise NotTrained(f"{k} seed {seed}")
                label = f"{k}-s{seed}"
                rows[label] = {"label": label, "env": env, "policy": "mlp" if k == A.FLAT else "mixture",
                               "K": "" if k == A.FLAT else k, "seed": seed, "controller_score": scores[k][seed]}
        os.makedirs(os.path.join(out, "results", name), exist_ok=True)
        controller_scores.write_scores(os.path.join(out, "results", name, controller_scores.FILE), rows)
        return {"seconds": 0.0, "compile_s": 0.0, "status": 0}
    return train


def seconds_per_run(env):
    """Seconds per 1M-step run in the task's own answer rounds (None where it ran none)."""
    path = os.path.join(HERE, "answers", env.removeprefix("dmc:"), "answer.json")
    if not os.path.exists(path):
        return None
    with open(path) as f:
        rounds = [r for r in json.load(f)["rounds"] if r["status"] == "done"]
    runs = sum(max(len(ks), 1) * len(seeds) for r in rounds for ks, seeds in r["plan"].values())
    secs = sum(s["seconds"] for r in rounds for s in r["sweeps"].values())
    return secs / runs if runs else None


def replay(env, ladder, scores, random_return, looks):
    """(final state or None, the reason it stopped) of the answer loop replayed on committed scores."""
    spec = {"steps": 1, "hparams": {}, "config": {}}
    setup = A.Setup(env, ladder, verdict.DEFAULT_MARGIN, looks, {"mlp": spec, "mixture": spec})
    with tempfile.TemporaryDirectory() as out:
        try:
            state = L.run_answer(out, setup, 1e12, lambda: random_return, log=lambda m: None,
                                 train=replay_trainer(env, scores))
        except NotTrained as e:
            return json.load(open(os.path.join(out, A.STATE))), f"needs runs nobody trained ({e})"
    return state, state["stopped"]


def random_return_of(env, dirs):
    """The random policy's record (episodes) that gsa_jax.plot measured for the task's committed tables."""
    for d in dirs:
        for path in glob.glob(os.path.join(ROOT, d, "random_policy.json")):
            with open(path) as f:
                found = json.load(f)
            if env in found:
                return found[env]
    raise FileNotFoundError(f"no random_policy.json for {env} (run experiments/verdicts/regenerate.sh)")


def speed_rows(log=print) -> list:
    """A row per task and design: the runs the replayed answer trains, where it stopped, its seeds, verdicts and answer."""
    rows = []
    for env, (ladder, dirs) in TASKS.items():
        scores, rnd = pool(env, dirs), random_return_of(env, dirs)
        per_run = seconds_per_run(env)
        for design, looks in (("fixed grid of 10 seeds", (10,)), ("gsa_jax.answer looks 10-20-40", (10, 20, 40))):
            state, stopped = replay(env, ladder, scores, rnd, looks)
            runs = sum(max(len(ks), 1) * len(got) for r in state["rounds"] if r["status"] == "done"
                       for ks, got in r["plan"].values())
            if "judged" in state:
                verdicts = {int(k): r["verdict"] for k, r in state["judged"].items()}
            else:  # stopped for runs nobody trained: the verdicts before the round it could not replay
                verdicts = {int(k): v for k, v in state["rounds"][-1]["verdicts_before"].items()}
            seeds = {}
            for r in state["rounds"]:
                if r["status"] == "done":
                    for policy, (ks, got) in r["plan"].items():
                        for k in ks or ["flat PPO"]:
                            seeds[str(k)] = seeds.get(str(k), 0) + len(got)
            rows.append({"env": env, "design": design, "runs_trained": runs, "stopped": stopped,
                         "seeds_per_cell": " ".join(f"{k}:{n}" for k, n in seeds.items()),
                         "verdicts": " ".join(f"{k}:{v}" for k, v in sorted(verdicts.items())),
                         "answer": verdict.sentence(env, verdicts, verdict.DEFAULT_MARGIN,
                                                    state.get("baseline", {}).get("versus", "flat PPO")) if verdicts else "",
                         "seconds_per_run": round(per_run, 1) if per_run else "",
                         "minutes_on_this_machine": round(runs * per_run / 60, 1) if per_run else ""})
            log(rows[-1])
    return rows


def main():
    write_csv(os.path.join(HERE, "results", "answer_speed.csv"), speed_rows())


if __name__ == "__main__":
    main()
