"""``s001`` and ``posespace``: seed 001's compressed transfer matrices interpolated from sampled poses (sec. 5).

Radiance methods on runs trained with ``train.s001`` (``s001.npz``) whose store has ``transfer_matrix``.
Per frame, :class:`prt_torch.s001.player.S001Player` (numpy) interpolates the 16-bit PCA coefficients (eq. 7,
``s001``: per segment from the normalized-cut group of the nearest sampled pose under the bone-weighted distance;
``posespace``: the same compressed data from the nearest sampled poses of the whole body, Table 3's baseline) and
shades in eq. 9's order with the compared lighting's SH (``lighting.sh``) and each compared analytic BRDF as
``B = brdf_matrix(brdf)``, ``H, G = factor(B, 4)`` (:mod:`prt_torch.s001.brdf_matrix`), times the BRDF's tint: the same
rule as :func:`prt_torch.s001.shading.shade_matrix` (checked against it in tests/compare/test_s001_method.py).

What the harness scores: radiance against ``sh_truth`` shaded on the shipping path (shadowed direct light only),
so the transfer matrices' interreflection bounces (``bake.matrix_bounces``) count as error there. The method's own
``info()`` therefore also scores it against the BAKED transfer matrices of the compared dataset rows (Table 3):
``transfer_rel_err`` (Frobenius, pooled over frames) and ``matrix_radiance_rel_rmse`` (both shaded by
:func:`~prt_torch.s001.shading.shade_matrix` with the same lighting and BRDFs), computed during the
harness's untimed warm-up call. ``compression_ratio`` = raw float32 transfer matrices of the sampled poses /
the bytes of ``s001.npz``'s arrays (``bytes()``).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from prt_torch.compare.methods.base import CompareRun, FrameBatch, FrameSet, MethodBase, RadianceRequest, register
from prt_torch.errors import check

#: compared frames scored against the baked matrices in info() (evenly spaced)
TRUTH_FRAMES = 16


@register
class S001(MethodBase):
    """Seed 001's segment-wise interpolation (module doc)."""

    name = "s001"
    output = "radiance"
    scheme: ClassVar[str] = "s001"
    default = True

    @classmethod
    def available(cls, run: CompareRun) -> bool:
        """Runs trained with ``train.s001`` (``s001.npz``) on a store with ``transfer_matrix``."""
        return run.run.s001.is_file() and "transfer_matrix" in run.dataset

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        from prt_torch.s001.player import S001Player
        from prt_torch.s001.posespace import CompressedTransfer

        self.data = CompressedTransfer.load(run.run.s001)
        check(self.data.n_vertices == run.n_vertices,
              f"{run.run.s001}: {self.data.n_vertices} vertices, the character {run.n_vertices}")
        self.player = S001Player(self.data, self.scheme)  # type: ignore[arg-type]
        self.run, self.frames = run, frames
        self.tints: dict[str, np.ndarray] = {}
        self.factors: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._light_key: Any = None
        self._info: dict[str, Any] = {}
        self.runtime = f"numpy: k-d tree + NRBF + eq. 9 ({self.scheme}, {self.data.meta.get('n_clusters')} clusters)"

    def _setup(self, shading: RadianceRequest) -> None:
        """BRDF factors and the lighting (first call = the harness's untimed warm-up), then the truth scores."""
        from prt_torch.s001.brdf_matrix import brdf_matrix, factor

        order = self.player.order
        if not self.factors:
            for name, brdf in shading.brdfs.items():
                self.factors[name] = factor(brdf_matrix(brdf, order), 4)
                self.tints[name] = np.asarray(getattr(brdf, "tint", np.ones(3)), np.float32)
        light = np.asarray(shading.lighting.sh, np.float64)[: order * order]
        self.player.set_shading(self.factors, light)
        self._light_key = id(shading.lighting)
        if not self._info:
            self._info = self._truth_scores(light, shading.eye)

    def _truth_scores(self, light: np.ndarray, eye: np.ndarray) -> dict[str, Any]:
        """Errors against the baked transfer matrices of the compared dataset rows (module doc)."""
        from prt_torch.s001.shading import shade_matrix
        from prt_torch.scoring.sampling import evenly_spaced

        fs = self.frames
        have = np.flatnonzero(fs.rows >= 0)
        if len(have) == 0:
            return {"transfer_rel_err": None, "matrix_radiance_rel_rmse": None}
        pick = have[evenly_spaced(len(have), min(TRUTH_FRAMES, len(have)))]
        sse_t = sst_t = sse_r = sst_r = 0.0
        for f in pick:
            truth = self.run.dataset.rows(fs.rows[f:f + 1], ("transfer_matrix",))["transfer_matrix"][0]
            got = self.player.transfer(fs.features[f], fs.frames[f])
            sse_t += float(((got - truth) ** 2).sum())
            sst_t += float((truth**2).sum())
            view = eye[None] - fs.positions[f].astype(np.float64)
            view /= np.linalg.norm(view, axis=1, keepdims=True)
            fr = fs.frames[f].astype(np.float64)
            for name, (h, g) in self.factors.items():
                args = (light, fr, view, h, g, self.tints[name])
                ref = shade_matrix(truth.astype(np.float64), *args)
                est = shade_matrix(got.astype(np.float64), *args)
                sse_r += float(((est - ref) ** 2).sum())
                sst_r += float((ref**2).sum())
        return {"transfer_rel_err": float(np.sqrt(sse_t / max(sst_t, 1e-30))),
                "matrix_radiance_rel_rmse": float(np.sqrt(sse_r / max(sst_r, 1e-30))),
                "truth_frames": int(len(pick)),
                "truth": "the baked transfer_matrix of the compared rows, shaded by shade_matrix (same light, BRDFs)"}

    def radiance(self, batch: FrameBatch, shading: RadianceRequest) -> dict[str, np.ndarray]:
        if self._light_key != id(shading.lighting):
            self._setup(shading)
        out: dict[str, list[np.ndarray]] = {n: [] for n in self.factors}
        for i in range(len(batch.index)):
            r = self.player.radiance(batch.features[i], batch.frames[i], batch.positions[i], shading.eye)
            for n, x in r.items():
                out[n].append(x * self.tints[n])
        return {n: np.stack(x).astype(np.float32) for n, x in out.items()}

    def bytes(self) -> int:
        return self.data.stored_bytes()

    def info(self) -> dict[str, Any]:
        m = self.data.meta
        return {"scheme": self.scheme, "compression_ratio": float(m["raw_bytes"]) / self.data.stored_bytes(),
                "raw_bytes": int(m["raw_bytes"]), "n_clusters": m.get("n_clusters"), "n_poses": m.get("n_poses"),
                **self._info}


@register
class PoseSpace(S001):
    """Table 3's baseline: global pose-space interpolation of the same compressed data."""

    name = "posespace"
    scheme: ClassVar[str] = "posespace"
