"""``prt play RUN --renderer s001|posespace``: the player with seed 001's run time instead of the ONNX graphs.

:class:`S001RunPlayer` is a :class:`~prt_torch.player.player.Player` (same posing, camera, tone map, mesh renderer,
video/PNG writers and timings) whose radiance per frame comes from :class:`prt_torch.s001.player.S001Player`: the
run's compressed transfer matrices (``s001.npz``, ``prt train`` with ``train.s001``) interpolated at the frame's pose
features (``s001``: eq. 7 per segment; ``posespace``: Table 3's global baseline) and shaded in eq. 9's order with
the player's lighting (``--env`` or the procedural sky, SH of the matrices' order, rotated by ``--light-angle``) and
the BRDF matrix of a catalogue BRDF, ``H, G = factor(brdf_matrix(brdf, order), 4)``, times the BRDF's tint (the rule
of ``prt compare``'s ``s001`` method).

The run need not be exported: the posing takes the character and the bake's vertex clusters (``cluster``,
``cluster_axis``, ``cluster_bone`` of the dataset, the arrays ``prt export`` copies into its frame data). numpy +
scipy only: this path never imports torch.
"""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.player.player import CAMERA_AZIMUTH, CAMERA_ELEVATION, Player, camera_target
from prt_torch.player.timing import FrameTimer

#: factored terms of the BRDF matrix (seed 001 uses 4; ``prt compare``'s s001 method too)
N_TERMS = 4


class _Info:
    """The few fields of a :class:`~prt_torch.player.bundle.RunBundle` / ``RPOTensors`` that :meth:`Player.play`
    records in its timings."""

    def __init__(self, **kw: Any) -> None:
        self.__dict__.update(kw)


class S001RunPlayer(Player):
    """A :class:`Player` shading with seed 001's compressed transfer matrices (module docstring).

    Args:
        run_dir: a run with ``s001.npz`` and its dataset's vertex clusters (exported or not).
        env: HDR environment map, or ``None`` for the procedural sky + sun.
        brdf: a catalogue BRDF name (``lambert``, ``phong``, ``blinn``, ``ggx``, ``ward``); default the first.
        scheme: ``"s001"`` or ``"posespace"`` (:class:`~prt_torch.s001.player.S001Player`).
        window_size: render size in pixels.
    """

    def __init__(self, run_dir: Any, env: str | os.PathLike[str] | None = None, brdf: str | None = None,
                 scheme: str = "s001", window_size: tuple[int, int] = (480, 640), n_lobes: int = 3,
                 **_: Any) -> None:
        from prt_torch.brdf.rpo import CATALOGUE, builtin_brdf
        from prt_torch.player.lighting import load_lighting
        from prt_torch.player.peaks import PeakLighting
        from prt_torch.player.posing import Poser
        from prt_torch.rundir import RunDir
        from prt_torch.s001.brdf_matrix import brdf_matrix, factor
        from prt_torch.s001.player import S001Player
        from prt_torch.s001.posespace import CompressedTransfer

        run = RunDir.of(run_dir)
        if not run.s001.is_file():
            raise PrtError(f"--renderer {scheme}: {run.s001} missing: train the run with a train.s001 config "
                           f"(e.g. configs/s001.yaml)")
        name = brdf or next(iter(CATALOGUE))
        if name not in CATALOGUE:
            raise PrtError(f"--renderer {scheme} shades catalogue BRDFs ({', '.join(CATALOGUE)}), not {name!r}")
        self._blas_limit = None
        self._pool = None
        self._renderer = None
        self.data = CompressedTransfer.load(run.s001)
        self.s001 = S001Player(self.data, scheme)  # type: ignore[arg-type]
        self.character = run.character()
        check(self.character.num_vertices == self.data.n_vertices,
              f"{run.s001} has {self.data.n_vertices} vertices, the run's character {self.character.num_vertices}")
        ds = run.dataset()
        self.poser = Poser(self.character, np.asarray(ds.cluster).astype(np.intp),
                           np.asarray(ds.cluster_axis, np.float32), np.asarray(ds.cluster_bone).astype(np.intp))
        self.order = self.s001.order
        self.graph = scheme
        self.vertex_order = None
        self.device = "cpu"
        self.crowd_chunk = None
        self.window_size = window_size
        self.exposure = None
        self.lighting = load_lighting(env, self.order, n_lobes)
        self.peaks = PeakLighting(self.lighting, [], None)  # the whole lighting (the sun included) on its own path
        self.peak_source = None
        self._peak_dirs = self.peaks.directions
        self.light_angle = 0.0
        self._lobe_dirs = self.lighting.dirs
        b = builtin_brdf(name)
        self._factors = {name: factor(brdf_matrix(b, self.order), N_TERMS)}
        self._tint = np.asarray(getattr(b, "tint", np.ones(3)), np.float32)
        self.rpo = _Info(name=name)  # type: ignore[assignment]
        self.bundle = _Info(n_vertices=self.data.n_vertices)  # type: ignore[assignment]
        self._shading_angle: float | None = None
        self.center, self.radius = camera_target(self.character.rest_vertices)
        self.camera_azimuth = CAMERA_AZIMUTH
        self.camera_elevation = CAMERA_ELEVATION

    def set_brdf(self, name: str) -> None:  # pragma: no cover - interactive key
        raise PrtError(f"--renderer {self.graph}: the BRDF is fixed when the player starts (--brdf)")

    def next_brdf(self) -> str:  # pragma: no cover - interactive key
        return str(self.rpo.name)

    def light_sh(self) -> np.ndarray:
        """The global SH lighting ``(C, 3)`` float64 shaded with: the player's, rotated by :attr:`light_angle`."""
        lit = self.lighting.rotated_about_z(self.light_angle) if self.light_angle else self.lighting
        return np.asarray(lit.sh, np.float64)

    def shade(self, state: Any, visibility: np.ndarray | None = None, checked: bool = True,
              timer: FrameTimer | None = None, rpo: Any = None) -> np.ndarray:
        """Radiance ``(B, V, 3)`` float32 of the posed batch (eq. 9, times the BRDF's tint)."""
        if visibility is not None or rpo is not None:
            raise PrtError(f"the {self.graph} renderer interpolates its own transfer; it takes no visibility input")
        t0 = time.perf_counter()
        if self._shading_angle != self.light_angle:  # Q_i = G^T U_i once; the lighting when it turned
            self.s001.set_shading(self._factors, self.light_sh())
            self._shading_angle = self.light_angle
        name = str(self.rpo.name)
        eye = self.eye
        frames = state.frames_vx33()  # (B, V, 3, 3)
        out = np.empty((*frames.shape[:2], 3), np.float32)
        for i in range(len(frames)):  # characters of the batch (1 when playing)
            rad = self.s001.radiance(state.features[i], frames[i], state.positions_vx3(i), eye)[name]
            out[i] = rad * self._tint
        if timer is not None:
            timer.add("shading", time.perf_counter() - t0)
        return out
