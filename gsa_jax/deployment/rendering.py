"""Pictures and videos with MuJoCo's offscreen renderer: a task's scene, a run's deterministic controller
playing. MUJOCO_GL picks the OpenGL backend; unset, this module uses OSMesa (Debian's libosmesa6,
software rendering, no display or GPU needed; `make scene` installs it), or EGL when only libEGL is
found. `gsa render` is its command."""

import ctypes.util
import os
from typing import Any

import numpy as np

import envs

from gsa_jax.errors import UserError


def pick_gl() -> str | None:
    """The MUJOCO_GL backend to use when the user did not choose one: osmesa, else egl, else None."""
    if ctypes.util.find_library("OSMesa"):
        return "osmesa"
    if ctypes.util.find_library("EGL"):
        return "egl"
    return None


if not envs.GL_FROM_USER:  # envs set "disable" for training; nothing has imported mujoco yet
    os.environ["MUJOCO_GL"] = pick_gl() or "osmesa"

GL_HELP = ("install Debian's libosmesa6 (`make scene` does) for MUJOCO_GL=osmesa, "
           "or libegl1 + libegl-mesa0 and set MUJOCO_GL=egl")


class RenderError(UserError):
    pass


def make_renderer(mj_model: Any, width: int, height: int) -> Any:
    import mujoco

    mj_model.vis.global_.offwidth = max(mj_model.vis.global_.offwidth, width)
    mj_model.vis.global_.offheight = max(mj_model.vis.global_.offheight, height)
    try:
        return mujoco.Renderer(mj_model, height, width)
    except Exception as e:  # missing libOSMesa / libEGL surfaces as ImportError, AttributeError or a GL error
        raise RenderError(f"no offscreen OpenGL with MUJOCO_GL={os.environ.get('MUJOCO_GL')!r} ({e}); {GL_HELP}") from e


def render_qpos(renderer: Any, mj_model: Any, qpos_seq: np.ndarray, camera: str | int | None) -> np.ndarray:
    """RGB frames (T, H, W, 3) of the model at each qpos."""
    import mujoco

    d = mujoco.MjData(mj_model)
    frames = []
    for q in qpos_seq:
        d.qpos[:] = q
        mujoco.mj_forward(mj_model, d)
        renderer.update_scene(d, camera=camera if camera is not None else -1)
        frames.append(renderer.render().copy())
    return np.stack(frames)


def default_camera(mj_model: Any) -> str | None:
    names = [mj_model.camera(i).name for i in range(mj_model.ncam)]
    return "front" if "front" in names else (names[0] if names else None)


def render_scene(env_name: str, out: str, width: int = 640, height: int = 480, camera: str | None = None,
                 seed: int = 0) -> str:
    """PNG of the task's start state (every camera of the model side by side when camera is None)."""
    import jax
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    base = envs.make_base(env_name)
    m = envs.mj_model(base)
    state = jax.jit(base.reset)(jax.random.PRNGKey(seed))
    qpos = np.asarray(state.pipeline_state.qpos)
    renderer = make_renderer(m, width, height)
    cams = [camera] if camera is not None else ([m.camera(i).name for i in range(m.ncam)] or [None])
    images = [render_qpos(renderer, m, [qpos], c)[0] for c in cams]
    plt.imsave(out, np.concatenate(images, axis=1))
    return out


def render_run(run_dir: str, out: str, episodes: int = 1, width: int = 480, height: int = 360, camera: str | None = None,
               fps: int = 50, seed: int = 0) -> tuple:
    """GIF (or MP4 when out ends in .mp4 and ffmpeg exists) of the deterministic controller of a run.
    Returns (path, returns of the rendered episodes)."""
    import jax

    from gsa_jax.deployment.inspection import last_iteration, load_run, rollout

    trainer, params, obs_stats, hp, meta = load_run(run_dir, require_mixture=False)
    roll = rollout(trainer, params, obs_stats, hp, jax.random.PRNGKey(seed), episodes, True, last_iteration(meta))
    m = envs.mj_model(trainer.env)  # the wrappers pass attribute lookups to the task
    dt = trainer.env.dt if hasattr(trainer.env, "dt") else 0.01
    stride = max(1, int(round(1.0 / (fps * float(dt)))))
    renderer = make_renderer(m, width, height)
    cam = camera if camera is not None else default_camera(m)
    frames = []
    for e in range(episodes):
        alive = roll["alive"][:, e] > 0.5
        frames.append(render_qpos(renderer, m, roll["qpos"][alive, e][::stride], cam))
    frames = np.concatenate(frames)
    write_video(frames, out, fps=1.0 / (stride * float(dt)))
    return out, (roll["reward"].sum(0)).tolist()


def write_video(frames: np.ndarray, out: str, fps: int) -> None:
    """frames (T, H, W, 3) uint8 -> GIF (Pillow, shipped with matplotlib) or MP4 (matplotlib + ffmpeg)."""
    if out.endswith(".mp4"):
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.animation as animation
        import matplotlib.pyplot as plt

        if not animation.writers.is_available("ffmpeg"):
            raise RenderError("writing .mp4 needs ffmpeg on PATH; write a .gif instead")
        fig = plt.figure(figsize=(frames.shape[2] / 100, frames.shape[1] / 100), dpi=100)
        ax = fig.add_axes([0, 0, 1, 1])
        ax.axis("off")
        im = ax.imshow(frames[0])
        anim = animation.FuncAnimation(fig, lambda i: [im.set_data(frames[i])], frames=len(frames))
        anim.save(out, writer=animation.FFMpegWriter(fps=fps))
        plt.close(fig)
        return
    from PIL import Image

    images = [Image.fromarray(f) for f in frames]
    images[0].save(out, save_all=True, append_images=images[1:], duration=int(round(1000 / fps)), loop=0)
