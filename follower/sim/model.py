"""The simulated NAO's body: a URDF built from primitive shapes with the NAO's leg geometry.

Dimensions are the manufacturer's (docs/follower.md): hip offset y 50 mm, hip offset z
85 mm, thigh 100 mm, tibia 102.9 mm, foot height 45.19 mm; total mass about 5.3 kg with
about 60 % in torso, head and arms (one rigid link here: arms and head do not move).

Simplifications (documented in ``docs/follower.md``):

- NAO's HipYawPitch is one motor shared by both legs, on an axis tilted 45 degrees.
  Here each leg has its own vertical **hip yaw** joint, which is what the paper's turning
  scheme (Sec. 3.1, Fig. 5) uses: only the stance leg's yaw moves, half the cycle's turn
  per single support.
- Links of the robot do not collide with each other (pybullet's default without
  ``URDF_USE_SELF_COLLISION``); the legs never cross in this gait.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["LEG_JOINTS", "NaoGeometry", "nao_urdf"]

#: Gait joints of one leg, in chain order (prefix ``L``/``R``), as NAO names them.
LEG_JOINTS = ("HipYaw", "HipRoll", "HipPitch", "KneePitch", "AnklePitch", "AnkleRoll")

#: NAO joint limits [rad] for the left leg (right leg: roll limits mirrored).
_LIMITS_DEG = {
    "HipYaw": (-65.62, 42.44),
    "HipRoll": (-21.74, 45.29),
    "HipPitch": (-88.0, 27.73),
    "KneePitch": (-5.29, 121.04),
    "AnklePitch": (-68.15, 52.86),
    "AnkleRoll": (-22.79, 44.06),
}


@dataclass(frozen=True)
class NaoGeometry:
    """Lengths [m] and masses [kg] of the simulated NAO.

    Attributes
    ----------
    hip_offset_y, hip_offset_z : float
        Hip joint position below and beside the torso origin [m].
    thigh, tibia, foot_height : float
        Hip-to-knee, knee-to-ankle and ankle-to-sole lengths [m].
    foot_length, foot_width : float
        Sole size [m].
    foot_x, foot_y_out : float
        Sole centre ahead of the ankle, and outward of it [m].
    m_torso : float
        Torso with head and arms [kg].
    m_thigh, m_tibia, m_foot, m_small : float
        Leg link masses [kg] (``m_small``: each of the hip yaw, hip roll, ankle pitch links).
    """

    hip_offset_y: float = 0.050
    hip_offset_z: float = 0.085
    thigh: float = 0.100
    tibia: float = 0.1029
    foot_height: float = 0.04519
    foot_length: float = 0.16
    foot_width: float = 0.088
    foot_x: float = 0.02
    foot_y_out: float = 0.005
    m_torso: float = 3.2
    m_thigh: float = 0.40
    m_tibia: float = 0.30
    m_foot: float = 0.20
    m_small: float = 0.05
    torso_com_z_m: float = 0.055
    rotor_pitch_kgm2: float = 0.0
    rotor_roll_kgm2: float = 0.0

    @property
    def total_mass(self) -> float:
        """Total mass [kg]."""
        return self.m_torso + 2 * (self.m_thigh + self.m_tibia + self.m_foot + 3 * self.m_small)

    @property
    def torso_com_z(self) -> float:
        """Torso (with head and arms) centre of mass above the torso origin [m]."""
        return self.torso_com_z_m


def _box_inertia(m: float, x: float, y: float, z: float, rotor: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> str:
    """Return a solid box's inertia [kg m^2] plus ``rotor``, a motor's reflected rotor inertia about x, y or z.

    The rotor is a disk: ``J`` about its axis, ``J / 2`` about the other two (a valid rigid
    body, which pybullet's URDF importer requires).
    """
    j = max(rotor)
    rx, ry, rz = (r if r else j / 2 for r in rotor) if j > 0 else rotor
    return (
        f'<inertia ixx="{m * (y * y + z * z) / 12 + rx:.6g}" iyy="{m * (x * x + z * z) / 12 + ry:.6g}" '
        f'izz="{m * (x * x + y * y) / 12 + rz:.6g}" ixy="0" ixz="0" iyz="0"/>'
    )


def _link(name: str, mass: float, com: tuple[float, float, float], inertia: str, shapes: str) -> str:
    cx, cy, cz = com
    return (
        f'<link name="{name}"><inertial><origin xyz="{cx:.5f} {cy:.5f} {cz:.5f}"/>'
        f'<mass value="{mass:.4f}"/>{inertia}</inertial>{shapes}</link>\n'
    )


def _shape(geom: str, xyz: tuple[float, float, float], color: str, collide: bool = True) -> str:
    x, y, z = xyz
    origin = f'<origin xyz="{x:.5f} {y:.5f} {z:.5f}"/>'
    vis = f'<visual>{origin}<geometry>{geom}</geometry><material name="{color}"/></visual>'
    col = f"<collision>{origin}<geometry>{geom}</geometry></collision>" if collide else ""
    return vis + col


def _joint(
    name: str,
    kind: str,
    parent: str,
    child: str,
    xyz: tuple[float, float, float],
    axis: str,
    limit: tuple[float, float] | None,
    effort: float,
) -> str:
    x, y, z = xyz
    lim = ""
    if limit is not None:
        lim = f'<limit lower="{limit[0]:.5f}" upper="{limit[1]:.5f}" effort="{effort:.2f}" velocity="7.0"/>'
    return (
        f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{x:.5f} {y:.5f} {z:.5f}"/><axis xyz="{axis}"/>{lim}</joint>\n'
    )


def _leg_urdf(g: NaoGeometry, side: str, s: float, effort_nm: float) -> list[str]:
    """Return the URDF links and joints of one leg (``side`` ``L`` or ``R``; ``s`` +1 left, -1 right).

    The chain hip yaw (z) - hip roll (x) - hip pitch (y) - knee pitch (y) - ankle pitch (y) -
    ankle roll (x) - foot, from the torso; the right leg's roll and yaw limits are mirrored.
    """
    rp, rr = g.rotor_pitch_kgm2, g.rotor_roll_kgm2
    parts: list[str] = []
    lim = {k: (math.radians(a), math.radians(b)) for k, (a, b) in _LIMITS_DEG.items()}
    if s < 0:  # the right leg's roll joints are mirrored
        for k in ("HipRoll", "AnkleRoll"):
            a, b = lim[k]
            lim[k] = (-b, -a)
        a, b = lim["HipYaw"]
        lim["HipYaw"] = (-b, -a)
    names = [f"{side}{j}" for j in LEG_JOINTS]
    links = [
        f"{side}_hipyaw",
        f"{side}_hiproll",
        f"{side}_thigh",
        f"{side}_tibia",
        f"{side}_anklepitch",
        f"{side}_foot",
    ]
    parts.append(_link(links[0], g.m_small, (0, 0, 0), _box_inertia(g.m_small, 0.02, 0.02, 0.02, (0, 0, rr)), ""))
    parts.append(_link(links[1], g.m_small, (0, 0, 0), _box_inertia(g.m_small, 0.02, 0.02, 0.02, (rr, 0, 0)), ""))
    thigh_geom = f'<cylinder radius="0.035" length="{g.thigh - 0.02:.4f}"/>'
    parts.append(
        _link(
            links[2],
            g.m_thigh,
            (0, 0, -g.thigh / 2),
            _box_inertia(g.m_thigh, 0.07, 0.07, g.thigh, (0, rp, 0)),
            _shape(thigh_geom, (0, 0, -g.thigh / 2), "white"),
        )
    )
    tibia_geom = f'<cylinder radius="0.03" length="{g.tibia - 0.02:.4f}"/>'
    parts.append(
        _link(
            links[3],
            g.m_tibia,
            (0, 0, -g.tibia / 2),
            _box_inertia(g.m_tibia, 0.06, 0.06, g.tibia, (0, rp, 0)),
            _shape(tibia_geom, (0, 0, -g.tibia / 2), "white"),
        )
    )
    parts.append(_link(links[4], g.m_small, (0, 0, 0), _box_inertia(g.m_small, 0.02, 0.02, 0.02, (0, rp, 0)), ""))
    sole_t = 0.015
    foot_c = (g.foot_x, s * g.foot_y_out, -g.foot_height + sole_t / 2)
    foot_geom = f'<box size="{g.foot_length} {g.foot_width} {sole_t}"/>'
    ankle_geom = '<box size="0.05 0.05 0.03"/>'
    parts.append(
        _link(
            links[5],
            g.m_foot,
            (g.foot_x, 0, -g.foot_height + 0.015),
            _box_inertia(g.m_foot, g.foot_length, g.foot_width, 0.03, (rr, 0, 0)),
            _shape(foot_geom, foot_c, "grey") + _shape(ankle_geom, (0, 0, -g.foot_height / 2), "white", collide=False),
        )
    )
    chain = [
        ("torso", (0.0, s * g.hip_offset_y, -g.hip_offset_z), "0 0 1"),
        (links[0], (0, 0, 0), "1 0 0"),
        (links[1], (0, 0, 0), "0 1 0"),
        (links[2], (0, 0, -g.thigh), "0 1 0"),
        (links[3], (0, 0, -g.tibia), "0 1 0"),
        (links[4], (0, 0, 0), "1 0 0"),
    ]
    for i, (parent, xyz, axis) in enumerate(chain):
        jn = LEG_JOINTS[i]
        parts.append(_joint(names[i], "revolute", parent, links[i], xyz, axis, lim[jn], effort_nm))
    return parts


def nao_urdf(geom: NaoGeometry | None = None, effort_nm: float = 10.0) -> str:
    """Return the URDF text of the simulated NAO.

    The base link is the torso (origin at NAO's torso frame, 85 mm above the hip joints);
    each leg is the chain hip yaw (z) - hip roll (x) - hip pitch (y) - knee pitch (y) -
    ankle pitch (y) - ankle roll (x) - foot. With all joints at zero the legs are straight.

    Parameters
    ----------
    geom : NaoGeometry, optional
        Lengths and masses (NAO defaults).
    effort_nm : float
        Joint torque limit written into the URDF [N m].
    """
    g = geom or NaoGeometry()
    parts = [
        '<?xml version="1.0"?>\n<robot name="bipedtele_nao">\n',
        '<material name="white"><color rgba="0.92 0.92 0.92 1"/></material>\n',
        '<material name="grey"><color rgba="0.45 0.45 0.5 1"/></material>\n',
        '<material name="blue"><color rgba="0.2 0.35 0.8 1"/></material>\n',
    ]
    # Torso + head + arms: one rigid body. Collision: torso box and head sphere.
    torso_shapes = (
        _shape('<box size="0.10 0.14 0.13"/>', (0.0, 0.0, 0.045), "white")
        + _shape('<sphere radius="0.055"/>', (0.0, 0.0, 0.18), "white")
        + _shape('<box size="0.02 0.02 0.005"/>', (0.052, 0.0, 0.185), "blue", collide=False)
        + _shape('<box size="0.05 0.05 0.17"/>', (0.0, 0.10, 0.04), "grey", collide=False)
        + _shape('<box size="0.05 0.05 0.17"/>', (0.0, -0.10, 0.04), "grey", collide=False)
    )
    # Torso, head and arms about their common centre of mass: 0.030, 0.028, 0.010 kg m^2 for the
    # NAO's 3.2 kg, scaled with the mass (a model with another torso mass keeps its shape).
    k = g.m_torso / 3.2
    torso_inertia = (
        f'<inertia ixx="{0.030 * k:.6g}" iyy="{0.028 * k:.6g}" izz="{0.010 * k:.6g}" ixy="0" ixz="0" iyz="0"/>'
    )
    parts.append(_link("torso", g.m_torso, (0.0, 0.0, g.torso_com_z), torso_inertia, torso_shapes))

    for side, s in (("L", 1.0), ("R", -1.0)):
        parts.extend(_leg_urdf(g, side, s, effort_nm))
    parts.append("</robot>\n")
    return "".join(parts)
