"""Task rows written once (issue 29 item 2): a task's rows come from its own ``jacobian``/``command`` and, for the
compiled steps, from its :meth:`~hqp_tpm.tasks.base.Task.row_source` read by one registration
(:mod:`hqp_tpm.control._task_rows`) and one kernel that writes ``b`` with :func:`~hqp_tpm.tasks.base.tracking_command`.

The planned step's kernel rows are compared with the task's own methods, to the last bit, with Harmonic and constant
references, relative ones started again, trajectories replaced mid-run and the extra command of Algorithm 1 (EE
repulsion (30)) added as :meth:`Task.command` adds it.
"""

import inspect
import pathlib
import re

import numpy as np
import pinocchio as pin
import pytest

import hqp_tpm
from hqp_tpm.control import _compiled_step
from hqp_tpm.control._task_rows import TaskProgram, described
from hqp_tpm.references.trajectories import Constant, Harmonic, harmonic_point
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import Gains, Task, tracking_command
from hqp_tpm.tasks.com import CenterOfMass
from hqp_tpm.tasks.frame_pose import FramePose
from hqp_tpm.tasks.frame_position import FramePosition
from hqp_tpm.tasks.posture import Posture

pytestmark = pytest.mark.skipif(not _compiled_step._compiled.AVAILABLE, reason="numba is not installed")


def _circle(relative=False):
    return Harmonic(center=np.array([0.1, 0.6, -0.2]), cos_amplitude=np.array([0.2, 0.0, 0.3]),
                    sin_amplitude=np.array([0.0, -0.1, 0.05]), omega=1.7, phase=0.3, relative=relative)


@pytest.mark.parametrize("order", [1, 2])
def test_task_programs_write_the_numbers_of_jacobian_and_command(order):
    """Frame positions (all axes, two axes), the CoM (velocity level) and a posture: the compiled rows equal
    ``jacobian`` and ``command`` at 200 random states and times, with and without an extra command, while their
    references change kind and numbers mid-run."""
    robot = Robot.load("iiwa7")
    n, rng = robot.nv, np.random.default_rng(order)
    tasks = [FramePosition(robot, "iiwa_ee", _circle(), Gains(7.0, 3.0)),
             FramePosition(robot, "iiwa_link_4", Harmonic(center=np.array([0.0, 0.1]),
                                                         cos_amplitude=np.array([0.2, 0.0]),
                                                         sin_amplitude=np.array([0.0, 0.3]), omega=2.0,
                                                         relative=True), Gains(3.0, 1.0), axes="zx"),
             Posture(robot, None, Gains(2.0, 1.0))]
    if order == 1:
        tasks.append(CenterOfMass(robot, [0.0, 0.1], Gains(4.0), axes="xy"))
    st, ref = State(robot), State(robot)
    st.update(robot.neutral(), np.zeros(n), 0.0)
    for task in tasks:
        task.start(st)
    bufs = [(np.full((t.dim, n), np.nan), np.full(t.dim, np.nan)) for t in tasks]
    programs = [TaskProgram.of(t, st, order, J, b) for t, (J, b) in zip(tasks, bufs, strict=True)]
    assert all(p is not None for p in programs)
    for i in range(200):
        q = robot.neutral() + rng.uniform(-2, 2, robot.nq)
        v = rng.normal(size=n) * rng.choice([1e-3, 1.0, 10.0])
        t = float(rng.uniform(0, 20))
        st.update(q, v, t)
        ref.update(q, v, t)
        if i == 60:  # numbers replaced, omega changed, the relative circle started again
            tasks[0].trajectory.center = np.array([0.3, 0.2, 0.1])
            tasks[0].trajectory.omega = 0.5
            tasks[1].start(ref)
        if i == 100:  # a constant reference in place of the Harmonic one, and back at 150
            tasks[0].target = [0.2, 0.4, 0.5]
        if i == 150:
            tasks[0].trajectory = _circle(relative=True)
            tasks[0].start(ref)
            tasks[2].target = rng.uniform(-1, 1, tasks[2].dim)
        for task, write, (J, b) in zip(tasks, programs, bufs, strict=True):
            extra = rng.normal(size=task.dim) if i % 2 and type(task) is not Posture else None
            write(t, extra)
            J_ref = task.jacobian(ref)
            np.testing.assert_array_equal(J, J_ref, err_msg=task.name)
            np.testing.assert_array_equal(b, task.command(ref, t, order, extra, J_ref), err_msg=f"{task.name} {i}")


def test_a_task_program_refuses_what_command_refuses():
    """An extra command of the wrong shape or not finite: the task's own ``command`` decides (the typed error naming
    the task), as on the readable path."""
    robot = Robot.load("iiwa7")
    task = FramePosition(robot, "iiwa_ee", [0.3, 0.2, 0.7], Gains(5.0), name="ee")
    st = State(robot)
    st.update(robot.neutral(), np.zeros(robot.nv), 0.0)
    J, b = np.zeros((3, robot.nv)), np.zeros(3)
    write = TaskProgram.of(task, st, 1, J, b)
    with pytest.raises(hqp_tpm.ShapeError, match="task 'ee': extra command has shape"):
        write(0.0, np.zeros(2))
    with pytest.raises(hqp_tpm.NonFiniteError, match="task 'ee': extra command holds non-finite"):
        write(0.0, [np.nan, 0.0, 0.0])


def test_a_subclass_that_changes_its_rows_is_not_described():
    """A subclass overriding a method the row source stands for (its ``jacobian``, say) gets no compiled rows: the
    steps call its own methods."""
    class Scaled(FramePosition):
        def jacobian(self, state):
            return 2.0 * super().jacobian(state)

    robot = Robot.load("iiwa7")
    assert described(FramePosition) and not described(Scaled) and not described(Task)
    st = State(robot)
    st.update(robot.neutral(), np.zeros(robot.nv), 0.0)
    assert TaskProgram.of(Scaled(robot, "iiwa_ee", [0.3, 0.2, 0.7]), st, 1, np.zeros((3, 7)), np.zeros(3)) is None
    # a pose (rotation error: log3 in the kernel, a few ulps from pinocchio's) stays with its own methods here
    pose = FramePose(robot, "iiwa_ee", pin.SE3.Identity())
    assert TaskProgram.of(pose, st, 1, np.zeros((6, 7)), np.zeros(6)) is None


def test_the_tracking_law_and_the_harmonic_reference_live_in_one_place():
    """``b = xd + kp e`` / ``xdd + kd (xd - J qd) + kp e - Jdot qd`` is written once (tasks/base.py); the kernels
    call it. Harmonic.reference's formula is written once (``harmonic_point``). On the old code the law was also in
    the fused kernel (twice), in robot/_compiled.py (rows1, rows2, feedback2) and in the Harmonic row writer."""
    law, root = re.compile(r"kd \* \(\s*xd"), pathlib.Path(hqp_tpm.__path__[0])
    where = [f.relative_to(root).as_posix() for f in root.rglob("*.py") if law.search(f.read_text())]
    assert where == ["tasks/base.py"], where
    assert inspect.getsource(tracking_command).count("kd * (xd - rate)") == 1
    t, (w, c) = 0.7, (1.7, 0.3)
    tr = Harmonic(center=np.array([0.1]), cos_amplitude=np.array([0.2]), sin_amplitude=np.array([0.05]), omega=w,
                  phase=c)
    x, xd, xdd = tr.reference(t)
    assert (x[0], xd[0], xdd[0]) == harmonic_point(0.1, 0.2, 0.05, w, np.cos(w * t + c), np.sin(w * t + c))
    assert type(Constant(value=np.zeros(2)).reference(0.0)[0]) is np.ndarray


def test_tasks_hold_no_step_machinery():
    """Tasks describe their rows (``row_source``) and know nothing of the compiled steps' programs: no
    ``row_writer``/``row_program`` on Task or on the frame, CoM and posture tasks."""
    for kind in (Task, FramePosition, FramePose, CenterOfMass, Posture):
        assert not {"row_writer", "row_program", "row_writer_takes_extra"} & set(dir(kind)), kind
