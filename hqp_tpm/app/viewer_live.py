"""The live viewer: a meshcat server showing a run as it goes (``hqp-tpm run ... --viz``)."""

from __future__ import annotations

import contextlib
import io
import time
import warnings

import numpy as np

with warnings.catch_warnings():  # meshcat's server module imports the deprecated zmq.eventloop.ioloop
    warnings.filterwarnings("ignore", category=DeprecationWarning, module="meshcat")
    import meshcat

from hqp_tpm.app.viewer_scene import COLORS, DEFAULT_VIEW, LINE_RADIUS, Scene
from hqp_tpm.control.controller import Controller, StepResult
from hqp_tpm.control.policy import Policy, SceneItems
from hqp_tpm.errors import ParameterError
from hqp_tpm.references.operator import Operator
from hqp_tpm.robot.model import Robot


class RateLimiter:
    """Paces a loop to simulated time: :meth:`wait` ``(t)`` sleeps until ``(t - t_first) / speed`` seconds of wall
    time have passed since the first call. A call that comes later than that by more than ``tolerance`` seconds
    is an overrun (the loop is slower than real time there): counted, with the largest lag."""

    def __init__(self, speed: float = 1.0, tolerance: float = 0.02, *, clock=time.perf_counter, sleep=time.sleep):
        if not (np.isfinite(speed) and speed > 0):
            raise ParameterError(f"real-time speed {speed!r} must be finite and > 0")
        self.speed, self.tolerance = float(speed), float(tolerance)
        self.clock, self.sleep = clock, sleep
        self._start: tuple[float, float] | None = None
        self.calls = 0
        self.overruns = 0
        self.max_lag = 0.0

    def wait(self, t: float) -> None:
        now = self.clock()
        self.calls += 1
        if self._start is None:
            self._start = (now, float(t))
            return
        due = self._start[0] + (float(t) - self._start[1]) / self.speed
        if now < due:
            self.sleep(due - now)
            return
        lag = now - due
        self.max_lag = max(self.max_lag, lag)
        if lag > self.tolerance:
            self.overruns += 1

    def report(self) -> str:
        return (f"real-time pacing: {self.calls} frames, {self.overruns} behind real time by more than "
                f"{1e3 * self.tolerance:.0f} ms (largest lag {1e3 * self.max_lag:.0f} ms)")


# ------------------------------------------------------------------------------------------ live
class LiveViewer:
    """A meshcat server showing the run as it goes; ``probe`` is a runner probe (returns ``{}``).

    ``items``: what to draw besides the robot (a run's ``RunContext.scene``; None: the robot alone).
    ``policy``: the run's policy; its :meth:`~hqp_tpm.control.policy.Policy.probe` gives the critical
    control point (``active_point``) drawn in blue (None: no critical point).
    ``realtime``: pace the run to simulated time (True, or a speed factor) with a :class:`RateLimiter`;
    :meth:`report` says how often the run could not keep up. The URL is printed once (meshcat's own
    message is silenced); :meth:`serve` keeps the server up until Ctrl-C.
    """

    def __init__(self, robot: Robot, items: SceneItems | None = None, every: int = 10, *,
                 policy: Policy | None = None, view=DEFAULT_VIEW, trace_every: int = 10,
                 zmq_url: str | None = None, realtime: bool | float = False, quiet: bool = False):
        with contextlib.redirect_stdout(io.StringIO()):  # meshcat prints its URL itself: once is enough
            self.vis = meshcat.Visualizer(zmq_url=zmq_url)
        self.url = self.vis.url()
        if not quiet:
            print(f"hqp-tpm: live meshcat viewer at {self.url}", flush=True)
        speed = 1.0 if realtime is True else float(realtime or 0.0)
        self.rate = RateLimiter(speed) if speed > 0 else None
        self.every = max(1, int(every))
        self.trace_every = max(1, int(trace_every))
        self.scene = Scene(self.vis, robot, items)
        self.policy = policy
        self.view = view
        self._count = 0
        self._updates = 0
        self._framed = False
        self._trace: list[np.ndarray] = []
        self._desired: list[np.ndarray] = []
        self._chunk = 0

    def show(self, q, t: float = 0.0, active_point: int | None = None, update_field: bool = True,
             record: dict | None = None) -> None:
        """Draw configuration ``q`` at time ``t`` (the first call also places the camera)."""
        q = np.asarray(q, dtype=float)
        state = self.scene.state(q, t, active_point, update_field=update_field, record=record)
        if not self._framed:
            pts = self.scene.key_points()
            pts += [o.placement_at(t).translation for o in self.scene.obstacles]
            period = self.scene.periodic_target()
            if period is not None:  # a periodic target: its whole path is known
                ts = t + np.linspace(0.0, period, 400)
                path = [x for x in (self.scene.desired_position(s) for s in ts) if x is not None]
                if len(path) > 1:
                    self.scene.draw_path("desired_path", path, COLORS["desired_path"], radius=0.7 * LINE_RADIUS)
                    pts += path
            period = self.scene.target_period()
            if period is not None:  # periodic targets (a humanoid's hands): their whole paths are known
                pts += self.scene.draw_target_paths(t + np.linspace(0.0, period, 400))
            self.scene.frame_scene(pts, direction=self.view, floor=self.scene.floor_height(q))
            self._framed = True
        self.scene.apply(state)
        ee = self.scene.ee_position()
        if ee is not None:
            self._trace.append(ee)
            if len(self._trace) > self.trace_every:
                self.scene.draw_path(f"ee_trace/{self._chunk}", self._trace, COLORS["ee_trace"])
                self._chunk += 1
                self._trace = self._trace[-1:]

    def probe(self, ctrl: Controller, res: StepResult) -> dict:
        """Runner probe: every ``every`` steps, show the state the step was computed from (``ctrl.state``;
        the distance field already holds it)."""
        self._count += 1
        if (self._count - 1) % self.every:
            return {}
        st = ctrl.state
        active = None if self.policy is None else self.policy.probe(ctrl, res).get("active_point")
        if self.rate is not None:
            self.rate.wait(st.t)
        self.show(st.q, st.t, active, update_field=False, record=_record(self.scene.operator))
        return {}

    def report(self) -> str | None:
        """What the real-time pacing saw (None without it)."""
        return None if self.rate is None else self.rate.report()

    def serve(self, message: bool = True, until=None) -> None:
        """Keep the server up until Ctrl-C (SIGINT) or one SIGTERM (``timeout``, ``docker stop``, systemd), or
        until ``until()`` returns true (checked every 0.5 s: a signal the caller's handler took), then stop it."""
        import signal
        import threading

        def _end(signum, frame):
            raise KeyboardInterrupt

        old: dict = {}
        try:  # a signal at any point from here on ends the wait
            if threading.current_thread() is threading.main_thread():  # either signal, whatever handler ran the run
                for sig in (signal.SIGINT, signal.SIGTERM):
                    old[sig] = signal.signal(sig, _end)
            if message:
                print("hqp-tpm: the run is over; the viewer stays up until you press Ctrl-C", flush=True)
            while until is None or not until():
                time.sleep(0.5)
        except KeyboardInterrupt:
            pass
        finally:
            for sig, handler in old.items():
                signal.signal(sig, handler)
            self.close()

    def close(self) -> None:
        """Stop the meshcat server this viewer started."""
        proc = self.vis.window.server_proc  # None when the viewer joined a server it did not start
        if proc is not None and proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=5)
            except Exception:  # noqa: BLE001
                proc.kill()

    def __enter__(self) -> LiveViewer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _record(op: Operator | None) -> dict:
    """The operator's force and marker of this step (co-manipulation runs), for the scene."""
    if op is None:
        return {}
    return {"operator_force": op.force, "marker": float(op.marker)}
