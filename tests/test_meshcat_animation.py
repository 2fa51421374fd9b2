"""Meshcat replay: the NED -> z-up conversion, the recording, and the saved page in a real
headless browser (Chromium over the DevTools protocol on a pipe: no extra packages)."""

import base64
import io
import json
import math
import queue
import shutil
import subprocess
import threading
import time

import numpy as np
import pytest

from quad_drake.models.rotations import quat_from_euler, rotation_from_quat
from quad_drake.output.meshcat_animation import frame_indices, ned_to_zup, show_live, write_replay

C = np.diag([1.0, -1.0, -1.0])


def test_ned_to_zup_positions():
    p = ned_to_zup([[1.0, 2.0, -3.0], [0.0, 0.0, 0.0]])
    assert np.array_equal(p, [[1.0, -2.0, 3.0], [0.0, 0.0, 0.0]])  # 3 m altitude -> z = +3
    assert ned_to_zup(np.array([0.5, 0.25, -1.0])).shape == (3,)


def test_ned_to_zup_maps_body_vectors_consistently():
    rng = np.random.default_rng(7)
    q = rng.normal(size=(20, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    v_body = rng.normal(size=(20, 3))
    _, q_zup = ned_to_zup(np.zeros((20, 3)), q)
    for k in range(20):
        # The FRD body vector, seen in N then converted, equals the FLU vector rotated by the new q.
        seen_in_n = ned_to_zup(rotation_from_quat(q[k]) @ v_body[k])
        assert np.allclose(rotation_from_quat(q_zup[k]) @ ned_to_zup(v_body[k]), seen_in_n, atol=1e-12)
        assert math.isclose(np.linalg.norm(q_zup[k]), 1.0, abs_tol=1e-12)
    assert np.linalg.det(C) == 1.0  # a rotation, not a mirror


def test_ned_to_zup_physical_directions():
    nose_east = ned_to_zup(rotation_from_quat(quat_from_euler(0, 0, math.pi / 2)) @ [1.0, 0, 0])
    assert np.allclose(nose_east, [0, -1, 0], atol=1e-12)  # east is -y in (north, west, up)
    _, q = ned_to_zup(np.zeros(3), quat_from_euler(0.3, 0.0, 0.0))  # roll right
    right_wing = rotation_from_quat(q) @ [0.0, -1.0, 0.0]  # FLU right = -y
    assert math.isclose(right_wing[2], -math.sin(0.3), abs_tol=1e-12)  # the right side goes down
    _, q = ned_to_zup(np.zeros(3), quat_from_euler(0.0, 0.2, 0.0))  # pitch up
    assert math.isclose((rotation_from_quat(q) @ [1.0, 0, 0])[2], math.sin(0.2), abs_tol=1e-12)


def test_frame_indices_pick_the_log_sample_at_or_after_each_frame():
    times = 0.005 * np.arange(1, 201)  # 0.005 .. 1.0 s
    frame_times, indices = frame_indices(times, fps=10)
    assert np.allclose(frame_times, 0.1 * np.arange(11))
    assert list(indices) == [0, 19, 39, 59, 79, 99, 119, 139, 159, 179, 199]
    assert np.allclose(times[indices[1:]], frame_times[1:])
    assert frame_indices(np.zeros(0))[1].size == 0


@pytest.fixture(scope="module")
def flight(gps_flight, tmp_path_factory):
    """A 3 s closed-loop flight on the estimate (11_gps_update) and its replay.html."""
    path = write_replay(gps_flight, tmp_path_factory.mktemp("replay") / "replay.html")
    return gps_flight, path


def test_replay_html_is_self_contained(flight):
    _, path = flight
    page = path.read_text()
    assert page.startswith("<!DOCTYPE html>") and len(page) > 1_000_000  # three.js inlined
    assert "<script src" not in page.replace(" ", "") and "<link" not in page
    assert "MeshCat.Viewer" in page


def test_replay_has_a_legend_and_opens_its_controls(flight):
    result, path = flight
    page = path.read_text()
    legend = page[page.index('<div id="quad-drake-legend"') :]
    assert legend.index("</div>") < legend.index("</body>")
    for words in ("Quad: body and flown path", "nose (the front)", "reference path", "estimated path"):
        assert words in legend[: legend.index("</div>")]
    assert "viewer.gui.open();" in page and "folders.Animations.open();" in page


def test_show_live_publishes_the_scene_and_a_recording(flight):
    result, _ = flight
    meshcat = show_live(result, rate=1e6, wait_for_browser=0.0, block=False)
    for path in ("quad/rotor_0", "path/flown", "path/reference", "path/estimated", "estimate"):
        assert meshcat.HasPath(f"/quad_drake/Quad/{path}"), path
    assert meshcat.get_mutable_recording().frames_per_second() == 30.0


class DevTools:
    """Chromium's DevTools protocol over --remote-debugging-pipe (fd 3 in, fd 4 out, NUL-framed JSON)."""

    def __init__(self, chromium, user_data_dir):
        argv = [
            chromium,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--no-first-run",
            "--window-size=900,650",
            f"--user-data-dir={user_data_dir}",
            "--remote-debugging-pipe",
            "about:blank",
        ]
        self.process = subprocess.Popen(
            ["bash", "-c", 'exec "$@" 3<&0 4>&1 0</dev/null 1>/dev/null', "_", *argv],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
        )
        self.inbox = queue.Queue()
        self.events = []
        self.last_id = 0
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        buffer = b""
        while chunk := self.process.stdout.read1(65536):
            buffer += chunk
            *messages, buffer = buffer.split(b"\0")
            for raw in messages:
                self.inbox.put(json.loads(raw))
        self.inbox.put(None)

    def _next(self, deadline):
        message = self.inbox.get(timeout=max(0.01, deadline - time.monotonic()))
        if message is None:
            raise RuntimeError("chromium closed the DevTools pipe")
        return message

    def call(self, method, params=None, session=None, timeout=30.0):
        self.last_id += 1
        message = {"id": self.last_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        self.process.stdin.write(json.dumps(message).encode() + b"\0")
        self.process.stdin.flush()
        deadline = time.monotonic() + timeout
        while (reply := self._next(deadline)).get("id") != self.last_id:
            self.events.append(reply)
        if "error" in reply:
            raise RuntimeError(f"{method}: {reply['error']}")
        return reply["result"]

    def wait_for(self, method, timeout=30.0):
        deadline = time.monotonic() + timeout
        while not any(e.get("method") == method for e in self.events):
            self.events.append(self._next(deadline))

    def close(self):
        try:
            self.call("Browser.close", timeout=5.0)
        except (RuntimeError, queue.Empty, OSError):
            pass
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


SCENE_PROBE = """(() => {
  let meshes = 0, lines = 0;
  viewer.scene.traverse(o => { if (o.isMesh) meshes++; if (o.isLine) lines++; });
  const animations = viewer.gui.__folders.Animations;
  return {meshes, lines, duration: viewer.animator.duration, controls_open: !viewer.gui.closed,
          animations_open: !animations.closed, legend: !!document.getElementById("quad-drake-legend")};
})()"""


@pytest.mark.browser
@pytest.mark.slow
def test_replay_loads_offline_and_draws_in_headless_chromium(flight, tmp_path):
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("chromium not installed (apt-get install chromium; .ci/run installs it)")
    result, path = flight
    browser = DevTools(chromium, tmp_path / "profile")
    try:
        targets = browser.call("Target.getTargets")["targetInfos"]
        page = next(t for t in targets if t["type"] == "page")
        session = browser.call("Target.attachToTarget", {"targetId": page["targetId"], "flatten": True})[
            "sessionId"
        ]
        for domain in ("Network", "Page", "Runtime"):
            browser.call(f"{domain}.enable", session=session)
        browser.call("Page.navigate", {"url": path.as_uri()}, session=session)
        browser.wait_for("Page.loadEventFired")
        time.sleep(1.5)  # let three.js render frames
        scene = browser.call(
            "Runtime.evaluate", {"expression": SCENE_PROBE, "returnByValue": True}, session=session
        )["result"]["value"]
        shot = browser.call("Page.captureScreenshot", {"format": "png"}, session=session)["data"]
    finally:
        browser.close()

    urls = [
        e["params"]["request"]["url"]
        for e in browser.events
        if e.get("method") == "Network.requestWillBeSent"
    ]
    assert path.as_uri() in urls  # the log does see requests
    assert [u[:60] for u in urls if not u.startswith(("file:", "data:", "blob:"))] == []
    errors = [e["params"] for e in browser.events if e.get("method") == "Runtime.exceptionThrown"]
    assert errors == []
    assert scene["meshes"] >= 13  # quad (12 parts) + estimate
    assert scene["lines"] >= 3  # flown, reference, estimated
    assert math.isclose(scene["duration"], result.times[-1], abs_tol=0.05)
    assert scene["controls_open"] and scene["animations_open"] and scene["legend"]  # not a closed panel

    import matplotlib.image

    image = matplotlib.image.imread(io.BytesIO(base64.b64decode(shot)), format="png")[..., :3]
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    estimated_path = (r > 0.6) & (g < 0.35) & (b > 0.4)  # magenta line
    flown_path = (r < 0.3) & (g > 0.3) & (g < 0.65) & (b > 0.55)  # the vehicle's blue
    assert estimated_path.sum() > 50 and flown_path.sum() > 50, (estimated_path.sum(), flown_path.sum())
