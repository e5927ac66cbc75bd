"""An exported controller in gymnasium's own MuJoCo tasks (their MJCF, reward, termination, time limit).

Brax's tasks, which we train on, are ports of gym's; their observations must still be checked, not
assumed, before a controller trained on one runs in the other. `make_gym(task, env_id)` builds
gymnasium's env with the options that make its observation ours (Ant-v5: no contact forces) and
checks it: same joints and actuators in the same order, the same action range, and, along a short
random rollout, gymnasium's observation equal to our task's observation function
(envs.mujoco_c) evaluated on gymnasium's own MjData. A task whose layout no option makes match is
refused with the reason. Needs the optional `deploy` extra (gymnasium[mujoco]); no JAX.
"""

import re
from typing import Any

import mujoco
import numpy as np

from envs import GYM_V5_TASKS
from envs.mujoco_c import BRAX_PORTS
from gsa_jax.errors import UserError

GYM_NAMES = {"hopper": "Hopper", "walker2d": "Walker2d", "halfcheetah": "HalfCheetah", "ant": "Ant",
             "inverted_double_pendulum": "InvertedDoublePendulum"}
# Options of gymnasium's env that make its observation layout ours, per task.
GYM_OPTIONS = {"ant": {"include_cfrc_ext_in_observation": False}}  # v5 appends 78 contact forces by default
NO_MATCH = {
    "inverted_double_pendulum": "gymnasium's InvertedDoublePendulum observes the cart's constraint force (v5: 9 "
                                "values, v4: 11) and Brax's task does not (8 values); no option of gymnasium's env "
                                "removes it",
    "allegro_cylinder": "gymnasium has no Allegro-hand task",
}


class GymnasiumError(UserError):
    pass


def parse_id(env_id: str) -> tuple:
    """'Hopper-v5' -> ('Hopper', 5)."""
    m = re.fullmatch(r"([A-Za-z0-9]+)-v(\d+)", env_id)
    if m is None:
        raise GymnasiumError(f"{env_id!r} is not a gymnasium env id like 'Hopper-v5'")
    return m.group(1), int(m.group(2))


def make_gym(task: str, env_id: str, check_steps: int = 50, seed: int = 0) -> tuple:
    """gymnasium's env `env_id` for a controller of `task`, with GYM_OPTIONS[task]; raises GymnasiumError
    with a one-line reason if it is another task or its observation layout differs from ours."""
    name, _ = parse_id(env_id)
    if task in GYM_V5_TASKS:  # trained on gymnasium's own task: the same id, nothing to check
        if env_id != task:
            raise GymnasiumError(f"the controller is for {task!r}, not {env_id!r}")
        return _make(env_id, {}), {}
    if task in NO_MATCH:
        raise GymnasiumError(f"the controller is for {task!r}: {NO_MATCH[task]}")
    if task not in GYM_NAMES:
        raise GymnasiumError(f"no gymnasium counterpart of {task!r}")
    if name != GYM_NAMES[task]:
        raise GymnasiumError(f"the controller is for {task!r} (gymnasium: {GYM_NAMES[task]}-v5), not {env_id!r}")
    options = GYM_OPTIONS.get(task, {})
    env = _make(env_id, options)
    check_layout(task, env, env_id, check_steps, seed)
    return env, options


def _make(env_id, options):
    """gymnasium.make(env_id, **options), or GymnasiumError with the first line of gymnasium's reason."""
    try:
        import gymnasium
    except ImportError as e:
        raise GymnasiumError(f"gymnasium is not installed: pip install 'gsa_jax[deploy]' ({e})") from None
    try:
        return gymnasium.make(env_id, **options)
    except (gymnasium.error.Error, TypeError, ValueError) as e:
        with_options = f" with options {options}" if options else ""
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise GymnasiumError(f"gymnasium cannot make {env_id!r}{with_options}: {first}") from None


def _structure(m):
    joints = [m.joint(j).name for j in range(m.njnt)]
    actuated = [m.joint(m.actuator_trnid[i, 0]).name for i in range(m.nu)]
    return joints, actuated


def check_layout(task: str, env: Any, env_id: str, steps: int = 50, seed: int = 0) -> None:
    """Raise GymnasiumError unless gymnasium's observation and action layout are our task's."""
    port = BRAX_PORTS[task]()
    u = env.unwrapped
    ours, theirs = _structure(port.model), _structure(u.model)
    if ours != theirs:
        raise GymnasiumError(f"{env_id} has joints/actuators {theirs}, our {task} {ours}")
    lo, hi = env.action_space.low, env.action_space.high
    if not (np.allclose(lo, port.model.actuator_ctrlrange[:, 0]) and np.allclose(hi, port.model.actuator_ctrlrange[:, 1])):
        raise GymnasiumError(f"{env_id}'s action range [{lo}, {hi}] is not our {task}'s")
    names = port.observation_layout()
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    current = mujoco.MjData(u.model)
    for t in range(steps + 1):
        # Our observation function on gymnasium's state, with kinematics of that state: after mj_step,
        # MjData's xpos are those of the last substep's start, which Brax's torso height reads (2 ms old)
        # and gymnasium's qpos-based one does not -- the same quantity, not a layout difference.
        mujoco.mj_copyData(current, u.model, u.data)
        mujoco.mj_kinematics(u.model, current)
        mine = port.observation(u.model, current)
        if np.shape(obs) != mine.shape:
            raise GymnasiumError(f"{env_id} observes {np.size(obs)} values, our {task} {mine.size} "
                                 f"(with options {GYM_OPTIONS.get(task, {})})")
        bad = np.flatnonzero(~np.isclose(np.asarray(obs, np.float32), mine, rtol=1e-5, atol=1e-5))
        if bad.size:
            i = int(bad[0])
            raise GymnasiumError(f"{env_id}'s observation [{i}] ({names[i]}) is {obs[i]:.6g} where ours reads "
                                 f"{mine[i]:.6g} from the same state: the layouts differ")
        obs, _, terminated, truncated, _ = env.step(rng.uniform(lo, hi).astype(np.float32))
        if terminated or truncated:
            obs, _ = env.reset(seed=seed + t + 1)


def check_bounds(controller: Any, env: Any, env_id: str) -> None:
    """Raise GymnasiumError unless the controller's action bounds are gymnasium's action space."""
    low, high = controller.bounds()
    if not (np.array_equal(low, env.action_space.low) and np.array_equal(high, env.action_space.high)):
        raise GymnasiumError(f"{env_id}'s action space [{env.action_space.low}, {env.action_space.high}] is not the "
                             f"controller's bounds [{low}, {high}]")


def run_episodes(env: Any, controller: Any, episodes: int, seed: int = 0) -> tuple:
    """Deterministic controller (gsa_jax.deployment.numpy_policy) in gymnasium's env, episodes ended by its own
    termination and time limit; its act() keeps actions inside the bounds (check_bounds). -> returns, lengths
    [episodes]."""
    returns, lengths = [], []
    for e in range(episodes):
        obs, _ = env.reset(seed=seed + e)
        total, t, done = 0.0, 0, False
        while not done:
            obs, r, terminated, truncated, _ = env.step(controller.act(obs))
            total += float(r)
            t += 1
            done = terminated or truncated
        returns.append(total)
        lengths.append(t)
    return np.array(returns), np.array(lengths)
