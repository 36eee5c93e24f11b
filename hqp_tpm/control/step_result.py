"""What one control step computed: :class:`StepResult`, whose costly fields a compiled step fills on demand
(:meth:`hqp_tpm.control.controller.Controller.step`)."""

from __future__ import annotations

import numpy as np

LAZY = object()  # a StepResult field not computed yet


class _OnDemand:
    """A field of a :class:`StepResult` that the step which made it computes on first read (``of(step, result)``)."""

    def __init__(self, of) -> None:
        self.of = of

    def __set_name__(self, owner: type, name: str) -> None:
        self.field = "_" + name

    def __get__(self, r, owner: type | None = None):
        if r is None:  # read on the class (help(), documentation tools)
            return self
        value = r.__dict__.get(self.field, LAZY)
        if value is LAZY:
            value = r.__dict__[self.field] = self.of(r._kept[0], r)
        return value


class StepResult:
    """What one step computed (before integration): the stack, the command, solver info and inputs.

    ``t``: the time of the step's state. ``stack``: the :class:`Stack` the policy chose. ``levels``: the solver's input,
    one :class:`~hqp_tpm.solvers.levels.Level` per priority level, highest first; solve them again with ``x0`` and
    ``box`` by :func:`~hqp_tpm.solvers.solve` or :func:`hqp_tpm.testing.assert_solvers_agree`. ``command``: the joint
    velocity (order 1) or acceleration (order 2). ``info``: the solver's account (e.g. ``scale``, ``saturated``,
    ``iterations``). ``x0``: the null-space term, ``box``: ``(lower, upper)`` of the command (None: none). A compiled
    step fills ``stack``, ``levels``, ``x0`` and ``box`` on first read (``_kept``): the readable step's numbers."""

    _kept = None

    def __init__(self, t: float, stack, levels, command: np.ndarray, info: dict | None = None, x0=None, box=None):
        self.t, self.command, self._info = t, command, {} if info is None else info
        self._stack, self._levels, self._x0, self._box = stack, levels, x0, box

    info = _OnDemand(lambda step, r: step.info_of(r))
    stack = _OnDemand(lambda step, r: step.stack_of(r))
    levels = _OnDemand(lambda step, r: step.levels_of(r))
    x0 = _OnDemand(lambda step, r: step.x0_of(r))
    box = _OnDemand(lambda step, r: step.box_of(r))

    def label(self) -> str:
        """``"a > b+c"``: the stack as text (:meth:`Stack.label`)."""
        return self.stack.label() if self._kept is None else self._kept[0].label_of(self._kept)

    def __repr__(self) -> str:
        cmd = np.asarray(self.command, dtype=float)
        info = f", info: {', '.join(self.info)}" if self.info else ""
        return (f"StepResult(t={self.t:.4f}, stack={self.label()!r}, |command|={np.linalg.norm(cmd):.4g} "
                f"({cmd.size} values){info})")
