"""Exception hierarchy of hqp-tpm.

Every error raised on bad input derives from :class:`HqpTpmError`, so a caller can
catch the whole family at once; the subclasses say what kind of input was wrong and
their messages name the bad value and, where there is a finite set, the valid choices.
"""

from __future__ import annotations

import reprlib

#: Longest message an error keeps (characters): beyond it the middle is elided, so that a value pasted whole into
#: a message (a list of 200,000 numbers) cannot make a megabyte of text.
MAX_MESSAGE = 2000


def elide(text: str, limit: int = MAX_MESSAGE) -> str:
    """``text`` cut to at most about ``limit`` characters, its middle replaced by ``... [N characters elided] ...``."""
    if len(text) <= limit:
        return text
    keep = max(limit // 2 - 40, 10)
    return f"{text[:keep]} ... [{len(text) - 2 * keep:,} characters elided] ... {text[-keep:]}"


_SHOWN = reprlib.Repr()
_SHOWN.maxlevel, _SHOWN.maxlist, _SHOWN.maxtuple, _SHOWN.maxdict = 3, 6, 6, 6
_SHOWN.maxstring, _SHOWN.maxother, _SHOWN.maxlong = 80, 80, 40


def shown(value: object) -> str:
    """A short ``repr`` of a bad value for an error message: nested containers cut at three levels and six items
    (``[1.0, 1.0, 1.0, 1.0, 1.0, 1.0, ...] (200000 items)``); never recursive, so any nesting depth is fine."""
    text = _SHOWN.repr(value)
    if isinstance(value, (list, tuple, dict)) and len(value) > 6:
        text += f" ({len(value)} items)"
    return text


class HqpTpmError(Exception):
    """Root of every error raised by hqp-tpm on bad input or impossible requests (messages are capped at
    :data:`MAX_MESSAGE` characters: :func:`elide`)."""

    #: where a run that failed with this error left the steps before it (set by ``hqp-tpm run``; None: nowhere)
    partial_result: object | None = None

    def __init__(self, *args) -> None:
        if args and isinstance(args[0], str) and len(args[0]) > MAX_MESSAGE:
            args = (elide(args[0]), *args[1:])
        super().__init__(*args)


class ShapeError(HqpTpmError, ValueError):
    """An array has the wrong shape (e.g. J rows vs b, J columns vs n)."""


class NonFiniteError(HqpTpmError, ValueError):
    """An array holds NaN or inf where a finite value is required."""


class MagnitudeError(NonFiniteError):
    """Finite values too large for the solvers' arithmetic: the sum of squares of a level's rows (their norm, from
    which the rank tolerances come) overflows float64 (entries beyond about 1e154)."""


class UnknownNameError(HqpTpmError, LookupError):
    """A name (frame, joint, task type, solver, scenario) is not among the valid ones."""

    def __str__(self) -> str:  # LookupError/KeyError would repr() the message
        return str(self.args[0]) if self.args else ""


class UnknownFrameError(UnknownNameError):
    """A frame name is not in the robot model."""


class RobotFileError(HqpTpmError, FileNotFoundError):
    """A robot description (URDF, mesh folder, SRDF) cannot be found or read."""


class SolverNotAvailableError(HqpTpmError):
    """A QP backend is unknown to qpsolvers or not installed."""


class ExtraNotInstalledError(HqpTpmError, ImportError):
    """A feature of an optional extra (e.g. figures and replays: ``pip install 'hqp-tpm[app]'``) is not installed."""


class SolverFailedError(HqpTpmError):
    """A numerical solver did not return a solution."""


class SolverBudgetError(SolverFailedError):
    """A solver spent more than its time budget on one level (the message names the level)."""


class BoxError(HqpTpmError, ValueError):
    """A box (lower, upper) is malformed: lower > upper, wrong length, NaN bounds."""


class GeometryError(HqpTpmError, ValueError):
    """A geometric parameter is invalid: negative radius or surveillance distance, degenerate mesh, ..."""


class ScenarioError(HqpTpmError, ValueError):
    """A scenario file is malformed: unknown task type, missing field, wrong dimension."""


class ParameterError(HqpTpmError, ValueError):
    """A parameter value is invalid: a negative gain, ``eps1 >= eps2``, a NaN damping, a bad order."""


class ArgumentTypeError(ParameterError, TypeError):
    """An argument of the wrong kind: a task name or a matrix where a Task is expected, a number as a policy."""


class StateError(HqpTpmError, RuntimeError):
    """An object is used in a state that does not allow the call (e.g. a task before its pair is assigned)."""


class DivergedError(HqpTpmError, RuntimeError):
    """A run's joint velocity left the scenario's ``velocity_bound``: the run stops there (naming the step, the joint
    and the value), the steps before it kept as a partial result."""


class SweepError(HqpTpmError, ValueError):
    """A sweep or campaign is ill-defined: a field path that resolves nowhere, a bad range, an unknown executor."""


class OutputError(HqpTpmError, OSError):
    """An output location cannot be used: a file where a folder is needed, a read-only folder, or a
    non-empty folder that is not a previous result of hqp-tpm (``--force`` to use it anyway)."""


class ResultFolderError(HqpTpmError, FileNotFoundError):
    """A folder given as a previous result (``hqp-tpm explain RUN_DIR``) is missing or holds no usable result."""


class PlantError(HqpTpmError, RuntimeError):
    """A physics plant cannot be built or used: MuJoCo is not installed, the robot's model file cannot be made
    into a MuJoCo model, or its joints do not match the controller's model."""


def unknown_name(kind: str, name: object, valid, cls=UnknownNameError) -> UnknownNameError:
    """Build an error naming the bad ``name`` and listing the ``valid`` choices."""
    choices = ", ".join(repr(v) for v in sorted(map(str, valid)))
    return cls(f"unknown {kind} {name!r}; valid {kind}s are: {choices}")


class InfeasibleError(SolverFailedError):
    """Hard constraints that no command meets. ``conflict`` holds the labels of an irreducible
    infeasible subset of them (e.g. ``"box upper of joint 2 (0.5)"``, ``"level 'top' row 0 (= 1)"``),
    found by a small LP certificate (:func:`hqp_tpm.solvers.account.check_feasible`)."""

    def __init__(self, message: str, conflict=()):
        super().__init__(message)
        self.conflict = tuple(conflict)


class EmptyBoxError(InfeasibleError, BoxError):
    """The hard box itself is empty (``lower > upper`` at some joint)."""
