"""Records dm_control's own episodes as the test fixtures of envs/dmc/ (tests/golden/dmc/<domain>-<task>.npz).

dm_control's `suite.load` needs mujoco 3.17 (it fails under mujoco 4.0), so this runs in its own environment:

    python3 -m venv /tmp/dmcref && /tmp/dmcref/bin/pip install mujoco==3.17.0 dm_control==1.0.50
    /tmp/dmcref/bin/python experiments/dmc_reference/record.py [domain-task ...]     (default: every task of envs/dmc)

Per task: the state after `reset()` of RESETS environments seeded 0.. (qpos, qvel and, where dm_control writes a
target into the model at reset, the target geom's position: the reset law's samples), and
EPISODES whole episodes (seeds 1000..) under uniform random actions in [-1.5, 1.5] (out-of-range ones included;
float32 values, so that the test replays them exactly): the start state (and target), every action, every flattened
observation (dm_control's dict in its key order), reward and discount, the episode's length, and the final state;
for the first episode also the state before every step (qpos, qvel, act, qacc_warmstart), from which the tests
take single steps (mujoco 3.17 and 4.0 differ in the last bits, which contacts amplify over an episode).
Reads nothing from this project but envs/dmc/__init__.py's task list (plain text).
"""

import ast
import os
import sys

import numpy as np

RESETS, EPISODES, ACTION_BOUND = 300, 3, 1.5
# quadruped's 78-value observations: 2 whole episodes keep its fixture under 2 MiB (its exact check is the single
# steps, every one of the first episode's; whole episodes part from mujoco 3.17's by step ~150 anyway)
EPISODES_OF = {"quadruped-walk": 2}
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
OUT = os.path.join(ROOT, "tests", "golden", "dmc")


def task_names():
    """The keys of envs/dmc/__init__.py's TASKS, read as text (this environment has not the project's packages)."""
    tree = ast.parse(open(os.path.join(ROOT, "envs", "dmc", "__init__.py")).read())
    for node in tree.body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "TASKS":
            return [k.value for k in node.value.keys]
    raise SystemExit("envs/dmc/__init__.py has no TASKS")


def flat(observation):
    return np.concatenate([np.asarray(v, np.float64).ravel() for v in observation.values()])


def target(physics):
    """The position dm_control wrote into the model's 'target' geom at reset (reacher, fish, swimmer), else []."""
    names = [physics.model.id2name(i, "geom") for i in range(physics.model.ngeom)]
    return physics.named.model.geom_pos["target"].copy() if "target" in names else np.zeros(0)


def record_episode(suite, domain, task, seed):
    env = suite.load(domain, task, task_kwargs={"random": seed})
    ts = env.reset()
    physics = env.physics
    start = (physics.data.qpos.copy(), physics.data.qvel.copy(), target(physics))
    rng = np.random.default_rng(seed)
    obs, rewards, discounts, actions, states = [flat(ts.observation)], [], [], [], []
    while not ts.last():
        a = rng.uniform(-ACTION_BOUND, ACTION_BOUND, env.action_spec().shape).astype(np.float32)
        d = physics.data
        states.append(np.concatenate([d.qpos, d.qvel, d.act, d.qacc_warmstart]))
        ts = env.step(a.astype(np.float64))
        actions.append(a)
        obs.append(flat(ts.observation))
        rewards.append(ts.reward)
        discounts.append(ts.discount)
    end = (physics.data.qpos.copy(), physics.data.qvel.copy())
    return (start, np.array(actions), np.array(obs), np.array(rewards, np.float64), np.array(discounts), end,
            np.array(states))


def record(name):
    import mujoco
    from dm_control import suite
    import dm_control

    domain, task = name.split("-", 1)
    env = suite.load(domain, task, task_kwargs={"random": 0})
    keys = [(k, int(np.prod(v.shape))) for k, v in env.observation_spec().items()]
    resets = []
    for seed in range(RESETS):
        e = suite.load(domain, task, task_kwargs={"random": seed})
        e.reset()
        resets.append(np.concatenate([e.physics.data.qpos, e.physics.data.qvel, target(e.physics)]))
    arrays = {"resets": np.array(resets), "obs_keys": np.array([k for k, _ in keys]),
              "obs_sizes": np.array([s for _, s in keys]), "n_sub_steps": np.array(env._n_sub_steps),
              "timestep": np.array(env.physics.timestep()), "dm_control": np.array(dm_control.__version__ if hasattr(
                  dm_control, "__version__") else _version("dm_control")), "mujoco": np.array(mujoco.__version__)}
    arrays["episodes"] = np.array(EPISODES_OF.get(name, EPISODES))
    for i in range(int(arrays["episodes"])):
        (q0, v0, target0), actions, obs, rewards, discounts, (q1, v1), states = record_episode(suite, domain, task, 1000 + i)
        if i == 0:  # the state before every step (qpos, qvel, act, qacc_warmstart): one-step checks
            arrays["ep0_states"] = states
        arrays.update({f"ep{i}_qpos0": q0, f"ep{i}_qvel0": v0, f"ep{i}_target": target0, f"ep{i}_actions": actions,
                       f"ep{i}_obs": obs, f"ep{i}_rewards": rewards, f"ep{i}_discounts": discounts,
                       f"ep{i}_qpos_end": q1, f"ep{i}_qvel_end": v1})
    os.makedirs(OUT, exist_ok=True)
    np.savez_compressed(os.path.join(OUT, f"{name}.npz"), **arrays)
    print(f"{name}: {len(actions)} steps per episode, observation {sum(s for _, s in keys)} ({keys}), "
          f"{env._n_sub_steps} physics steps per control step", flush=True)


def _version(dist):
    from importlib import metadata

    return metadata.version(dist)


if __name__ == "__main__":
    for name in sys.argv[1:] or task_names():
        record(name)
