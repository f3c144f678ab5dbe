"""The interactive window: a clip played at its own rate by the wall clock, looping until closed.

:class:`Playback` is the schedule (which frame is due now; pause, resume, step), with an injectable clock so that
what it does never depends on how fast a machine draws: the frame due at time ``t`` after ``(t0, f0)`` (the last
time the schedule was anchored: start, resume, step) is ``(f0 + floor((t - t0) fps)) mod n``. A frame that takes
longer than ``1 / fps`` to draw makes the window skip frames, never slow the clip down.

:class:`Viewer` runs a :class:`~prt_torch.player.render.MeshRenderer` window (``off_screen=False``) on that schedule:
each tick it asks the schedule for the due frame, draws it when it changed (``draw(frame)``, the caller's: pose,
shade and update the mesh), lets VTK handle the window's events (the keys below arrive through the render window
interactor's ``KeyPressEvent``, pyvista's key table), renders, and sleeps until the next frame is due. Keys
(:data:`KEYS`, listed in the window and toggled with ``h``): ``space`` pause / play, ``period`` / ``comma`` one
frame forward / back (pausing), ``Left`` / ``Right`` / ``Up`` / ``Down`` orbit the camera, ``l`` turn the light,
``b`` next BRDF, ``h`` the key list, ``q`` / ``Escape`` (or closing the window) quit. The window closes when the
loop ends.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from prt_torch.errors import PrtError, check, warn

#: ``(keysym, what it does)`` of the window's keys, in the order the window lists them
KEYS: tuple[tuple[str, str], ...] = (
    ("space", "pause / play"),
    ("period", "next frame (pauses)"),
    ("comma", "previous frame (pauses)"),
    ("Left", "orbit left"),
    ("Right", "orbit right"),
    ("Up", "orbit up"),
    ("Down", "orbit down"),
    ("l", "turn the light 15 deg"),
    ("b", "next BRDF"),
    ("h", "show / hide these keys"),
    ("q", "quit (also Escape)"),
)
#: the longest the loop sleeps between ticks (seconds): keys are handled at least this often
MAX_IDLE = 1.0 / 60.0


class Playback:
    """Which frame of an ``n``-frame clip at ``fps`` is due (module docstring), looping (``loop``) or holding the
    last frame. ``clock()``: seconds, monotonic (default :func:`time.perf_counter`)."""

    def __init__(self, n: int, fps: float, clock: Callable[[], float] = time.perf_counter, loop: bool = True) -> None:
        check(int(n) >= 1, f"playback needs at least one frame, got {n}")
        check(math.isfinite(fps) and fps > 0, f"playback rate must be > 0 frames/s, got {fps}")
        self.n, self.fps, self.loop = int(n), float(fps), loop
        self.clock = clock
        self.paused = False
        self._f0, self._t0 = 0, clock()

    def restart(self) -> None:
        """Play from frame 0 now."""
        self._f0, self._t0, self.paused = 0, self.clock(), False

    def _wrap(self, f: int) -> int:
        return f % self.n if self.loop else min(max(f, 0), self.n - 1)

    def frame(self) -> int:
        """The frame due now."""
        if self.paused:
            return self._f0
        return self._wrap(self._f0 + int(math.floor((self.clock() - self._t0) * self.fps)))

    def until_next(self) -> float:
        """Seconds until the due frame changes (``inf`` while paused or held at the end)."""
        if self.paused or (not self.loop and self.frame() == self.n - 1):
            return math.inf
        elapsed = (self.clock() - self._t0) * self.fps
        return max(0.0, (math.floor(elapsed) + 1 - elapsed) / self.fps)

    def pause(self) -> None:
        if not self.paused:
            self._f0, self.paused = self.frame(), True

    def resume(self) -> None:
        """Play on from the frame shown (it stays on screen for a whole frame time)."""
        if self.paused:
            self._t0, self.paused = self.clock(), False

    def toggle(self) -> None:
        self.resume() if self.paused else self.pause()

    def step(self, k: int) -> None:
        """Pause and move ``k`` frames (wrapping when looping)."""
        self.pause()
        self._f0 = self._wrap(self._f0 + int(k))


class Viewer:
    """An interactive window playing frames ``0 .. n-1`` at ``fps`` (module docstring).

    Args:
        renderer: a :class:`~prt_torch.player.render.MeshRenderer` with ``off_screen=False``.
        n, fps: frames and rate of the clip.
        draw: ``draw(frame)`` updates the renderer's mesh (and camera) for ``frame``.
        actions: what the non-playback keys do: ``{"Left": fn, ...}`` (keys of :data:`KEYS`; a missing one does
            nothing); each action redraws the frame shown.
        title: the window's title.
        clock, sleep: the schedule's clock and the loop's sleep (injectable: a test runs the loop on a fake clock).
        on_tick: ``on_tick(viewer)`` after each tick (a test drives keys from there).
    """

    def __init__(self, renderer: Any, n: int, fps: float, draw: Callable[[int], None],
                 actions: dict[str, Callable[[], Any]] | None = None, title: str = "prt play",
                 clock: Callable[[], float] = time.perf_counter, sleep: Callable[[float], None] = time.sleep,
                 on_tick: Callable[[Viewer], None] | None = None) -> None:
        check(not renderer.off_screen, "the viewer needs a window renderer (off_screen=False)")
        self.renderer = renderer
        self.plotter = renderer.plotter
        self.playback = Playback(n, fps, clock)
        self.draw = draw
        self.actions = dict(actions or {})
        self.title = title
        self.sleep = sleep
        self.on_tick = on_tick
        self.closed = False
        self.show_keys = True
        self.shown: int | None = None  # the frame on screen
        self.drawn = 0  # frames drawn
        self.ticks = 0
        self._dirty = True
        self._on_screen: dict[str, str] = {}  # the texts shown

    # -- keys --------------------------------------------------------------------------------------------------
    def _bind(self) -> None:
        pl = self.plotter
        pl.iren.clear_key_event_callbacks()  # pyvista's defaults (b picks, Up/Down zoom) would fight these keys
        table: dict[str, Callable[[], Any]] = {
            "space": lambda: self.playback.toggle(),
            "period": lambda: self.playback.step(1),
            "comma": lambda: self.playback.step(-1),
            "h": self._toggle_keys,
            "q": self.close,
            "Escape": self.close,
        }
        for key, fn in self.actions.items():
            table[key] = self._redrawing(fn)
        for key, fn in table.items():
            pl.add_key_event(key, fn)
        # the window's close button and VTK's own q / e (the interactor style's char events) end the loop too
        pl.iren.interactor.AddObserver("ExitEvent", lambda *_: self.close())

    def _redrawing(self, fn: Callable[[], Any]) -> Callable[[], None]:
        def run() -> None:
            try:
                fn()
            except PrtError as e:  # e.g. a renderer whose BRDF is fixed: a warning, the window plays on
                warn(str(e))
            self._dirty = True

        return run

    def _toggle_keys(self) -> None:
        self.show_keys = not self.show_keys

    def close(self) -> None:
        """End the loop (the window closes when it returns)."""
        self.closed = True

    # -- the window's text -------------------------------------------------------------------------------------
    def status(self) -> str:
        """The status line: frame, rate and state."""
        pb = self.playback
        state = "paused" if pb.paused else "playing"
        return f"frame {self.shown if self.shown is not None else 0} / {pb.n}  {pb.fps:g} frames/s  {state}"

    def _text(self) -> None:
        """Put the status line and the key list on screen (only what changed)."""
        pl = self.plotter
        status = self.status()
        keys = "\n".join(f"{k:<7} {what}" for k, what in KEYS) if self.show_keys else "h  keys"
        if status != self._on_screen.get("status"):
            pl.add_text(status, position="lower_left", font_size=9, name="prt-status")
        if keys != self._on_screen.get("keys"):
            pl.add_text(keys, position="upper_left", font_size=8, name="prt-keys")
        self._on_screen.update(status=status, keys=keys)

    # -- the loop ----------------------------------------------------------------------------------------------
    def tick(self) -> None:
        """Handle the window's events (keys -> the callbacks above), draw the due frame if it changed, render."""
        self.plotter.iren.process_events()
        if self.closed:
            return
        f = self.playback.frame()
        if f != self.shown or self._dirty:
            self._dirty = False
            self.draw(f)
            self.shown = f
            self.drawn += 1
        self._text()  # the status (paused / playing) changes without a new frame
        self.plotter.render()
        self.ticks += 1

    def run(self) -> int:
        """Open the window, play until closed; returns the frames drawn."""
        pl = self.plotter
        pl.title = self.title
        self._bind()
        self.draw(0)
        self.shown, self.drawn = 0, 1
        self._dirty = False
        self._text()
        pl.show(interactive_update=True, auto_close=False)
        self.playback.restart()  # the clip starts now
        try:
            while not self.closed:
                self.tick()
                if self.on_tick is not None:
                    self.on_tick(self)
                if not self.closed:
                    self.sleep(min(self.playback.until_next(), MAX_IDLE))
        finally:
            self.renderer.close()
        return self.drawn
