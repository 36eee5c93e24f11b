"""Where a pinocchio frame is in the MuJoCo model: the body that carries it and its placement in that body.

The URDF's links are MuJoCo bodies of the same names (static ones kept: ``fusestatic = false``), and a link's frame
is its body's frame. Any other frame (pinocchio's joint frames, frames added by hand) rides on a link that moves with
the same pinocchio joint: its placement in that link is ``link.placement^-1 * frame.placement`` (both relative to
the joint).
"""

from __future__ import annotations

import pinocchio as pin

from hqp_tpm.errors import PlantError


def body_of_frame(model: pin.Model, bodies, frame: int) -> tuple[str, pin.SE3]:
    """``(MuJoCo body name, frame placement in that body)`` of pinocchio frame ``frame``; ``bodies``: the MuJoCo
    model's body names (``world`` for the universe)."""
    fr = model.frames[frame]
    if fr.name in bodies:
        return fr.name, pin.SE3.Identity()
    for other in model.frames:
        if other.parentJoint == fr.parentJoint and other.name in bodies:
            return other.name, other.placement.actInv(fr.placement)
    if fr.parentJoint == 0:
        return "world", fr.placement
    raise PlantError(f"frame {fr.name!r} rides on no MuJoCo body (joint {model.names[fr.parentJoint]!r})")
