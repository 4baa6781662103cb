"""The Spider's leg table: each leg is data, so body variants never need hand-edited XML (§5.2.1).

A leg is mounted on the torso by a rigid link (Ant's ``aux`` capsule) pointing in direction
``angle_deg`` around the torso's z axis (0 = +x = forward, 90 = +y = left). After the mount comes a
**hip** joint (yaw about z, like Ant's hip) and the first segment; every further segment is
preceded by a **pitch** joint whose axis is horizontal and perpendicular to the leg, oriented so
that a positive angle moves the leg tip *down* (pushes the body up). Joint angle 0 is the rest
pose given by the segments' tilts, so ``qpos = 0`` is the standing body and joint ranges are
symmetric around it.

Sub-action space of a leg = its actuated joints in order (hip first), one motor per joint with
``ctrlrange [-1, 1]`` and a ``gear``; its dimension is ``len(leg.joints)``.

The default table (``DEFAULT_LEGS``) is the body of paper §5.2.1:

=================  ======  =====================================  ===========
leg                angle   segments (after the hip)               sub-action
=================  ======  =====================================  ===========
front_left         45°     Ant leg: thigh + shin, own lengths     hip, ankle
front_right        -45°    Ant leg                                hip, ankle
back_left          135°    Ant leg                                hip, ankle
back_right         225°    Ant leg                                hip, ankle
mid_left           90°     long: thigh + femur + tibia            hip, knee, ankle
mid_right          270°    long                                   hip, knee, ankle
front              0°      short rigid peg                        hip
back               180°    short rigid peg                        hip
=================  ======  =====================================  ===========

The two three-segment (two pitch joint) legs and the two rigid (zero pitch joint) legs sit
symmetrically in the four directions, as in the paper; the four Ant legs each have their own
length, so the neighbours of every leg differ. Each segment's rest tilt is solved so that every
foot touches the floor when the torso is at ``STANCE_HEIGHT``.

Forward is +x and left is +y, so ``angle_deg`` 45 is the direction (1, 1, 0) / sqrt(2) (front left).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Literal

JointKind = Literal["hip", "pitch"]

#: Torso-centre height (m) at which every default leg's foot touches the floor in the rest pose.
STANCE_HEIGHT = 0.5
#: Capsule radius of every leg segment (m), as Ant's 0.08; the foot sphere has the same radius.
LEG_RADIUS = 0.08


@dataclasses.dataclass(frozen=True)
class JointSpec:
    """One actuated hinge of a leg.

    Attributes:
      name: short name, unique inside the leg (``hip``, ``knee``, ``ankle``).
      kind: ``"hip"`` (yaw about the torso z axis) or ``"pitch"`` (lifts/lowers the distal part).
      range_deg: (low, high) joint limits in degrees around the rest pose (0).
      gear: motor gear; torque = gear * ctrl with ctrl in [-1, 1].
    """

    name: str
    kind: JointKind
    range_deg: tuple[float, float]
    gear: float = 150.0

    def __post_init__(self):
        if self.kind not in ("hip", "pitch"):
            raise ValueError(
                f"joint {self.name!r}: kind must be 'hip' or 'pitch', got {self.kind!r}"
            )
        lo, hi = self.range_deg
        if not lo < 0.0 < hi:
            raise ValueError(
                f"joint {self.name!r}: range_deg must contain the rest pose 0 strictly inside, "
                f"got {self.range_deg}"
            )
        if self.gear <= 0:
            raise ValueError(f"joint {self.name!r}: gear must be positive, got {self.gear}")


@dataclasses.dataclass(frozen=True)
class LegSpec:
    """One leg = one sub-action space.

    Attributes:
      name: leg name (the sub-space is called ``leg_<name>``).
      angle_deg: mounting direction around the torso z axis, 0 = forward (+x), 90 = left (+y).
      segment_lengths: ``[k]`` lengths (m) of the segments after the hip; segment 0 hangs on the
        hip joint, segment ``i > 0`` on pitch joint ``i``.
      segment_tilts_deg: ``[k]`` rest downward tilt of each segment from the horizontal (degrees;
        negative points up, e.g. a raised spider knee).
      joints: ``[k]`` joints; ``joints[0]`` is the hip, the rest are pitch joints.
      mount_length: length (m) of the rigid link from the torso centre to the hip.
    """

    name: str
    angle_deg: float
    segment_lengths: tuple[float, ...]
    segment_tilts_deg: tuple[float, ...]
    joints: tuple[JointSpec, ...]
    mount_length: float = 0.28

    def __post_init__(self):
        k = len(self.segment_lengths)
        if k < 1:
            raise ValueError(f"leg {self.name!r}: needs at least one segment")
        if len(self.segment_tilts_deg) != k or len(self.joints) != k:
            raise ValueError(
                f"leg {self.name!r}: segment_lengths, segment_tilts_deg and joints need the same "
                "length (one joint before each segment), "
                f"got {k}, {len(self.segment_tilts_deg)}, {len(self.joints)}"
            )
        kinds = [j.kind for j in self.joints]
        if kinds[0] != "hip" or any(x != "pitch" for x in kinds[1:]):
            raise ValueError(
                f"leg {self.name!r}: joints must be one 'hip' followed by 'pitch' joints, "
                f"got {kinds}"
            )
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            raise ValueError(f"leg {self.name!r}: duplicate joint names {names}")
        if any(length <= 0 for length in self.segment_lengths) or self.mount_length <= 0:
            raise ValueError(f"leg {self.name!r}: lengths must be positive")

    @property
    def subspace_name(self) -> str:
        return f"leg_{self.name}"

    @property
    def n_actuators(self) -> int:
        return len(self.joints)

    def tip_drop(self) -> float:
        """Vertical distance (m) from the hip down to the leg tip's centre in the rest pose."""
        return sum(
            length * math.sin(math.radians(t))
            for length, t in zip(self.segment_lengths, self.segment_tilts_deg, strict=True)
        )


def solve_tilt(drop: float, length: float) -> float:
    """Downward tilt (degrees) that makes a segment of ``length`` descend by ``drop`` (m)."""
    if not 0.0 < drop < length:
        raise ValueError(f"a segment of length {length} cannot descend {drop}")
    return math.degrees(math.asin(drop / length))


def ant_leg(name: str, angle_deg: float, thigh: float, shin: float, gear: float = 150.0) -> LegSpec:
    """Ant's leg (horizontal thigh on a yaw hip, shin on a pitch ankle), scaled lengths.

    The shin's rest tilt is solved so the foot touches the floor at ``STANCE_HEIGHT``. Ranges
    are Ant's: hip ±30°, ankle ±20° around the rest (Ant's 30°..70°).
    """
    tilt = solve_tilt(STANCE_HEIGHT - LEG_RADIUS, shin)
    return LegSpec(
        name,
        angle_deg,
        (thigh, shin),
        (0.0, tilt),
        (
            JointSpec("hip", "hip", (-30.0, 30.0), gear),
            JointSpec("ankle", "pitch", (-20.0, 20.0), gear),
        ),
    )


def long_leg(
    name: str,
    angle_deg: float,
    thigh: float,
    femur: float,
    tibia: float,
    knee_up_deg: float = 30.0,
    gear: float = 150.0,
) -> LegSpec:
    """A longer three-segment spider leg: yaw hip, raised knee (pitch), ankle (pitch)."""
    drop = STANCE_HEIGHT - LEG_RADIUS + femur * math.sin(math.radians(knee_up_deg))
    tilt = solve_tilt(drop, tibia)
    return LegSpec(
        name,
        angle_deg,
        (thigh, femur, tibia),
        (0.0, -knee_up_deg, tilt),
        (
            JointSpec("hip", "hip", (-30.0, 30.0), gear),
            JointSpec("knee", "pitch", (-25.0, 25.0), gear),
            JointSpec("ankle", "pitch", (-25.0, 25.0), gear),
        ),
    )


def rigid_leg(name: str, angle_deg: float, length: float, gear: float = 100.0) -> LegSpec:
    """A short rigid peg on a yaw hip (one actuator); it reaches the floor at the stance height."""
    tilt = solve_tilt(STANCE_HEIGHT - LEG_RADIUS, length)
    return LegSpec(
        name, angle_deg, (length,), (tilt,), (JointSpec("hip", "hip", (-30.0, 30.0), gear),)
    )


#: The default 8-leg body of §5.2.1; sub-action dims [2, 2, 2, 2, 3, 3, 1, 1].
DEFAULT_LEGS: tuple[LegSpec, ...] = (
    ant_leg("front_left", 45.0, thigh=0.28, shin=0.57),
    ant_leg("front_right", -45.0, thigh=0.24, shin=0.50),
    ant_leg("back_left", 135.0, thigh=0.32, shin=0.64),
    ant_leg("back_right", 225.0, thigh=0.26, shin=0.54),
    long_leg("mid_left", 90.0, thigh=0.30, femur=0.42, tibia=0.75),
    long_leg("mid_right", 270.0, thigh=0.30, femur=0.42, tibia=0.75),
    rigid_leg("front", 0.0, length=0.46),
    rigid_leg("back", 180.0, length=0.46),
)

DEFAULT_LEG_NAMES: tuple[str, ...] = tuple(leg.name for leg in DEFAULT_LEGS)


def _canonical(name: str) -> str:
    """Leg names may be given with or without the sub-space prefix ``leg_``."""
    return name[len("leg_") :] if name.startswith("leg_") else name


def select_legs(
    legs: Sequence[str | LegSpec] | None, table: Sequence[LegSpec] = DEFAULT_LEGS
) -> tuple[LegSpec, ...]:
    """Resolve the ``legs`` option of ``make_spider`` into a leg table.

    Args:
      legs: ``None`` (the whole default table); a sequence of leg names (``"front_left"`` or
        ``"leg_front_left"``) to keep, returned in the default table's order; or a sequence of
        ``LegSpec`` (a custom table, used as given).
      table: the table names are looked up in.

    Raises:
      ValueError: unknown or duplicate names (the message lists the accepted ones), an empty
        selection, or a mix of names and LegSpecs.
    """
    if legs is None:
        return tuple(table)
    legs = tuple(legs)
    if not legs:
        raise ValueError(
            f"legs must name at least one leg; accepted: {[leg.name for leg in table]}"
        )
    if all(isinstance(x, LegSpec) for x in legs):
        names = [leg.name for leg in legs]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate leg names in the custom table: {names}")
        return legs
    if not all(isinstance(x, str) for x in legs):
        raise ValueError("legs must be all names (str) or all LegSpec, not a mix")
    wanted = [_canonical(x) for x in legs]
    known = [leg.name for leg in table]
    unknown = [x for x, w in zip(legs, wanted, strict=True) if w not in known]
    if unknown:
        raise ValueError(
            f"unknown leg name(s) {unknown}; accepted: {known} (optionally prefixed with 'leg_')"
        )
    if len(set(wanted)) != len(wanted):
        raise ValueError(f"duplicate leg names in {list(legs)}")
    return tuple(leg for leg in table if leg.name in set(wanted))
