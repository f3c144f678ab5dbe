"""``learned_transfer``: seed 000's learned diffuse transfer, shaded ``albedo * (L . t)`` (a radiance method).

The run's ``models/transfer_<kind>.pt`` (``prt train`` with ``train.transfer``, :mod:`prt_torch.fit.transfer`;
``transfer.json`` lists them) predicts the world-frame transfer ``t (V, C6)`` of a pose. One graph
(:func:`radiance_graph`: the model as exported by :class:`prt_torch.export.graphs.VisibilityGraph`, then ``L . t`` by
:func:`prt_torch.shade.diffuse.shade_diffuse_prt`) is exported into the run's compare directory with
:func:`prt_torch.export.onnx_file.export_onnx` (re-exported when the model file is newer) and run through
onnxruntime (:class:`prt_torch.runtime.session.OrtGraph`), like the ``learned_<kind>`` methods. ``L``: the player's
lighting as world-frame SH (``lighting.sh``, the run's order; the first ``min(C, C6)`` coefficients of ``t`` meet
it); the albedo of each compared BRDF is the tint of its shipped RPO (radiance ``tint * (L . t)``). A diffuse
transfer has no view dependence: the glossy column is that BRDF's diffuse stand-in of the same albedo (seed 000 is
diffuse only), and ``t`` includes the bake's ``bounces`` interreflections, which ``sh_truth`` (direct lighting) has
not.

``learned_transfer`` runs ``transfer.json``'s default kind; ``learned_transfer_<kind>`` (opt-in) each trained kind.
``info()`` adds ``transfer_rel_err``: the compared frames' predicted transfer vs the baked one (held-out dataset
frames; ``None`` for frames posed here), the full-sphere relative L2 of :mod:`prt_torch.fit.transfer`.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from prt_torch.compare.methods import CompareRun, FrameBatch, FrameSet, MethodBase, RadianceRequest, register
from prt_torch.errors import PrtError, check

ARRAY = "transfer"


def transfer_radiance(t: np.ndarray, light_sh: np.ndarray, albedo: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``{brdf: (B, V, 3)}`` radiance ``albedo[brdf] * (L . t)`` of transfer ``t (B, V, C6)`` under world-frame SH
    lighting ``light_sh (C, 3)`` (the first ``min(C, C6)`` coefficients of both; float32)."""
    import torch

    from prt_torch.shade.diffuse import shade_diffuse_prt

    t = np.asarray(t, dtype=np.float32)
    light_sh = np.asarray(light_sh, dtype=np.float32)
    check(t.ndim == 3 and light_sh.ndim == 2 and light_sh.shape[1] == 3,
          f"transfer_radiance: expected t (B, V, C) and lighting (C, 3), got {t.shape} and {light_sh.shape}")
    c = min(t.shape[2], light_sh.shape[0])
    rad = shade_diffuse_prt(torch.from_numpy(np.ascontiguousarray(t[..., :c])), torch.from_numpy(light_sh[:c]),
                            check=False).numpy()
    return {b: rad * np.asarray(a, dtype=np.float32).reshape(1, 1, 3) for b, a in albedo.items()}


def radiance_graph(model: Any, n_light: int) -> Any:
    """``(pose (B, A), light (n_light, 3)) -> (transfer (B, V, C6), radiance (B, V, 3))``: the learned transfer
    model (as exported, :class:`prt_torch.export.graphs.VisibilityGraph`) and its unit-albedo shading ``L . t``
    (:func:`prt_torch.shade.diffuse.shade_diffuse_prt`, the first ``min(C6, n_light)`` coefficients) in one
    graph, so onnxruntime runs the whole per-frame path."""
    import torch

    from prt_torch.export.graphs import VisibilityGraph
    from prt_torch.shade.diffuse import shade_diffuse_prt

    class TransferRadiance(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.transfer = VisibilityGraph(model)
            self.c = min(int(model.n_coeffs), int(n_light))

        def forward(self, pose: torch.Tensor, light: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            t = self.transfer(pose)
            return t, shade_diffuse_prt(t[..., : self.c], light[: self.c], check=False)

    return TransferRadiance().eval()


def transfer_meta(run: CompareRun) -> dict[str, Any] | None:
    """The run's verified ``transfer.json``, or None (not trained with ``train.transfer``, or damaged)."""
    if not run.run.transfer_json.is_file():
        return None
    try:
        return run.run.transfer_meta()
    except PrtError:
        return None


class LearnedTransfer(MethodBase):
    """The learned transfer of ``kind`` (``""``: ``transfer.json``'s default kind) through onnxruntime."""

    name = "learned_transfer"
    output = "radiance"
    kind: ClassVar[str] = ""

    @classmethod
    def _kind(cls, meta: dict[str, Any]) -> str:
        return cls.kind or str(meta.get("default_kind", ""))

    @classmethod
    def available(cls, run: CompareRun) -> bool:
        meta = transfer_meta(run)
        if meta is None or ARRAY not in meta.get("arrays", {}):
            return False
        kind = cls._kind(meta)
        return kind in meta.get("kinds", []) and run.run.transfer_model_path(kind, ARRAY).is_file()

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        from prt_torch.export.onnx_file import initializer_bytes
        from prt_torch.runtime.session import OrtGraph

        meta = transfer_meta(run)
        check(meta is not None and ARRAY in meta.get("arrays", {}),
              f"{run.run.path}: no learned transfer (train with a `train.transfer` section)")
        self.meta = meta
        self.kind_used = self._kind(meta)
        self.n_light = run.order**2
        path = self._export(run)
        self.graph = OrtGraph(path, threads=run.threads)
        self._bytes = initializer_bytes(path)
        self.runtime = f"onnxruntime ({run.run.relative(path)}: transfer and L . t, exported by prt compare)"
        self._light: tuple[int, np.ndarray, dict[str, np.ndarray]] | None = None
        self.rel_err: float | None = None
        if len(frames.rows) and (frames.rows >= 0).all() and ARRAY in run.dataset:
            truth = run.dataset.rows(frames.rows, (ARRAY,))[ARRAY]
            zero = np.zeros((self.n_light, 3), np.float32)
            pred = np.concatenate([self._run(frames.features[i:i + 64], zero)[0]
                                   for i in range(0, frames.n_frames, 64)])
            from prt_torch.fit.transfer import transfer_rel_err

            self.rel_err = transfer_rel_err(pred, truth)

    def _export(self, run: CompareRun) -> Any:
        import torch

        from prt_torch.export.onnx_file import export_onnx, read_metadata
        from prt_torch.models import load_model_file

        model_file = run.run.transfer_model_path(self.kind_used, ARRAY)
        path = run.run.compare_graph_path(f"{ARRAY}_{self.kind_used}")
        if path.is_file() and path.stat().st_mtime >= model_file.stat().st_mtime \
                and read_metadata(path).get("prt.n_light") == str(self.n_light):
            return path
        path.parent.mkdir(parents=True, exist_ok=True)
        model = load_model_file(model_file)
        export_onnx(radiance_graph(model, self.n_light), [torch.zeros(1, model.n_features),
                                                           torch.zeros(self.n_light, 3)],
                    path, ("pose", "light"), (ARRAY, "radiance"),
                    {"pose": {0: "B"}, ARRAY: {0: "B"}, "radiance": {0: "B"}},
                    metadata={"prt.graph": f"{ARRAY}+radiance", "prt.model_kind": self.kind_used,
                              "prt.precision": "fp32", "prt.n_light": str(self.n_light)})
        return path

    def _run(self, features: np.ndarray, light: np.ndarray) -> list[np.ndarray]:
        return self.graph.run_unchecked({"pose": np.ascontiguousarray(features, dtype=np.float32), "light": light})

    def radiance(self, batch: FrameBatch, shading: RadianceRequest) -> dict[str, np.ndarray]:
        if self._light is None or self._light[0] != id(shading.lighting):
            albedo = {b: np.asarray(r.tint, dtype=np.float32) for b, r in shading.rpos.items()}
            sh = np.zeros((self.n_light, 3), np.float32)  # the lighting's first n_light coefficients (zero padded)
            src = np.asarray(shading.lighting.sh, dtype=np.float32)[: self.n_light]
            sh[: len(src)] = src
            self._light = (id(shading.lighting), sh, albedo)
        rad = self._run(batch.features, self._light[1])[1]
        return {b: rad * a.reshape(1, 1, 3) for b, a in self._light[2].items()}

    def bytes(self) -> int:
        return int(self._bytes)

    def info(self) -> dict[str, Any]:
        arr = self.meta["arrays"][ARRAY]
        return {"kind": self.kind_used, "transfer_rel_err": self.rel_err, "output_pca": arr.get("output_pca"),
                "reduced_inputs": arr.get("reduced_inputs"), "output_dims": arr.get("output_dims"),
                "bounces": self.meta.get("bake", {}).get("bounces")}


class BakedTransfer(MethodBase):
    """``baked_transfer`` (opt-in): the dataset's own baked transfer of the compared frames, shaded by the same rule
    (:func:`transfer_radiance`): the ceiling of ``learned_transfer`` (what a perfect regressor would score); held-out
    dataset frames only."""

    name = "baked_transfer"
    output = "radiance"
    default = False
    runtime = "numpy (baked transfer read ahead) + albedo * (L . t)"

    @classmethod
    def available(cls, run: CompareRun) -> bool:
        return ARRAY in run.dataset

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        check(len(frames.rows) > 0 and bool((frames.rows >= 0).all()),
              "baked_transfer compares baked dataset frames only (not --clip / --motion)")
        self.t = run.dataset.rows(frames.rows, (ARRAY,))[ARRAY].astype(np.float32)

    def radiance(self, batch: FrameBatch, shading: RadianceRequest) -> dict[str, np.ndarray]:
        albedo = {b: np.asarray(r.tint, dtype=np.float32) for b, r in shading.rpos.items()}
        return transfer_radiance(self.t[batch.index], shading.lighting.sh, albedo)


register(LearnedTransfer)
register(BakedTransfer)
for _kind in ("linear", "quadratic", "mlp"):
    register(type(f"LearnedTransfer{_kind.capitalize()}", (LearnedTransfer,),
                  {"name": f"learned_transfer_{_kind}", "kind": _kind, "default": False, "__module__": __name__,
                   "__doc__": f"learned_transfer with the {_kind} model (opt-in)."}))
