"""A task as a gymnasium environment, for the tools that take one (Stable-Baselines3, CleanRL, gymnasium's wrappers
and vector envs):

    env = envs.as_gymnasium("examples.reacher:Reacher")     # a task name, a Task subclass or instance
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

It steps the task's plain MuJoCo C twin (the record's make_c(): envs.task.TaskC over a task definition, our ports of
Brax's tasks, the Allegro hand), so its episodes are the twin's step for step: reset(seed=s) is the twin's
reset(s), the task's own start law (without a seed, one drawn from the env's np_random); step clips the action to
envs.ACTION_RANGE, as training does, and returns the twin's observation (float64), reward and termination;
truncated at the task's time limit (its episode_length). Needs gymnasium (the deploy extra); no JAX.
"""

import gymnasium
import numpy as np
from gymnasium import spaces

from envs.names import ACTION_RANGE

SEED_RANGE = 2**31 - 1  # start seeds drawn from np_random when reset() is given none


class TaskEnv(gymnasium.Env):
    """gymnasium.Env over a task's MuJoCo C twin (envs.as_gymnasium)."""

    metadata = {"render_modes": []}

    def __init__(self, record):
        self.task_name = record.name
        self.twin = record.make_c()
        self.max_episode_steps = int(record.episode_length())
        self.action_space = spaces.Box(ACTION_RANGE[0], ACTION_RANGE[1], shape=(record.action_size(),),
                                       dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(record.observation_size(),), dtype=np.float64)
        self.steps = 0

    def reset(self, *, seed=None, options=None):
        """The twin's start for `seed` (else one drawn from np_random) -> (obs, {})."""
        super().reset(seed=seed)
        start = seed if seed is not None else int(self.np_random.integers(SEED_RANGE))
        self.steps = 0
        return np.asarray(self.twin.reset(start), np.float64), {}

    def step(self, action):
        """One step of the twin with the action clipped to the action space -> (obs, reward, terminated, truncated,
        {}); truncated once max_episode_steps steps are done."""
        a = np.clip(np.asarray(action, np.float64), self.action_space.low, self.action_space.high)
        obs, reward, terminated = self.twin.step(a)
        self.steps += 1
        return (np.asarray(obs, np.float64), float(reward), bool(terminated), self.steps >= self.max_episode_steps, {})

