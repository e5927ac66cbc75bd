"""The built-in tasks' names and the constants every task shares (no JAX, no MuJoCo).

Tasks: Brax's MJX variants of the gym MuJoCo benchmarks used in the paper's Figure 1 (BRAX_TASKS),
`allegro_cylinder` (envs/allegro.py), gymnasium's own v5 tasks (GYM_V5_TASKS, gymnasium's ids: envs/v5_tasks.py) and
the DeepMind Control Suite's (DMC_TASKS, 'dmc:<domain>-<task>': envs/dmc/). envs/registry.py makes each a record.
"""

from envs.dmc import NAMES as DMC_TASKS

BRAX_TASKS = ("inverted_double_pendulum", "hopper", "halfcheetah", "walker2d", "ant")  # Brax's MJX variants
GYM_V5_TASKS = ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5", "InvertedDoublePendulum-v5")  # gymnasium's own: envs/v5_tasks.py

NAMES = BRAX_TASKS + ("allegro_cylinder",) + GYM_V5_TASKS + DMC_TASKS
DEFAULT_EPISODE_LENGTH = 1000
# Every task's action bounds, per action: PPO clips its actions to them (training and evaluation,
# gsa_jax/algorithm/ppo.py) and an exported controller's act() does (gsa_jax/deployment/numpy_policy.py). They are
# the locomotion tasks' actuator ctrlrange and gymnasium's action_space (tests/test_export.py), and the range of
# allegro_cylinder's PD-target steps (envs/allegro.py).
ACTION_RANGE = (-1.0, 1.0)
RESET_MODES = ("first", "fresh")  # where an ended episode restarts (envs/wrappers.py's AutoReset)
