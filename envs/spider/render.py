"""Off-screen rendering of Spider rollouts to PNG frames and a GIF (``mujoco.Renderer``).

Rendering needs an OpenGL backend, chosen by ``MUJOCO_GL`` *before* ``mujoco`` is first
imported: ``osmesa`` (software; Debian/Ubuntu package ``libosmesa6``) works on any headless
machine, ``egl`` uses a GPU driver. ``envs.spider`` defaults it to ``osmesa`` when it is unset
and there is no display; ``render_frames`` raises ``RenderingUnavailable`` with this advice
when no context can be created.

CLI (a sinusoidal-gait rollout of the default body)::

    MUJOCO_GL=osmesa python -m envs.spider.render --out runs/spider_render --steps 100

writes ``frame_0000.png`` ... and ``rollout.gif`` into ``--out``. ``render_rollout`` is the
function a trained policy's rollout goes through too (pass its ``qpos`` sequence).
"""

from __future__ import annotations

import argparse
import os
import warnings
from collections.abc import Sequence
from pathlib import Path

import jax
import mujoco
import numpy as np

from envs.spider.env import make_spider
from envs.spider.gait import gait_actions
from envs.spider.rollout import make_rollout, reset_batch


class RenderingUnavailable(RuntimeError):
    """No OpenGL context could be created for off-screen rendering."""


def _loaded_backend() -> str:
    """The ``MUJOCO_GL`` value mujoco read when it was imported (may differ from the current
    env)."""
    try:
        from mujoco.rendering.classic import gl_context

        return f"MUJOCO_GL={gl_context._MUJOCO_GL or '<unset: glfw>'}"
    except (ImportError, AttributeError):
        return f"MUJOCO_GL={os.environ.get('MUJOCO_GL', '<unset: glfw>')}"


def make_renderer(model: mujoco.MjModel, width: int, height: int) -> mujoco.Renderer:
    """``mujoco.Renderer`` or ``RenderingUnavailable`` saying which backend failed and what to
    do."""
    try:
        return mujoco.Renderer(model, height=height, width=width)
    except Exception as err:  # GLFW/OSMesa/EGL report failures with several exception types
        raise RenderingUnavailable(
            f"cannot create an OpenGL context with the backend mujoco loaded ({_loaded_backend()}; "
            f"{type(err).__name__}: {err}). "
            "Set MUJOCO_GL=osmesa (needs the libosmesa6 package) "
            "or MUJOCO_GL=egl (needs a GPU driver) "
            "before mujoco is imported."
        ) from err


def tracking_camera(
    model: mujoco.MjModel, distance: float = 3.2, azimuth: float = 120.0, elevation: float = -25.0
) -> mujoco.MjvCamera:
    """A camera that follows the torso (``body 1``) from a three-quarter view."""
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    cam.trackbodyid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "torso")
    cam.distance, cam.azimuth, cam.elevation = distance, azimuth, elevation
    return cam


def render_frames(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    width: int = 480,
    height: int = 360,
    camera: mujoco.MjvCamera | None = None,
) -> list[np.ndarray]:
    """Render one RGB frame ``[height, width, 3]`` uint8 per row of ``qpos [T, nq]``.

    Only positions matter for a picture, so each frame is ``mj_forward`` at that ``qpos``. The
    renderer is closed before returning (it owns a GL context).
    """
    qpos = np.atleast_2d(np.asarray(qpos, np.float64))
    if qpos.shape[1] != model.nq:
        raise ValueError(f"qpos has {qpos.shape[1]} columns, the model has nq={model.nq}")
    camera = camera or tracking_camera(model)
    data = mujoco.MjData(model)
    renderer = make_renderer(model, width, height)
    try:
        frames = []
        for q in qpos:
            data.qpos[:] = q
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera=camera)
            frames.append(renderer.render().copy())
        return frames
    finally:
        renderer.close()


def mp4_unavailable_reason() -> str | None:
    """None when MP4 files can be written (imageio's ffmpeg plugin, ``imageio-ffmpeg``, finds an
    ffmpeg binary), else why not and how to fix it."""
    try:
        import imageio_ffmpeg
    except ImportError:
        return 'MP4 needs imageio-ffmpeg: pip install -e ".[render]"'
    try:
        imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError as err:
        return f"imageio-ffmpeg finds no ffmpeg binary ({err})"
    return None


def save_frames(
    frames: Sequence[np.ndarray],
    out_dir: str | Path,
    fps: float = 20.0,
    png: bool = True,
    gif: bool = True,
    mp4: bool = False,
) -> dict[str, list[Path]]:
    """Write ``frame_XXXX.png`` files, ``rollout.gif`` and/or ``rollout.mp4`` (H.264, needs
    ``imageio-ffmpeg``: see ``mp4_unavailable_reason``) into ``out_dir``; returns the paths."""
    import imageio.v3 as iio

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written: dict[str, list[Path]] = {"png": [], "gif": [], "mp4": []}
    if png:
        for i, frame in enumerate(frames):
            path = out_dir / f"frame_{i:04d}.png"
            iio.imwrite(path, frame)
            written["png"].append(path)
    if gif and frames:
        path = out_dir / "rollout.gif"
        iio.imwrite(path, np.stack(frames), duration=1000.0 / fps, loop=0)
        written["gif"].append(path)
    if mp4 and frames:
        reason = mp4_unavailable_reason()
        if reason is not None:
            raise RuntimeError(reason)
        import imageio.v2 as iio2

        path = out_dir / "rollout.mp4"
        with warnings.catch_warnings():
            # imageio-ffmpeg starts ffmpeg with subprocess (fork + exec at once): Python warns
            # about os.fork under JAX's threads, which does not apply to an immediate exec
            warnings.filterwarnings("ignore", message=r"os\.fork\(\)", category=RuntimeWarning)
            # macro_block_size 8: 480 x 360 frames are encoded as they are (16 would rescale)
            iio2.mimwrite(path, list(frames), fps=fps, macro_block_size=8)
        written["mp4"].append(path)
    return written


def render_rollout(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    out_dir: str | Path,
    fps: float = 20.0,
    width: int = 480,
    height: int = 360,
    png: bool = True,
    gif: bool = True,
    mp4: bool = False,
) -> dict[str, list[Path]]:
    """Render ``qpos [T, nq]`` (e.g. ``Trajectory.qpos[:, b]``) to PNG frames, a GIF and/or an
    MP4 in ``out_dir``.

    ``fps`` should be ``1 / env.dt`` (20 for the default Spider) for real-time playback.
    """
    return save_frames(render_frames(model, qpos, width, height), out_dir, fps, png, gif, mp4)


def gait_rollout_qpos(env, steps: int, seed: int = 0) -> np.ndarray:
    """``[steps + 1, nq]`` qpos of one open-loop sinusoidal-gait episode (reset state first)."""
    state = reset_batch(env, jax.random.PRNGKey(seed), 1)
    actions = gait_actions(env.legs, env.space, steps, env.dt)[:, None]
    _, traj = make_rollout(env)(state, actions)
    return np.concatenate([np.asarray(state.sim.data.qpos), np.asarray(traj.qpos[:, 0])], axis=0)


def main(argv: Sequence[str] | None = None) -> dict[str, list[Path]]:
    parser = argparse.ArgumentParser(
        description="Render a sinusoidal-gait rollout of the Spider to PNG frames and a GIF."
    )
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument(
        "--steps", type=int, default=100, help="environment steps (dt = 0.05 s each)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--width", type=int, default=480)
    parser.add_argument("--height", type=int, default=360)
    parser.add_argument(
        "--legs", nargs="*", default=None, help="leg names to keep (default: all 8)"
    )
    parser.add_argument("--no-png", action="store_true", help="only write the GIF")
    args = parser.parse_args(argv)
    env = make_spider(legs=args.legs)
    qpos = gait_rollout_qpos(env, args.steps, args.seed)
    written = render_rollout(
        env.mj_model,
        qpos,
        args.out,
        fps=1.0 / env.dt,
        width=args.width,
        height=args.height,
        png=not args.no_png,
    )
    print(f"wrote {len(written['png'])} PNG frames and {len(written['gif'])} GIF to {args.out}")
    return written


if __name__ == "__main__":
    main()
