"""The task definition: what a user writes to define a MuJoCo task for gsa_jax, in one file.

    import numpy as np
    from envs.task import Task

    class Reach(Task):
        xml = "<mujoco>...</mujoco>"          # an MJCF: a path, an XML string, or a mujoco.MjSpec
        frame_skip, episode_length = 2, 200   # physics steps per env step; time limit (a truncation)
        noise = 0.1                           # start: qpos ~ init_qpos + U(-noise, noise) (a scalar or [nq])
        derived = ("site_xpos",)              # MjData fields observe/outcome read (as mj_step leaves them)

        def observe(self, qpos, qvel, derived, xp=np):            # [n, nq], [n, nv], {field: [n, ...]} -> [n, d]
            return xp.concatenate([qpos, qvel], axis=1)

        def outcome(self, before, qpos, qvel, derived, action, xp=np):   # after a step -> (obs, reward, terminated)
            reward = -xp.sum(xp.square(action), axis=1)
            return self.observe(qpos, qvel, derived, xp), reward, xp.zeros(qpos.shape[:1], bool)

    python -m gsa_jax.train --env my_module:Reach --physics c     # or envs.register("reach", Reach)

dm_control's tasks (envs/dmc/) read their derived fields as its legacy step leaves them: `derived_after = "step1"`
runs mj_step1 after the step, so position- and velocity-dependent fields (xpos, xmat, their sensors) are the new
state's, while acceleration-dependent ones (touch, accelerometer, force sensors) stay the last substep's; the
state itself is the same either way.

Observation, reward and termination are written once over batches (a leading axis of simulations) for NumPy and
jax.numpy (`xp`): backend 'c' (envs/c_backend.py) evaluates them in float64 on MuJoCo C's arrays inside the
compiled trainer, MJX (envs/task_mjx.py) with jax.numpy on MJX's data, and TaskC here (plain MuJoCo C, no JAX)
steps one MjData for deployment, evaluation and robustness. gymnasium's v5 tasks (envs/gym_v5.py) are
instances. A step: `before` reads what the reward needs from the state before it, ctrl = controls(action) (the action,
already clipped to [-1, 1], or with ctrl_range 'model' its map onto the actuators' ctrlrange), mj_step frame_skip times (and mj_rnePostConstraint if post_constraint), then
`outcome`. validate() checks a definition in one line before anything compiles.

Task, its checks and TaskC's stepping are defined in envs/definition.py (below the task registry, which builds every
task from them); this module is where a user imports them, and its TaskC also takes a task's name.
"""

from envs import definition
from envs.definition import (  # noqa: F401 - re-exported: what a task's author imports
    DERIVED_AFTER, KINDS, POST_CONSTRAINT_FIELDS, Task, TaskError, check_jax_agrees, check_rows, coordinate_names,
    load_model, seed_words, source_record, start_noise, validate,
)
from envs.registry import resolve_task


class TaskC(definition.TaskC):
    """One task on one MjData in plain MuJoCo C (no JAX), stepped as the trainer's backends step it
    (ctrl = action, mj_step frame_skip times, mj_rnePostConstraint), reading obs, reward and termination
    from the Task. task: a Task, or a task's name (its definition, resolved by envs/registry.py)."""

    def __init__(self, task: "Task | str"):
        super().__init__(resolve_task(task) if isinstance(task, str) else task)
