"""``sg_vct``: seed 004's renderer, no bake at all: SG lighting (multiscale HEALPix fit + peaks), SG BRDF lobes,
visibility by voxel cone tracing of each posed frame (:class:`prt_torch.vct.renderer.SGVCTRenderer`).

A ``radiance`` method. Its frame time counts voxelisation + cone tracing + SG shading (the light and BRDF fits are
done once, on the untimed warm-up call, from the compare's :class:`~prt_torch.compare.reference.LightSpec`: the
full-resolution lighting, the sun disk rasterised). ``sg_vct_nopeak`` is the Fig. 8 ablation: the same light,
but the peak lobes are shaded with the BRDF sub-cones instead of their own cones. Both are opt-in
(``--methods sg_vct,...``): a frame costs seconds on two CPU cores.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from prt_torch.compare.methods.base import CompareRun, FrameBatch, FrameSet, MethodBase, RadianceRequest, register
from prt_torch.errors import PrtError


@register
class SGVCT(MethodBase):
    name = "sg_vct"
    output = "radiance"
    runtime = "torch"
    default = False
    #: voxels per side of the grid, SG lobes per specular / diffuse BRDF term, HEALPix scales of the light fit
    resolution: ClassVar[int] = 128
    peaks: ClassVar[bool] = True
    brdf_lobes: ClassVar[int] = 1
    #: 1: the 2-3-lobe cosine fits of prt_torch.sg.brdf_fit currently cancel amplitudes of +-6e5 (float32 garbage)
    diffuse_lobes: ClassVar[int] = 1
    max_level: ClassVar[int] = 2

    @classmethod
    def available(cls, run: CompareRun) -> bool:
        try:
            import healpy  # noqa: F401
            import torch  # noqa: F401
        except ImportError:
            return False
        return True

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        import torch

        self.faces = np.asarray(run.character.faces)
        self.device = "cuda" if torch.cuda.is_available() else "cpu"
        self.renderer: Any = None
        self._info: dict[str, Any] = {}
        self.runtime = f"torch {self.device}: voxelise {self.resolution}^3 + cone trace + SG shade"

    def _build(self, shading: RadianceRequest) -> None:
        from prt_torch.compare.reference import spec_envmap
        from prt_torch.sg.brdf_fit import fit_brdf_sg
        from prt_torch.sg.shading import sg_light_from_env
        from prt_torch.vct.renderer import SGVCTRenderer

        spec = shading.extra.get("light_spec")
        if spec is None:
            raise PrtError("sg_vct needs the compare's light specification (RadianceRequest.extra['light_spec'])")
        light = sg_light_from_env(spec_envmap(spec), peaks=True, max_level=self.max_level)
        brdfs = {n: fit_brdf_sg(b, self.brdf_lobes, diffuse_lobes=self.diffuse_lobes)
                 for n, b in shading.brdfs.items()}
        self.renderer = SGVCTRenderer(self.faces, brdfs, light, self.resolution, peaks=self.peaks, device=self.device)
        self._info = {"sg_light": light.source, "sg_peaks": light.n_peaks, "vct_resolution": self.resolution,
                      "peak_cones": self.peaks,
                      "sg_brdf_rel_error": {n: {f"{k:g}": v for k, v in b.rel_error.items()} for n, b in brdfs.items()}}
        self._times: list[tuple[float, float, float]] = []

    def radiance(self, batch: FrameBatch, shading: RadianceRequest) -> dict[str, np.ndarray]:
        if self.renderer is None:
            self._build(shading)
        outs: dict[str, list[np.ndarray]] = {n: [] for n in shading.brdfs}
        for b in range(batch.positions.shape[0]):  # frames of the batch (batch 1 when timed)
            r = self.renderer.radiance(batch.positions[b], batch.frames[b, :, 2], shading.eye)
            t = self.renderer.times
            self._times.append((t.voxelize, t.trace, t.shade))
            for n in outs:
                outs[n].append(r[n].detach().cpu().numpy().astype(np.float32))
        return {n: np.stack(v) for n, v in outs.items()}

    def bytes(self) -> int:
        if self.renderer is None:
            return 0
        r = self.resolution
        light = self.renderer.light
        return int(4 * r ** 3 * 8 // 7 + 4 * 7 * (len(light.lobes) + len(light.peak_lobes)))

    def info(self) -> dict[str, Any]:
        out = dict(self._info)
        if getattr(self, "_times", None):
            t = np.median(np.asarray(self._times), axis=0) * 1e3
            out["ms_voxelize_trace_shade"] = [float(x) for x in t]
        return out


@register
class SGVCTNoPeak(SGVCT):
    name = "sg_vct_nopeak"
    peaks = False
