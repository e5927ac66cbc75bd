"""Answer how few linear controllers a task needs: one command trains, judges and adds seeds until it is decided.

    gsa answer --env TASK [--clusters 1,2,4] [--margin 0.1] [--target SCORE] [--looks 10,20,40]
                [--steps auto|N] [--max-steps 1000000] [--budget-minutes 120] [--start-from RESULTS_DIR ...] [--out DIR]
    make answer ENV=TASK

Trains flat PPO and a mixture of K linear controllers for every K of the ladder (default K = ceil(m d_a), m in 0.5,
1, 2, 4), scores every run by its exported controller in MuJoCo C from fixed start states, and judges each K
sufficient, insufficient or undecided at the margin (gsa_jax.analysis.verdicts.verdict: the IQM gap on the scale of the
reference's gain over a random policy measured over 128 episodes, Yuen's trimmed-mean t, no resampling). The
reference is flat PPO where it is adequate, else the published or tuned PPO score it falls below
(gsa_jax.analysis.verdicts.baseline: --references); the report says which, and whether flat PPO still learns at the
budget. --steps auto (default): every class trains to the first budget (of --max-steps halved four times, doubled
back) at which flat PPO's first seeds have learned the task and stopped learning (gsa_jax.analysis.verdicts.step_budget).
Seeds are added, look by look, only to the undecided K below the smallest sufficient one (and to flat PPO), every
sweep of a class one program (compiled once per answer, loaded after), until the smallest sufficient K is decided, the last look (the seed cap) is
reached or the budget would run out. The design (an alpha-spending function over the looks, Holm over the K) keeps
the chance that the answer names a K that is not within the margin at most 2.5% over all K and looks
(gsa_jax.analysis.verdicts.sequential). --target SCORE judges against a score your robot needs instead. --start-from takes
committed results (gsa extract --results; e.g. experiments/atlas_dmc/results/<task>/*): their runs are the first
seeds (judged at the same looks as a table of them) and their sweep.json settings train the new ones.

Writes DIR (default runs/answers/<task>): answer.json (the state: the same command resumes it), report.md (the
answer in one sentence, the baseline's standing, the verdicts with the seeds each used, other margins as sensitivity,
score against K with the margin drawn, the rounds' times, the command), verdicts.csv, score_vs_k.png,
controller/controller.{npz,h,onnx} (the chosen K's best seed, re-scored on fresh start states),
random_policy.json, results/<round>/ (what each round's sweeps commit: sweep.json, tidy metrics, controllers,
controller_scores.csv). Exit status: 0 answered (decided or not), 2 bad input, 3 a sweep failed.
"""

import argparse
import json
import math
import os
import shlex
import sys

import envs
from gsa_jax.algorithm import partitions
from gsa_jax.analysis.sweeps import controller_scores
from gsa_jax.analysis.verdicts import sequential, verdict
from gsa_jax.analysis.verdicts.answering import (DEFAULT_LOOKS, DEFAULT_SPENDING, FLAT, AnswerError, Evidence, Setup,
                                              save_state)
from gsa_jax.commands.command_line import command_parser, whole_number
from gsa_jax.errors import run_command
from gsa_jax.orchestration.answer_loop import check_setup, run_answer
from gsa_jax.running.runinfo import git_commit

MULTIPLIERS = (0.5, 1, 2, 4)
AUTO = "auto"


def steps_option(text: str) -> "int | str":
    """--steps: 'auto' or a whole number (argparse type)."""
    return AUTO if text.strip().lower() == AUTO else whole_number(text)


def parse_ints(text: str, what: str) -> tuple:
    """'1,2,4' -> (1, 2, 4); AnswerError in one line otherwise."""
    try:
        values = tuple(int(v) for v in text.replace(" ", ",").split(",") if v != "")
    except ValueError:
        raise AnswerError(f"{what} must be integers separated by commas, got {text!r}") from None
    if not values:
        raise AnswerError(f"{what} is empty")
    return values


def default_ladder(env: str) -> tuple:
    """K = ceil(m d_a) for m in MULTIPLIERS, the atlas's ladder ({1, 2, 4} on a one-action task)."""
    d_a = envs.action_size(env)
    return (1, 2, 4) if d_a == 1 else tuple(sorted({max(1, math.ceil(m * d_a - 1e-9)) for m in MULTIPLIERS}))


def start_specs(dirs: list) -> dict:
    """{policy: base spec} from the sweep.json of each --start-from directory (their settings train new seeds)."""
    from gsa_jax.analysis.sweeps.results import sweep_metas

    specs = {}
    for d in dirs:
        if not os.path.isdir(d):
            raise AnswerError(f"--start-from {d!r} is not a directory")
        metas = sweep_metas(d)
        if not metas:
            raise AnswerError(f"--start-from {d!r} holds no sweep.json (give gsa extract --results directories)")
        for meta in metas:
            for policy in meta["spec"]["policies"]:
                specs[policy] = {k: v for k, v in meta["spec"].items() if k not in ("seeds", "policies", "envs")}
    return specs


def base_specs(args: argparse.Namespace, env: str) -> dict:
    """The base spec per class: --start-from's, else the defaults with --steps and the backend."""
    backend = args.physics or ("c" if envs.has_c_backend(env) else "mjx")
    try:
        config = json.loads(args.config)
    except json.JSONDecodeError as e:
        raise AnswerError(f"--config must be a JSON object of config fields, e.g. '{{\"num_envs\": 16}}' ({e})") from None
    if not isinstance(config, dict):
        raise AnswerError(f"--config must be a JSON object of config fields, got {args.config!r}")
    steps = args.max_steps if args.steps == AUTO else args.steps
    default = {"steps": steps, "hparams": {}, "config": {**config, "physics": {"backend": backend}}}
    specs = {"mlp": dict(default), "mixture": dict(default)}
    specs.update(start_specs(args.start_from or []))
    if args.partition is not None:  # the mixtures' partition class (flat PPO has none)
        mixture = {k: v for k, v in specs["mixture"].items() if k != "partitions"}
        specs["mixture"] = {**mixture, "config": {**mixture.get("config", {}), "partition": args.partition}}
    return specs


def make_setup(args: argparse.Namespace) -> Setup:
    """The checked Setup of the command line (AnswerError in one line; nothing compiles)."""
    if args.budget_minutes <= 0:
        raise AnswerError(f"--budget-minutes must be > 0, got {args.budget_minutes:g}")
    if not 0.0 < args.margin < 1.0:
        raise AnswerError(f"--margin must be in (0, 1), got {args.margin:g}")
    for name, value in (("--steps", args.steps), ("--max-steps", args.max_steps)):
        if value != AUTO and value < 1:
            raise AnswerError(f"{name} must be >= 1, got {value}")
    try:
        envs.check_name(args.env)
    except ValueError as e:
        raise AnswerError(" ".join(str(e).split())) from None
    if not envs.has_c_backend(args.env):
        raise AnswerError(f"{args.env!r} has no MuJoCo C version, and the answer scores every run by its controller in "
                          "MuJoCo C: give a gymnasium v5 task, a dmc: task or your own Task (envs/task.py)")
    ladder = parse_ints(args.clusters, "--clusters (the K ladder)") if args.clusters is not None else default_ladder(args.env)
    setup = Setup(args.env, tuple(sorted(set(ladder))), args.margin, parse_ints(args.looks, "--looks"),
                  base_specs(args, args.env), args.target, tuple(args.start_from or ()), spending=args.spending,
                  futility=args.futility, references=os.path.abspath(args.references) if args.references else None,
                  max_steps=args.max_steps if args.steps == AUTO and not args.start_from and args.target is None else None)
    check_setup(setup)
    return setup


def random_policy(out: str, setup: Setup) -> dict:
    """The random policy's episodes on the task in MuJoCo C (controller_scores.random_policy: 128 episodes, kept in
    out/random_policy.json)."""
    return controller_scores.random_policy(out, envs.resolve(setup.env))


def finish(out: str, setup: Setup, state: dict, argv: list, final: bool = True) -> str:
    """The answer's sentence, report and exported controller (verified where its task declares an equilibrium and the
    answer has ended: `final`) -> the sentence."""
    import jax
    import mujoco

    from gsa_jax.analysis.verdicts.answer_report import export_choice, write_report
    from gsa_jax.analysis.verdicts.answering import collect_evidence

    evidence = collect_evidence(out, setup)
    verdicts = {int(k): r["verdict"] for k, r in state["judged"].items()}
    versus = (state.get("baseline") or {}).get("versus", "flat PPO")
    sentence = verdict.sentence(setup.env, verdicts, setup.margin, versus)
    if verdicts and all(v == verdict.NO_SCALE for v in verdicts.values()) and state.get("baseline", {}).get("why"):
        sentence = f"{setup.env}: no answer: {state['baseline']['why']}."
    from gsa_jax.analysis.verdicts.answer_report import still_learning

    chosen, _ = verdict.smallest_sufficient(verdicts)
    # a K whose verdict could change the answer: not sufficient and below the chosen K (any, where none is chosen)
    learning = [k for k in still_learning(state) if verdicts.get(k) != verdict.SUFFICIENT and (chosen is None or k < chosen)]
    if learning and state.get("steps", {}).get("mode") == "auto":
        one = len(learning) == 1
        sentence += (f" The training returns of K = {', '.join(map(str, learning))} were still rising at "
                     f"{state['steps']['budget']:,} steps: a longer --steps may change {'its verdict' if one else 'their verdicts'}.")
    built = constructive_part(out, setup, state, evidence)
    shown = built["smallest"] if built else None
    choice = None
    if shown is not None or chosen is not None:
        k = shown if shown is not None else chosen
        choice = export_choice(out, list(setup.start_from) + [os.path.join(out, "results")], setup.env, k,
                               evidence.scores)
        if choice:
            choice["K"] = k
            choice["verify"] = None
    command = "gsa answer " + " ".join(shlex.quote(a) for a in argv)
    versions = {"jax": jax.__version__, "mujoco": mujoco.__version__, "git commit": git_commit() or "unknown"}
    steps = next_steps(argv, out, setup, state)
    path = write_report(out, setup, state, evidence, sentence, choice, (command, steps), versions)
    whole = sentence + ("\n" + built["sentence"] if built else "")
    if final and choice and has_equilibrium(setup):  # the answer first, then its controller's check
        print(BEFORE_VERIFY + "\n" + whole, flush=True)
        choice["verify"] = verify_export(out, choice)
        path = write_report(out, setup, state, evidence, sentence, choice, (command, steps), versions)
    print(f"wrote {path}")
    for line in steps:
        print(f"next: {line}")
    return whole


BEFORE_VERIFY = "answer (its exported controller's gsa verify --quick runs next; report.md holds the answer):"


def has_equilibrium(setup: Setup) -> bool:
    """Whether the task declares an equilibrium (Task.equilibrium_qpos) for gsa verify to check the controller at."""
    from gsa_jax.verify.system import equilibrium_guess

    return equilibrium_guess(envs.resolve_task(setup.env)) is not None


def verify_export(out: str, choice: dict) -> str:
    """gsa verify --quick on the exported controller (a task with an equilibrium: has_equilibrium): its closed loop's
    fixed points, region of attraction and worst starts in out/verify -> that folder."""
    from gsa_jax.commands.verify import verify_controller

    where = os.path.join(out, "verify")
    verify_controller([choice["files"][0], "--quick", "--out", where])
    return where


def constructive_part(out: str, setup: Setup, state: dict, evidence: "Evidence") -> dict | None:
    """The constructive answer of the answer's runs, kept in answer.json ('constructive') -> its record, or None where
    flat PPO or every mixture has no controller to exhibit."""
    from gsa_jax.analysis.verdicts import constructive
    from gsa_jax.orchestration.constructive_answer import judge_constructive, record, search_words

    built, _ = judge_constructive(out, setup, state, evidence)
    if built is None:
        return None
    search = search_words({cls: s.seeds for cls, s in built.shares.items()},
                          int(state["steps"]["budget"]))
    state["constructive"] = record(built, constructive.sentence(setup.env, built, search, FLAT), search)
    save_state(out, state)
    return state["constructive"]


def without(argv: list, flag: str) -> list:
    """argv less the option `flag` and its value (either spelling: '--flag V' or '--flag=V')."""
    out, skip = [], False
    for a in argv:
        if skip or a.startswith(flag + "="):
            skip = False
            continue
        skip = a == flag
        out += [] if skip else [a]
    return out


def next_steps(argv: list, out: str, setup: Setup, state: dict) -> list:
    """What to run where the answer is not decided, by why it stopped: more minutes resume it (the same design); a
    higher seed cap or a longer step budget is a new answer in its own folder (another design)."""
    from gsa_jax.running.runinfo import resume_command

    stopped, argv = state.get("stopped", ""), [*without(argv, "--out"), "--out", out]  # resumable from any folder
    if stopped.startswith("budget"):
        minutes = 2 * state.get("budget_s", 7200.0) / 60
        return [f"{resume_command('answer', *without(argv, '--budget-minutes'))} --budget-minutes {minutes:g}   (resumes it "
                "with twice the minutes; the same design)"]
    fresh, base = [*without(without(argv, "--out"), "--looks")], os.path.normpath(out)
    if stopped.startswith(("seed cap", "futility")):
        cap = 2 * setup.looks[-1]
        looks = ",".join(map(str, (*setup.looks, cap)))
        return [f"{resume_command('answer', *fresh, '--looks', looks)} --out {shlex.quote(base + '-more-seeds')}   (a new "
                f"answer with a seed cap of {cap} per cell, in its own folder: it trains seeds 0-{cap - 1} again)"]
    if stopped == "no answer" and setup.auto_steps():
        steps = 2 * (setup.max_steps or setup.steps())
        return [f"{resume_command('answer', *without(fresh, '--max-steps'), '--max-steps', str(steps))} --out "
                f"{shlex.quote(base + '-longer')}   (a new answer whose flat PPO has up to {steps:,} steps to learn the task)"]
    return []


def build_parser() -> argparse.ArgumentParser:
    """`gsa answer`'s options."""
    p = command_parser("answer", __doc__)
    p.runs_jax = True  # it runs JAX programs (command_line.CommandParser)
    p.add_argument("--env", required=True, help="the task (any name gsa train takes, your own 'module:Class' too)")
    p.add_argument("--clusters", default=None, help="the K ladder, e.g. 1,2,4 (default: ceil(m d_a), m = 0.5, 1, 2, 4)")
    p.add_argument("--margin", type=float, default=verdict.DEFAULT_MARGIN,
                   help="the margin delta, a fraction of the reference's gain over a random policy (default %(default)s)")
    p.add_argument("--target", type=float, default=None,
                   help="judge against this score (the task's return) instead of flat PPO (default: flat PPO)")
    p.add_argument("--looks", default=",".join(map(str, DEFAULT_LOOKS)),
                   help=f"seeds per cell at each look (at least {sequential.MIN_SEEDS}); the last is the seed cap (default %(default)s)")
    p.add_argument("--spending", choices=sequential.SPENDING, default=DEFAULT_SPENDING,
                   help="how each K's error is spread over the looks (default %(default)s: Pocock-type, see docs/answer.md)")
    p.add_argument("--futility", type=float, default=verdict.FUTILITY, metavar="CHANCE",
                   help="stop adding seeds to an undecided K whose chance to be decided by the seed cap, if its gap is "
                        "what it looks, is below CHANCE (0: every undecided K goes to the cap; never decides a K, so "
                        "the error rate holds; default %(default)s)")
    p.add_argument("--references", default=None, metavar="CSV",
                   help="the PPO references flat PPO must reach (default: the shipped table, gsa_jax/analysis/verdicts/ppo_references.csv)")
    p.add_argument("--steps", type=steps_option, default=AUTO,
                   help="env steps per run, or auto (default): the budget at which flat PPO has learned the task and "
                        "stopped learning, found by training its first seeds at doubling budgets up to --max-steps "
                        "(docs/answer.md); every class trains to it. With --target or --start-from: --max-steps or the "
                        "committed runs' steps")
    p.add_argument("--max-steps", type=whole_number, default=1_000_000,
                   help="the largest step budget --steps auto tries (default %(default)s)")
    p.add_argument("--physics", choices=("c", "mjx"), default=None, help="physics backend (default: c where the task has MuJoCo C)")
    p.add_argument("--partition", choices=tuple(partitions.PARTITIONS), default=None,
                   help="the mixtures' partition class: mlp (the paper's, default) or linear (polyhedral cells)")
    p.add_argument("--config", default="{}", metavar="JSON",
                   help="the runs' config fields as a JSON object, e.g. '{\"num_envs\": 16}' (default: the defaults)")
    p.add_argument("--budget-minutes", type=float, default=120.0, help="stop before a round that would run past it (default %(default)s)")
    p.add_argument("--start-from", nargs="+", default=None, metavar="RESULTS_DIR",
                   help="committed results whose runs are the first seeds (their sweep.json settings train the rest; "
                        "default: none, every seed trained here)")
    p.add_argument("--out", default=None, help="output directory (default runs/answers/<task>)")
    return p


def answer(argv: list) -> int:
    """Run (or resume) the answer and print its sentence."""
    from gsa_jax.running.trained import path_part

    args = build_parser().parse_args(argv)
    setup = make_setup(args)
    out = args.out or os.path.join("runs", "answers", path_part(setup.env))
    try:
        state = run_answer(out, setup, args.budget_minutes * 60.0, lambda: random_policy(out, setup),
                           interim=lambda now: print(interim_text(finish(out, setup, now, argv, final=False))))
    except KeyboardInterrupt:
        print(f"\ngsa answer: interrupted; every finished sweep and chunk is saved in {out} (continue with: "
              f"{again(argv, args.out, out)})", file=sys.stderr)
        return 130
    print(finish(out, setup, state, argv))
    return 0


def interim_text(sentence: str) -> str:
    """The answer so far, printed before a further round trains (its report is written, as at the end)."""
    return "answer so far (more seeds are training; report.md holds it until the answer ends):\n" + sentence


def again(argv: list, typed_out: "str | None", out: str) -> str:
    """The command that resumes this answer: the same options (with --out where it was not typed, so it resumes from
    any folder)."""
    from gsa_jax.running.runinfo import resume_command

    return resume_command("answer", *argv, *(() if typed_out else ("--out", out)))


def main(argv: list | None = None) -> int:
    """`gsa answer`: exit status 0 answered (decided or not), 2 bad input, 3 a sweep failed."""
    argv = list(sys.argv[1:] if argv is None else argv)
    return run_command("answer", lambda: answer(argv))
