"""The Spider environment of paper §5.2 (MuJoCo MJX): ``envs.make("spider", ...)``.

Modules, one job each: ``legs`` (leg table), ``model`` (MJCF from the table), ``physics``
(the MJX step), ``env`` (``SpiderEnv``, ``make_spider``), ``gait`` (open-loop reference gait),
``rollout`` (batched MJX and plain-MuJoCo rollouts), ``render`` (PNG/GIF off-screen).
"""

import ctypes.util
import os

# MuJoCo picks its OpenGL backend once, when it is first imported. On a headless machine
# (no DISPLAY) its default (GLFW) cannot render, so default to software OSMesa there
# (Debian package libosmesa6) when that library is installed. Without it, MUJOCO_GL=osmesa
# would make ``import mujoco`` itself fail (PyOpenGL raises while loading), so simulation and
# training must not depend on it: only rendering needs it, and render.py says how to get it.
# An explicit MUJOCO_GL (e.g. "egl" on a GPU box) always wins.
if (
    "MUJOCO_GL" not in os.environ
    and not os.environ.get("DISPLAY")
    and ctypes.util.find_library("OSMesa")
):
    os.environ["MUJOCO_GL"] = "osmesa"
