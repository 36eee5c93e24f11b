"""Write URDF files for 7-joint serial arms from a standard-DH table.

Standard DH (Craig's "distal" convention), one transform per joint:

    A_i = Rot_z(theta_i) . Trans_z(d_i) . Trans_x(a_i) . Rot_x(alpha_i),   theta_i = q_i

DH -> URDF:

* link i's frame is DH frame (i-1) . Rot_z(q_i); link 0 is DH frame 0 (the base);
* joint 1 has the identity origin; joint i+1 has origin Trans_z(d_i) . Trans_x(a_i) . Rot_x(alpha_i),
  written ``xyz="a_i 0 d_i" rpy="alpha_i 0 0"``; every joint axis is z;
* DH frame k (k >= 1) is therefore a fixed frame on link k with that same origin; the end effector
  (fixed joint ``<prefix>_ee_joint``) is DH frame 7, the flange.

Collision capsules: every segment is written as a ``<collision name=...>`` with a ``<cylinder>`` plus
a ``<collision_checking><capsule name=.../></collision_checking>`` entry on the link.  The file stays
plain URDF 1.0 (any URDF tool sees a cylinder of that radius and length), and pinocchio's URDF parser
(checked with pinocchio 4.1 / urdfdom 6) turns exactly those cylinders into ``coal.Capsule`` of the
same radius and length (the length of the cylindrical part).  For parsers that do not know this
convention, and for the visual model, :func:`cylinders_to_capsules` does the same on a loaded
``pinocchio.GeometryModel``.  (A ``<capsule>`` geometry element is only read by urdfdom when the
``<robot>`` element says ``version="1.1"``; without it the collision element is dropped, and older
urdfdom never reads it, hence the cylinder form.)

Run ``python tools/dh_to_urdf.py`` to regenerate the committed files, ``--check`` to verify that
they are up to date (exit status 1 otherwise).  The output is deterministic.  No hqp_tpm imports.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: The package data folder the generated robot files are written to.
ROBOTS = HERE.parent / "hqp_tpm" / "data" / "robots"


@dataclass(frozen=True)
class Segment:
    """A capsule around the z axis of ``link``, its axis running from z = z0 to z = z1 (link frame)."""

    name: str
    link: int
    z0: float
    z1: float
    radius: float


@dataclass(frozen=True)
class Frame:
    """A fixed, massless frame: child link ``name`` on link ``link`` at origin ``xyz``/``rpy``."""

    name: str
    link: int
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class ArmSpec:
    """Everything needed to write one arm.  Angles in degrees here, radians in the URDF."""

    robot: str  # <robot name=...>
    prefix: str  # joints <prefix>_joint_i, links <prefix>_link_i, EE <prefix>_ee
    title: str
    d: tuple[float, ...]  # DH d_1..d_7 (m)
    a: tuple[float, ...]  # DH a_1..a_7 (m)
    alpha_deg: tuple[float, ...]  # DH alpha_1..alpha_7 (deg)
    limit_deg: tuple[float, ...]  # symmetric position limits +-limit (deg)
    velocity_deg: tuple[float, ...]  # velocity limits (deg/s)
    effort: tuple[float, ...]  # effort limits (N m)
    masses: tuple[float, ...]  # link_0 .. link_7 (kg), simple solid cylinders
    body_radius: float  # radius of the inertia cylinders (m)
    base_z: tuple[float, float]  # inertia cylinder of link 0, z range in the base frame
    segments: tuple[Segment, ...]
    frames: tuple[Frame, ...] = field(default=())
    notes: tuple[str, ...] = field(default=())

    def link(self, i: int) -> str:
        return f"{self.prefix}_link_{i}"

    def joint(self, i: int) -> str:
        return f"{self.prefix}_joint_{i}"

    def dh_frame(self, name: str, k: int) -> Frame:
        """DH frame k (k >= 1) as a fixed frame on link k: origin Trans_z(d_k) Trans_x(a_k) Rot_x(alpha_k)."""
        return Frame(name, k, (self.a[k - 1], 0.0, self.d[k - 1]), (math.radians(self.alpha_deg[k - 1]), 0.0, 0.0))


# ----------------------------------------------------------------------------------------------------------------------
# The two arms
# ----------------------------------------------------------------------------------------------------------------------

ALPHA_DEG = (90.0, -90.0, -90.0, 90.0, 90.0, -90.0, 0.0)
ZERO_A = (0.0,) * 7


def _arm_frames(spec: ArmSpec) -> tuple[Frame, ...]:
    """shoulder = DH frame 2, elbow = DH frame 3, wrist = DH frame 5 (their origins are the joint centres)."""
    p = spec.prefix
    return (spec.dh_frame(f"{p}_shoulder", 2), spec.dh_frame(f"{p}_elbow", 3), spec.dh_frame(f"{p}_wrist", 5))


def _arm_segments(d: tuple[float, ...], base: tuple[float, float]) -> tuple[Segment, ...]:
    """Base column, shoulder-elbow, elbow-wrist, wrist-flange (all along a link z axis since a = 0, d2 = d4 = d6 = 0).

    Link 3 starts at the shoulder (origin of DH frame 2) and reaches the elbow at z = d3; link 5 starts at the elbow
    (origin of DH frame 4 = origin of DH frame 3) and reaches the wrist at z = d5; link 7 starts at the wrist and
    reaches the flange at z = d7.
    """
    return (
        Segment("base", 0, base[0], base[1], 0.07),
        Segment("upper_arm", 3, 0.0, d[2], 0.07),
        Segment("forearm", 5, 0.0, d[4], 0.065),
        Segment("wrist", 7, 0.0, d[6], 0.06),
    )


# body control points of papers/000 (m from the shoulder towards the elbow, from the elbow towards the wrist)
LWR_UPPER_ARM_CP = (0.40, 0.35, 0.30, 0.25)
LWR_FOREARM_CP = (0.39, 0.2925, 0.195, 0.0975)


def lwr4_spec() -> ArmSpec:
    """KUKA LWR IV, base frame at the shoulder (d1 = 0), EE at the flange (no tool)."""
    d = (0.0, 0.0, 0.4, 0.0, 0.39, 0.0, 0.078)
    base_height = 0.3105  # mounting flange of the real LWR IV below the shoulder: only used for the base capsule
    spec = ArmSpec(
        robot="kuka_lwr4",
        prefix="lwr",
        title="KUKA LWR IV",
        d=d,
        a=ZERO_A,
        alpha_deg=ALPHA_DEG,
        limit_deg=(170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 170.0),
        velocity_deg=(110.0, 110.0, 128.0, 128.0, 204.0, 184.0, 184.0),
        effort=(176.0, 176.0, 100.0, 100.0, 100.0, 30.0, 30.0),
        masses=(2.0, 2.7, 2.7, 2.7, 2.7, 1.7, 1.6, 0.3),
        body_radius=0.06,
        base_z=(-base_height, 0.0),
        segments=_arm_segments(d, (-base_height + 0.07, 0.0)),
        notes=(
            "Base frame (lwr_link_0) at the shoulder: d1 = 0 as in papers/000; the base capsule stands for the",
            "column below it (0.3105 m to the mounting flange).",
            "q7 turns about the EE z axis: it moves neither the EE position nor the EE z axis.",
        ),
    )
    cps = [Frame(f"lwr_cp_{k + 1}", 3, (0.0, 0.0, s)) for k, s in enumerate(LWR_UPPER_ARM_CP)]
    cps += [Frame(f"lwr_cp_{k + 5}", 5, (0.0, 0.0, s)) for k, s in enumerate(LWR_FOREARM_CP)]
    return replace(spec, frames=_arm_frames(spec) + tuple(cps))


def iiwa7_spec() -> ArmSpec:
    """KUKA LBR iiwa 7 R800, base frame on the floor (d1 = 0.34), EE at the flange (no sensor, no tool)."""
    d = (0.34, 0.0, 0.40, 0.0, 0.40, 0.0, 0.126)
    spec = ArmSpec(
        robot="kuka_iiwa7",
        prefix="iiwa",
        title="KUKA LBR iiwa 7 R800",
        d=d,
        a=ZERO_A,
        alpha_deg=ALPHA_DEG,
        limit_deg=(170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 175.0),
        velocity_deg=(98.0, 98.0, 100.0, 130.0, 140.0, 180.0, 180.0),
        effort=(176.0, 176.0, 110.0, 110.0, 110.0, 40.0, 40.0),
        masses=(5.0, 4.0, 4.0, 3.0, 2.7, 1.7, 1.8, 0.3),
        body_radius=0.06,
        base_z=(0.0, 0.1575),
        segments=_arm_segments(d, (0.07, d[0])),
        notes=("Base frame (iiwa_link_0) on the mounting surface; the shoulder is 0.34 m above it.",),
    )
    return replace(spec, frames=_arm_frames(spec))


SPECS = {
    "kuka_lwr4/lwr4.urdf": lwr4_spec,
    "kuka_iiwa7/iiwa7.urdf": iiwa7_spec,
}


# ----------------------------------------------------------------------------------------------------------------------
# URDF writer
# ----------------------------------------------------------------------------------------------------------------------


def num(x: float) -> str:
    """Shortest round-trip decimal of a float ("0" for +-0)."""
    x = float(x)
    return "0" if x == 0.0 else repr(x)


def round_sig(x: float, digits: int = 9) -> float:
    """For derived quantities only (inertias, cylinder centres): drop float noise such as 0.0056700000000000006."""
    return float(f"{x:.{digits}g}")


def vec(v) -> str:
    return " ".join(num(x) for x in v)


def origin(xyz, rpy=(0.0, 0.0, 0.0)) -> str:
    return f'<origin xyz="{vec(xyz)}" rpy="{vec(rpy)}"/>'


def cylinder_inertial(mass: float, radius: float, z0: float, z1: float) -> str:
    """Solid cylinder of axis z from z0 to z1: centre of mass on the axis, principal axes = link axes."""
    length = round_sig(z1 - z0, 12)
    ixx = round_sig(mass * (3.0 * radius**2 + length**2) / 12.0)
    izz = round_sig(mass * radius**2 / 2.0)
    return (
        "    <inertial>\n"
        f"      {origin((0.0, 0.0, round_sig(0.5 * (z0 + z1), 12)))}\n"
        f'      <mass value="{num(mass)}"/>\n'
        f'      <inertia ixx="{num(ixx)}" ixy="0" ixz="0" iyy="{num(ixx)}" iyz="0" izz="{num(izz)}"/>\n'
        "    </inertial>\n"
    )


def inertia_range(spec: ArmSpec, i: int) -> tuple[float, float]:
    """z range of link i's inertia cylinder: [0, d_i] if the link reaches along its axis, else a joint housing."""
    if i == 0:
        return spec.base_z
    if spec.d[i - 1] > 0.0:
        return (0.0, spec.d[i - 1])
    return (-spec.body_radius, spec.body_radius)


def segment_xml(spec: ArmSpec, s: Segment) -> tuple[str, str]:
    """(visual, collision) xml of a capsule segment: cylinder along z (+ spheres at the ends in the visual)."""
    cname = f"{spec.prefix}_{s.name}_capsule"
    length = round_sig(s.z1 - s.z0, 12)  # round_sig(., 12): no float noise in the file, error < 1e-13 m
    mid = origin((0.0, 0.0, round_sig(0.5 * (s.z0 + s.z1), 12)))
    cyl = f'<cylinder radius="{num(s.radius)}" length="{num(length)}"/>'
    visual = (
        f'    <visual name="{spec.prefix}_{s.name}_visual">\n'
        f"      {mid}\n"
        f"      <geometry>{cyl}</geometry>\n"
        '      <material name="kuka_orange"/>\n'
        "    </visual>\n"
    )
    for end, z in (("start", s.z0), ("end", s.z1)):
        visual += (
            f'    <visual name="{spec.prefix}_{s.name}_{end}_visual">\n'
            f"      {origin((0.0, 0.0, z))}\n"
            f'      <geometry><sphere radius="{num(s.radius)}"/></geometry>\n'
            '      <material name="kuka_orange"/>\n'
            "    </visual>\n"
        )
    collision = (
        f'    <collision name="{cname}">\n'
        f"      {mid}\n"
        f"      <geometry>{cyl}</geometry>\n"
        "    </collision>\n"
        f'    <collision_checking><capsule name="{cname}"/></collision_checking>\n'
    )
    return visual, collision


def link_xml(spec: ArmSpec, i: int) -> str:
    body = cylinder_inertial(spec.masses[i], spec.body_radius, *inertia_range(spec, i))
    for s in spec.segments:
        if s.link == i:
            visual, collision = segment_xml(spec, s)
            body += visual + collision
    return f'  <link name="{spec.link(i)}">\n{body}  </link>\n'


def joint_xml(spec: ArmSpec, i: int) -> str:
    """Revolute joint i (1..7) between link i-1 and link i."""
    if i == 1:
        xyz, rpy = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    else:
        xyz, rpy = (spec.a[i - 2], 0.0, spec.d[i - 2]), (math.radians(spec.alpha_deg[i - 2]), 0.0, 0.0)
    lim = math.radians(spec.limit_deg[i - 1])
    return (
        f'  <joint name="{spec.joint(i)}" type="revolute">\n'
        f'    <parent link="{spec.link(i - 1)}"/>\n'
        f'    <child link="{spec.link(i)}"/>\n'
        f"    {origin(xyz, rpy)}\n"
        '    <axis xyz="0 0 1"/>\n'
        f'    <limit lower="{num(-lim)}" upper="{num(lim)}" '
        f'velocity="{num(math.radians(spec.velocity_deg[i - 1]))}" effort="{num(spec.effort[i - 1])}"/>\n'
        "  </joint>\n"
    )


def fixed_frame_xml(spec: ArmSpec, f: Frame) -> str:
    return (
        f'  <link name="{f.name}"/>\n'
        f'  <joint name="{f.name}_joint" type="fixed">\n'
        f'    <parent link="{spec.link(f.link)}"/>\n'
        f'    <child link="{f.name}"/>\n'
        f"    {origin(f.xyz, f.rpy)}\n"
        "  </joint>\n"
    )


def header(spec: ArmSpec) -> str:
    rows = "\n".join(
        f"    {i + 1}   q{i + 1}  {num(spec.d[i]):>6}  {num(spec.a[i]):>3}  {num(spec.alpha_deg[i]):>6}"
        f"  +-{num(spec.limit_deg[i]):>5}  {num(spec.velocity_deg[i]):>5}  {num(spec.effort[i]):>5}"
        for i in range(7)
    )
    notes = "".join(f"  {n}\n" for n in spec.notes)
    return (
        f"<!--\n  {spec.title} ({spec.robot}), generated by tools/dh_to_urdf.py from its DH table: do not edit by\n"
        "  hand, change the table in the script and run it again.\n\n"
        "  Standard DH: A_i = Rot_z(q_i) Trans_z(d_i) Trans_x(a_i) Rot_x(alpha_i); lengths m, angles deg below\n"
        "  (radians in the file), velocity deg/s, effort N m.\n"
        "    i  theta     d    a   alpha   limit    vel  effort\n"
        f"{rows}\n\n"
        f"  Link i frame = DH frame (i-1) Rot_z(q_i); {spec.prefix}_ee = DH frame 7 (flange).\n"
        f"{notes}\n"
        "  Collision: each collision cylinder is a CAPSULE of the same radius and length (length = cylindrical\n"
        "  part, hemispheres added at both ends). pinocchio's URDF parser reads the collision_checking/capsule\n"
        "  entries and builds coal.Capsule directly; other loaders must turn these cylinders into capsules\n"
        "  (tools/dh_to_urdf.py: cylinders_to_capsules). Visuals: the same cylinders plus end spheres.\n"
        "-->\n"
    )


def build_urdf(spec: ArmSpec) -> str:
    """The URDF text of one arm (deterministic)."""
    parts = [
        '<?xml version="1.0"?>\n',
        header(spec),
        f'<robot name="{spec.robot}">\n',
        '  <material name="kuka_orange"><color rgba="1.0 0.45 0.0 1.0"/></material>\n',
        link_xml(spec, 0),
    ]
    for i in range(1, 8):
        parts += [joint_xml(spec, i), link_xml(spec, i)]
    parts.append(fixed_frame_xml(spec, spec.dh_frame(f"{spec.prefix}_ee", 7)))
    parts += [fixed_frame_xml(spec, f) for f in spec.frames]
    parts.append("</robot>\n")
    return "".join(parts)


def generate() -> dict[Path, str]:
    """{path: URDF text} of every committed file."""
    return {ROBOTS / rel: build_urdf(make()) for rel, make in SPECS.items()}


# ----------------------------------------------------------------------------------------------------------------------
# Loader helper
# ----------------------------------------------------------------------------------------------------------------------


def cylinders_to_capsules(geom_model):
    """Replace every ``coal.Cylinder`` of a pinocchio GeometryModel by a ``coal.Capsule`` of the same radius and
    length (cylindrical part), in place; returns the model.  A no-op on models whose cylinders pinocchio already
    turned into capsules."""
    import coal  # only needed by loaders, not by the generator

    for obj in geom_model.geometryObjects:
        g = obj.geometry
        if isinstance(g, coal.Cylinder):
            obj.geometry = coal.Capsule(g.radius, 2.0 * g.halfLength)
    return geom_model


def write_or_check(files: dict[Path, str], script: str, argv: list[str] | None = None) -> int:
    """Write the generated ``files``, or with ``--check`` exit 1 if one differs (shared by the generators)."""
    parser = argparse.ArgumentParser(description=f"Generate the robot files of tools/{script}.")
    parser.add_argument("--check", action="store_true", help="do not write; exit 1 if a file differs")
    args = parser.parse_args(argv)
    stale = []
    for path, text in files.items():
        rel = path.relative_to(HERE.parent)
        if args.check:
            if not path.exists() or path.read_bytes() != text.encode():
                stale.append(rel)
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(text.encode())
        print(f"wrote {rel}")
    if stale:
        print("out of date: " + ", ".join(map(str, stale)) + f" (run python tools/{script})", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    return write_or_check(generate(), "dh_to_urdf.py", argv)


if __name__ == "__main__":
    sys.exit(main())
