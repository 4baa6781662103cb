"""The Spider environment of paper §5.2 (MuJoCo MJX): ``envs.make("spider", ...)``.

Modules, one job each: ``legs`` (leg table), ``model`` (MJCF from the table), ``physics``
(the MJX step), ``env`` (``SpiderEnv``, ``make_spider``), ``gait`` (open-loop reference gait),
``rollout`` (batched MJX and plain-MuJoCo rollouts), ``render`` (PNG/GIF off-screen).
"""

import os

# MuJoCo picks its OpenGL backend once, when it is first imported. On a headless machine
# (no DISPLAY) its default (GLFW) cannot render, so default to software OSMesa there
# (Debian package libosmesa6). An explicit MUJOCO_GL (e.g. "egl" on a GPU box) always wins.
if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
    os.environ["MUJOCO_GL"] = "osmesa"
