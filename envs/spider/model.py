"""MJCF generation: leg table + physics options -> MuJoCo model of the Spider (§5.2.1).

The body follows Ant (brax's ``ant.xml``): a sphere torso on a free joint, capsule legs, motors
with ``ctrlrange [-1, 1]``, joint armature 1 and damping 1, density 5. Differences that make
the model cheap in MJX without changing what it simulates:

* Only the foot spheres and the torso sphere collide, and only with the floor (``contype=1``
  on them, ``conaffinity=1`` on the floor, everything else 0): 9 sphere-plane pairs, the
  cheapest MJX collision, instead of all geom pairs. (Ant's feet do the same.)
* Every body frame is world-aligned and a segment's rest tilt is baked into its capsule, so
  ``qpos = 0`` on the leg joints is the standing pose and joint ranges are symmetric.
* The hip mount capsule is a geom of the torso, not a joint-less body of its own: fewer
  bodies make MJX's per-tree-level kinematics cheaper.
* Solver settings (Newton, few iterations, ``eulerdamp`` off) come from ``PhysicsOptions``,
  following MJX's performance notes; ``tests/test_spider.py`` checks that they stay close to
  MuJoCo run with its accurate defaults.
"""

from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence

import mujoco
import numpy as np

from envs.spider.legs import LEG_RADIUS, STANCE_HEIGHT, LegSpec

TORSO_RADIUS = 0.25


@dataclasses.dataclass(frozen=True)
class PhysicsOptions:
    """MuJoCo ``<option>`` values (static: they change the compiled computation).

    Attributes:
      timestep: physics step (s); Ant's 0.01.
      solver: ``"newton"`` or ``"cg"``.
      iterations: constraint-solver iterations (MJX notes: 1-4 suffice for locomotion).
      ls_iterations: line-search iterations (MJX notes: 4-8).
      eulerdamp: implicit joint damping in the Euler integrator; off saves one factorisation.
      cone: friction cone, ``"pyramidal"`` (cheaper in MJX) or ``"elliptic"``.
      limits: enforce joint limits (one constraint row per limited joint).
    """

    timestep: float = 0.01
    solver: str = "newton"
    iterations: int = 1
    ls_iterations: int = 4
    eulerdamp: bool = False
    cone: str = "pyramidal"
    limits: bool = True

    def __post_init__(self):
        if self.solver not in ("newton", "cg"):
            raise ValueError(f"solver must be 'newton' or 'cg', got {self.solver!r}")
        if self.cone not in ("pyramidal", "elliptic"):
            raise ValueError(f"cone must be 'pyramidal' or 'elliptic', got {self.cone!r}")
        if self.iterations < 1 or self.ls_iterations < 1:
            raise ValueError("iterations and ls_iterations must be >= 1")


def _fmt(v: Sequence[float]) -> str:
    return " ".join(f"{x:.6g}" for x in v)


def _direction(angle_deg: float, tilt_deg: float) -> np.ndarray:
    """Unit vector along a leg at ``angle_deg`` around z, tilted ``tilt_deg`` below the
    horizontal."""
    a, t = math.radians(angle_deg), math.radians(tilt_deg)
    return np.array([math.cos(a) * math.cos(t), math.sin(a) * math.cos(t), -math.sin(t)])


def _pitch_axis(angle_deg: float) -> np.ndarray:
    """Horizontal axis perpendicular to the leg, signed so that a positive angle lowers the tip.

    Rotating the leg direction d = (cos a, sin a, 0) about k = (-sin a, cos a, 0) moves it along
    k x d = (0, 0, -1), i.e. down.
    """
    a = math.radians(angle_deg)
    return np.array([-math.sin(a), math.cos(a), 0.0])


def _add_leg(torso: ET.Element, leg: LegSpec) -> None:
    """Append the mount capsule to ``torso`` and the leg's body chain below it."""
    prefix = f"{leg.name}_"
    mount_end = _direction(leg.angle_deg, 0.0) * leg.mount_length
    ET.SubElement(
        torso,
        "geom",
        name=prefix + "mount",
        type="capsule",
        fromto=_fmt([0, 0, 0, *mount_end]),
        size=_fmt([LEG_RADIUS]),
    )
    parent, pos = torso, mount_end
    for i, (joint, length, tilt) in enumerate(
        zip(leg.joints, leg.segment_lengths, leg.segment_tilts_deg, strict=True)
    ):
        body = ET.SubElement(parent, "body", name=prefix + f"seg{i}", pos=_fmt(pos))
        axis = (0.0, 0.0, 1.0) if joint.kind == "hip" else _pitch_axis(leg.angle_deg)
        ET.SubElement(
            body,
            "joint",
            name=prefix + joint.name,
            type="hinge",
            axis=_fmt(axis),
            range=_fmt(joint.range_deg),
        )
        end = _direction(leg.angle_deg, tilt) * length
        ET.SubElement(
            body,
            "geom",
            name=prefix + f"seg{i}",
            type="capsule",
            fromto=_fmt([0, 0, 0, *end]),
            size=_fmt([LEG_RADIUS]),
        )
        parent, pos = body, end
    # The foot: the only geom of the leg that collides (with the floor only).
    ET.SubElement(
        parent,
        "geom",
        name=prefix + "foot",
        type="sphere",
        pos=_fmt(pos),
        size=_fmt([LEG_RADIUS]),
        contype="1",
        mass="0",
        rgba="0.8 0.3 0.2 1",
    )


def spider_xml(
    legs: Sequence[LegSpec],
    physics: PhysicsOptions = PhysicsOptions(),
    init_height: float = STANCE_HEIGHT + 0.1,
) -> str:
    """MJCF text of a spider with the given legs (in order; actuators follow the same order).

    Args:
      legs: the leg table (``envs.spider.legs``); joint names are ``<leg>_<joint>``.
      physics: solver / integrator options.
      init_height: torso-centre height (m) of the model's ``qpos0``: 0.1 m above the stance
        height, so that Ant's reset noise (±0.1 on qpos) never starts a foot inside the floor
        (a deep initial penetration makes the body jump).
    """
    root = ET.Element("mujoco", model="spider")
    ET.SubElement(root, "compiler", angle="degree", inertiafromgeom="true", autolimits="true")
    disable = [] if physics.eulerdamp else ["eulerdamp"]
    option = ET.SubElement(
        root,
        "option",
        timestep=f"{physics.timestep:g}",
        solver={"newton": "Newton", "cg": "CG"}[physics.solver],
        iterations=str(physics.iterations),
        ls_iterations=str(physics.ls_iterations),
        cone=physics.cone,
        integrator="Euler",
    )
    if not physics.limits:
        disable.append("limit")
    if disable:
        ET.SubElement(option, "flag", **{name: "disable" for name in disable})
    default = ET.SubElement(root, "default")
    ET.SubElement(default, "joint", armature="1", damping="1", limited="true")
    ET.SubElement(
        default,
        "geom",
        contype="0",
        conaffinity="0",
        condim="3",
        density="5.0",
        friction="1 0.5 0.5",
        rgba="0.4 0.33 0.26 1",
    )
    ET.SubElement(default, "motor", ctrllimited="true", ctrlrange="-1 1")

    visual = ET.SubElement(root, "visual")
    ET.SubElement(
        visual, "headlight", ambient="0.35 0.35 0.35", diffuse="0.5 0.5 0.5", specular="0.1 0.1 0.1"
    )
    asset = ET.SubElement(root, "asset")
    ET.SubElement(
        asset,
        "texture",
        name="grid",
        type="2d",
        builtin="checker",
        width="256",
        height="256",
        rgb1="0.35 0.4 0.45",
        rgb2="0.55 0.6 0.65",
    )
    ET.SubElement(
        asset, "material", name="grid", texture="grid", texrepeat="8 8", reflectance="0.1"
    )
    ET.SubElement(
        asset,
        "texture",
        name="sky",
        type="skybox",
        builtin="gradient",
        rgb1="0.4 0.6 0.8",
        rgb2="0 0 0",
        width="64",
        height="64",
    )

    world = ET.SubElement(root, "worldbody")
    ET.SubElement(
        world,
        "light",
        name="sun",
        directional="true",
        pos="0 0 3",
        dir="0 0 -1",
        diffuse="0.8 0.8 0.8",
    )
    ET.SubElement(
        world,
        "geom",
        name="floor",
        type="plane",
        size="0 0 0.05",
        material="grid",
        conaffinity="1",
        condim="3",
    )
    torso = ET.SubElement(world, "body", name="torso", pos=_fmt([0, 0, init_height]))
    ET.SubElement(torso, "freejoint", name="root")
    # The torso collides with the floor too: a spider that flips lands on its back instead of
    # sinking through the floor, which would drive its feet deep below the plane (huge contact
    # forces, NaN). One more sphere-plane pair.
    ET.SubElement(
        torso,
        "geom",
        name="torso",
        type="sphere",
        size=_fmt([TORSO_RADIUS]),
        contype="1",
        rgba="0.3 0.3 0.35 1",
    )
    for leg in legs:
        _add_leg(torso, leg)

    actuator = ET.SubElement(root, "actuator")
    for leg in legs:
        for joint in leg.joints:
            name = f"{leg.name}_{joint.name}"
            ET.SubElement(actuator, "motor", name=name, joint=name, gear=f"{joint.gear:g}")
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")


def build_mj_model(
    legs: Sequence[LegSpec], physics: PhysicsOptions = PhysicsOptions()
) -> mujoco.MjModel:
    """Compile the spider's MJCF into a ``mujoco.MjModel`` (host side, float64)."""
    names = [leg.name for leg in legs]
    if len(set(names)) != len(names):
        raise ValueError(f"duplicate leg names {names}")
    return mujoco.MjModel.from_xml_string(spider_xml(legs, physics))


def foot_geom_ids(model: mujoco.MjModel, legs: Sequence[LegSpec]) -> np.ndarray:
    """``[n_legs]`` geom ids of the feet, in leg order."""
    return np.asarray(
        [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"{leg.name}_foot") for leg in legs],
        np.int32,
    )
