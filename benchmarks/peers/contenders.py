"""The contenders: the same problem in hqp-tpm, pink, PlaCo and TSID.

Every contender has ``setup(cfg)`` (targets and state of one configuration, not timed), ``step()``
(a full step at that state: kinematics + task rows + solve; returns the joint velocity or
acceleration in hqp-tpm's column order) and ``solve()`` (the solver alone on the problem ``step``
built, where the library lets it be separated; ``None`` where not). Closed loops are in
:func:`circle_loop`.

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
    """hqp-tpm through its public API: Controller(robot, Stack, solver) with ``compute()`` as the step (``lean``: its
    compiled step; else ``compute(record=True)``, the readable path)."""

    def __init__(self, robot, problem, solver: str, lean: bool = False):
        from hqp_tpm.solvers import cascaded_qp, sns_tpm, tpm

        self.robot, self.problem, self.solver, self.lean = robot, problem, solver, lean
        self.name = f"hqp-tpm {solver}" + (" (lean)" if lean else "")
        self._tpm, self._sns, self._qp = tpm, sns_tpm, cascaded_qp

    def setup(self, cfg):
        self.ctrl = P.hqp_controller(self.robot, self.problem, cfg, self.solver)
        res = self.ctrl.compute(record=True)
        self.levels = res.levels
        st = self.ctrl.state
        self.box = self.ctrl.box(st, self.ctrl.t) if self.ctrl.box is not None else None
        if self.lean:  # the compiled step (hqp_tpm.control._lean): one preallocated J, b; no Level objects
            from hqp_tpm.control._lean import LeanStep
            from hqp_tpm.solvers.sns import sns_tpm, sns_tpm_stacked
            from hqp_tpm.solvers.tpm import tpm_stacked

            self.fast = f = self.ctrl._compiled_step()
            if f is None:
                raise RuntimeError(f"no compiled step: {LeanStep.why_not(self.ctrl)}")
            self.ctrl.compute()
            if self.solver == "tpm":
                self._lean_solve = lambda: tpm_stacked(f.J, f.b, f.sizes, f.n, f.lambda_max, f.eps)
            elif self.solver == "sns_tpm":
                lo, up = (a.copy() for a in f._box(st, self.ctrl.t))
                self._lean_solve = (lambda: sns_tpm_stacked(f.J, f.b, f.sizes, lo, up, lambda_max=f.lambda_max,
                                                            eps=f.eps)) if f.x0 is None else \
                    (lambda: sns_tpm(f.levels, lo, up, lambda_max=f.lambda_max, eps=f.eps))
            else:
                self._lean_solve = None

    def step(self):
        return self.ctrl.compute(record=not self.lean).command

    def solve(self):
        nv = self.robot.nv
        if self.lean and self._lean_solve is not None:
            return self._lean_solve()
        if self.solver == "tpm":
            return self._tpm(self.levels, n=nv)
        lo, up = self.box
        if self.solver == "sns_tpm":
            return self._sns(self.levels, lo, up)
        return self._qp(self.levels, solver=self.solver.split(":", 1)[1], lower=lo, upper=up, n=nv)


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

    def setup(self, cfg):
        self.q = cfg.q
        self.conf.update(cfg.q)
        if self.problem.robot_name == P.IIWA:
            self.ee.set_target(cfg.targets["ee"])
            q_ref = cfg.targets["posture"]
        else:
            t = cfg.targets
            self.frames["right_sole"].set_target(t["right_sole"])
            for key in ("left_foot", "left_hand", "right_hand"):
                cur = self.conf.get_transform_frame_to_world(self.frames[key].frame)
                self.frames[key].set_target(pin.SE3(cur.rotation, np.asarray(t[key])))
            com = pin.centerOfMass(self.robot.model, self.robot.model.createData(), cfg.q)
            self.com.set_target(np.array([t["com"][0], t["com"][1], com[2]]))
            q_ref = cfg.q.copy()
            q_ref[7:] = t["posture"]
        self.posture.set_target(q_ref)
        self.problem_qp = self._build(self.conf, self.tasks, P.DT, limits=self.limits, constraints=self.constraints)

    def step(self):
        self.conf.update(self.q)
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

    def setup(self, cfg):
        a = P.KP_EE * P.DT if self.problem.robot_name == P.IIWA else P.KP_ROMEO * P.DT
        self._set_q(cfg.q)
        self.pr.update_kinematics()
        t = cfg.targets

        def blend_pose(frame, M):   # kp dt of the way (position and world rotation vector)
            T = self.pr.get_T_world_frame(frame)
            R, p = T[:3, :3], T[:3, 3]
            out = np.eye(4)
            out[:3, 3] = p + a * (M.translation - p)
            out[:3, :3] = pin.exp3(a * pin.log3(M.rotation @ R.T)) @ R
            return out

        if self.problem.robot_name == P.IIWA:
            self.ee.T_world_frame = blend_pose(P.IIWA_EE, t["ee"])
            q_ref, ap = t["posture"], P.KP_POSTURE * P.DT
            q_now = cfg.q
        else:
            self.sole.T_world_frame = blend_pose("r_sole", t["right_sole"])
            com = np.array(self.pr.com_world())
            self.com.target_world = np.array([com[0] + a * (t["com"][0] - com[0]),
                                              com[1] + a * (t["com"][1] - com[1]), com[2]])
            for k, task in self.pos.items():
                p = self.pr.get_T_world_frame(P.ROMEO_FRAMES[k])[:3, 3]
                task.target_world = p + a * (np.asarray(t[k]) - p)
            q_ref, ap = t["posture"], P.KP_ROMEO_POSTURE * P.DT
            q_now = cfg.q[7:]
        self.joints.set_joints({n: float(q_now[i] + ap * (q_ref[i] - q_now[i]))
                                for i, n in enumerate(self.joint_names)})

    def step(self):
        self.pr.state.q = self.q
        self.pr.update_kinematics()
        return self.solver.solve(False)[self.vi] / P.DT

    def solve(self):
        return self.solver.solve(False)[self.vi] / P.DT


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

    def set_ee_reference(self, M, vel=None, acc=None):
        s = self.tsid.TrajectorySE3Constant("ee_ref", M).computeNext()
        if vel is not None:
            s.derivative(np.asarray(vel))
            s.second_derivative(np.asarray(acc))
        self.ee.setReference(s)

    def setup(self, cfg):
        self.q, self.v = cfg.q, cfg.v
        self.set_ee_reference(cfg.targets["ee"])
        self.posture.setReference(self.tsid.TrajectoryEuclidianConstant("posture_ref",
                                                                         cfg.targets["posture"]).computeNext())
        self.data = self.form.computeProblemData(0.0, self.q, self.v)

    def step(self):
        data = self.form.computeProblemData(0.0, self.q, self.v)
        return self.form.getAccelerations(self.qp.solve(data))

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
    if kind.startswith("hqp"):
        ctrl, _ = P.hqp_circle_controller(robot, order, kw.get("solver", "tpm"))
        record = not kw.get("lean")  # the compiled step, or the readable path
        for _ in range(steps):
            t0 = timer()
            res = ctrl.step(record)
            times.append(timer() - t0)
            qs.append(ctrl.q)
            cmds.append(res.command)
        return times, qs, cmds
    if kind.startswith("pink"):
        import pink
        from pink.tasks import FrameTask, PostureTask

        conf = pink.Configuration(robot.model, robot.model.createData(), q0)
        ee = FrameTask(P.IIWA_EE, position_cost=1.0, orientation_cost=1.0, gain=P.KP_EE * dt)
        post = PostureTask(cost=1e-3, gain=P.KP_POSTURE * dt)
        post.set_target(q0)
        tasks, limits = [ee, post], (None if kw.get("limits") else [])
        for k in range(steps):
            t0 = timer()
            p, _, _ = P.circle_reference(p0, k * dt)
            ee.set_target(pin.SE3(R0, p))
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
        T = np.eye(4)
        T[:3, :3] = R0
        for k in range(steps):
            t0 = timer()
            p, _, _ = P.circle_reference(p0, (k + 1) * dt)   # the pose at the end of the step
            T[:3, 3] = p
            c.ee.T_world_frame = T
            c.pr.update_kinematics()
            dq = c.solver.solve(True)   # PlaCo's usage: the whole error in one step, applied to the state
            times.append(timer() - t0)
            qs.append(np.array(c.pr.state.q)[c.qi])
            cmds.append(dq[c.vi] / dt)
        return times, qs, cmds
    if kind.startswith("tsid"):
        c = Tsid(robot, P.Problem("iiwa_acc", P.IIWA, 2, []))
        c.posture.setReference(c.tsid.TrajectoryEuclidianConstant("posture_ref", q0).computeNext())
        q, v = q0.copy(), np.zeros(robot.nv)
        model = robot.model
        for k in range(steps):
            t0 = timer()
            p, pd, pdd = P.circle_reference(p0, k * dt)
            c.set_ee_reference(pin.SE3(R0, p), np.r_[pd, 0.0, 0.0, 0.0], np.r_[pdd, 0.0, 0.0, 0.0])
            data = c.form.computeProblemData(k * dt, q, v)
            a = c.form.getAccelerations(c.qp.solve(data))
            q = pin.integrate(model, q, v * dt + 0.5 * a * dt * dt)
            v = v + a * dt
            times.append(timer() - t0)
            qs.append(q)
            cmds.append(a)
        return times, qs, cmds
    raise ValueError(kind)
