"""The SG + voxel-cone-tracing renderer of one posed frame (seed 004): voxelise, trace cones, shade.

Per frame: :meth:`~prt_torch.vct.visibility.ConeTracer.voxelize` the posed mesh; for every BRDF the view-warped
SG lobes per vertex (:meth:`prt_torch.sg.brdf_fit.SGBRDF.view_lobes`); each lobe's cones (7 sub-cones by circle
packing, or 1 for a lobe sharper than :data:`~prt_torch.vct.cones.SPECULAR_SHARPNESS`; the diffuse cosine lobes,
all about the normal and identical for every BRDF, share the cones of the widest one, traced once); one cone per
light peak (``peaks=True``); ONE trace call for all of them; then :func:`prt_torch.sg.shading.shade_sg`. Torch on
the device of the renderer (CPU or CUDA).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from prt_torch.errors import PrtError, check
from prt_torch.sg.shading import SGLight, shade_sg
from prt_torch.shapes import check_shape
from prt_torch.vct.cones import SPECULAR_SHARPNESS, pack_lobe_cones, peak_cones
from prt_torch.vct.trace import TraceSettings
from prt_torch.vct.visibility import ConeTracer


@dataclass
class FrameTimes:
    """Seconds of the last frame: ``voxelize``, ``trace``, ``shade`` (device-synchronised)."""

    voxelize: float = 0.0
    trace: float = 0.0
    shade: float = 0.0

    @property
    def total(self) -> float:
        return self.voxelize + self.trace + self.shade


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


@dataclass
class SGVCTRenderer:
    """Renders posed frames of a mesh with fixed ``faces`` under ``light`` for the SG BRDFs ``brdfs``.

    Args:
        faces: ``(T, 3)`` triangles. brdfs: ``{name: SGBRDF}``. light: :class:`~prt_torch.sg.shading.SGLight`.
        resolution: voxel grid side (64-256). peaks: trace one extra cone per light peak (seed 004 Fig. 8);
            ``False`` shades the peak lobes with the sub-cones (the ablation).
        settings: cone-tracing settings. device: ``"cpu"``, ``"cuda"``, ... (default CPU).
        specular_sharpness: lobes at least this sharp (median over vertices) get a single cone.
    """

    faces: np.ndarray
    brdfs: dict[str, Any]
    light: SGLight
    resolution: int = 128
    peaks: bool = True
    settings: TraceSettings = field(default_factory=TraceSettings)
    device: str | torch.device = "cpu"
    specular_sharpness: float = SPECULAR_SHARPNESS
    solid: bool | None = None

    def __post_init__(self) -> None:
        check(len(self.brdfs) > 0, "SG renderer: no BRDFs to shade")
        self.device = torch.device(self.device)
        self.tracer = ConeTracer(self.faces, self.resolution, solid=self.solid, settings=self.settings)
        self._light = self.light.to(self.device)
        self.times = FrameTimes()

    def radiance(self, positions: np.ndarray | torch.Tensor, normals: np.ndarray | torch.Tensor,
                 eye: np.ndarray | torch.Tensor) -> dict[str, torch.Tensor]:
        """``{brdf: (V, 3)}`` outgoing radiance toward ``eye (3,)`` of the posed vertices ``positions (V, 3)`` with
        unit ``normals (V, 3)`` (world)."""
        dev = self.device
        p = torch.as_tensor(np.asarray(positions) if not isinstance(positions, torch.Tensor) else positions,
                            dtype=torch.float32).to(dev)
        n = torch.as_tensor(np.asarray(normals) if not isinstance(normals, torch.Tensor) else normals,
                            dtype=torch.float32).to(dev)
        e = torch.as_tensor(np.asarray(eye, dtype=np.float32) if not isinstance(eye, torch.Tensor) else eye,
                            dtype=torch.float32).to(dev)
        dims = check_shape(p, "V 3", name="SG renderer: positions")
        check_shape(n, "V 3", name="SG renderer: normals", dims=dims)
        if not (bool(torch.isfinite(p).all()) and bool(torch.isfinite(n).all()) and bool(torch.isfinite(e).all())):
            raise PrtError("SG renderer: positions, normals or eye contain NaN or Inf")
        n = n / n.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        view = e[None] - p
        view = view / view.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        v = p.shape[0]
        _sync(dev)
        t0 = time.perf_counter()
        frame = self.tracer.voxelize(p)
        _sync(dev)
        t1 = time.perf_counter()
        # cones of every BRDF lobe (diffuse cosine lobes shared), then the peak cones
        lobes: dict[str, tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}
        cone_dirs: list[torch.Tensor] = []
        cone_half: list[torch.Tensor] = []
        slots: dict[str, list[tuple[int, int]]] = {}  # brdf -> per lobe (first column, n cones)
        shared: dict[tuple[str, float], tuple[int, int]] = {}
        col = 0
        for name, brdf in self.brdfs.items():
            pa, la, ma = brdf.view_lobes(n, view)
            pa, la, ma = pa.to(torch.float32), la.to(torch.float32), ma.to(torch.float32)
            lobes[name] = (pa, la, ma)
            n_diffuse = len(brdf.cosine.sharpness) if brdf.kd > 0 else 0
            slots[name] = []
            for j in range(la.shape[1]):  # a loop over the <= 6 lobes of a BRDF
                # every diffuse (cosine) lobe is about the normal: all share the cones of the widest one
                key = ("diffuse", round(float(la[0, :n_diffuse].min()), 4)) if j < n_diffuse else None
                if key is not None and key in shared:
                    slots[name].append(shared[key])
                    continue
                lam_j = la[:, :n_diffuse].min(dim=1).values if key is not None else la[:, j]
                nc = 1 if float(lam_j.median()) >= self.specular_sharpness else 7
                d, h, _ = pack_lobe_cones(pa[:, j], lam_j, nc)
                cone_dirs.append(d)
                cone_half.append(h)
                slots[name].append((col, nc))
                if key is not None:
                    shared[key] = (col, nc)
                col += nc
        n_peaks = self._light.n_peaks if self.peaks else 0
        if n_peaks:
            pd, ph = peak_cones(self._light.peak_dirs, self._light.peak_solid_angle)
            cone_dirs.append(pd[None].expand(v, -1, -1))
            cone_half.append(ph[None].expand(v, -1))
        from prt_torch.vct.cones import ConeSet

        dirs = torch.cat(cone_dirs, dim=1)
        half = torch.cat(cone_half, dim=1)
        cones = ConeSet(dirs, half, torch.ones_like(half), torch.zeros(dirs.shape[1], dtype=torch.long, device=dev))
        vis = self.tracer.trace(frame, p, n, cones)  # (V, N)
        _sync(dev)
        t2 = time.perf_counter()
        peak_vis = vis[:, col:col + n_peaks] if n_peaks else None
        out: dict[str, torch.Tensor] = {}
        for name, (pa, la, ma) in lobes.items():
            c = max(nc for _, nc in slots[name])
            idx = torch.as_tensor([[s + (i if i < nc else 0) for i in range(c)] for s, nc in slots[name]],
                                  dtype=torch.long, device=dev)  # (J, C): a 1-cone lobe repeats its cone
            out[name] = shade_sg(self._light, pa, la, ma, dirs[:, idx], half[:, idx], vis[:, idx], peak_vis)
        _sync(dev)
        t3 = time.perf_counter()
        self.times = FrameTimes(t1 - t0, t2 - t1, t3 - t2)
        return out
