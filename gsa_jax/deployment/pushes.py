"""Pushes as paired events: every push has its own control, the same deterministic episode without it.

A controller that falls early anyway has less to lose from a push that comes later, so random pushes over
whole episodes favour weak controllers. Here each push is one event: from a control episode (the controller
from a fixed start, no push) we copy the simulator's whole state (MjData) at the push time t, apply the push
during step t of the copy, and run the same controller on for W steps. The push counts for a window W only
where the control survives steps t .. t+W-1 (and t+W is within the episode); it made the robot fall if the
copy terminates at one of those steps; the return it cost is the control's reward over the window minus the
copy's. Push times and directions are drawn from the start seed alone, never from the controller, so every
controller meets the same events.
"""

import copy
from typing import Any, Callable, NamedTuple

import numpy as np

from envs.randomization import push_force
from gsa_jax.deployment.shifts import Shift, is_planar, shifted_task, step_task, task_step_seconds

PUSH_SIZES = (0.25, 0.5, 1.0)  # m/s: the velocity change of the whole robot each push gives
WINDOWS = (20, 50, 100)  # env steps after the push in which a fall counts
PER_EPISODE = 10  # push events per start state


class Event(NamedTuple):
    start: int  # index of the start state (seed START + start)
    time: int  # env step during which the push acts (0-based)
    direction: tuple  # horizontal unit vector (x, y)


def push_events(seed: int, per_episode: int, latest: int, planar: bool, draw: int = 0) -> list:
    """[Event] of one start: `per_episode` push times uniform in [0, latest] and directions (+-x for planar
    robots, any horizontal angle otherwise), drawn from `seed` alone (the same for every controller); draw > 0:
    another independent draw of them (0: the robustness experiment's)."""
    rng = np.random.default_rng([int(seed), 0x9055] + ([int(draw)] if draw else []))
    times = np.sort(rng.integers(0, latest + 1, per_episode))
    angle = np.where(rng.random(per_episode) < 0.5, 0.0, np.pi) if planar else rng.uniform(0, 2 * np.pi, per_episode)
    return [(int(t), (float(np.cos(a)), float(np.sin(a)))) for t, a in zip(times, angle)]


def window_outcomes(control_fall: int, branch_fall: int | None, time: int, length: int, windows: tuple) -> tuple:
    """(counted [W], fell [W]) of one push at env step `time` for each window W: counted where the control
    survives W steps from the push (control_fall, steps from the push to the control's termination, 1 = during
    the push's step, None = never) and time + W <= length; fell where counted and the pushed copy terminates
    within them (branch_fall likewise)."""
    counted = np.array([(control_fall is None or control_fall > w) and time + w <= length for w in windows])
    fell = counted & np.array([branch_fall is not None and branch_fall <= w for w in windows])
    return counted, fell


class Control(NamedTuple):
    rewards: np.ndarray  # [E, length] the control episodes' rewards (0 after termination)
    fall: np.ndarray  # [E] the env step (0-based) at which each terminated, -1 where it did not
    lengths: np.ndarray  # [E] steps taken
    snapshots: dict  # {(start, time): (task copy, observation)} at the event times


def run_controls(ctrl: Any, make_task: Callable, seeds: np.ndarray, times: dict, length: int) -> Control:
    """The controller's deterministic episodes from each start seed in fresh tasks make_task(), with copies
    of the task (its MjData) and observation taken before each step listed in times {start: set(step)}."""
    tasks = [make_task() for _ in seeds]
    obs = np.stack([t.reset(int(s)) for t, s in zip(tasks, seeds)]).astype(np.float64)
    rewards, fall = np.zeros((len(seeds), length)), np.full(len(seeds), -1)
    alive, lengths, snaps = np.ones(len(seeds), bool), np.zeros(len(seeds), int), {}
    for t in range(length):
        for e in np.flatnonzero(alive):
            if t in times.get(e, ()):
                snaps[(e, t)] = (copy_task(tasks[e]), obs[e].copy())
        action = act_each(ctrl, obs)
        for e in np.flatnonzero(alive):
            obs[e], rewards[e, t], done = tasks[e].step(action[e])
            lengths[e] = t + 1
            if done:
                alive[e], fall[e] = False, t
        if not alive.any():
            break
    return Control(rewards, fall, lengths, snaps)


def act_each(ctrl: Any, obs: np.ndarray) -> np.ndarray:
    """[B, d_a] the controller's actions for observations [B, d_s], each computed alone: a batched float32
    product rounds differently with the batch's size, and a pushed copy must differ from its control by
    the push only (deployment's episodes act one observation at a time too)."""
    return np.stack([ctrl.act(o.astype(np.float32)) for o in obs]).astype(np.float64)


def copy_task(task: Any) -> Any:
    """A copy of a MuJoCo C task sharing its model, with its own copy of the whole MjData."""
    twin = copy.copy(task)
    twin.data = copy.copy(task.data)
    return twin


def run_branches(ctrl: Any, branches: list, limits: list) -> tuple:
    """Pushed copies stepped together: branches [(task, obs, force [2])], the force acting during the first
    step only, branch b for limits[b] steps at most -> (fall [B], steps from the push to termination or None;
    rewards [B, max(limits)], 0 after termination or the limit)."""
    tasks = [b[0] for b in branches]
    obs = np.stack([b[1] for b in branches])
    limits = np.asarray(limits, int)
    rewards, fall = np.zeros((len(branches), int(limits.max(initial=0)))), [None] * len(branches)
    alive = limits > 0
    for k in range(rewards.shape[1]):
        action = act_each(ctrl, obs)
        for e in np.flatnonzero(alive):
            force = branches[e][2] if k == 0 else np.zeros(2)
            obs[e], rewards[e, k], done = step_task(tasks[e], action[e], force)
            if done:
                fall[e] = k + 1
            alive[e] = not done and k + 1 < limits[e]
        if not alive.any():
            break
    return fall, rewards


def event_row(control: Control, e: int, t: int, branch_fall: np.ndarray, branch_rewards: np.ndarray, windows: tuple,
              length: int) -> dict:
    """The outcome columns of one pushed copy: control_fall, branch_fall and, per window W, counted_W,
    fell_W and lost_W (the control's return over the window minus the copy's; blank where not counted)."""
    cf = int(control.fall[e]) - t + 1 if control.fall[e] >= 0 else None
    counted, fell = window_outcomes(cf, branch_fall, t, length, windows)
    row = {"control_fall": "" if cf is None else cf, "branch_fall": "" if branch_fall is None else branch_fall}
    for w, c, f in zip(windows, counted, fell):
        lost = control.rewards[e, t:t + w].sum() - branch_rewards[:w].sum()
        row.update({f"counted_W{w}": int(c), f"fell_W{w}": int(f), f"lost_W{w}": round(float(lost), 4) if c else ""})
    return row


class PushPlan(NamedTuple):
    """Which pushes a controller meets: push sizes, the windows after a push its loss is counted over, events
    per episode, the episode length, and which independent draw of push events (push_events; 0: the robustness
    experiment's)."""

    sizes: tuple = PUSH_SIZES
    windows: tuple = WINDOWS
    per_episode: int = PER_EPISODE
    length: int = 1000
    draw: int = 0


def push_start(ctrl: Any, make_task: Callable, planar: bool, seed: int, plan: PushPlan) -> tuple:
    """(rows, control) of one start seed: the control episode, then every push event x size (push_events' draw)
    as a pushed copy of it (none where the control has ended or terminates at the push's step: a row never
    counted)."""
    sizes, windows, length = plan.sizes, plan.windows, plan.length
    wmax = max(windows)
    events = push_events(seed, plan.per_episode, length - wmax, planar, plan.draw)
    control = run_controls(ctrl, make_task, [seed], {0: {t for t, _ in events}}, length)
    keys, branches, limits = [], [], []
    for j, (t, direction) in enumerate(events):
        survives = control.fall[0] - t if control.fall[0] >= 0 else wmax  # steps from t the control survives
        task, obs = control.snapshots.get((0, t), (None, None))
        for size in sizes:
            live = task is not None and survives >= 1
            keys.append((j, t, size, len(branches) if live else None))
            if live:
                impulse = push_force(size, task.model, task_step_seconds(task))
                branches.append((copy_task(task), obs.copy(), impulse * np.asarray(direction)))
                limits.append(min(wmax, survives))
    fall, rew = run_branches(ctrl, branches, limits) if branches else ([], None)
    rows = [{"start_seed": int(seed), "event": j, "time": t, "size": size,
             **event_row(control, 0, t, None if i is None else fall[i], np.zeros(wmax) if i is None else rew[i],
                         windows, length)} for j, t, size, i in keys]
    return rows, control


def evaluate_pushes(ctrl: Any, env_name: str, seeds: np.ndarray, plan: PushPlan = PushPlan(),
                    make_task: Callable | None = None) -> tuple:
    """(rows, nominal) of one controller: a row per push event x size (start_seed, event, time, size and
    event_row's columns) and its control episodes' {nominal_score, mean_length, full_length_fraction}.
    make_task: the task's MuJoCo C twin (default: env_name's, nominal physics)."""
    make_task = make_task or (lambda: shifted_task(env_name, Shift("nominal")))
    rows, returns, lengths, planar = [], [], [], is_planar(make_task())
    for seed in seeds:
        new, control = push_start(ctrl, make_task, planar, seed, plan)
        rows += new
        returns.append(control.rewards.sum())
        lengths.append(int(control.lengths[0]))
    nominal = {"nominal_score": round(float(np.mean(returns)), 3), "mean_length": round(float(np.mean(lengths)), 2),
               "full_length_fraction": round(float(np.mean(np.array(lengths) >= plan.length)), 4), "episodes": len(seeds)}
    return rows, nominal
