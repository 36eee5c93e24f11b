"""Write URDF files for the planar arms of papers/004 (Petrič et al., "Obstacle Avoidance with Industrial Robots").

The paper's examples are a planar manipulator with five revolute joints (Secs. 4-5, Figs. 2-13) and one with
four (Fig. 14). It gives neither link lengths nor limits; the documented choices here:

* every link is 0.5 m long (``planar5``: reach 2.5 m; ``planar4``: 2.0 m), so the 0.2 m obstacle of Sec. 4
  and the 0.4 m one of Sec. 5 are of the size of a link;
* joint limits +-170 deg, velocity limits 180 deg/s (nothing in the examples reaches them);
* the arm moves in the world x-y plane: every joint axis is world z, joint 1 at the origin, link i
  along its own x axis from 0 to L_i; the zero configuration is the arm stretched along +x;
* collision: each link is a *segment* (a capsule of radius 0) on its x axis, so the distance of an obstacle to
  "the nearest link" (Figs. 3, 5, 9, 11) is a point-segment distance; the visual cylinders have radius 0.03 m.

Frames: ``<p>_link_0`` (base, fixed to the world) ... ``<p>_link_n``, joints ``<p>_joint_1`` ... ``<p>_joint_n``,
``<p>_ee`` = the tip of the last link (fixed frame at x = L_n on ``<p>_link_n``) and ``<p>_tip_i`` = the tip of
link i (i < n, the elbows; Fig. 14's control points).

The capsules are written as in ``dh_to_urdf.py``: a ``<cylinder>`` plus a ``<collision_checking><capsule/>``
entry, which pinocchio turns into ``coal.Capsule``. The cylinder axis is z, so the collision origin turns it
onto the link's x axis (``rpy = 0 pi/2 0``).

Run ``python tools/planar_to_urdf.py`` to regenerate, ``--check`` to verify (exit 1 if a file differs).
No hqp_tpm imports.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: The package data folder the generated robot files are written to.
ROBOTS = HERE.parent / "hqp_tpm" / "data" / "robots"


@dataclass(frozen=True)
class PlanarSpec:
    robot: str  # <robot name=...>
    prefix: str
    title: str
    lengths: tuple[float, ...]  # m
    limit_deg: float = 170.0
    velocity_deg: float = 180.0
    effort: float = 100.0
    mass: float = 1.0  # per link, kg: a thin rod
    visual_radius: float = 0.03


def planar5() -> PlanarSpec:
    return PlanarSpec("planar5", "planar5", "planar 5-DOF arm of papers/004 (Secs. 4-5)", (0.5,) * 5)


def planar4() -> PlanarSpec:
    return PlanarSpec("planar4", "planar4", "planar 4-DOF arm of papers/004 (Fig. 14)", (0.5,) * 4)


SPECS = {"planar/planar5.urdf": planar5, "planar/planar4.urdf": planar4}


def num(x: float) -> str:
    x = float(x)
    return "0" if x == 0.0 else repr(x)


def link_xml(spec: PlanarSpec, i: int) -> str:
    name = f"{spec.prefix}_link_{i}"
    if i == 0:
        return (f'  <link name="{name}">\n'
                '    <visual><geometry><sphere radius="0.05"/></geometry><material name="grey"/></visual>\n'
                "  </link>\n")
    L = spec.lengths[i - 1]
    ixx = 1e-4
    izz = round(spec.mass * L * L / 12.0, 12)
    cname = f"{spec.prefix}_link_{i}_capsule"
    mid = f'<origin xyz="{num(L / 2)} 0 0" rpy="0 {num(math.pi / 2)} 0"/>'
    return (
        f'  <link name="{name}">\n'
        "    <inertial>\n"
        f'      <origin xyz="{num(L / 2)} 0 0" rpy="0 0 0"/>\n'
        f'      <mass value="{num(spec.mass)}"/>\n'
        f'      <inertia ixx="{num(ixx)}" ixy="0" ixz="0" iyy="{num(izz)}" iyz="0" izz="{num(izz)}"/>\n'
        "    </inertial>\n"
        f'    <visual name="{spec.prefix}_link_{i}_visual">\n'
        f"      {mid}\n"
        f'      <geometry><cylinder radius="{num(spec.visual_radius)}" length="{num(L)}"/></geometry>\n'
        '      <material name="orange"/>\n'
        "    </visual>\n"
        f'    <collision name="{cname}">\n'
        f"      {mid}\n"
        f'      <geometry><cylinder radius="0" length="{num(L)}"/></geometry>\n'
        "    </collision>\n"
        f'    <collision_checking><capsule name="{cname}"/></collision_checking>\n'
        "  </link>\n"
    )


def joint_xml(spec: PlanarSpec, i: int) -> str:
    x = 0.0 if i == 1 else spec.lengths[i - 2]
    lim = math.radians(spec.limit_deg)
    return (
        f'  <joint name="{spec.prefix}_joint_{i}" type="revolute">\n'
        f'    <parent link="{spec.prefix}_link_{i - 1}"/>\n'
        f'    <child link="{spec.prefix}_link_{i}"/>\n'
        f'    <origin xyz="{num(x)} 0 0" rpy="0 0 0"/>\n'
        '    <axis xyz="0 0 1"/>\n'
        f'    <limit lower="{num(-lim)}" upper="{num(lim)}" velocity="{num(math.radians(spec.velocity_deg))}" '
        f'effort="{num(spec.effort)}"/>\n'
        "  </joint>\n"
    )


def fixed_frame_xml(name: str, parent: str, x: float) -> str:
    return (f'  <link name="{name}"/>\n'
            f'  <joint name="{name}_joint" type="fixed">\n'
            f'    <parent link="{parent}"/>\n'
            f'    <child link="{name}"/>\n'
            f'    <origin xyz="{num(x)} 0 0" rpy="0 0 0"/>\n'
            "  </joint>\n")


def build_urdf(spec: PlanarSpec) -> str:
    n = len(spec.lengths)
    lengths = ", ".join(num(v) for v in spec.lengths)
    parts = [
        '<?xml version="1.0"?>\n',
        f"<!--\n  {spec.title} ({spec.robot}), generated by tools/planar_to_urdf.py: do not edit by hand.\n"
        f"  Link lengths (m): {lengths}; limits +-{num(spec.limit_deg)} deg, {num(spec.velocity_deg)} deg/s.\n"
        "  Plane x-y, joint axes z; collision: one segment (capsule of radius 0) per link.\n-->\n",
        f'<robot name="{spec.robot}">\n',
        '  <material name="orange"><color rgba="1.0 0.45 0.0 1.0"/></material>\n',
        '  <material name="grey"><color rgba="0.5 0.5 0.5 1.0"/></material>\n',
        link_xml(spec, 0),
    ]
    for i in range(1, n + 1):
        parts += [joint_xml(spec, i), link_xml(spec, i)]
    parts.append(fixed_frame_xml(f"{spec.prefix}_ee", f"{spec.prefix}_link_{n}", spec.lengths[-1]))
    for i in range(1, n):
        parts.append(fixed_frame_xml(f"{spec.prefix}_tip_{i}", f"{spec.prefix}_link_{i}", spec.lengths[i - 1]))
    parts.append("</robot>\n")
    return "".join(parts)


def generate() -> dict[Path, str]:
    return {ROBOTS / rel: build_urdf(make()) for rel, make in SPECS.items()}


def main(argv: list[str] | None = None) -> int:
    sys.path.insert(0, str(HERE))
    from dh_to_urdf import write_or_check  # the same write/--check as the DH generator

    return write_or_check(generate(), "planar_to_urdf.py", argv)


if __name__ == "__main__":
    sys.exit(main())
