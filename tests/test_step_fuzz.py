"""Randomized lock-step check: ``ctrl.step()`` (the compiled step, where the set-up has one) gives the numbers of the
readable step ``ctrl.step(record=True)`` on random stacks and policies, edited between steps.

Each case (``tests/step_fuzz_cases.py``: plain data drawn from a seed, by hypothesis or a seeded sweep) builds two
identical controllers on a real robot (iiwa, LWR, the planar 5-link arm, the free-floating Romeo and Talos) from a
random mix of the task classes (frame position on axis subsets, pose, orientation, quaternion orientation, CoM,
posture on joint subsets, joint limit, manipulability, pointing as equality or cone, avoidance assigned by a
policy's update, a user's own task class and a FramePosition subclass) with random gains and targets (constant,
relative, held, Harmonic, relative Harmonic), at velocity or acceleration level, with or without null-space damping,
with ``tpm``, ``nullspace``, ``sns_tpm`` and ``sns`` (with and without a JointLimits box, command-rate boxes
included) or the cascaded QP, damped or not, as a fixed stack, a stack policy (switching stacks, blending) or a
planning policy (extra commands). One controller is stepped by ``step()``, the other by ``step(record=True)``;
between steps both get the same events: targets assigned (every target form), trajectories swapped (Harmonic, a
Harmonic subclass, Line, relative constants, a user's in-place trajectory), a Harmonic's or Constant's fields
reassigned, trajectories started again, gains replaced, levels added, removed or replaced, the policy, the solver or
the box replaced, damping settings changed, the state set, ``compute()``, both controllers deep-copied, and faults
(a NaN, infinite or too large reference; a task whose Jacobian turns NaN) after which both must raise the same typed
error with the same words and keep their state.

At every step: the commands, ``q``, ``v``, ``t`` and the step counts agree to the documented tolerance
(docs/guarantees.md: bit for bit for a fixed stack at velocity level without a rotation error, else 1e-12 of
``max(1, |x|)``; the cascaded QP 1e-9), and so do the StepResult fields computed on demand (label, levels, info, x0,
box), read at once or after the next step (and after the events that follow it). After a step that is not bit-equal
the compiled controller takes the readable one's state (``set_state``), so that each step is compared from the same
state. Where the rows agree to 1e-12 but not to the bit, a discontinuous solver may amplify their last bits: an SNS
tie orders or chooses saturations otherwise (the same command), or flips a decision (:func:`sensitive_solve`: then
each step's command must be the solver's own answer to its own rows). A diverged state ends a case.
"""

from __future__ import annotations

import copy
import os

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from step_fuzz_cases import (
    EVENTS,
    POLICY_KINDS,
    Case,
    Glitch,
    InPlace,
    JointSum,
    ScheduledStacks,
    ShiftedHarmonic,
    build,
    draw_case,
    make_task,
)

from hqp_tpm import (
    Constant,
    FixedStack,
    Gains,
    Harmonic,
    HqpTpmError,
    JointLimits,
    Line,
    NonFiniteError,
    Pointing,
    Stack,
    StackPolicy,
    Trajectory,
)
from hqp_tpm.control.command_rate import solve_around
from hqp_tpm.solvers.registry import solve

#: docs/guarantees.md: a compiled step within 1e-12 of the readable one (relative to max(1, |x|)); the QP 1e-9.
TOL, QP_TOL = 1e-12, 1e-9
ROTATION_KINDS = ("FramePose", "FrameOrientation")


def close(a, b, tol, what):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, (what, a.shape, b.shape)
    fin = np.isfinite(b)
    np.testing.assert_array_equal(np.isfinite(a), fin, err_msg=what)
    np.testing.assert_array_equal(a[~fin], b[~fin], err_msg=what)  # (a box's infinities)
    scale = max(1.0, float(np.abs(b[fin]).max(initial=0.0)))
    err = float(np.abs(a[fin] - b[fin]).max(initial=0.0))
    assert err <= tol * scale, f"{what}: {err:.3g} > {tol:g} * {scale:.3g}\n{a}\n{b}"


def same_fields(res, want, label, tol, solver, info=True):
    """A compiled step's result (fields computed on demand) against the readable step's record (``label``: its
    stack's label at the step, None: not compared, the readable record's stack is the policy's own object, which
    later edits changed; ``info``: compare the solver's info)."""
    assert res.t == want.t
    assert label is None or res.label() == label, (res.label(), label)
    lv, lw = res.levels, want.levels
    assert [x.name for x in lv] == [x.name for x in lw], ([x.name for x in lv], [x.name for x in lw])
    for a, b in zip(lv, lw, strict=True):
        close(a.J, b.J, tol, f"{b.name}.J")
        for part in ("b", "lower", "upper"):
            if getattr(b, part) is None:
                assert getattr(a, part) is None, (b.name, part)
            else:
                close(getattr(a, part), getattr(b, part), tol, f"{b.name}.{part}")
        np.testing.assert_array_equal(a.active_rows(), b.active_rows(), err_msg=b.name)
    for part in ("x0",):
        a, b = getattr(res, part), getattr(want, part)
        assert (a is None) == (b is None), part
        if b is not None:
            close(a, b, tol, part)
    if want.box is None:
        assert res.box is None
    else:
        close(res.box[0], want.box[0], tol, "box.lower")
        close(res.box[1], want.box[1], tol, "box.upper")
    if info and not solver.startswith("qp"):
        info, winfo = res.info, want.info
        assert set(info) == set(winfo), (info, winfo)
        for key, value in winfo.items():
            if key in ("scale", "scales") and not np.allclose(info[key], value, rtol=0.0, atol=tol):
                assert not rows_equal(res, want), (key, info[key], value)  # (at a tie: below)
            elif key in ("scale", "scales"):
                pass
            elif key in ("saturated", "iterations") and info[key] != value:
                # rows that are not bit-equal (a rotation error, order 2, a compiled row writer): at a tie (joints
                # that saturate at the same scale, the two legs of Romeo; a joint whose command is at its bound to
                # the last bits) the loop saturates them in another order or not at all, with the same command
                assert not rows_equal(res, want), (key, info[key], value)
            else:
                assert info[key] == value, (key, info[key], value)


# -- events ---------------------------------------------------------------------------------------------------------
def _rng(seed):
    return np.random.default_rng(seed)


def _levels_of(ctrl):
    """The level list an edit changes (the fixed stack's, the first stack's or the first plan's)."""
    policy = ctrl.policy
    if type(policy) is FixedStack:
        return policy.stack.levels
    if type(policy) is ScheduledStacks:
        return policy.stacks[0].levels
    return None


def apply_event(event, ctrl, tasks, case):
    """Apply ``event`` to ``ctrl`` (its tasks ``tasks``); returns an undo to run after the next step, or None."""
    kind = event[0]
    rob = ctrl.robot
    if kind in ("target", "trajectory", "harmonic_edit", "restart"):
        task, rng = tasks[event[1]], _rng(event[2])
        name = type(task).__name__
        if name == "Pointing":  # (its reference stays cos(alpha_d): its level, not its targets, is fuzzed)
            return None
        x_d = task.reference(ctrl.t)[0]
        if kind == "target":
            if name == "Posture" and rng.random() < 0.3:  # a whole configuration (its joints' angles read)
                q = ctrl.q.copy()
                q[task.angles.idx] = x_d + rng.normal(0.0, 0.03, task.dim)
                task.target = q
            elif name in ("FramePosition", "CenterOfMass", "Posture", "OffsetPosition"):
                task.target = x_d + rng.normal(0.0, 0.03, task.dim)
            elif name == "FramePose":
                M = task.target
                M = pin.SE3(pin.exp3(rng.normal(0.0, 0.1, 3)) @ M.rotation, M.translation + rng.normal(0.0, 0.03, 3))
                form = rng.integers(3)  # (the target forms: SE3, 4 x 4 matrix, (position, rotation))
                task.target = M if form == 0 else M.homogeneous if form == 1 else (M.translation, M.rotation)
            elif name == "FrameOrientation":
                task.target = pin.exp3(rng.normal(0.0, 0.1, 3)) @ task.target
            elif name in ("JointLimit", "Manipulability", "JointSum"):
                task.trajectory = Constant(value=x_d + rng.normal(0.0, 0.02, task.dim))
        elif kind == "trajectory":
            if name in ("Avoidance", "Pointing", "QuaternionOrientation", "JointLimit"):
                return None
            d = task.dim
            traj = Harmonic(center=(x_d if name not in ROTATION_KINDS else np.zeros(d)) + rng.normal(0, 0.02, d),
                            cos_amplitude=rng.normal(0, 0.03, d), sin_amplitude=rng.normal(0, 0.03, d),
                            omega=float(rng.uniform(1, 5)), phase=float(rng.uniform(-1, 1)))
            which = rng.integers(5)
            if which == 0 and name not in ROTATION_KINDS:  # a user's trajectories
                traj = InPlace(x_d + rng.normal(0, 0.02, d), rng.normal(0, 0.03, d))
            elif which == 1:
                traj = ShiftedHarmonic(center=traj.center, cos_amplitude=traj.cos_amplitude,
                                       sin_amplitude=traj.sin_amplitude, omega=traj.omega)
            elif which == 2 and name not in ROTATION_KINDS:  # a relative constant, started (else refused)
                traj = Constant(value=rng.normal(0, 0.02, d), relative=True)
                traj.start(x_d)
            elif which == 3 and name not in ROTATION_KINDS:  # a straight line from the reference, starting now
                traj = Line(start_point=x_d, end_point=x_d + rng.normal(0, 0.05, d), v_max=0.5, a_max=20.0,
                            t_start=ctrl.t)
            if rng.random() < 0.5 and name in ("FramePosition", "CenterOfMass", "Posture", "OffsetPosition"):
                task.target = traj
            else:
                task.trajectory = traj if name not in ROTATION_KINDS or rng.random() < 0.5 else \
                    Constant(value=np.zeros(d))
        elif kind == "restart":  # the trajectory started again from a new value (relative ones move)
            if name not in ("Avoidance",):
                task.trajectory.start(x_d + rng.normal(0.0, 0.02, x_d.size) if x_d.size else x_d)
        else:
            traj = task.trajectory
            if type(traj) is Constant and traj.value.size:
                traj.value = traj.value + rng.normal(0.0, 0.02, traj.value.size)
            if type(traj) is Harmonic:
                what = rng.integers(4)
                if what == 0:
                    traj.center = traj.center + rng.normal(0.0, 0.02, traj.center.size)
                elif what == 1:
                    traj.omega = float(rng.uniform(0.5, 4.0))
                elif what == 2:
                    traj.phase = float(rng.uniform(-2.0, 2.0))
                else:
                    traj.sin_amplitude = rng.normal(0.0, 0.03, traj.center.size)
        return None
    if kind == "gains":
        tasks[event[1]].gains = Gains(*event[2])
        return None
    if kind in ("add_level", "replace_level", "remove_level"):
        levels = _levels_of(ctrl)
        if kind != "remove_level":
            recipe = event[1]
            task = tasks.get(recipe[1]) or make_task(recipe, rob)
            tasks[task.name] = task
            if any(task in lv for lv in (levels or [])) or any(task in p for p in
                                                               getattr(ctrl.policy, "plans", ())):
                return None
        if levels is None:  # a planning policy: its first plan edited
            plans = ctrl.policy.plans
            p = list(plans[0])
            if kind == "add_level":
                p.insert(event[2] % (len(p) + 1), task)
            elif kind == "replace_level":
                p[event[2] % len(p)] = task
            elif len(p) > 1:
                del p[event[1] % len(p)]
            plans[0] = tuple(p)
            if kind != "remove_level":
                ctrl.policy._tasks.append(task)
            return None
        if kind == "add_level":
            levels.insert(event[2] % (len(levels) + 1), (task,))
        elif kind == "replace_level":
            levels[event[2] % len(levels)] = (task,)
        elif len(levels) > 1:
            del levels[event[1] % len(levels)]
        if type(ctrl.policy) is ScheduledStacks and kind != "remove_level":
            ctrl.policy._tasks.append(task)
        return None
    if kind == "replace_policy":
        policy = ctrl.policy
        if type(policy) is FixedStack:
            levels = list(policy.stack.levels)
        elif type(policy) is ScheduledStacks:
            levels = list(policy.stacks[0].levels)
        else:
            levels = [(t,) for t in policy.plans[0]]
        if any(type(t).__name__ == "Avoidance" for lv in levels for t in lv):
            return None  # (assigned by the policy's update only)
        perm = _rng(event[1]).permutation(len(levels))
        ctrl.policy = Stack([levels[i] for i in perm])
        return None
    if kind == "settings":
        ctrl.lambda_max, ctrl.eps = (event[1], event[2]) if event[1] and event[2] else (0.0, 0.0)
        if ctrl.order == 2:
            ctrl.nullspace_damping = event[3]
        return None
    if kind == "set_state":
        q = pin.integrate(rob.model, ctrl.q, np.array(event[1]))
        v = ctrl.v + np.array(event[2]) if ctrl.order == 2 else ctrl.v
        if event[1][0] > 0:
            ctrl.set_state(q, v)
        else:  # (the property setters)
            ctrl.q, ctrl.v = q, v
        return None
    if kind == "solver":
        if ctrl.box is None or event[1] in ("sns_tpm", "sns"):
            ctrl.solver = event[1]
        return None
    if kind == "box":
        ctrl.box = None if event[1] is None else JointLimits(rob, order=ctrl.order, dt=ctrl.dt, **event[1])
        return None
    if kind == "glitch":
        task = tasks[event[1]]
        old = task.trajectory
        task.trajectory = Glitch(old, event[2])

        def undo():
            task.trajectory = old
        return undo
    if kind == "bad_rows":
        bad = [t for t in tasks.values() if type(t) is JointSum]
        for t in bad:
            t.bad = True

        def undo_rows():
            for t in bad:
                t.bad = False
        return undo_rows
    return None


def exact_step(ctrl, case) -> bool:
    """Whether docs/guarantees.md states bit equality for this step: a fixed stack at velocity level whose tasks
    have no rotation error, solved by an analytic or SNS solver."""
    policy = ctrl.policy
    return (type(policy) is FixedStack and ctrl.order == 1 and not ctrl.solver.startswith("qp")
            and not any(type(t).__name__ in ROTATION_KINDS for t in policy.stack.tasks()))


#: The events that change a stack's levels in place; the faults (undone after the step).
STRUCTURE = ("add_level", "remove_level", "replace_level")
FAULTS = ("glitch", "bad_rows")
#: A state beyond these (rad, rad/s) has diverged (an undamped singular stack at acceleration level): the case ends
#: there (the rows' terms grow as v^2 and cancel; their rounding is no longer relative to the rows).
DIVERGED = 50.0
#: A blended command from rows that agree to TOL but not to the bit: beyond the main solve's difference, the
#: rounding of the blend's other solves amplified.
BLENDED = 1e-9


def rows_equal(res, want) -> bool:
    """Whether the two results' levels are equal to the bit."""
    return all(np.array_equal(a.J, b.J) and all(np.array_equal(getattr(a, p), getattr(b, p))
                                                for p in ("b", "lower", "upper"))
               for a, b in zip(res.levels, want.levels, strict=True))


def solve_like(ctrl, res, v):
    """The command ``ctrl``'s solver gives on ``res``'s levels, as the readable step solves them from velocity ``v``."""
    if ctrl.box is not None and ctrl.order == 1 and ctrl.box.command_rate:
        return solve_around(ctrl.solver, res.levels, ctrl.robot.nv, v, res.box, lambda_max=ctrl.lambda_max,
                            eps=ctrl.eps)[0]
    return solve(ctrl.solver, res.levels, ctrl.robot.nv, x0=res.x0, box=res.box, lambda_max=ctrl.lambda_max,
                 eps=ctrl.eps)[0]


def sensitive_solve(res, want, ref, v, tol, stats) -> bool:
    """Whether the commands of one step differ beyond ``tol`` because the solver is discontinuous at the step's rows:
    the rows (levels) of both agree to ``tol`` but are not bit-equal, and the compiled command is the solver's own
    answer to its rows (an SNS saturation decision at a tie flips with the rows' last bits; docs/guarantees.md
    leaves such draws out). Checked where the step is one solve of its levels (no blend, no command-rate box)."""
    scale = max(1.0, np.abs(want.command).max())
    diff = np.abs(res.command - want.command).max()
    if diff <= tol * scale:
        return False
    same_fields(res, want, want.label(), tol, ref.solver, info=False)  # the rows agree to the tolerance...
    if rows_equal(res, want):
        return False  # ...and are not bit-equal (equal rows, different commands: a real difference)
    xc, xr = solve_like(ref, res, v), solve_like(ref, want, v)
    if ref.policy.blends:  # (1 - w) x + w x_other, clipped: x_other from both steps' readable calls, the same
        bound = (1.0 - ref.policy.weight) * np.abs(xc - xr).max() + BLENDED * scale
        assert diff <= bound, f"blended command: {diff:.3g} > {bound:.3g}"
        if stats is not None:
            stats["sensitive"] = stats.get("sensitive", 0) + 1
        return True
    close(xc, res.command, tol, "the solver on the compiled step's rows")
    close(xr, want.command, tol, "the solver on the readable step's rows")
    if stats is not None:
        stats["sensitive"] = stats.get("sensitive", 0) + 1
    return True


def same_words(err, want) -> bool:
    """The same error message (a blend's other solve included: both name the step, ``(step at t = ...)``)."""
    if err is None or want is None:
        return err is want
    return str(err) == str(want)


def attempt(fn):
    try:
        return fn(), None
    except HqpTpmError as exc:
        return None, exc


def run_case(case: Case, stats: dict | None = None) -> None:
    lockstep(build(case), build(case), case.events, case.steps, case, stats)


def lockstep(fast_pair, ref_pair, events: dict, steps: int, case, stats: dict | None = None) -> None:
    """Step ``fast`` by ``step()`` and ``ref`` by ``step(record=True)`` (each with its tasks by name) ``steps``
    times, ``events[k]`` applied to both before step ``k``, and compare them (module doc)."""
    (fast, fast_tasks), (ref, ref_tasks) = fast_pair, ref_pair
    tol = QP_TOL if ref.solver.startswith("qp") else TOL
    late = None  # a compiled step's result whose fields are read after the next step
    for k in range(steps):
        undo = []
        compute = mix = False
        if late is not None and any(e[0] in STRUCTURE for e in events.get(k, [])):
            late = (late[0], late[1], None)  # (a readable record's stack is the live one: its label changed)
        for event in sorted(events.get(k, []), key=lambda e: e[0] in FAULTS):  # (faults last: the
            if event[0] == "compute":                                               # others read references)
                compute = True
                continue
            if event[0] == "mix":  # the compiled controller takes this step by the readable path
                mix = True
                continue
            if event[0] == "copy":  # both controllers go on as deep copies (a copy plans its own compiled step)
                (fast, fast_tasks), (ref, ref_tasks) = copy.deepcopy((fast, fast_tasks)), copy.deepcopy((ref,
                                                                                                          ref_tasks))
                continue
            for ctrl, tasks in ((ref, ref_tasks), (fast, fast_tasks)):
                u = apply_event(event, ctrl, tasks, case)
                if u is not None:
                    undo.append(u)
        if compute:
            xf, ef = attempt(fast.compute)
            xr, er = attempt(lambda ref=ref: ref.compute(record=True))
            assert type(ef) is type(er) and same_words(ef, er), (k, ef, er)
            if er is None and not sensitive_solve(xf, xr, ref, ref.v, tol, stats):
                close(xf.command, xr.command, tol, f"compute at step {k}")
                same_fields(xf, xr, xr.label(), tol, ref.solver)
        before = [(c.q, c.v, c.t, c.steps) for c in (fast, ref)]
        exact = exact_step(ref, case)
        res, err = attempt(fast.step if not mix else lambda fast=fast: fast.step(record=True))
        want, werr = attempt(lambda ref=ref: ref.step(record=True))
        for u in reversed(undo):
            u()
        assert type(err) is type(werr), f"step {k}: compiled {err!r}, readable {werr!r}"
        assert same_words(err, werr), f"step {k}: compiled {err!r}, readable {werr!r}"
        if werr is not None:  # a failed step changed nothing, on both paths
            for c, (q, v, t, steps) in zip((fast, ref), before, strict=True):
                np.testing.assert_array_equal(c.q, q)
                np.testing.assert_array_equal(c.v, v)
                assert c.t == t and c.steps == steps
            if stats is not None:
                stats["errors"] = stats.get("errors", 0) + 1
            continue
        assert fast.t == ref.t and fast.steps == ref.steps
        if exact:
            np.testing.assert_array_equal(res.command, want.command, err_msg=f"step {k} (bit for bit)")
            np.testing.assert_array_equal(fast.q, ref.q, err_msg=f"step {k} q")
            np.testing.assert_array_equal(fast.v, ref.v, err_msg=f"step {k} v")
        sensitive = not exact and sensitive_solve(res, want, ref, before[1][1], tol, stats)
        if not exact and not sensitive:
            close(res.command, want.command, tol, f"step {k} command")
            close(fast.q, ref.q, tol, f"step {k} q")
            close(fast.v, ref.v, tol, f"step {k} v")
        if late is not None:
            same_fields(*late, tol, ref.solver)
            late = None
        if sensitive:
            pass  # (the fields but the solver's info compared there)
        elif k % 2:
            late = (res, want, want.label())
        else:
            same_fields(res, want, want.label(), tol, ref.solver)
        if stats is not None:
            stats["steps"] = stats.get("steps", 0) + 1
            stats["compiled"] = stats.get("compiled", 0) + fast.compiled()
            stats["exact"] = stats.get("exact", 0) + exact
        if not (np.array_equal(fast.q, ref.q) and np.array_equal(fast.v, ref.v)):
            fast.set_state(ref.q, ref.v)  # (each step compared from the same state)
        if max(np.abs(ref.q).max(), np.abs(ref.v).max()) > DIVERGED:
            if stats is not None:
                stats["diverged"] = stats.get("diverged", 0) + 1
            break
    if late is not None:
        same_fields(*late, tol, ref.solver)


ROBOTS = ("iiwa7", "lwr4", "planar5", "romeo21")
SOLVERS = ("tpm", "tpm", "sns_tpm", "sns_tpm", "nullspace", "sns", "qp:daqp")


@st.composite
def cases(draw):
    """A case: its structure drawn by hypothesis (shrinking to fewer levels, steps and events), its numbers from a
    drawn seed."""
    name = draw(st.sampled_from(ROBOTS))
    policy = draw(st.sampled_from(("fixed", "fixed", "stacks", "plan")))
    solver = draw(st.sampled_from(SOLVERS if policy == "fixed" else ("tpm", "sns_tpm")))
    order = draw(st.sampled_from((1, 2)))
    n_levels = draw(st.integers(1, 5))
    steps = draw(st.integers(2, 6 if name == "romeo21" else 14))
    n_events = draw(st.integers(0, 6))
    seed = draw(st.integers(0, 2**32 - 1))
    return draw_case(np.random.default_rng(seed), name, order, solver, policy, n_levels, steps, n_events)


def seeded_case(seed: int, robot_name: str | None = None) -> Case:
    """Case ``seed`` of the seeded sweep: structure and numbers from one generator (``robot_name``: on that robot)."""
    r = np.random.default_rng(seed)
    name = ROBOTS[r.integers(len(ROBOTS))]
    name = robot_name or name
    policy = ("fixed", "fixed", "stacks", "plan")[r.integers(4)]
    solvers = SOLVERS if policy == "fixed" else ("tpm", "sns_tpm")
    solver = solvers[r.integers(len(solvers))]
    order = int(r.integers(1, 3))
    return draw_case(r, name, order, solver, policy, int(r.integers(1, 6)),
                     int(r.integers(2, 7 if name in ("romeo21", "talos") else 15)), int(r.integers(0, 7)))


def checked(case: Case, stats: dict | None = None) -> None:
    try:
        run_case(case, stats)
    except AssertionError as exc:
        raise AssertionError(f"{case.describe()}\n{exc}") from exc


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(cases())
def test_compiled_step_equals_the_readable_step(case):
    checked(case)


#: The seeded sweep's cases (``HQP_TPM_FUZZ_CASES`` sets the count: a long hunt).
SWEEP = int(os.environ.get("HQP_TPM_FUZZ_CASES", "1000"))


def test_seeded_sweep_equals_and_covers_the_mix():
    """The same check on ``SWEEP`` seeded cases, which must cover what the test is for: steps that ran compiled
    (most of them), bit-equal steps, failed steps (both paths raising the same typed error), every event kind, every
    task kind, solver and policy."""
    stats: dict = {}
    seen: set = set()
    for seed in range(SWEEP):
        case = seeded_case(seed)
        seen |= {case.solver, case.policy, case.robot, f"order{case.order}"}
        seen |= {r[0] for lv in case.levels for r in lv}
        seen |= {e[0] for events in case.events.values() for e in events}
        try:
            checked(case, stats)
        except AssertionError as exc:
            raise AssertionError(f"seeded case {seed}: {exc}") from exc
    if SWEEP < 1000:
        return
    assert stats["compiled"] >= 0.7 * stats["steps"], stats
    assert stats["exact"] >= 0.05 * stats["steps"] and stats["errors"] >= 0.02 * stats["steps"], stats
    want = {*SOLVERS, "fixed", "stacks", "plan", *ROBOTS, "order1", "order2", *EVENTS, *POLICY_KINDS}
    assert want <= seen, want - seen


def test_seeded_cases_on_talos():
    """A few cases on Talos (38 joints, a floating base, the grippers' mimic joints)."""
    for seed in range(40):
        checked(seeded_case(seed, "talos"))


# -- what the fuzzing found, reduced ----------------------------------------------------------------------------------
def test_an_inactive_cone_keeps_its_level_in_a_planned_steps_record():
    """A stack policy's level with a pointing cone whose axis is inside the cone (inactive, e <= 0): the planned
    step's ``levels`` hold the cone's inactive row as the readable step's do (on the old code its level was left
    out: ``['post']`` against ``['post+cone']``, and a cone alone in a level lost its level)."""
    from hqp_tpm import Controller, Pointing, Posture, Robot, State

    rob = Robot.load("iiwa7")
    q0 = np.linspace(-0.5, 0.5, 7)
    z = State(rob).update(q0, np.zeros(7)).rotation(rob.frame_id("iiwa_ee"))[:, 2]
    for order in (1, 2):
        for alone in (False, True):
            def make(alone=alone, order=order):
                post, cone = Posture(rob, None, name="post"), Pointing(rob, "iiwa_ee", z, 0.5, name="cone")
                stack = Stack.of(post, cone) if alone else Stack.of((post, cone))
                return Controller(rob, _OneStack(stack), order=order, q0=q0, v0=np.full(7, 0.1) if order == 2 else None)
            fast, ref = make(), make()
            assert fast.compiled()
            for _ in range(3):
                res, want = fast.step(), ref.step(record=True)
                close(res.command, want.command, TOL, "command")
                same_fields(res, want, want.label(), TOL, "tpm")
                assert not want.levels[-1].active_rows()[-1]  # (the cone is inactive)


def test_a_compiled_steps_result_keeps_its_x0_and_box():
    """``StepResult.x0`` and ``.box`` of a compiled step, computed when first read, are those of the step (the
    damping and box it was planned with), as the readable record's: on the old code they were computed from the
    controller's settings at the time of reading (x0 -0.3 for -1.5 after ``nullspace_damping = 1``, box 1 for 50)."""
    from hqp_tpm import Controller, FramePosition, JointLimits, Posture, Robot

    rob = Robot.load("iiwa7")
    for policy in ("fixed", "stacks"):
        def make(policy=policy):
            stack = Stack.of(FramePosition(rob, "iiwa_ee", [0.4, 0.1, 0.6]), Posture(rob))
            return Controller(rob, stack if policy == "fixed" else ScheduledStacks(rob, [stack], 1.0), order=2,
                              solver="sns_tpm", nullspace_damping=5.0, box=JointLimits(rob, order=2, dt=1e-3),
                              q0=np.linspace(-0.5, 0.5, 7), v0=np.full(7, 0.3))
        fast, ref = make(), make()
        assert fast.compiled()
        res, want = fast.step(), ref.step(record=True)
        for c in (fast, ref):  # settings changed after the step, before its fields are read
            c.nullspace_damping = 1.0
            c.box = JointLimits(rob, order=2, dt=1e-3, acceleration_limit=1.0)
        same_fields(res, want, want.label(), TOL, "sns_tpm")
        np.testing.assert_array_equal(res.x0, want.x0)
        np.testing.assert_array_equal(res.box[1], want.box[1])


class _OneStack(StackPolicy):
    """A stack policy that returns one stack (the planned step's)."""

    def __init__(self, stack):
        self.stack = stack

    def tasks(self):
        return self.stack.tasks()

    def __call__(self, state, t):
        return self.stack


def _cone_pair(reference):
    """Two iiwa controllers (compiled, readable) with a pointing cone above a posture in a stack policy, the cone's
    axis 6 degrees from the EE's z axis (inside its 0.5 rad cone: inactive by ``alpha_d``), the cone's reference
    replaced by ``reference``."""
    from hqp_tpm import Controller, Pointing, Posture, Robot, State

    rob = Robot.load("iiwa7")
    q0 = np.linspace(-0.5, 0.5, 7)
    z = State(rob).update(q0, np.zeros(7)).rotation(rob.frame_id("iiwa_ee"))[:, 2]
    axis = 0.9 * z + 0.1 * np.array([1.0, 0.0, 0.0])

    def make():
        cone = Pointing(rob, "iiwa_ee", axis, 0.5, name="cone")
        cone.trajectory = reference
        return Controller(rob, _OneStack(Stack.of(cone, Posture(rob, None, name="post"))), order=1, q0=q0)
    return make(), make()


def test_a_cone_with_another_reference_is_active_alike():
    """A pointing cone whose reference is not ``cos(alpha_d)`` (here 0.999, a narrower cone): the readable step
    keeps the cone inactive (``pointing_error`` from ``alpha_d``) and gives a zero command, and so does the planned
    step (on 82bfea4 it made the cone active from its row writer's ``e``, the reference's, and moved the arm)."""
    fast, ref = _cone_pair(Constant(value=np.array([0.999])))
    res, want = fast.step(), ref.step(record=True)
    close(res.command, want.command, TOL, "command")


class _NaNReference(Trajectory):
    def reference(self, t):
        return np.array([np.nan]), np.zeros(1), np.zeros(1)


def test_a_cone_with_a_nan_reference_fails_alike():
    """A NaN reference on a pointing cone: the readable step raises NonFiniteError naming the level and keeps its
    state, and so does the planned step (on the old code its row writer's ``e`` was NaN, the cone taken as inactive
    and its row never tested: it stepped)."""
    fast, ref = _cone_pair(_NaNReference())
    with pytest.raises(NonFiniteError, match="cone"):
        ref.step(record=True)
    q = fast.q
    with pytest.raises(NonFiniteError, match="cone"):
        fast.step()
    assert fast.q is q


def test_a_copied_pointing_task_follows_its_state():
    """A deep-copied or unpickled controller with a pointing cone: its ``pointing_error`` (the cone's activity on
    the readable path, the policies' switching) follows the copy's state (on 82bfea4 it read the z column as it was
    when copied: -0.045 for +0.036 at ``q = 0.6``, the cone taken as inactive)."""
    import pickle

    from hqp_tpm import Controller, Posture, Robot

    rob = Robot.load("iiwa7")
    cone = Pointing(rob, "iiwa_ee", [0.0, 0.0, 1.0], 0.3, name="cone")
    ctrl = Controller(rob, Stack.of(cone, Posture(rob, None)), order=1, q0=np.linspace(-0.5, 0.5, 7))
    ctrl.step(record=True)
    for twin in (copy.deepcopy(ctrl), pickle.loads(pickle.dumps(ctrl))):
        task = twin.policy.stack.levels[0][0]
        st = twin.state.update(np.full(7, 0.6), np.zeros(7))
        assert task.pointing_error(st) == pytest.approx(task._cos - task.value(st)[0], abs=1e-12)


# -- the shipped policies, under events ---------------------------------------------------------------------------
#: The bundled scenarios whose policy has a compiled step (the planned step), at most 2 s of CPU to build.
POLICY_SCENARIOS = ("iiwa_admittance", "iiwa_comanipulation", "lwr_avoid3d", "lwr_point35_equality",
                    "lwr_point35_inequality", "lwr_relaxed", "lwr_velocity", "planar5_approximate", "planar5_dmp",
                    "planar5_exact", "planar5_primary", "planar5_transition", "planar5_two_obstacles",
                    "romeo_obstacles_sns_tpm")
SCENARIO_EVENTS = ("target", "trajectory", "harmonic_edit", "restart", "gains", "settings", "set_state", "compute",
                   "glitch", "copy")


def scenario_events(rng, ctrl, steps: int, count: int) -> dict:
    """``count`` events among :data:`SCENARIO_EVENTS` on ``ctrl``'s tasks (the policy keeps its own stacks)."""
    names = [t.name for t in ctrl.tasks() if type(t).__name__ in ("FramePosition", "CenterOfMass", "Posture",
                                                                   "FramePose", "FrameOrientation", "JointLimit",
                                                                   "Manipulability")]
    out: dict = {}
    for _ in range(count):
        kind = str(rng.choice(SCENARIO_EVENTS))
        if not names and kind in ("target", "trajectory", "harmonic_edit", "restart", "gains", "glitch"):
            kind = "compute"
        pick = str(rng.choice(names)) if names else ""
        if kind in ("target", "trajectory", "harmonic_edit", "restart"):
            event = (kind, pick, int(rng.integers(1 << 30)))
        elif kind == "gains":
            kp = float(rng.choice([1.0, 10.0, 50.0]))
            event = (kind, pick, (kp, 2.0 * np.sqrt(kp) if ctrl.order == 2 else 0.0))
        elif kind == "settings":
            event = (kind, float(rng.choice([0.0, 0.02, 0.05])), float(rng.choice([0.0, 0.05, 0.1])),
                     float(rng.choice([0.0, 3.0])))
        elif kind == "set_state":
            event = (kind, rng.normal(0.0, 0.02, ctrl.robot.nv).tolist(), rng.normal(0.0, 0.1, ctrl.robot.nv).tolist())
        elif kind == "glitch":
            event = (kind, pick, float(rng.choice([np.nan, np.inf, 1e160])))
        else:
            event = (kind,)
        out.setdefault(int(rng.integers(1, steps)), []).append(event)
    return out


@pytest.mark.parametrize("name", POLICY_SCENARIOS)
def test_shipped_policies_under_events(name):
    """Every shipped policy with a compiled step (Algorithm 1 with coal distances, the whole-body avoidance, the
    switching, admittance and papers/004 schemes), from its scenario's start moved by a random state, under random
    events: the compiled step gives the readable step's numbers (as :func:`lockstep` checks)."""
    from hqp_tpm.app.build import build as build_scenario
    from hqp_tpm.app.scenario import load

    def pair():
        ctrl = build_scenario(load(name))[1]
        return ctrl, {t.name: t for t in ctrl.tasks()}

    fast, ref = pair(), pair()
    assert fast[0].compiled()
    for seed in range(2):
        rng = np.random.default_rng(seed)
        c = fast[0]
        q = pin.integrate(c.robot.model, c.q, rng.normal(0.0, 0.05, c.robot.nv))
        v = c.v + (rng.normal(0.0, 0.1, c.robot.nv) if c.order == 2 else 0.0)
        for ctrl, _ in (fast, ref):
            ctrl.set_state(q, v)
        steps = 6 if name.startswith("romeo") else 15
        events = scenario_events(rng, c, steps, int(rng.integers(2, 6)))
        try:
            lockstep(fast, ref, events, steps, None)
        except AssertionError as exc:
            raise AssertionError(f"{name}, seed {seed}, events {events}:\n{exc}") from exc
