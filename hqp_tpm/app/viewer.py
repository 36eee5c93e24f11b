"""Meshcat views of a run, as papers/000 Fig. 3: a self-contained HTML replay and a live viewer.

The code lives in three modules, re-exported here:

- :mod:`hqp_tpm.app.viewer_scene`: :class:`Scene`, what is drawn and where (robot, obstacles, control
  points, distance segment, paths, pointing cone, markers, the operator's force), camera framing, and
  the decimated, cached robot meshes;
- :mod:`hqp_tpm.app.viewer_replay`: :func:`write_replay` / :func:`replay_html`, one HTML file (meshcat's
  JavaScript embedded, works offline) with the run as a meshcat animation, a play/pause bar and the
  active stack's name; ``replay.html#t=2.5`` opens it paused at t = 2.5 s;
- :mod:`hqp_tpm.app.viewer_live`: :class:`LiveViewer`, a meshcat server updated from a runner probe,
  optionally paced in real time (:class:`RateLimiter`), kept up until Ctrl-C.
"""

from hqp_tpm.app.viewer_live import LiveViewer, RateLimiter
from hqp_tpm.app.viewer_replay import replay_html, write_replay
from hqp_tpm.app.viewer_scene import COLORS, Scene, viewer_geometry

__all__ = ["COLORS", "LiveViewer", "RateLimiter", "Scene", "replay_html", "viewer_geometry", "write_replay"]
