"""The contenders: the same problem in hqp-tpm, pink, PlaCo and TSID.

Every contender has ``setup(cfg)`` (targets and state of one configuration, not timed), ``step()``
(what a user's control step does: the state fed in, the targets assigned again -- they alternate between the
configuration's and :func:`~benchmarks.peers.problems.moved` ones, so they move every call --, kinematics, task
rows, solve; returns the joint velocity or acceleration in hqp-tpm's column order), ``rows_solve()`` (task rows and
solve at the state already fed, what PlaCo's ``solve`` does; ``None`` where the library cannot separate it) and
``solve()`` (the solver alone on the problem ``step`` built; ``None`` where not separable). Closed loops are in
:func:`circle_loop`: each library used natively, nothing of the harness timed (the peers' circle samples are
made before the loop).

Gains: pink's task gain is ``kp dt`` (its tasks drive ``J dq = -gain e`` per step of ``dt``).
PlaCo has no task gains (its tasks drive the whole error in one step), so its targets are set
``kp dt`` of the way from the current value to the problem's target (computed in ``setup``, not
timed); its displacement divided by ``dt`` is the velocity. TSID's tasks take kp, kd directly.
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import numpy as np
import pinocchio as pin

from benchmarks.peers import problems as P


def _hqp_cols(robot, names_q_v):
    """Index arrays mapping another model's (q, v) onto hqp-tpm's by joint name."""
    m = robot.model
    q_idx, v_idx = [], []
    for j in range(1, m.njoints):
        iq, iv = names_q_v[m.names[j]]
        q_idx += list(range(iq, iq + m.joints[j].nq))
        v_idx += list(range(iv, iv + m.joints[j].nv))
    return np.array(q_idx), np.array(v_idx)


# -- hqp-tpm ------------------------------------------------------------------------------------
class Hqp:
    """hqp-tpm through its public API, as a user runs it: ``step`` feeds the state (``ctrl.set_state``), assigns
    the targets (moved every call) and computes (``ctrl.compute()``); ``rows_solve`` is the task rows and the solve
    at the state already set (``Stack.to_levels`` + the solver: what PlaCo's ``solve`` does); ``solve`` the solver
    alone on the levels of the configuration."""

    def __init__(self, robot, problem, solver: str):
        from hqp_tpm.solvers import cascaded_qp, sns_tpm, tpm

        self.robot, self.problem, self.solver = robot, problem, solver
        self.name = f"hqp-tpm {solver}"
        self._tpm, self._sns, self._qp = tpm, sns_tpm, cascaded_qp

    def setup(self, cfg):
        tasks = P.hqp_tasks(self.robot, self.problem, cfg)
        self.tasks = {}
        for item in tasks:
            for task in item if isinstance(item, tuple) else (item,):
                self.tasks[task.name] = task
        self.ctrl = P.hqp_controller(self.robot, self.problem, cfg, self.solver, tasks=tasks)
        self.stack = self.ctrl.policy.stack
        self.q, self.v = cfg.q, cfg.v
        self.targets = (cfg.targets, P.moved(cfg.targets))
        self.k = 0
        res = self.ctrl.compute()
        self.levels = res.levels
        st = self.ctrl.state
        self.box = self.ctrl.box(st, self.ctrl.t) if self.ctrl.box is not None else None

    def step(self):
        self.k ^= 1
        P.assign_targets(self.tasks, self.targets[self.k])
        self.ctrl.set_state(self.q, self.v)
        return self.ctrl.compute().command

    def _solve(self, levels):
        nv, c = self.robot.nv, self.ctrl
        if self.solver == "tpm":
            return self._tpm(levels, n=nv, lambda_max=c.lambda_max, eps=c.eps)
        lo, up = self.box
        if self.solver == "sns_tpm":
            return self._sns(levels, lo, up, lambda_max=c.lambda_max, eps=c.eps)
        return self._qp(levels, solver=self.solver.split(":", 1)[1], lower=lo, upper=up, n=nv,
                        lambda_max=c.lambda_max, eps=c.eps)

    def rows_solve(self):
        c = self.ctrl
        return self._solve(self.stack.to_levels(c.state, c.t, c.order))

    def solve(self):
        return self._solve(self.levels)


# -- pink ---------------------------------------------------------------------------------------
class Pink:
    """pink: one weighted QP (daqp); ``limits``: pink's default configuration + velocity limits."""

    def __init__(self, robot, problem, limits: bool, hard_top: bool = False):
        import pink
        from pink.tasks import ComTask, FrameTask, PostureTask

        self.robot, self.problem, self.limits = robot, problem, (None if limits else [])
        self.name = ("pink, top as constraint" if hard_top else "pink") + (" + limits" if limits else "")
        model = robot.model
        self.conf = pink.Configuration(model, model.createData(), robot.neutral())
        dt = P.DT
        if problem.robot_name == P.IIWA:
            self.ee = FrameTask(P.IIWA_EE, position_cost=1.0, orientation_cost=1.0, gain=P.KP_EE * dt)
            self.posture = PostureTask(cost=1e-3, gain=P.KP_POSTURE * dt)
            self.tasks = [self.ee, self.posture]
        else:
            g = P.KP_ROMEO * dt
            self.frames = {"right_sole": FrameTask("r_sole", position_cost=100.0, orientation_cost=100.0, gain=g),
                           "left_foot": FrameTask("l_sole", position_cost=10.0, orientation_cost=0.0, gain=g),
                           "left_hand": FrameTask("l_gripper", position_cost=1.0, orientation_cost=0.0, gain=g),
                           "right_hand": FrameTask("r_gripper", position_cost=1.0, orientation_cost=0.0, gain=g)}
            self.com = ComTask(cost=np.array([10.0, 10.0, 0.0]), gain=g)
            self.posture = PostureTask(cost=1e-3, gain=P.KP_ROMEO_POSTURE * dt)
            self.tasks = [*self.frames.values(), self.com, self.posture]
        # hard_top: the top task as an equality constraint of the QP (pink's ``constraints``), the rest weighted
        self.constraints = [self.tasks.pop(0)] if hard_top else None
        self._build = pink.build_ik if hasattr(pink, "build_ik") else __import__("pink.solve_ik").solve_ik.build_ik
        self._solve_ik = pink.solve_ik
        import qpsolvers

        self._qp = qpsolvers.solve_problem

    def _targets(self, t, q):
        """pink's targets (task, value) of one target set ``t`` at configuration ``q``."""
        if self.problem.robot_name == P.IIWA:
            return [(self.ee, t["ee"]), (self.posture, t["posture"])]
        out = [(self.frames["right_sole"], t["right_sole"])]
        for key in ("left_foot", "left_hand", "right_hand"):
            cur = self.conf.get_transform_frame_to_world(self.frames[key].frame)
            out.append((self.frames[key], pin.SE3(cur.rotation, np.asarray(t[key]))))
        com = pin.centerOfMass(self.robot.model, self.robot.model.createData(), q)
        q_ref = q.copy()
        q_ref[7:] = t["posture"]
        return [*out, (self.com, np.array([t["com"][0], t["com"][1], com[2]])), (self.posture, q_ref)]

    def setup(self, cfg):
        self.q = cfg.q
        self.conf.update(cfg.q)
        self.targets = (self._targets(cfg.targets, cfg.q), self._targets(P.moved(cfg.targets), cfg.q))
        self.k = 0
        for task, value in self.targets[0]:
            task.set_target(value)
        self.problem_qp = self._build(self.conf, self.tasks, P.DT, limits=self.limits, constraints=self.constraints)

    def step(self):
        self.k ^= 1
        for task, value in self.targets[self.k]:
            task.set_target(value)
        self.conf.update(self.q)
        return self._solve_ik(self.conf, self.tasks, P.DT, solver="daqp", limits=self.limits,
                              constraints=self.constraints, safety_break=False)

    def rows_solve(self):
        return self._solve_ik(self.conf, self.tasks, P.DT, solver="daqp", limits=self.limits,
                              constraints=self.constraints, safety_break=False)

    def solve(self):
        return self._qp(self.problem_qp, solver="daqp").x / P.DT

    def own_residual(self, x):
        """Top task's residual in pink's own formulation, ``|J dq + gain e| / dt`` (velocity units)."""
        top = self.constraints[0] if self.constraints else self.tasks[0]
        self.conf.update(self.q)
        J, e = top.compute_jacobian(self.conf), top.compute_error(self.conf)
        return float(np.linalg.norm(J @ (x * P.DT) + top.gain * e) / P.DT)


# -- PlaCo --------------------------------------------------------------------------------------
def reduced_urdf(source: Path, keep, out_dir: Path) -> Path:
    """``source`` with every revolute/continuous/prismatic joint not in ``keep`` made fixed (at 0: the
    configuration pinocchio's ``buildReducedModel`` locks them at for the neutral ``q_ref``), without
    visual and collision geometry."""
    text = source.read_text()

    def fix(m):
        tag = m.group(0)
        name = re.search(r'name="([^"]+)"', tag).group(1)
        if name in keep:
            return tag
        return re.sub(r'type="(revolute|continuous|prismatic)"', 'type="fixed"', tag)

    text = re.sub(r"<joint\b[^>]*>", fix, text)
    # geometry is not used by the kinematics (and its package:// meshes need a package path)
    text = re.sub(r"<(visual|collision)\b.*?</\1>", "", text, flags=re.S)
    out = out_dir / f"{source.stem}_reduced.urdf"
    out.write_text(text)
    return out


def romeo_urdf() -> Path:
    import example_robot_data as erd

    loader = erd.robots_loader.ROBOTS["romeo"]()
    return Path(loader.df_path)


class Placo:
    """PlaCo's KinematicsSolver: the top level ``hard``, the others ``soft`` with weights."""

    _tmp = None

    def __init__(self, robot, problem, limits: bool):
        import placo

        self.robot, self.problem = robot, problem
        self.name = "PlaCo + limits" if limits else "PlaCo"
        if problem.robot_name == P.IIWA:
            path = P.urdf_path(robot)
        else:
            from hqp_tpm.robot.model import ROMEO21_JOINTS

            Placo._tmp = Placo._tmp or tempfile.mkdtemp(prefix="peers-")
            path = reduced_urdf(romeo_urdf(), set(ROMEO21_JOINTS), Path(Placo._tmp))
        self.pr = placo.RobotWrapper(str(path), placo.Flags.ignore_collisions)
        pm = self.pr.model
        names = {pm.names[j]: (pm.joints[j].idx_q, pm.joints[j].idx_v) for j in range(1, pm.njoints)}
        if problem.robot_name == P.IIWA:
            self.base = True
            self.qi, self.vi = _hqp_cols(robot, names)
        else:
            names[robot.model.names[1]] = (0, 0)  # both free-flyers first
            self.base = False
            self.qi, self.vi = _hqp_cols(robot, names)
        self.solver = s = placo.KinematicsSolver(self.pr)
        s.dt = P.DT
        if self.base:
            s.mask_fbase(True)
        s.enable_velocity_limits(limits)
        s.enable_joint_limits(limits)
        if problem.robot_name == P.IIWA:
            self.ee = s.add_frame_task(P.IIWA_EE, np.eye(4))
            self.ee.configure("ee", "hard", 1.0, 1.0)
            self.joints = s.add_joints_task()
            self.joints.configure("posture", "soft", 1e-3)
            self.joint_names = [robot.model.names[j] for j in range(1, robot.model.njoints)]
        else:
            self.sole = s.add_frame_task("r_sole", np.eye(4))
            self.sole.configure("right_sole", "hard", 1.0, 1.0)
            self.com = s.add_com_task(np.zeros(3))
            self.com.mask.set_axises("xy")
            self.com.configure("com", "soft", 10.0)
            self.pos = {k: s.add_position_task(P.ROMEO_FRAMES[k], np.zeros(3))
                        for k in ("left_foot", "left_hand", "right_hand")}
            self.pos["left_foot"].configure("left_foot", "soft", 10.0)
            self.pos["left_hand"].configure("left_hand", "soft", 1.0)
            self.pos["right_hand"].configure("right_hand", "soft", 1.0)
            self.joints = s.add_joints_task()
            self.joints.configure("posture", "soft", 1e-3)
            self.joint_names = [robot.model.names[j] for j in range(2, robot.model.njoints)]
        self.q_full = np.array(self.pr.state.q)

    def _set_q(self, q):
        qp = self.q_full.copy()
        qp[self.qi] = q
        self.pr.state.q = qp
        self.q = qp

    def _targets(self, t, q):
        """PlaCo's targets of one target set ``t`` at configuration ``q`` (kinematics updated there): each ``kp dt``
        of the way from the current value (PlaCo's tasks drive the whole error in one step)."""
        a = P.KP_EE * P.DT if self.problem.robot_name == P.IIWA else P.KP_ROMEO * P.DT

        def blend_pose(frame, M):   # kp dt of the way (position and world rotation vector)
            T = self.pr.get_T_world_frame(frame)
            R, p = T[:3, :3], T[:3, 3]
            out = np.eye(4)
            out[:3, 3] = p + a * (M.translation - p)
            out[:3, :3] = pin.exp3(a * pin.log3(M.rotation @ R.T)) @ R
            return out

        if self.problem.robot_name == P.IIWA:
            poses = [(self.ee, blend_pose(P.IIWA_EE, t["ee"]))]
            positions = []
            q_ref, ap, q_now = t["posture"], P.KP_POSTURE * P.DT, q
        else:
            poses = [(self.sole, blend_pose("r_sole", t["right_sole"]))]
            com = np.array(self.pr.com_world())
            positions = [(self.com, np.array([com[0] + a * (t["com"][0] - com[0]),
                                              com[1] + a * (t["com"][1] - com[1]), com[2]]))]
            for k, task in self.pos.items():
                p = self.pr.get_T_world_frame(P.ROMEO_FRAMES[k])[:3, 3]
                positions.append((task, p + a * (np.asarray(t[k]) - p)))
            q_ref, ap, q_now = t["posture"], P.KP_ROMEO_POSTURE * P.DT, q[7:]
        joints = {n: float(q_now[i] + ap * (q_ref[i] - q_now[i])) for i, n in enumerate(self.joint_names)}
        return poses, positions, joints

    def _assign(self, targets):
        poses, positions, joints = targets
        for task, T in poses:
            task.T_world_frame = T
        for task, p in positions:
            task.target_world = p
        self.joints.set_joints(joints)

    def setup(self, cfg):
        self._set_q(cfg.q)
        self.pr.update_kinematics()
        self.targets = (self._targets(cfg.targets, cfg.q), self._targets(P.moved(cfg.targets), cfg.q))
        self.k = 0
        self._assign(self.targets[0])

    def step(self):
        self.k ^= 1
        self._assign(self.targets[self.k])
        self.pr.state.q = self.q
        self.pr.update_kinematics()
        return self.solver.solve(False)[self.vi] / P.DT

    def rows_solve(self):   # PlaCo builds its task matrices inside solve
        return self.solver.solve(False)[self.vi] / P.DT

    #: the solver alone on built matrices: not separable in PlaCo's API
    solve = None


# -- TSID ---------------------------------------------------------------------------------------
def import_tsid():
    """TSID's bindings (the 1.7.1 wheel installs its ``__init__`` one folder too deep: fall back to
    the ``tsid_pywrap`` extension module)."""
    import tsid

    if hasattr(tsid, "RobotWrapper"):
        return tsid
    from tsid import tsid_pywrap

    return tsid_pywrap


class Tsid:
    """TSID 1.7: InverseDynamicsFormulationAccForce, EE at priority 0 (constraint), posture at 1 (cost),
    SolverHQuadProgFast (eiquadprog)."""

    def __init__(self, robot, problem):
        tsid = import_tsid()
        self.tsid, self.robot, self.problem = tsid, robot, problem
        self.name = "TSID"
        urdf = P.urdf_path(robot)   # the same URDF, fixed base (the Model constructor assumes a free-flyer)
        self.rw = tsid.RobotWrapper(str(urdf), [str(urdf.parent)], False)
        self.form = tsid.InverseDynamicsFormulationAccForce("tsid", self.rw, False)
        q0, v0 = robot.neutral(), np.zeros(robot.nv)
        self.form.computeProblemData(0.0, q0, v0)
        self.ee = tsid.TaskSE3Equality("ee", self.rw, P.IIWA_EE)
        self.ee.setKp(P.KP_EE_ACC * np.ones(6))
        self.ee.setKd(P.KD_EE_ACC * np.ones(6))
        if hasattr(self.ee, "useLocalFrame"):
            self.ee.useLocalFrame(False)   # world-aligned errors, as hqp-tpm's FramePose
        self.form.addMotionTask(self.ee, 1.0, 0, 0.0)
        self.posture = tsid.TaskJointPosture("posture", self.rw)
        self.posture.setKp(P.KP_POSTURE_ACC * np.ones(robot.nv))
        self.posture.setKd(P.KD_POSTURE_ACC * np.ones(robot.nv))
        self.form.addMotionTask(self.posture, 1e-3, 1, 0.0)
        self.qp = tsid.SolverHQuadProgFast("qp")
        self.qp.resize(self.form.nVar, self.form.nEq, self.form.nIn)

    def ee_sample(self, M, vel=None, acc=None):
        """TSID's reference sample of an EE pose (with velocity and acceleration when given)."""
        s = self.tsid.TrajectorySE3Constant("ee_ref", M).computeNext()
        if vel is not None:
            s.derivative(np.asarray(vel))
            s.second_derivative(np.asarray(acc))
        return s

    def set_ee_reference(self, M, vel=None, acc=None):
        self.ee.setReference(self.ee_sample(M, vel, acc))

    def _samples(self, t):
        return (self.ee_sample(t["ee"]),
                self.tsid.TrajectoryEuclidianConstant("posture_ref", np.asarray(t["posture"])).computeNext())

    def setup(self, cfg):
        self.q, self.v = cfg.q, cfg.v
        self.targets = (self._samples(cfg.targets), self._samples(P.moved(cfg.targets)))
        self.k = 0
        self.ee.setReference(self.targets[0][0])
        self.posture.setReference(self.targets[0][1])
        self.data = self.form.computeProblemData(0.0, self.q, self.v)

    def step(self):
        self.k ^= 1
        ee, posture = self.targets[self.k]
        self.ee.setReference(ee)
        self.posture.setReference(posture)
        data = self.form.computeProblemData(0.0, self.q, self.v)
        return self.form.getAccelerations(self.qp.solve(data))

    #: task rows without the kinematics: not separable in TSID's API (computeProblemData does both)
    rows_solve = None

    def solve(self):
        return self.form.getAccelerations(self.qp.solve(self.data))


# -- closed loops -------------------------------------------------------------------------------
def circle_loop(kind: str, robot, order: int, steps: int, timer, **kw):
    """Run ``steps`` steps of the iiwa circle with contender ``kind``; returns ``(times_ns, qs, cmds)``.

    ``timer()`` is ``time.perf_counter_ns``. Each step: target of the step, kinematics, tasks,
    solve, integration (each library's own). The EE target is the circle at the step's time.
    """
    dt = P.DT
    q0 = P.circle_start(robot)
    fid = robot.frame_id(P.IIWA_EE)
    data0 = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data0, q0)
    p0 = data0.oMf[fid].translation.copy()
    R0 = data0.oMf[fid].rotation.copy()
    times, qs, cmds = [], [], []
    if kind.startswith("hqp"):   # the circle is the task's own trajectory (Harmonic): nothing to assign
        ctrl, _ = P.hqp_circle_controller(robot, order, kw.get("solver", "tpm"))
        for _ in range(steps):
            t0 = timer()
            res = ctrl.step()
            times.append(timer() - t0)
            qs.append(ctrl.q)
            cmds.append(res.command)
        return times, qs, cmds
    # the peers have no circle trajectory of their own: its samples are made before the loop (not timed)
    circle = [P.circle_reference(p0, k * dt) for k in range(steps + 1)]
    if kind.startswith("pink"):
        import pink
        from pink.tasks import FrameTask, PostureTask

        conf = pink.Configuration(robot.model, robot.model.createData(), q0)
        ee = FrameTask(P.IIWA_EE, position_cost=1.0, orientation_cost=1.0, gain=P.KP_EE * dt)
        post = PostureTask(cost=1e-3, gain=P.KP_POSTURE * dt)
        post.set_target(q0)
        tasks, limits = [ee, post], (None if kw.get("limits") else [])
        targets = [pin.SE3(R0, p) for p, _, _ in circle]
        for k in range(steps):
            t0 = timer()
            ee.set_target(targets[k])
            v = pink.solve_ik(conf, tasks, dt, solver="daqp", limits=limits, safety_break=False)
            conf.integrate_inplace(v, dt)
            times.append(timer() - t0)
            qs.append(conf.q)
            cmds.append(v)
        return times, qs, cmds
    if kind.startswith("placo"):
        c = Placo(robot, P.Problem("iiwa_vel", P.IIWA, 1, []), kw.get("limits", False))
        c._set_q(q0)
        c.pr.update_kinematics()
        c.joints.set_joints({n: float(q0[i]) for i, n in enumerate(c.joint_names)})
        targets = []
        for p, _, _ in circle[1:]:   # the pose at the end of the step
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = R0, p
            targets.append(T)
        for k in range(steps):
            t0 = timer()
            c.ee.T_world_frame = targets[k]
            c.pr.update_kinematics()
            dq = c.solver.solve(True)   # PlaCo's usage: the whole error in one step, applied to the state
            times.append(timer() - t0)
            qs.append(np.array(c.pr.state.q)[c.qi])
            cmds.append(dq[c.vi] / dt)
        return times, qs, cmds
    if kind.startswith("tsid"):
        c = Tsid(robot, P.Problem("iiwa_acc", P.IIWA, 2, []))
        c.posture.setReference(c.tsid.TrajectoryEuclidianConstant("posture_ref", q0).computeNext())
        samples = [c.ee_sample(pin.SE3(R0, p), np.r_[pd, 0.0, 0.0, 0.0], np.r_[pdd, 0.0, 0.0, 0.0])
                   for p, pd, pdd in circle]
        q, v = q0.copy(), np.zeros(robot.nv)
        model, integrate = robot.model, pin.integrate
        for k in range(steps):
            t0 = timer()
            c.ee.setReference(samples[k])
            data = c.form.computeProblemData(k * dt, q, v)
            a = c.form.getAccelerations(c.qp.solve(data))
            q = integrate(model, q, (v + 0.5 * dt * a) * dt)
            v = v + dt * a
            times.append(timer() - t0)
            qs.append(q)
            cmds.append(a)
        return times, qs, cmds
    raise ValueError(kind)
