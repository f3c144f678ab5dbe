"""Drives the interactive window in a process of its own (tests/player/test_viewer.py runs it under Xvfb): VTK picks
its render window kind once per process - after one window was made without a display every later one is an
offscreen EGL window - so the window tests cannot share the test session's process.

``python -m tests.player.viewer_driver player RUN OUT.json`` plays ``wave`` of the run in a window on a fake clock,
presses keys through the interactor (``SetKeySym`` + ``KeyPressEvent`` + ``CharEvent``: pyvista's key table and VTK's
interactor style run as for a real key) at scripted ticks and writes what it saw; ``... close OUT.json`` closes a
window through its ExitEvent (the window manager's close)."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from typing import Any

import numpy as np

from prt_torch.player.viewer import Viewer

BACKGROUND = np.round(np.array([0.08, 0.08, 0.1]) * 255)


class FakeClock:
    """A clock that moves only when the loop sleeps, by ``step`` seconds (a dyadic step: exact float times)."""

    def __init__(self, step: float = 0.125) -> None:
        self.t, self.step = 0.0, step

    def __call__(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        assert seconds >= 0
        self.t += self.step


def press(viewer: Viewer, keysym: str, char: str = "") -> None:
    """One key as the X interactor delivers it: the key sym and code, the press, the char event, the release."""
    it = viewer.plotter.iren.interactor
    it.SetKeySym(keysym)
    it.SetKeyCode(char[:1] or "\0")
    it.InvokeEvent("KeyPressEvent")
    it.InvokeEvent("CharEvent")
    it.InvokeEvent("KeyReleaseEvent")


def key_text(viewer: Viewer) -> str:
    return str(viewer.plotter.actors["prt-keys"].GetText(2))  # vtkCornerAnnotation: upper left


def status_text(viewer: Viewer) -> str:
    return str(viewer.plotter.actors["prt-status"].GetText(0))  # lower left


def drive_player(run: str) -> dict[str, Any]:
    from prt_torch.player.player import Player

    player = Player(run, brdf="lambert", threads=1, window_size=(120, 160))
    clip = "wave"
    n, fps = player.character.clip(clip).num_frames, float(player.character.clip(clip).fps)
    clock = FakeClock()
    log: list[dict[str, Any]] = []
    seen: dict[str, Any] = {"n": n, "fps": fps}
    t0 = int(1.5 * n / fps / clock.step)  # a tick after the clip has looped once
    seen["t0"] = t0

    def opened(v: Viewer) -> None:
        rw = v.plotter.render_window
        seen["window"] = [type(rw).__name__, int(rw.GetMapped()), list(rw.GetSize())]
        img = v.plotter.screenshot(return_img=True)[..., :3].astype(int)
        seen["drawn_pixels"] = int((np.abs(img - BACKGROUND).max(-1) > 8).sum())
        seen["keys_text"] = key_text(v)

    def around(name: str, keysym: str, char: str, value: Callable[[], Any]) -> Callable[[Viewer], None]:
        def run(v: Viewer) -> None:
            before = value()
            press(v, keysym, char)
            seen[name] = [before, value()]
        return run

    def mark(name: str, value: Callable[[Viewer], Any], keysym: str | None = None, char: str = "") \
            -> Callable[[Viewer], None]:
        def run(v: Viewer) -> None:
            seen[name] = value(v)
            if keysym is not None:
                press(v, keysym, char)
        return run

    script: dict[int, Callable[[Viewer], None]] = {
        1: opened,
        t0: mark("paused_at", lambda v: v.shown, "space", " "),
        t0 + 4: mark("paused_status", status_text),
        t0 + 5: mark("next_from", lambda v: v.shown, "period", "."),
        t0 + 7: mark("previous_from", lambda v: v.shown, "comma", ","),
        t0 + 9: mark("resume", lambda v: [v.shown, clock.t], "space", " "),
        t0 + 20: around("left", "Left", "", lambda: player.camera_azimuth),
        t0 + 21: around("up", "Up", "", lambda: player.camera_elevation),
        t0 + 22: around("light", "l", "l", lambda: player.light_angle),
        t0 + 23: around("brdf", "b", "b", lambda: str(player.rpo.name)),
        t0 + 24: mark("keys_before_h", key_text, "h", "h"),
        t0 + 25: mark("keys_hidden", key_text),
        t0 + 26: mark("quit_at", lambda v: v.ticks, "q", "q"),
    }

    def on_tick(v: Viewer) -> None:
        cam = v.plotter.camera
        log.append({"tick": v.ticks, "t": clock.t, "shown": v.shown, "paused": v.playback.paused,
                    "focal": list(cam.focal_point), "position": list(cam.position),
                    "azimuth": player.camera_azimuth, "elevation": player.camera_elevation})
        fn = script.get(v.ticks)
        if fn is not None:
            fn(v)
        if v.ticks > t0 + 40:
            raise RuntimeError("q did not close the window")

    try:
        res = player.play(clip, show=True, viewer={"clock": clock, "sleep": clock.sleep, "on_tick": on_tick})
        seen["frames"] = res.frames
        seen["renderer_after"] = player._renderer is None
        track = player.follow(clip)
        seen["track_center"] = track.center.tolist()
        seen["track_radius"] = track.radius.tolist()
        seen["brdf_names"] = list(player.bundle.brdf_names)
    finally:
        player.close()
    seen["log"] = log
    return seen


def drive_close() -> dict[str, Any]:
    from prt_torch.player.render import MeshRenderer
    from prt_torch.rig.builtin import make_character

    ch = make_character(density=0.05)
    r = MeshRenderer(ch.rest_vertices, ch.faces, window_size=(96, 64), off_screen=False)
    pos = ch.skin_mesh(ch.pose("walk"))[0]
    clock = FakeClock()
    drawn: list[int] = []

    def draw(i: int) -> None:
        drawn.append(i)
        r.update(pos[i], np.full((ch.num_vertices, 3), 200, np.uint8))

    def on_tick(v: Viewer) -> None:
        if v.ticks == 5:
            v.plotter.iren.interactor.InvokeEvent("ExitEvent")
        if v.ticks > 20:
            raise RuntimeError("the close did not end the loop")

    v = Viewer(r, len(pos), 10.0, draw, clock=clock, sleep=clock.sleep, on_tick=on_tick)
    returned = v.run()
    return {"returned": returned, "drawn": len(drawn), "closed": v.closed, "ticks": v.ticks,
            "render_window_none": v.plotter.render_window is None}


def main(argv: list[str]) -> int:
    mode, out = argv[0], argv[-1]
    result = drive_player(argv[1]) if mode == "player" else drive_close()
    with open(out, "w") as f:
        json.dump(result, f)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
