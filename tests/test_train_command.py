"""`gsa train` (`python -m gsa_jax.train`): bad input, outputs, interrupt + resume, NaN handling."""

import csv
import json
import os

import numpy as np
import pytest
from golden_runs import arrays_digest, check_fingerprint, summarize, table_digest

from gsa_jax.cli import COMMANDS
from gsa_jax.running.metrics import RUN_COLUMNS as METRIC_COLUMNS
from gsa_jax.running.tensorboard import FILE_NAME, read_scalars
from gsa_jax.train import main

ROOT = os.path.join(os.path.dirname(__file__), "..")

SMALL = ["--steps", "2048", "--num-envs", "16", "--unroll-length", "32", "--minibatches", "8", "--epochs", "2",
         "--episode-length", "200", "--chunk", "1", "--eval-every", "2", "--eval-envs", "4", "--quiet"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--env", "pong"], "unknown env 'pong'; choose one of inverted_double_pendulum, hopper"),
        (["--policy", "rbf"], "unknown --policy 'rbf'; choose mixture or mlp"),
        (["--clusters", "0"], "--clusters must be >= 1"),
        (["--clusters", "8", "--k-max", "4"], "--clusters 8 exceeds --k-max 4"),
        (["--steps", "0"], "--steps must be positive"),
        (["--num-envs", "10", "--unroll-length", "3", "--minibatches", "4"], "is not divisible by --minibatches = 4"),
        (["--out", "/proc/nope"], "is not writable"),
        (["--eps-init", "1.5"], "eps_init must be in [0, 1)"),
        (["--subpolicy", "cubic"], "unknown --subpolicy 'cubic'; choose one of constant, linear, quadratic"),
        (["--policy", "mlp", "--subpolicy", "constant"], "--subpolicy applies to --policy mixture only"),
        (["--partition", "cubic"], "unknown partition 'cubic'; choose one of mlp, linear"),
        (["--policy", "mlp", "--partition", "linear"], "--partition applies to --policy mixture only"),
        (["--solver-iterations", "0"], "--solver-iterations must be an integer >= 1"),
        (["--ls-iterations", "-2"], "--ls-iterations must be an integer >= 1"),
        (["--value-target", "td"], "unknown --value-target 'td'; choose one of gae, retrace"),
        (["--value-target", "retrace", "--retrace-iterations", "0"], "--retrace-iterations must be >= 1, got 0"),
        (["--policy", "mlp", "--clusters", "3"], "--clusters applies to --policy mixture only"),
        (["--policy", "mlp", "-K3", "--k-max", "4"], "--clusters and --k-max apply to --policy mixture only"),
        (["--resume"], "no run in "),  # a typo in --out: not a new run of the default task
    ],
)
def test_bad_input_one_line_error(argv, message, capsys, tmp_path):
    if "--out" not in argv:
        argv = argv + ["--out", str(tmp_path / "run")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and message in err, err


def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def strip_wall(rows):
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "full"
    assert main(SMALL + ["--out", str(out)]) == 0
    return out


def test_outputs(full_run):
    names = set(os.listdir(full_run))
    assert {"config.json", "metrics.csv", "params.npz", "curve.png", "tensorboard"} <= names
    # stored as a group of one (gsa_jax.running.store): the resume state is dropped once finished
    assert {"runs.csv", "metrics.npz", "failed.json", "DONE"} <= names and "state.npz" not in names
    assert read_csv(full_run / "runs.csv") == [{"env": "inverted_double_pendulum", "policy": "mixture", "K": "4", "seed": "0"}]
    rows = read_csv(full_run / "metrics.csv")
    assert list(rows[0]) == list(METRIC_COLUMNS) and len(rows) == 4
    assert [int(r["env_steps"]) for r in rows] == [512, 1024, 1536, 2048]
    assert [r["eval_return"] != "" for r in rows] == [False, True, False, True]
    cfg = json.loads((full_run / "config.json").read_text())
    assert cfg["versions"]["jax"] and cfg["versions"]["mujoco"] and "git_commit" in cfg
    assert cfg["format_version"] == 1  # running.formats.FORMAT_VERSION, which every writer stamps
    assert cfg["config"]["env"] == "inverted_double_pendulum" and cfg["hparams"]["K"] == 4
    assert cfg["result"]["status"] == "finished" and cfg["timing"]["compile_s"] >= 0 and cfg["timing"]["train_s"] > 0
    with np.load(full_run / "params.npz") as p:
        keys = set(p.files)
        assert p["['obs_stats']['mean']"].shape[0] == 1  # the run axis of a group of one
    assert "['params']['policy']['L']" in keys and "['obs_stats']['mean']" in keys


def test_fixed_run_computes_what_it_computed(full_run):
    """The fixed run's metrics and parameters are bit for bit the ones recorded for this host family, and its
    summary is the recorded one within the tolerance that holds across hosts (tests/golden_runs.py; the
    parameters' fingerprint is the run's row of params.npz, recorded when a run directory had no run axis)."""
    check_fingerprint("train_cli_small", {"table": table_digest(full_run / "metrics.csv"),
                                          "params.npz": arrays_digest(full_run / "params.npz", run=0)},
                      summarize(full_run))


def test_existing_out_needs_resume(full_run, capsys):
    assert main(SMALL + ["--out", str(full_run)]) == 2
    assert "already holds a run; pass --resume" in capsys.readouterr().err


def test_interrupt_then_resume_equals_uninterrupted(full_run, tmp_path):
    out = tmp_path / "split"
    assert main(SMALL + ["--out", str(out), "--stop-after", "2"]) == 0
    assert len(read_csv(out / "metrics.csv")) == 2
    assert json.loads((out / "config.json").read_text())["result"]["status"] == "interrupted"
    board = out / "tensorboard" / FILE_NAME
    board.write_bytes((full_run / "tensorboard" / FILE_NAME).read_bytes())  # as if written past the checkpoint
    assert main(["--resume", "--out", str(out), "--quiet"]) == 0  # the saved settings: none typed again
    assert strip_wall(read_csv(out / "metrics.csv")) == strip_wall(read_csv(full_run / "metrics.csv"))
    assert all(r["wall_s"] != "" for r in read_csv(out / "metrics.csv"))  # the wall clock before the resume kept
    # TensorBoard: the resumed run's events restart from the checkpoint: each iteration once, as uninterrupted
    got, ref = read_scalars(str(board)), read_scalars(str(full_run / "tensorboard" / FILE_NAME))
    assert got == ref and [s for s, _ in got["returns/episode_return"]] == [512, 1024, 1536, 2048]
    assert [v for _, v in got["ppo/policy_loss"]] == pytest.approx([float(r["policy_loss"]) for r in read_csv(out / "metrics.csv")])
    with np.load(out / "params.npz") as a, np.load(full_run / "params.npz") as b:
        for k in a.files:
            if not k.startswith("meta/"):
                np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_the_printed_resume_command_resumes(full_run, tmp_path, capsys):
    """The command a stopped run prints is run as printed (a shell command from the working directory) and
    continues the run to the uninterrupted one's metrics; without --out, --resume is a one-line error."""
    import shlex
    import subprocess

    out = tmp_path / "hinted"
    assert main(SMALL[:-1] + ["--out", str(out), "--stop-after", "1", "--no-tensorboard"]) == 0
    hint = capsys.readouterr().out.strip().splitlines()[-1].split("continue with: ", 1)[1]
    command = shlex.split(hint)
    flags = ["--resume", "--out", str(out)]
    assert command[1:] in (["train", *flags], ["-m", "gsa_jax.train", *flags]) and os.path.exists(command[0]), hint
    import jax

    cache = {"JAX_COMPILATION_CACHE_DIR": jax.config.jax_compilation_cache_dir or ""}  # the suite's compiled programs
    done = subprocess.run(hint, shell=True, capture_output=True, text=True, timeout=600, env={**os.environ, **cache})
    assert done.returncode == 0, done.stderr
    assert strip_wall(read_csv(out / "metrics.csv")) == strip_wall(read_csv(full_run / "metrics.csv"))
    assert json.loads((out / "config.json").read_text())["tensorboard"] is False  # a saved setting kept
    assert main(["--resume"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--resume needs --out DIR" in err


def test_ctrl_c_in_a_running_process_is_130_and_keeps_what_is_saved(tmp_path):
    """Ctrl-C (SIGINT) sent to a real `python -m gsa_jax train` process mid-run: exit status 130, a closing line
    naming the last saved iteration and the command that continues it, and that many rows saved."""
    import re
    import signal
    import subprocess
    import sys
    import time

    import jax

    out = tmp_path / "ctrl_c"
    # As a terminal starts it: SIGINT unblocked and at its default, whatever this test process's threads left in the
    # signal mask or dispositions it hands on (the launcher resets both, then execs the very command).
    launcher = ("import os, signal, sys; signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT]); "
                "signal.signal(signal.SIGINT, signal.SIG_DFL); os.execv(sys.executable, [sys.executable, *sys.argv[1:]])")
    argv = [sys.executable, "-c", launcher, "-m", "gsa_jax", "train", *SMALL[2:-1], "--steps", "100000000",
            "--out", str(out), "--no-tensorboard"]
    cache = {"JAX_COMPILATION_CACHE_DIR": jax.config.jax_compilation_cache_dir or ""}  # the suite's compiled programs
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                            env={**os.environ, **cache})
    deadline = time.time() + 600
    while proc.poll() is None and time.time() < deadline:  # until two iterations are saved
        if (out / "metrics.csv").exists() and len(read_csv(out / "metrics.csv")) >= 2:
            break
        time.sleep(0.5)
    assert proc.poll() is None, proc.communicate()[1]
    with open(f"/proc/{proc.pid}/status") as f:  # what the run's SIGINT state is, for the message if it does not stop
        state = " ".join(line.strip() for line in f if line.startswith(("SigBlk", "SigIgn", "SigCgt")))
    proc.send_signal(signal.SIGINT)
    try:
        err = proc.communicate(timeout=300)[1]
    except subprocess.TimeoutExpired:
        proc.kill()
        rows = len(read_csv(out / "metrics.csv"))
        pytest.fail(f"gsa train did not stop within 300 s of SIGINT ({rows} rows saved; before the signal: {state})")
    assert proc.returncode == 130, err
    saved = re.search(r"interrupted; everything up to iteration (\d+) is saved in .*continue with: (.*)\)", err)
    flags = ["--resume", "--out", str(out)]
    assert saved and saved.group(2).split()[1:] in (["train", *flags], ["-m", "gsa_jax.train", *flags]), err
    assert len(read_csv(out / "metrics.csv")) >= int(saved.group(1)) >= 1  # rows past the last checkpoint: redone on resume
    assert json.loads((out / "config.json").read_text())["result"]["status"] == "interrupted"


def test_no_tensorboard_writes_no_event_files(tmp_path):
    out = tmp_path / "quiet"
    assert main(SMALL + ["--out", str(out), "--stop-after", "1", "--no-tensorboard"]) == 0
    assert not (out / "tensorboard").exists() and json.loads((out / "config.json").read_text())["tensorboard"] is False


def test_resume_with_other_config_refused(full_run, capsys):
    """Only typed options are compared with the saved run: one that differs is refused with its diff."""
    assert main(["--seed", "5", "--out", str(full_run), "--resume"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "(seed: 0 -> 5);" in err and "--force" in err, err
    assert main(["--eval-every", "1", "--out", str(full_run), "--resume"]) == 2
    assert "eval_every: 2 -> 1" in capsys.readouterr().err
    assert main(SMALL[:-1] + ["--solver-iterations", "1", "--out", str(full_run), "--resume"]) == 2
    assert "config.physics.solver_iterations: null -> 1" in capsys.readouterr().err


def test_resume_run_saved_before_solver_fields(full_run, tmp_path):
    """A run whose config.json predates the physics record (its options flat Config fields) and, before that,
    solver_iterations / ls_iterations (None by default) resumes."""
    import shutil

    old = tmp_path / "old"
    shutil.copytree(full_run, old)
    meta = json.loads((old / "config.json").read_text())
    for key in ("format_version", "eval_seed", "tensorboard"):  # a version-0 record (running.formats) lacks them
        meta.pop(key)
    physics = meta["config"].pop("physics")
    meta["config"].update({k: v for k, v in physics.items() if k not in ("solver_iterations", "ls_iterations", "threads")},
                          physics_threads=physics["threads"])
    (old / "config.json").write_text(json.dumps(meta))
    assert main(SMALL + ["--out", str(old), "--resume"]) == 0


def test_run_directories_of_an_older_layout_refused_in_one_line(full_run, tmp_path, capsys):
    """A run directory written before runs were stored as groups of one (no runs.csv; params.npz without a run
    axis) is refused by --resume and by every reader in one line that says how to go on; nothing is filled in
    silently. So is a metrics.npz that lacks a tracked metric."""
    import shutil

    from gsa_jax.commands.inspect_run import main as inspect_main
    from gsa_jax.export import main as export_main

    old = tmp_path / "old"
    shutil.copytree(full_run, old)
    (old / "runs.csv").unlink()
    capsys.readouterr()
    for command in (lambda: main(SMALL + ["--out", str(old), "--resume"]), lambda: export_main([str(old)]),
                    lambda: inspect_main([str(old)])):
        status, err = command(), capsys.readouterr().err.strip()
        assert status == 2 and err.count("\n") == 0 and "older gsa_jax" in err and "git_commit" in err, err
    stopped = tmp_path / "stopped"
    assert main(SMALL + ["--out", str(stopped), "--stop-after", "1"]) == 0
    with np.load(stopped / "metrics.npz") as m:
        kept = {k: m[k] for k in m.files if k != "eval_failures"}
    for name in ("metrics.npz", "metrics.prev.npz"):
        if (stopped / name).exists():
            np.savez(stopped / name, **kept)
    capsys.readouterr()
    assert main(SMALL + ["--out", str(stopped), "--resume"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "older gsa_jax (no eval_failures)" in err and "git_commit" in err


def test_resume_of_an_ended_run(full_run, tmp_path, capsys):
    """--resume of a finished run trains nothing and says so (a run stopped by NaN/inf: test_nan_stops...)."""
    assert main(SMALL[:-1] + ["--out", str(full_run), "--resume"]) == 0  # not --quiet
    assert "is finished; nothing to resume" in capsys.readouterr().out


def test_nan_stops_and_keeps_last_good_params(tmp_path, capsys):
    out = tmp_path / "nan"
    assert main(SMALL + ["--out", str(out), "--lr", "1e30", "--no-anneal-lr"]) == 1
    err = capsys.readouterr().err
    assert "NaN/inf" in err and "Last good parameters" in err
    with np.load(out / "params.npz") as p:
        assert all(np.all(np.isfinite(p[k])) for k in p.files if not k.startswith("meta/"))
    assert json.loads((out / "config.json").read_text())["result"]["status"] == "nan"
    capsys.readouterr()
    assert main(SMALL + ["--out", str(out), "--lr", "1e30", "--no-anneal-lr", "--resume"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "stopped at a NaN/inf at iteration" in err and "nothing to resume" in err


def test_evaluation_starts_do_not_depend_on_the_training_seed(full_run):
    """The same parameters evaluated by the programs of two training seeds score the same (same starts);
    another eval seed draws other starts. (The program is the one full_run compiled.)"""
    import jax

    from gsa_jax.running.programs import single_program
    from gsa_jax.commands.train import build_parser, resolve

    plan = resolve(build_parser().parse_args(SMALL))
    cfg, hp, chunk = plan.cfg, plan.hp, plan.chunk
    p0, _ = single_program(cfg, chunk, 0, hp)
    p1, _ = single_program(cfg, chunk, 1, hp)
    p2, _ = single_program(cfg, chunk, 0, hp, eval_seed=7)
    state = jax.device_get(p0.state)
    returns = [float(p.evaluate(state, p.hps, 3)[0]) for p in (p0, p1, p2)]
    assert returns[0] == returns[1] and returns[2] != returns[0], returns


def test_inspect_mixture_run(full_run, tmp_path, capsys):
    from gsa_jax.commands.inspect_run import main as inspect_main

    out = tmp_path / "inspect"
    assert inspect_main([str(full_run), "--episodes", "3", "--out", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    for mode in ("deterministic", "stochastic"):
        usage = np.array(s[mode]["usage"])
        assert len(usage) == 4 and abs(usage.sum() - 1.0) < 1e-6 and np.all(usage >= 0)
        assert 1 <= s[mode]["clusters_used"] <= 4 and s[mode]["mean_dwell_steps"] >= 1
    assert len(s["return_deterministic"]) == 3 and np.isfinite(s["return_stochastic_mean"])
    text = (out / "controllers.md").read_text()
    assert text.count("## cluster") == 4 and "strongest inputs" in text
    assert (out / "clusters_time.png").stat().st_size > 10_000 and (out / "clusters_pca.png").stat().st_size > 10_000


def test_inspect_bad_run_dirs(tmp_path, capsys):
    from gsa_jax.commands.inspect_run import main as inspect_main

    assert inspect_main([str(tmp_path / "nope")]) == 2
    assert "is not a gsa_jax run: neither a run directory" in capsys.readouterr().err
    assert inspect_main([str(tmp_path)]) == 2
    assert "is not a gsa_jax run: neither a run directory" in capsys.readouterr().err
    (tmp_path / "config.json").write_text(json.dumps({"config": {"policy": "mlp"}}))
    (tmp_path / "runs.csv").write_text("env,policy,K,seed\nhopper,mlp,1,0\n")
    np.savez(tmp_path / "params.npz", x=np.zeros((1, 2)))
    assert inspect_main([str(tmp_path)]) == 2
    assert "is a 'mlp' run; inspect reads mixture-of-linear runs" in capsys.readouterr().err


def test_export_real_run_matches_jax(full_run, tmp_path):
    """The exported controller of a trained run acts like the JAX deterministic policy (every sub-policy
    class, on fabricated run directories: tests/test_export.py)."""
    import jax

    from gsa_jax.algorithm.normalize import normalize
    from gsa_jax.deployment import numpy_policy
    from gsa_jax.deployment.inspection import load_run
    from gsa_jax.export import main as export_main

    assert export_main([str(full_run), "--out", str(tmp_path / "c.npz")]) == 0
    ctrl = numpy_policy.load(str(tmp_path / "c.npz"))
    trainer, params, stats, hp, _ = load_run(str(full_run))
    obs = np.random.default_rng(0).normal(size=(200, trainer.env.observation_size)).astype(np.float32)
    sched = {"K": hp.K, "epsilon": hp.eps_init, "sigma_min": hp.sigma_min_init}
    a, c = jax.vmap(trainer.policy.mode, in_axes=(None, 0, None))(params["policy"], normalize(stats, obs), sched)
    np.testing.assert_allclose(ctrl.act(obs, clip=False), np.asarray(a), rtol=1e-5, atol=1e-5)  # the raw action
    np.testing.assert_array_equal(ctrl.act(obs), np.clip(ctrl.act(obs, clip=False), -1.0, 1.0))  # the task's bounds
    np.testing.assert_array_equal(ctrl.cluster(obs), np.asarray(c))
    assert ctrl.subpolicy == trainer.cfg.subpolicy == "linear"
    assert np.abs(ctrl.L).sum() > 0  # trained: not the L = 0 init


@pytest.mark.parametrize("module", sorted(COMMANDS.values()))
def test_help_describes_the_command_in_whole_sentences(module, capsys):
    """Every command's --help opens with its docstring's first paragraph, whole (not cut at a line end); train's
    --env names every kind of task name, playground:<Name> included."""
    import importlib

    from gsa_jax.running.runinfo import cli_description

    mod = importlib.import_module(f"gsa_jax.commands.{module}")
    with pytest.raises(SystemExit):
        mod.main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    description = cli_description(mod.__doc__)
    assert description in text and description.endswith((".", ")", "`")), description
    if module == "train":
        assert "'playground:<Name>'" in text and "'brax:<name>'" in text and "'module:Class'" in text


def test_a_nan_is_attributed_to_the_tasks_reward_where_an_episode_shows_it():
    """The failure line names the task's reward where an episode that ended in the failing iteration returned a
    non-finite total, and the loss or parameters otherwise, saying what it could not see."""
    from gsa_jax.commands.train import failure_line

    m = {"failed_at": np.array([[-1, -1, 3]]), "episodes": np.array([[2.0, 1.0, 4.0]]),
         "episode_return": np.array([[1.0, 2.0, np.nan]])}  # iteration 3 failed
    line = failure_line(m, 3, "OUT")
    assert line.startswith("NaN/inf in the task's reward") and "check its outcome()" in line and "at iteration 3;" in line
    m["episode_return"][0, 2] = 5.0
    assert failure_line(m, 3, "OUT").startswith("NaN/inf in the loss or parameters (the episodes that ended in it ")
    m["episodes"][0, 2], m["episode_return"][0, 2] = 0.0, np.nan
    assert "no episode ended in it" in failure_line(m, 3, "OUT")


def test_the_summary_names_the_iteration_of_its_returns(full_run, capsys):
    """config.json's result and the closing line say which iteration the final training and evaluation returns
    are from (the last with an ended episode / an evaluation, not always the last iteration)."""
    from gsa_jax.commands.train import report_end

    rows = read_csv(full_run / "metrics.csv")
    result = json.loads((full_run / "config.json").read_text())["result"]
    assert result["final_episode_return_iteration"] == max(int(r["iteration"]) for r in rows if r["episode_return"])
    assert result["final_eval_return_iteration"] == max(int(r["iteration"]) for r in rows if r["eval_return"])
    config = {"timing": {"env_steps_run": 10, "wall_s": 1.0, "compile_s": 0.5, "env_steps_per_s": 10.0},
              "result": {**result, "final_episode_return": 1.25, "final_episode_return_iteration": 3}}
    ended = type("Ended", (), {"status": "finished", "done": 4, "iterations": 4})
    lines = []
    assert report_end(ended, config, "OUT", lines.append) == 0
    assert "final return 1.2 (iteration 3), eval " in lines[0] and f"(iteration {result['final_eval_return_iteration']})" in lines[0]


def test_the_evaluation_compiles_with_the_run(full_run):
    """A run that evaluates compiles its evaluation with its training chunk (so 'compiled in' counts it, not the
    first chunk); one without evaluations leaves it to jit."""
    import jax

    from gsa_jax.algorithm.config import make_hparams
    from gsa_jax.algorithm.ppo import shares_starts
    from gsa_jax.commands.train import build_parser, resolve
    from gsa_jax.running.programs import compile_single

    plan = resolve(build_parser().parse_args(SMALL))
    assert plan.eval_every > 0
    _, init, _, evaluate = compile_single(plan.cfg, plan.chunk)  # the programs full_run compiled: reused
    assert isinstance(evaluate.rest, jax.stages.Compiled), type(evaluate.rest)
    # init (and the reset it shares with the evaluation where the run shares one) compile as programs run once
    # (xla_cache.once_options: XLA:CPU's older fusion code generation)
    key, hp = jax.random.PRNGKey(0), make_hparams(**plan.hp)
    assert init.reset is evaluate.reset and (init.reset is not None) == shares_starts(plan.cfg)
    lowered = [init.rest.lower(key, hp)] if init.reset is None else [
        init.rest.lower(key, hp, init.reset(init.keys_of(key))), init.reset.lower(init.keys_of(key))]
    for lowered in lowered:
        assert ("xla_cpu_use_fusion_emitters", False) in lowered._lowering._compiler_options_kvs  # jax 0.10.1's
