"""``shexp``: self-shadowing of the character by its own sphere blockers (SHEXP, Ren 2006; seed 003 sec. 7).

Per frame: the run's spheres (:class:`prt_torch.blockers.SphereSet`) are carried by their bones
(:func:`prt_torch.blockers.pose_spheres` with the frame's skinning matrices, :attr:`FrameSet.skin`: the frames
posed by compare's one clip-name rule like the bake), then every vertex's local-frame SH visibility is the SH
exponential (HYB) of the summed log-visibility of the spheres that do not contain it. The whole-sphere result gets
the dataset's below-horizon convention (``"zero"``: ``H * v``, ``"one"``: ``1 - H * (1 - v)``, one constant ``(C,
C)`` product matrix; docs/DESIGN.md) so it is scored like every other visibility.

Run-time path: the exported ``shexp.onnx`` and ``blockers.npz`` through onnxruntime
(:class:`prt_torch.runtime.session.OrtGraph`) when the run's export has them (a graph from an older SHEXP graph
version is re-exported into the run's compare directory first, like the learned methods' graphs, so the timing is
this code's); otherwise the spheres are fitted here (the bake config's ``blockers`` count) and the torch
:func:`prt_torch.shexp.shexp_visibility` runs (``runtime`` says which). ``bytes()`` = sphere file + graph
initialisers (the tables).

A default method (issue 10) of runs exported with a sphere set (:meth:`Shexp.available`); not available for
other runs.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from prt_torch.compare.methods.base import CompareRun, FrameBatch, FrameSet, MethodBase, register
from prt_torch.errors import check
from prt_torch.shapes import check_shape


def frame_skins(run: CompareRun, frames: FrameSet) -> np.ndarray:
    """``(F, J, 4, 4)`` skinning matrices of the compared frames: the :class:`FrameSet`'s own (posed by compare's
    one clip-name rule, so a held-out frame range of a training clip is posed like the bake posed it)."""
    check(frames.skin is not None, f"shexp: the compared frames of {run.run.path} carry no skinning matrices")
    assert frames.skin is not None
    check_shape(frames.skin, "F J 4 4", name="shexp: frame skins",
                dims={"F": frames.n_frames, "J": run.character.num_joints})
    return np.asarray(frames.skin, dtype=np.float64)


def has_sphere_set(run: CompareRun) -> bool:
    """Whether the run was exported with sphere blockers and a SHEXP graph (``export.json`` entry and both files)."""
    rd = run.run
    return bool((run.export_meta or {}).get("shexp")) and rd.blockers_path.is_file() and rd.shexp_path.is_file()


@register
class Shexp(MethodBase):
    """SHEXP sphere-blocker self-shadowing (module doc)."""

    name = "shexp"
    output = "visibility"
    default = True

    @classmethod
    def available(cls, run: CompareRun) -> bool:
        """Runs exported with a sphere set (:func:`has_sphere_set`): a default method there, unavailable
        elsewhere. (:meth:`prepare` still has a torch path for a run without one, used by tests.) Never for a
        deformable (cloth) dataset: its spheres would be posed by skin matrices, which a vertex cache has not."""
        from prt_torch.bake.deformable import is_deformable

        return has_sphere_set(run) and not is_deformable(dict(run.dataset.attrs))

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        from prt_torch.blockers import SphereSet, fit_spheres

        rd = run.run
        shipped = has_sphere_set(run)
        self.order = run.order
        self.skins = frame_skins(run, frames)
        if shipped:
            from prt_torch.export.onnx_file import initializer_bytes
            from prt_torch.runtime.session import OrtGraph
            from prt_torch.shexp.graph import export_shexp, is_current

            self.spheres = SphereSet.load(rd.blockers_path)
            path, how = rd.shexp_path, "shipped"
            if not is_current(path):  # an export by an older SHEXP graph version: time this code's graph
                path = rd.compare_dir / rd.shexp_path.name
                if not (path.is_file() and is_current(path)):
                    path.parent.mkdir(parents=True, exist_ok=True)
                    export_shexp(path, self.order)
                how = "re-exported: the run's graph is an older version"
            self.graph: Any = OrtGraph(path, threads=run.threads)
            self._bytes = initializer_bytes(path) + rd.blockers_path.stat().st_size
            self.runtime = f"onnxruntime ({rd.relative(path)}, {how}, {self.spheres.num_spheres} spheres)"
        else:
            import torch

            from prt_torch.shexp import ShexpVisibility
            from prt_torch.shexp.graph import blocker_count

            self.spheres = fit_spheres(run.character, blocker_count(run.dataset.attrs))
            self.graph = None
            self._bytes = (sum(b.numel() * b.element_size() for b in ShexpVisibility(self.order).buffers())
                           + len(self.spheres.to_bytes()))
            torch.set_num_threads(run.threads)
            self.runtime = f"torch (run not exported with blockers; {self.spheres.num_spheres} spheres fitted here)"
        self.radii = self.spheres.radius[None].astype(np.float32)
        from prt_torch.bake.store import below_horizon_of

        self.below = below_horizon_of(run.dataset.attrs)

    def visibility(self, batch: FrameBatch) -> np.ndarray:
        from prt_torch.blockers import pose_spheres
        from prt_torch.sh.product import mask_below_horizon

        centers = pose_spheres(self.spheres, self.skins[batch.index])
        radii = np.broadcast_to(self.radii, centers.shape[:2]).astype(np.float32)
        pts = np.ascontiguousarray(batch.positions, dtype=np.float32)
        frm = np.ascontiguousarray(batch.frames, dtype=np.float32)
        if self.graph is not None:
            v = self.graph.run_unchecked({"points": pts, "frames": frm, "centers": centers, "radii": radii})[0]
        else:
            from prt_torch.shexp import shexp_visibility

            v = shexp_visibility(pts, centers, radii, self.order, frames=frm).numpy()
        return mask_below_horizon(v, self.order, self.below).astype(np.float32)

    def bytes(self) -> int:
        return int(self._bytes)

    def info(self) -> dict[str, Any]:
        return {"n_spheres": self.spheres.num_spheres, "below_horizon": self.below,
                "graph": "shipped" if self.graph is not None else "torch"}
