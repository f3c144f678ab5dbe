"""The interactive window (prt_torch.player.viewer), under Xvfb: the schedule on an injected clock (the frame due at
time t is floor(t fps) mod n from its last anchor: plays at the clip's rate, loops, pauses, steps), and the real
window of ``Player.play(show=True)``, driven in a process of its own (tests/player/viewer_driver.py): it opens (an X
window of the asked size, the character drawn), each key - delivered as the X interactor delivers one,
``SetKeySym`` + ``KeyPressEvent`` + ``CharEvent`` through VTK, so pyvista's key table and VTK's interactor style
run - does what the key list says, the camera follows the clip, and ``q`` (or the window's close, VTK's
ExitEvent) ends the loop and closes the window."""

from __future__ import annotations

import json
import math
import os
import select
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from prt_torch.player.viewer import KEYS, Playback
from tests.player.viewer_driver import FakeClock

XVFB = shutil.which("Xvfb")
needs_x = pytest.mark.skipif(XVFB is None, reason="Xvfb absent (scripts/setup.sh installs it): no X server for "
                                                  "the window tests")


@pytest.fixture(scope="module")
def display() -> Iterator[str]:
    """An Xvfb server for this module; ``DISPLAY`` points at it while the module runs."""
    assert XVFB is not None
    r, w = os.pipe()
    proc = subprocess.Popen([XVFB, "-displayfd", str(w), "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
                            pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(w)
    buf = b""
    while not buf.endswith(b"\n"):
        ready, _, _ = select.select([r], [], [], 20.0)
        chunk = os.read(r, 64) if ready else b""
        if not chunk:
            proc.kill()
            pytest.fail("Xvfb did not report its display within 20 s")
        buf += chunk
    os.close(r)
    old = os.environ.get("DISPLAY")
    os.environ["DISPLAY"] = f":{int(buf)}"
    try:
        yield os.environ["DISPLAY"]
    finally:
        if old is None:
            os.environ.pop("DISPLAY", None)
        else:
            os.environ["DISPLAY"] = old
        proc.terminate()
        proc.wait(timeout=20)


def test_playback_schedule():
    clock = FakeClock()
    n, fps = 7, 10.0
    pb = Playback(n, fps, clock)
    for k in range(40):  # plays at the clip's rate and loops: frame = floor(t fps) mod n
        clock.t = k * 0.0625
        assert pb.frame() == math.floor(clock.t * fps) % n
        left = pb.until_next()
        assert 0 < left <= 1 / fps and math.floor((clock.t + left) * fps + 1e-9) == math.floor(clock.t * fps) + 1
    clock.t = 1.0  # frame 10 % 7 = 3
    pb.pause()
    held = pb.frame()
    assert held == 3
    clock.t = 5.0
    assert pb.frame() == held and pb.until_next() == math.inf  # paused: time passes, the frame stays
    pb.step(1)
    assert pb.frame() == 4 and pb.paused
    pb.step(-6)
    assert pb.frame() == 5  # 4 - 6 wraps to 5
    pb.resume()
    assert pb.frame() == 5  # resumes from the frame shown
    clock.t = 5.0 + 0.25
    assert pb.frame() == (5 + 2) % n
    pb.toggle()
    assert pb.paused and pb.frame() == 0
    hold = Playback(3, fps, clock, loop=False)
    clock.t += 10.0
    assert hold.frame() == 2 and hold.until_next() == math.inf
    with pytest.raises(Exception, match="rate must be > 0"):
        Playback(3, 0.0, clock)


ROOT = Path(__file__).resolve().parents[2]


def drive(mode: str, display: str, out: Path, *args: str) -> dict:
    """Run tests/player/viewer_driver.py in a fresh process on ``display``; its JSON report."""
    env = {**os.environ, "DISPLAY": display}
    proc = subprocess.run([sys.executable, "-m", "tests.player.viewer_driver", mode, *args, str(out)], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"the window driver failed:\n{proc.stderr[-4000:]}"
    return json.loads(out.read_text())


@needs_x
def test_window_plays_keys_and_closes(tiny_run: Path, display: str, tmp_path: Path):
    from prt_torch.player.player import camera_eye

    s = drive("player", display, tmp_path / "player.json", str(tiny_run))
    n, fps, t0, log = s["n"], s["fps"], s["t0"], s["log"]
    kind, mapped, size = s["window"]
    assert kind == "vtkXOpenGLRenderWindow" and mapped and size == [160, 120]  # an X window of the asked size
    assert s["drawn_pixels"] > 200  # the character on the background
    for keysym, _ in KEYS:  # the window lists its keys
        assert keysym in s["keys_text"]
    # every frame at its own follow camera (the orbit keys applied): the track's centre and eye
    center, radius = np.asarray(s["track_center"]), np.asarray(s["track_radius"])
    for e in log:
        c = center[e["shown"]].astype(np.float32)
        want = camera_eye(c, float(radius[e["shown"]]), e["azimuth"], e["elevation"])
        np.testing.assert_allclose(e["focal"], c, rtol=0, atol=1e-6)  # float32 values carried in float64
        np.testing.assert_allclose(e["position"], want, rtol=0, atol=1e-6)
    assert len({e["shown"] for e in log}) == n and np.ptp(center[:, 2]) > 0  # the camera moves with the clip
    # before the pause: the clip at its rate from t = 0, looping
    before = [e for e in log if e["tick"] <= t0]
    assert before[-1]["t"] * fps > n
    for e in before:
        assert e["shown"] == math.floor(e["t"] * fps) % n and not e["paused"]
    # space: the frame holds while the clock runs; the status line says so
    held = [e for e in log if t0 < e["tick"] <= t0 + 5]
    assert {e["shown"] for e in held} == {s["paused_at"]} and all(e["paused"] for e in held)
    assert "paused" in s["paused_status"] and held[-1]["t"] - held[0]["t"] >= 4 * 0.125
    # period / comma: one frame forward / back, still paused
    tick = {e["tick"]: e for e in log}
    assert tick[t0 + 6]["shown"] == (s["next_from"] + 1) % n and tick[t0 + 6]["paused"]
    assert tick[t0 + 8]["shown"] == (s["previous_from"] - 1) % n and tick[t0 + 8]["paused"]
    # space again: on from the frame shown, at the clip's rate
    f_r, t_r = s["resume"]
    for k in range(t0 + 10, t0 + 20):
        e = tick[k]
        assert not e["paused"] and e["shown"] == (f_r + math.floor((e["t"] - t_r) * fps)) % n
    # the other keys do what the list says
    assert math.isclose(s["left"][1] - s["left"][0], -np.radians(10), abs_tol=1e-12)
    assert math.isclose(s["up"][1] - s["up"][0], np.radians(8), abs_tol=1e-12)
    assert math.isclose(s["light"][1] - s["light"][0], np.radians(15), abs_tol=1e-12)
    names = s["brdf_names"]
    assert s["brdf"][1] == names[(names.index(s["brdf"][0]) + 1) % len(names)]
    assert "pause" in s["keys_before_h"] and "pause" not in s["keys_hidden"]
    # q: the loop ended on that tick, the window closed
    assert log[-1]["tick"] == s["quit_at"] == t0 + 26
    assert s["renderer_after"] and s["frames"] >= n


@needs_x
def test_window_close_ends_the_loop(display: str, tmp_path: Path):
    """The window's close (the interactor's ExitEvent, what VTK raises for the window manager's close) ends the loop
    on that tick; the plotter is closed afterwards."""
    s = drive("close", display, tmp_path / "close.json")
    assert s["closed"] and s["ticks"] == 5 and s["render_window_none"] and s["returned"] == s["drawn"] >= 1
