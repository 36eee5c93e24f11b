"""A robot: pinocchio model, collision and visual geometry, names and limits (loaded by :meth:`Robot.load`)."""

from __future__ import annotations

import difflib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from hqp_tpm.data import robots_dir
from hqp_tpm.errors import RobotFileError, UnknownFrameError, UnknownNameError, unknown_name

#: Folder of the shipped robot descriptions (package data; override with HQP_TPM_ROBOTS).
ROBOTS_DIR = robots_dir()

#: Robots shipped in ``hqp_tpm/data/robots/``: short name -> URDF path relative to ROBOTS_DIR.
PROJECT_ROBOTS = {"lwr4": "kuka_lwr4/lwr4.urdf", "iiwa7": "kuka_iiwa7/iiwa7.urdf",
                  "planar5": "planar/planar5.urdf", "planar4": "planar/planar4.urdf"}

#: The 21 joints of the papers' simplified Romeo (docs/setups.md).
ROMEO21_JOINTS = (
    "LHipYaw", "LHipRoll", "LHipPitch", "LKneePitch", "LAnklePitch", "LAnkleRoll",
    "RHipYaw", "RHipRoll", "RHipPitch", "RKneePitch", "RAnklePitch", "RAnkleRoll",
    "TrunkYaw",
    "LShoulderPitch", "LShoulderYaw", "LElbowRoll", "LElbowYaw",
    "RShoulderPitch", "RShoulderYaw", "RElbowRoll", "RElbowYaw",
)

#: Reduced robots built from example-robot-data: name -> (robot, joints kept).
REDUCED_ROBOTS = {"romeo21": ("romeo", ROMEO21_JOINTS)}


@dataclass
class Robot:
    """Pinocchio model with its geometry. ``joint_names`` has one entry per velocity column."""

    model: pin.Model
    collision_model: pin.GeometryModel | None = None
    visual_model: pin.GeometryModel | None = None
    name: str = ""
    source: str = ""
    joint_names: list[str] = field(init=False)

    def __post_init__(self) -> None:
        names: list[str] = []
        for joint, jname in zip(self.model.joints[1:], self.model.names[1:], strict=True):
            axes = ["x", "y", "z", "wx", "wy", "wz"] if joint.nv == 6 else [str(k) for k in range(joint.nv)]
            names.extend([jname] if joint.nv == 1 else [f"{jname}_{a}" for a in axes])
        self.joint_names = names
        self.name = self.name or self.model.name

    # -- loading -----------------------------------------------------------------------------
    @classmethod
    def from_urdf(cls, path, *, package_dirs=None, free_flyer: bool = False, name: str = "") -> Robot:
        """Load a URDF file; collision and visual geometry are loaded when their files exist."""
        path = Path(path)
        if not path.is_file():
            raise RobotFileError(f"robot file not found: {str(path)!r}")
        dirs = [str(d) for d in (package_dirs or [path.parent, path.parent.parent])]
        try:
            args = (str(path), dirs, pin.JointModelFreeFlyer()) if free_flyer else (str(path), dirs)
            model, collision, visual = pin.buildModelsFromUrdf(*args)
        except (RuntimeError, ValueError) as exc:
            raise RobotFileError(f"cannot read robot file {str(path)!r}: {exc}") from exc
        return cls(model, collision, visual, name=name or model.name, source=str(path))

    @classmethod
    def from_example_robot_data(cls, name: str) -> Robot:
        """Load one of example-robot-data's robots by name (e.g. ``"romeo"``)."""
        import example_robot_data as erd

        try:
            wrapper = erd.load(name)
        except (ValueError, KeyError, RuntimeError, OSError) as exc:
            valid = sorted(getattr(erd.robots_loader, "ROBOTS", {}).keys())
            raise RobotFileError(f"cannot load example-robot-data robot {name!r} ({exc}); known robots: "
                                 f"{', '.join(valid)}") from exc
        return cls(wrapper.model, wrapper.collision_model, wrapper.visual_model, name=name,
                   source=f"example-robot-data:{name}")

    @classmethod
    def load(cls, spec: str | os.PathLike) -> Robot:
        """``spec``: a robot shipped in the package (:data:`PROJECT_ROBOTS`, :data:`REDUCED_ROBOTS`), a URDF path, or an
        example-robot-data name (``"romeo"``, ``"panda"``, ...)."""
        key = str(spec)
        if key in REDUCED_ROBOTS:
            base, keep = REDUCED_ROBOTS[key]
            return cls.from_example_robot_data(base).reduced(keep, name=key)
        if key in PROJECT_ROBOTS:
            return cls.from_urdf(ROBOTS_DIR / PROJECT_ROBOTS[key], name=key)
        if key.endswith(".urdf") or os.sep in key:
            return cls.from_urdf(key)
        try:
            return cls.from_example_robot_data(key)
        except RobotFileError as exc:
            import example_robot_data as erd

            erd_names = sorted(getattr(erd.robots_loader, "ROBOTS", {}).keys())
            if key in erd_names:  # a known name whose files failed: that error says why
                raise
            ours = sorted([*PROJECT_ROBOTS, *REDUCED_ROBOTS])
            close = difflib.get_close_matches(key, [*ours, *erd_names], n=3, cutoff=0.6)
            hint = f" (did you mean {' or '.join(map(repr, close))}?)" if close else ""
            raise RobotFileError(f"unknown robot {key!r}{hint}; valid: hqp-tpm's robots {', '.join(ours)}; a URDF "
                                 f"file path (ending in .urdf); or one of example-robot-data's robots: "
                                 f"{', '.join(erd_names)}") from exc

    def reduced(self, keep, q_ref=None, name: str = "") -> Robot:
        """The robot with every 1-DOF joint not in ``keep`` locked at ``q_ref`` (default: neutral); the free-flyer and
        the geometry models are kept (reduced along)."""
        model = self.model
        names = [model.names[j] for j in range(1, model.njoints)]
        unknown = [k for k in keep if k not in names]
        if unknown:
            raise unknown_name("joint", unknown[0], names)
        lock = [j for j in range(1, model.njoints) if model.names[j] not in keep and model.joints[j].nv == 1]
        q_ref = self.neutral() if q_ref is None else np.asarray(q_ref, dtype=float)
        geoms = [g for g in (self.collision_model, self.visual_model) if g is not None]
        if geoms:
            red, geoms_red = pin.buildReducedModel(model, geoms, lock, q_ref)
        else:
            red, geoms_red = pin.buildReducedModel(model, lock, q_ref), []
        it = iter(geoms_red)
        col = next(it) if self.collision_model is not None else None
        vis = next(it) if self.visual_model is not None else None
        return Robot(red, col, vis, name=name or f"{self.name}_reduced", source=f"{self.source} reduced")

    def __repr__(self) -> str:
        geoms = ", ".join(f"{len(g.geometryObjects)} {what} geometries" for what, g in
                          (("collision", self.collision_model), ("visual", self.visual_model)) if g is not None)
        base = ", free-flyer base" if self.has_free_flyer else ""
        return (f"Robot({self.name!r}, nq={self.nq}, nv={self.nv}{base}, {len(self.model.frames)} frames"
                f"{', ' + geoms if geoms else ''})")

    # -- names and sizes ---------------------------------------------------------------------
    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def nv(self) -> int:
        return self.model.nv

    @property
    def has_free_flyer(self) -> bool:
        return self.model.njoints > 1 and self.model.joints[1].nv == 6

    def frame_id(self, name: str) -> int:
        """Index of frame ``name``; an unknown name raises an error listing the valid ones."""
        if not self.model.existFrame(name):
            raise unknown_name("frame", name, [f.name for f in self.model.frames], UnknownFrameError)
        return self.model.getFrameId(name)

    def joint_index(self, name: str) -> int:
        """Velocity column of the one-DOF joint ``name``."""
        if name not in self.joint_names:
            raise unknown_name("joint", name, self.joint_names)
        return self.joint_names.index(name)

    # -- limits (velocity space; free-flyer columns unbounded) -------------------------------
    def position_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower/upper position limits per velocity column (1-DOF joints; +-inf elsewhere)."""
        lo = np.full(self.nv, -np.inf)
        up = np.full(self.nv, np.inf)
        for j in self.model.joints[1:]:
            if j.nq == 1 and j.nv == 1:
                lo[j.idx_v] = self.model.lowerPositionLimit[j.idx_q]
                up[j.idx_v] = self.model.upperPositionLimit[j.idx_q]
        return lo, up

    def velocity_limits(self) -> np.ndarray:
        """Velocity limit per velocity column (inf where the model gives none)."""
        v = np.array(self.model.velocityLimit, dtype=float)
        v[~np.isfinite(v) | (v <= 0)] = np.inf
        if self.has_free_flyer:
            v[:6] = np.inf
        return v

    def neutral(self) -> np.ndarray:
        return pin.neutral(self.model)

    @property
    def references(self) -> list[str]:
        """Names of the model's reference configurations (an SRDF's, e.g. example-robot-data's ``"half_sitting"``
        of Talos); kept through :meth:`reduced`."""
        return sorted(str(k.key()) for k in self.model.referenceConfigurations)

    def reference(self, name: str) -> np.ndarray:
        """The reference configuration ``name`` (a copy of ``q``); an unknown name lists the available ones."""
        names = self.references
        if name not in names:
            if not names:
                raise UnknownNameError(f"unknown reference configuration {name!r}: robot {self.name!r} has none "
                                       "(its model came without an SRDF)")
            raise unknown_name("reference configuration", name, names)
        return np.array(self.model.referenceConfigurations[name], dtype=float)

    def configuration(self, joint_values: dict[str, float] | None = None, base=None, *,
                      reference: str | None = None) -> np.ndarray:
        """A configuration from the neutral one (or the reference configuration ``reference``, see
        :meth:`reference`), with named 1-DOF joints set (radians) and the free-flyer at ``base`` if given."""
        q = self.neutral() if reference is None else self.reference(reference)
        for jname, val in (joint_values or {}).items():
            if not self.model.existJointName(jname):
                raise unknown_name("joint", jname, [n for n in self.model.names[1:]])
            q[self.model.joints[self.model.getJointId(jname)].idx_q] = float(val)
        if base is not None:
            q[:7] = np.asarray(base, dtype=float)
        return q
