"""Draw a task's scene, or a video of a trained run's deterministic controller (`gsa render ENV --out scene.png`;
`gsa render ENV --run RUN --out video.gif`, RUN a run directory or SWEEP_DIR/<run label>).

Uses MuJoCo's offscreen renderer. MUJOCO_GL picks the OpenGL backend; when it is not set, this
module uses OSMesa (Debian's libosmesa6, software rendering, no display or GPU needed; `make scene`
installs it), or EGL when only libEGL is found.
"""

import argparse
import os

import envs
from gsa_jax.deployment.rendering import RenderError, render_run, render_scene
from gsa_jax.commands.command_line import command_parser
from gsa_jax.errors import run_command
from gsa_jax.running.trained import read_run


def build_parser() -> argparse.ArgumentParser:
    """`gsa render`'s options."""
    p = command_parser("render", __doc__)
    p.add_argument("env", help=f"one of: {', '.join(envs.NAMES)}; a task of yours, 'module:Class'; 'brax:<name>', 'playground:<Name>'")
    p.add_argument("--out", required=True, help="scene.png, or with --run: video.gif / video.mp4")
    p.add_argument("--run", default=None, help="a run directory or SWEEP_DIR/<run label>: render its deterministic controller")
    p.add_argument("--episodes", type=int, default=1, help="episodes in the video (with --run; default %(default)s)")
    p.add_argument("--camera", default=None, help="camera name (default: all cameras side by side / 'front')")
    p.add_argument("--width", type=int, default=None, help="image width in pixels (default: 640, a video's 480)")
    p.add_argument("--height", type=int, default=None, help="image height in pixels (default: 480, a video's 360)")
    p.add_argument("--seed", type=int, default=0, help="seed of the start states drawn (default %(default)s)")
    return p


def render(argv: list | None) -> int:
    """Write the scene picture or the run's video; a ValueError (an unknown task, or MuJoCo's renderer refusing a
    camera or a size larger than its framebuffer) is one line."""
    args = build_parser().parse_args(argv)
    try:
        return draw(args)
    except ValueError as e:
        raise RenderError(e) from None


def draw(args: argparse.Namespace) -> int:
    """The picture or the video the options ask for."""
    envs.check_name(args.env)
    out_dir = os.path.dirname(os.path.abspath(args.out))
    if not os.path.isdir(out_dir):
        raise RenderError(f"--out: directory {out_dir!r} does not exist")
    if args.run is None:
        if not args.out.endswith(".png"):
            raise RenderError("--out must end in .png for a scene picture (add --run DIR for a video)")
        render_scene(args.env, args.out, args.width or 640, args.height or 480, args.camera, args.seed)
        print(f"wrote {args.out}")
        return 0
    if not args.out.endswith((".gif", ".mp4")):
        raise RenderError("--out must end in .gif or .mp4 for a video")
    run_env = read_run(args.run).meta["config"]["env"]
    if run_env != args.env:
        raise RenderError(f"{args.run!r} was trained on {run_env!r}, not {args.env!r}")
    out, returns = render_run(args.run, args.out, args.episodes, args.width or 480, args.height or 360, args.camera, seed=args.seed)
    print(f"wrote {out} (deterministic controller, episode returns {', '.join(f'{r:.1f}' for r in returns)})")
    return 0


def main(argv: list | None = None) -> int:
    """`gsa render`: exit status 0, or 2 on bad input."""
    return run_command("render", lambda: render(argv))
