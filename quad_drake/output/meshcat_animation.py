"""Meshcat 3D replay of a run: a quadrotor model per vehicle, its flown, reference and
estimated paths, animated from the logs.

The simulator's world is NED with FRD bodies; Meshcat's is z-up. :func:`ned_to_zup`
is the one place the frames change. ``write_replay`` saves a recording as a
self-contained HTML page (``Meshcat.StaticHtml()``: three.js and the scene are
inlined, so it opens offline); ``show_live`` plays the flight in a live Meshcat.
"""

import html
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import Box, Cylinder, Meshcat, MeshcatAnimation, MeshcatParams, Rgba, Sphere
from pydrake.math import RigidTransform, RollPitchYaw

from ..conventions import P_SLICE, Q_SLICE, REF_P_SLICE
from .outdir import write_text_atomic

ROOT = "/quad_drake"
FPS = 30.0
"""Recording frame rate, frames per s of simulated time."""
MAX_PATH_POINTS = 2000
VEHICLE_COLORS = (
    (0.12, 0.47, 0.71),
    (1.0, 0.5, 0.05),
    (0.17, 0.63, 0.17),
    (0.84, 0.15, 0.16),
    (0.58, 0.4, 0.74),
    (0.55, 0.34, 0.29),
    (0.89, 0.47, 0.76),
    (0.5, 0.5, 0.5),
    (0.74, 0.74, 0.13),
    (0.09, 0.75, 0.81),
)
REFERENCE_COLOR = Rgba(0.1, 0.1, 0.1, 1.0)
ESTIMATE_COLOR = Rgba(0.85, 0.1, 0.6, 1.0)


def ned_to_zup(p_ned, q_ned=None) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Positions (..., 3) [and wxyz quaternions (..., 4)] from NED/FRD to Meshcat's z-up.

    The map is the rotation by pi about north: (x, y, z)_NED -> (x, -y, -z), i.e. x north,
    y west, z up. Body frames change the same way (FRD -> FLU), so R_zup = C R_NED C with
    C = diag(1, -1, -1), which for a quaternion is (w, x, y, z) -> (w, x, -y, -z). Body
    vectors map like positions. Returns a new array, or a (positions, quaternions) pair.
    """
    p = np.asarray(p_ned, dtype=float) * np.array([1.0, -1.0, -1.0])
    if q_ned is None:
        return p
    return p, np.asarray(q_ned, dtype=float) * np.array([1.0, 1.0, -1.0, -1.0])


def _quiet_meshcat(params):
    """A Meshcat without the INFO line about its port on stderr."""
    logger = logging.getLogger("drake")
    level = logger.level
    logger.setLevel(logging.WARNING)
    try:
        return Meshcat(params)
    finally:
        logger.setLevel(level)


def _rgba(color, alpha=1.0):
    return Rgba(*color, alpha)


def add_quadrotor(meshcat, path, arm_length, color) -> None:
    """A quadrotor in its FLU body frame at `path`: body, X arms, motors, rotor discs (front red)."""
    a = arm_length / math.sqrt(2.0)
    meshcat.SetObject(f"{path}/body", Box(0.6 * a, 0.45 * a, 0.05), _rgba(color))
    for i, angle in enumerate((math.pi / 4, -math.pi / 4)):
        meshcat.SetObject(f"{path}/arm_{i}", Box(2 * arm_length, 0.012, 0.012), Rgba(0.25, 0.25, 0.25, 1.0))
        meshcat.SetTransform(f"{path}/arm_{i}", RigidTransform(RollPitchYaw(0, 0, angle), [0, 0, 0]))
    # motors 0..3: front left, front right, rear left, rear right (FLU: left is +y)
    for i, (x, y) in enumerate(((a, a), (a, -a), (-a, a), (-a, -a))):
        front = x > 0
        meshcat.SetObject(f"{path}/motor_{i}", Cylinder(0.014, 0.03), Rgba(0.15, 0.15, 0.15, 1.0))
        meshcat.SetTransform(f"{path}/motor_{i}", RigidTransform([x, y, 0.015]))
        meshcat.SetObject(
            f"{path}/rotor_{i}",
            Cylinder(0.4 * arm_length, 0.004),
            Rgba(0.9, 0.2, 0.15, 0.55) if front else Rgba(0.3, 0.3, 0.35, 0.45),
        )
        meshcat.SetTransform(f"{path}/rotor_{i}", RigidTransform([x, y, 0.035]))
    meshcat.SetObject(f"{path}/nose", Sphere(0.018), Rgba(0.9, 0.1, 0.1, 1.0))
    meshcat.SetTransform(f"{path}/nose", RigidTransform([0.35 * a, 0.0, 0.03]))


def _line(points_ned):
    """(3, m) z-up vertices of an (n, 3) NED path, decimated to at most MAX_PATH_POINTS."""
    step = max(1, math.ceil(points_ned.shape[0] / MAX_PATH_POINTS))
    points = points_ned[::step]
    if (points_ned.shape[0] - 1) % step:
        points = np.vstack([points, points_ned[-1:]])
    return np.ascontiguousarray(ned_to_zup(points).T)


class _Track:
    """One vehicle's animated poses in z-up, from its logs."""

    def __init__(self, name, logs):
        self.name = name
        self.p, self.q = ned_to_zup(logs["state"][:, P_SLICE], logs["state"][:, Q_SLICE])
        self.q /= np.linalg.norm(self.q, axis=1, keepdims=True)
        self.reference = logs["reference"][:, REF_P_SLICE] if "reference" in logs else None
        self.estimate = logs["estimated_state"][:, 0:3] if "estimated_state" in logs else None
        self.true_path = logs["state"][:, P_SLICE]
        self.estimate_zup = None if self.estimate is None else ned_to_zup(self.estimate)

    def set_pose(self, meshcat, k, time_in_recording=None):
        pose = RigidTransform(Quaternion(self.q[k]), self.p[k])
        meshcat.SetTransform(f"{ROOT}/{self.name}/quad", pose, time_in_recording)
        if self.estimate_zup is not None:
            meshcat.SetTransform(
                f"{ROOT}/{self.name}/estimate", RigidTransform(self.estimate_zup[k]), time_in_recording
            )


def _tracks(result):
    return [_Track(vehicle, result.logs[vehicle]) for vehicle in (v.name for v in result.scenario.vehicles)]


def frame_indices(times, fps=FPS) -> tuple[np.ndarray, np.ndarray]:
    """(frame times [s], log sample index per frame) at `fps` over the logged span from t = 0."""
    if times.size == 0:
        return np.zeros(0), np.zeros(0, dtype=int)
    frame_times = np.arange(0.0, float(times[-1]) + 0.5 / fps, 1.0 / fps)
    indices = np.clip(np.searchsorted(times, frame_times - 1e-9), 0, times.size - 1)
    return frame_times, indices


def build_scene(meshcat, result) -> list[_Track]:
    """Add every vehicle's model and static paths; point the camera at the flight. -> tracks."""
    meshcat.Delete(ROOT)
    tracks = _tracks(result)
    vehicles = {v.name: v for v in result.scenario.vehicles}
    for i, track in enumerate(tracks):
        color = VEHICLE_COLORS[i % len(VEHICLE_COLORS)]
        base = f"{ROOT}/{track.name}"
        add_quadrotor(meshcat, f"{base}/quad", vehicles[track.name].physics.arm_length, color)
        meshcat.SetLine(f"{base}/path/flown", _line(track.true_path), 2.0, _rgba(color))
        if track.reference is not None:
            meshcat.SetLine(f"{base}/path/reference", _line(track.reference), 1.0, REFERENCE_COLOR)
        if track.estimate is not None:
            meshcat.SetLine(f"{base}/path/estimated", _line(track.estimate), 1.0, ESTIMATE_COLOR)
            meshcat.SetObject(f"{base}/estimate", Sphere(0.025), Rgba(0.85, 0.1, 0.6, 0.5))
        if track.p.shape[0]:
            track.set_pose(meshcat, 0)
    _aim_camera(meshcat, tracks)
    return tracks


def _aim_camera(meshcat, tracks):
    points = np.vstack([t.p for t in tracks if t.p.shape[0]] + [np.zeros((1, 3))])
    points = points[np.all(np.isfinite(points), axis=1)]
    low, high = points.min(axis=0), points.max(axis=0)
    target = 0.5 * (low + high)
    distance = max(3.0, 1.2 * float(np.max(high - low)))
    meshcat.SetCameraPose(target + distance * np.array([-0.6, -0.6, 0.55]), target)


def record(meshcat, tracks, times, fps=FPS) -> None:
    """Record every track's poses at `fps` into meshcat's animation and publish it."""
    meshcat.StartRecording(frames_per_second=fps, set_visualizations_while_recording=False)
    frame_times, indices = frame_indices(times, fps)
    for t, k in zip(frame_times, indices, strict=True):
        for track in tracks:
            track.set_pose(meshcat, int(k), float(t))
    meshcat.StopRecording()
    animation = meshcat.get_mutable_recording()
    animation.set_autoplay(True)
    animation.set_loop_mode(MeshcatAnimation.LoopMode.kLoopRepeat)
    animation.set_repetitions(1000)
    meshcat.PublishRecording()


def _css(rgba):
    return f"rgb({round(255 * rgba.r())}, {round(255 * rgba.g())}, {round(255 * rgba.b())})"


def legend_html(result) -> str:
    """A fixed legend naming what the replay draws: each vehicle's colour (body and flown path),
    its nose, the reference and the estimate."""
    rows = []
    for i, vehicle in enumerate(v.name for v in result.scenario.vehicles):
        color = _css(_rgba(VEHICLE_COLORS[i % len(VEHICLE_COLORS)]))
        rows.append(
            f'<span style="color:{color}">&#9473;&#9473;</span> {html.escape(vehicle)}: body and flown path'
        )
    rows.append(
        '<span style="color:rgb(230, 26, 26)">&#9679;</span> nose (the front); red rotors: the front pair'
    )
    rows.append(f'<span style="color:{_css(REFERENCE_COLOR)}">&#9473;&#9473;</span> reference path')
    estimate = f'<span style="color:{_css(ESTIMATE_COLOR)}">&#9473;&#9473; &#9679;</span>'
    rows.append(f"{estimate} estimated path and position")
    style = (
        "position:fixed;left:8px;bottom:8px;z-index:10;background:rgba(255,255,255,0.85);"
        "font:12px sans-serif;padding:6px 8px;border-radius:4px;pointer-events:none"
    )
    title = f"<b>{html.escape(result.scenario.name)}</b> (seed {result.scenario.seed}; z up, NED shown z-up)"
    return f'<div id="quad-drake-legend" style="{style}">' + "<br>".join([title, *rows]) + "</div>"


OPEN_CONTROLS = """<script>
(function openControls(tries) {  // quad_drake: the controls and the animation folder start open
  var later = function () { if (tries < 100) setTimeout(openControls, 100, tries + 1); };
  if (typeof viewer === "undefined" || !viewer.gui) { later(); return; }
  viewer.gui.open();
  var folders = viewer.gui.__folders || {};
  if (!folders.Animations) { later(); return; }
  folders.Animations.open();
  for (var name in folders.Animations.__folders) folders.Animations.__folders[name].open();
})(0);
</script>
"""


def replay_html(result, fps=FPS) -> str:
    """The self-contained HTML text of a run's recording (Meshcat.StaticHtml), with a legend
    (:func:`legend_html`) and the controls open (:data:`OPEN_CONTROLS`)."""
    meshcat = _quiet_meshcat(MeshcatParams(host="localhost", port=0, show_stats_plot=False))
    tracks = build_scene(meshcat, result)
    record(meshcat, tracks, result.times, fps)
    page = meshcat.StaticHtml()
    head, body_end, tail = page.rpartition("</body>")
    if not body_end:
        return page
    return head + legend_html(result) + "\n" + OPEN_CONTROLS + body_end + tail


def write_replay(result, path, fps=FPS) -> Path:
    """Write replay.html (a Meshcat recording of the run, opens offline); -> path."""
    path = Path(path)
    return write_text_atomic(path, replay_html(result, fps))


def show_live(result, meshcat=None, rate=1.0, wait_for_browser=60.0, block=True) -> Meshcat:
    """Play a run in a live Meshcat at `rate` × real time, then leave a replayable recording.

    Prints the URL and waits up to `wait_for_browser` s for a browser to connect.
    With `block`, waits for Enter (or end of input) before returning the Meshcat.
    """
    meshcat = meshcat or _quiet_meshcat(MeshcatParams())
    print(f"Meshcat: open {meshcat.web_url()} in a browser", flush=True)
    tracks = build_scene(meshcat, result)
    deadline = time.monotonic() + wait_for_browser
    while meshcat.GetNumActiveConnections() == 0 and time.monotonic() < deadline:
        time.sleep(0.1)
    frame_times, indices = frame_indices(result.times)
    start = time.monotonic()
    for t, k in zip(frame_times, indices, strict=True):
        delay = start + t / rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        for track in tracks:
            track.set_pose(meshcat, int(k))
    record(meshcat, tracks, result.times)
    meshcat.Flush()
    if block:
        print("Replay published (use the Animation controls to scrub); press Enter to quit.", flush=True)
        try:
            sys.stdin.readline()
        except (EOFError, OSError):
            pass
    return meshcat
