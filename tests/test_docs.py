"""The README and docs/ pages: every relative link and image resolves to a file in the repository; in those and
the experiment pages, every number quoted from the committed tables is what they give."""

import glob
import os
import re
import sys

import pytest

ROOT = os.path.join(os.path.dirname(__file__), "..")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def relative_links(path):
    """[(target as written, resolved path)] of a Markdown file's links that are not URLs or anchors."""
    with open(path) as f:
        text = f.read()
    out = []
    for target in LINK.findall(text):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        out.append((target, os.path.normpath(os.path.join(os.path.dirname(path), target.split("#")[0]))))
    return out


def test_every_relative_link_in_readme_and_docs_resolves():
    pages = [os.path.join(ROOT, "README.md")] + sorted(glob.glob(os.path.join(ROOT, "docs", "*.md")))
    assert len(pages) >= 8
    broken = [(os.path.relpath(p, ROOT), t) for p in pages for t, r in relative_links(p) if not os.path.exists(r)]
    assert not broken, broken
    readme_links = {t for t, _ in relative_links(pages[0])}
    assert all(f"docs/{os.path.basename(p)}" in readme_links for p in pages[1:])  # every page reachable


def test_link_check_sees_a_broken_link(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("![a](missing.png) [b](https://example.org) [c](#top) [d](page.md)")
    assert [(t, os.path.exists(r)) for t, r in relative_links(str(page))] == [("missing.png", False), ("page.md", True)]


def test_every_quoted_number_is_what_the_committed_tables_give():
    """Per-run and per-cell numbers in the pages are quoted from the committed tables (gsa_jax.analysis.quoting.quote):
    none has drifted from them."""
    from gsa_jax.analysis.quoting.quote import requote

    pages = [os.path.join(ROOT, "README.md")] + sorted(glob.glob(os.path.join(ROOT, "docs", "*.md"))) + sorted(
        glob.glob(os.path.join(ROOT, "experiments", "*", "README.md")))
    stale = []
    for page in pages:
        with open(page) as f:
            stale += [(os.path.relpath(page, ROOT), spec) for spec, _, _ in requote(f.read(), os.path.dirname(page))[1]]
    assert not stale, stale


def python_blocks(page):
    """The ```python blocks of a page under docs/, as written."""
    with open(os.path.join(ROOT, "docs", page)) as f:
        return re.findall(r"```python\n(.*?)```", f.read(), re.S)


def test_the_documented_evaluator_is_numpy_policy_on_a_padded_controller():
    """docs/deploy.md's evaluator, run as written, gives numpy_policy's actions and clusters on a committed mixture
    controller whose partition outputs are padded beyond its K (an argmax over all of them would pick clusters that
    do not exist) and on a flat MLP controller."""
    import numpy as np

    from gsa_jax.deployment import numpy_policy

    code = next(b for b in python_blocks("deploy.md") if "def evaluate(" in b)
    assert len(code.strip().splitlines()) <= 25
    namespace = {}
    exec(code, namespace)
    padded = os.path.join(ROOT, "experiments", "atlas_dmc", "results", "point_mass-easy", "mixture", "controllers",
                          "dmc.point_mass-easy-mixture-K4-s6.npz")
    flat = os.path.join(ROOT, "experiments", "fig1_v5", "results", "fig1_v5_Ant-v5_seeds_0_4", "controllers",
                        "Ant-v5-mlp-s0.npz")
    with np.load(padded) as f:
        assert f[f"w{int(f['n_layers']) - 1}"].shape[-1] > f["L"].shape[0] == 4  # padded beyond its K
    for path in (padded, flat):
        ctrl = numpy_policy.load(path)
        obs = (ctrl.obs_mean + 3 * ctrl.obs_std * np.random.default_rng(0).normal(size=(2000, ctrl.obs_mean.size)))
        obs = obs.astype(np.float32)
        action, cluster = namespace["evaluate"](path, obs)
        np.testing.assert_array_equal(cluster, ctrl.cluster(obs))
        np.testing.assert_allclose(action, ctrl.act(obs), rtol=1e-6, atol=1e-6)
        if path == padded:  # the argmax over every output picks clusters that do not exist, and crashes
            exec(code.replace('x[..., : f["L"].shape[0]]', "x"), unpadded := {})
            with pytest.raises(IndexError):
                unpadded["evaluate"](path, obs)


def test_your_task_page_gives_the_signatures_as_called_and_its_example_runs_as_written():
    """docs/your_task.md's reference block declares observe, outcome, before, observation_layout and initialize with
    envs.task.Task's own parameters and defaults (xp=np); its example, run as written, is a valid task (the checks
    train runs, jax.numpy included) stepped in MuJoCo C, with a layout naming every observation entry."""
    import ast
    import inspect

    import numpy as np

    from envs.task import Task
    from envs.task_checks import check_jax_agrees, validate

    blocks = python_blocks("your_task.md")
    reference = next(b for b in blocks if b.startswith("class Task:"))
    documented = {n.name: n.args for n in ast.walk(ast.parse(reference)) if isinstance(n, ast.FunctionDef)}
    for name in ("observe", "outcome", "before", "observation_layout", "initialize"):
        params = list(inspect.signature(getattr(Task, name)).parameters.values())
        assert [a.arg for a in documented[name].args] == [p.name for p in params], name
        defaults = ["np" if p.default is np else repr(p.default) for p in params if p.default is not p.empty]
        assert [ast.unparse(d) for d in documented[name].defaults] == defaults, name
    assert "qpos[:, :0] + 0.0" in inspect.getsource(Task.before) and "qpos[:, :0] + 0.0" in reference
    example = next(b for b in blocks if "class Pendulum(Task)" in b)
    namespace = {}
    exec(example, namespace)
    task = namespace["Pendulum"]()
    validate(task, "the documented example")
    check_jax_agrees(task, "the documented example")
    assert namespace["obs"].shape == (3,) and isinstance(namespace["terminated"], bool)
    assert len(task.observation_layout()) == task.observation_size == 3
    assert task.before(np.zeros((2, 1)), {}).shape == (2, 0)


def test_the_stable_baselines3_snippet_gets_what_sb3_needs_without_torch(monkeypatch):
    """The same snippet with SB3's PPO stood in by what it asks of its env (SB3 and torch are not test
    dependencies): gymnasium's API as gymnasium's own check_env tests it, Box spaces, and rollouts of the snippet's
    100,000 steps (here 2,048, one SB3 rollout) that reset on terminated or truncated with finite rewards."""
    import types

    import numpy as np
    from gymnasium.spaces import Box
    from gymnasium.utils.env_checker import check_env

    class StandInPPO:
        def __init__(self, policy, env, seed=None, device="auto"):
            assert policy == "MlpPolicy" and device == "cpu"
            check_env(env, skip_render_check=True)
            assert isinstance(env.observation_space, Box) and isinstance(env.action_space, Box)
            self.env = env
            env.action_space.seed(seed)

        def learn(self, total_timesteps):
            self.env.reset(seed=0)
            for _ in range(total_timesteps):
                obs, reward, terminated, truncated, _ = self.env.step(self.env.action_space.sample())
                assert obs.shape == self.env.observation_space.shape and np.isfinite(reward)
                if terminated or truncated:
                    self.env.reset()
            return self

        def predict(self, obs, deterministic=False):
            assert obs.shape == self.env.observation_space.shape and deterministic
            return np.zeros(self.env.action_space.shape, self.env.action_space.dtype), None

    monkeypatch.setitem(sys.modules, "stable_baselines3", types.ModuleType("stable_baselines3"))
    monkeypatch.setattr(sys.modules["stable_baselines3"], "PPO", StandInPPO, raising=False)
    code = next(b for b in python_blocks("your_task.md") if "stable_baselines3" in b)
    assert code.count("total_timesteps=100_000") == 1
    namespace = {}
    exec(code.replace("total_timesteps=100_000", "total_timesteps=2048"), namespace)
    assert namespace["env"].action_space.contains(namespace["action"].astype("float32"))

