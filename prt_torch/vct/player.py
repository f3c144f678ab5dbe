"""``prt play RUN --renderer sg``: the player with seed 004's renderer instead of the ONNX graphs.

:class:`SGPlayer` is a :class:`~prt_torch.player.player.Player` (same posing, camera, tone map, mesh renderer,
video/PNG writers and timings) whose radiance per frame comes from
:class:`prt_torch.vct.renderer.SGVCTRenderer`: the posed mesh voxelised, cones traced from every vertex, SG
lighting x SG BRDF x cone visibility. No model is evaluated: cone-traced soft shadows follow the animation
whatever the pose. The lighting is the player's: the HDR ``env`` file, or the procedural sky with its sun as a
small disk (:func:`sg_environment`), fitted once by :func:`prt_torch.sg.shading.sg_light_from_env`.

torch, healpy and the SG/VCT modules are imported lazily inside the functions: the player's base install has
no torch and never imports this module unless ``--renderer sg`` is asked for.
"""

from __future__ import annotations

import math
import os
import time
from typing import Any

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.player.player import Player


def sg_environment(env: str | os.PathLike[str] | None) -> Any:
    """The player's lighting as an :class:`~prt_torch.light.envmap.EnvMap` at full resolution: the ``env`` file,
    or the procedural sky (:func:`prt_torch.light.sources.sky_envmap`) plus its sun (direction and power of
    :data:`~prt_torch.player.lighting.DEFAULT_SUN_DIRECTION` / ``DEFAULT_SUN_COLOR``, the half-angle of
    :func:`prt_torch.light.sources.sky_sh`) as a disk."""
    import inspect

    from prt_torch.light.envmap import load_envmap
    from prt_torch.light.sources import sky_envmap, sky_sh
    from prt_torch.player.lighting import DEFAULT_SUN_COLOR, DEFAULT_SUN_DIRECTION
    from prt_torch.sg.shading import add_sun_disk, sun_map_height

    if env is not None and str(env) not in ("", "sky"):
        return load_envmap(env)
    half = float(inspect.signature(sky_sh).parameters["sun_half_angle"].default)
    sun = np.asarray(DEFAULT_SUN_DIRECTION, dtype=np.float64)
    sun = sun / np.linalg.norm(sun)
    sky = sky_envmap(sun, height=sun_map_height(half))
    return add_sun_disk(sky, sun, half, np.asarray(DEFAULT_SUN_COLOR), source="procedural sky + sun disk")


class SGPlayer(Player):
    """A :class:`Player` rendering with SG lighting and voxel cone-traced visibility (module docstring).

    Args:
        run_dir: an exported run (its character, vertex frames and BRDF names are used; not its models).
        env: HDR environment map, or ``None`` for the procedural sky + sun.
        brdf: a catalogue BRDF name (``lambert``, ``phong``, ``blinn``, ``ggx``, ``ward``); default the run's first
            (for a character with its own material too: :attr:`Player.shades_material`).
        resolution: voxel grid side (64-256). peaks: extra cones toward the light peaks (seed 004 Fig. 8).
        device: torch device (``"cpu"``, ``"cuda"``). max_level: HEALPix scales of the light fit.
        **kwargs: passed to :class:`Player` (``window_size``, ``exposure``, ...).
    """

    shades_material = False  # SG fits of the catalogue BRDFs only: a glTF character's default is the catalogue's first

    def __init__(self, run_dir: Any, env: str | os.PathLike[str] | None = None, brdf: str | None = None,
                 resolution: int = 128, peaks: bool = True, device: str = "cpu", max_level: int = 2,
                 **kwargs: Any) -> None:
        from prt_torch.vct.grid import check_resolution

        check_resolution(resolution)
        super().__init__(run_dir, env=env, brdf=brdf, graph="split", **kwargs)
        self.env = env
        self.resolution = int(resolution)
        self.sg_peaks = bool(peaks)  # seed 004 cone peaks (not the player's peak lights, Player.peaks)
        self.sg_device = device
        self.max_level = int(max_level)
        self._sg: Any = None
        self._sg_angle = 0.0
        self._sg_light: Any = None

    def _sgvct(self) -> Any:
        """The :class:`~prt_torch.vct.renderer.SGVCTRenderer` (built on first use; rebuilt when the BRDF or the
        light rotation changed)."""
        from prt_torch.brdf.rpo import CATALOGUE, builtin_brdf
        from prt_torch.sg.brdf_fit import fit_brdf_sg
        from prt_torch.sg.shading import sg_light_from_env
        from prt_torch.vct.renderer import SGVCTRenderer

        name = self.rpo.name
        if name not in CATALOGUE:
            raise PrtError(f"--renderer sg shades catalogue BRDFs ({', '.join(CATALOGUE)}), not {name!r}")
        if self._sg_light is None:
            self._sg_light = sg_light_from_env(sg_environment(self.env), peaks=True, max_level=self.max_level)
        stale = self._sg is None or self._sg_brdf != name or self._sg_angle != self.light_angle
        if stale:
            light = _rotated(self._sg_light, self.light_angle)
            self._sg = SGVCTRenderer(np.asarray(self.character.faces), {name: fit_brdf_sg(builtin_brdf(name))}, light,
                                     self.resolution, peaks=self.sg_peaks, device=self.sg_device)
            self._sg_brdf, self._sg_angle = name, self.light_angle
        return self._sg

    def shade(self, state: Any, visibility: np.ndarray | None = None, checked: bool = True,
              timer: Any = None) -> np.ndarray:
        """Radiance ``(B, V, 3)`` float32 of the posed batch by SG + VCT (``visibility`` must be ``None``)."""
        if visibility is not None:
            raise PrtError("the sg renderer traces its own visibility; it takes no visibility input")
        r = self._sgvct()
        name = self.rpo.name
        eye = self.eye
        b = state.frames.shape[0]
        out = np.empty((b, self.bundle.n_vertices, 3), np.float32)
        for i in range(b):  # characters of the batch (1 when playing)
            t0 = time.perf_counter()
            nrm = np.ascontiguousarray(state.normals[i].T)
            rad = r.radiance(state.positions_vx3(i), nrm, eye)[name]
            out[i] = rad.detach().cpu().numpy()
            if timer is not None:  # the player's compute steps: visibility = voxelise + trace, shading = SG shade
                t = r.times
                timer.add("visibility", t.voxelize + t.trace)
                timer.add("shading", time.perf_counter() - t0 - t.voxelize - t.trace)
                timer.add("voxelize", t.voxelize)
        return out


def _rotated(light: Any, angle: float) -> Any:
    """The SG light rotated by ``angle`` radians about the world z axis."""
    if angle == 0.0:
        return light
    import torch

    from prt_torch.sg.lobes import SGLobes
    from prt_torch.sg.shading import SGLight

    c, s = math.cos(angle), math.sin(angle)
    R = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def rot(lo: SGLobes) -> SGLobes:
        return SGLobes(lo.axis @ R.to(lo.axis).T, lo.sharpness, lo.amplitude) if len(lo) else lo

    return SGLight(rot(light.lobes), rot(light.peak_lobes), light.peak_index, light.peak_dirs @ R.to(light.peak_dirs).T,
                   light.peak_solid_angle, light.rel_error, light.source)
