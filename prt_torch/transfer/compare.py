"""``learned_transfer``: seed 000's learned diffuse transfer (+ subsurface), shaded ``albedo * (L . t) + sss_tint *
(L . t_sss)`` (a radiance method).

The run's ``models/transfer_<kind>.pt`` (``prt train`` with ``train.transfer``, :mod:`prt_torch.transfer.fit`;
``transfer.json`` lists them) predicts the world-frame transfer ``t (V, C6)`` of a pose, and
``models/subsurface_<kind>.pt`` (when the bake had ``bake.subsurface``) the subsurface exit-radiance transfer
``t_sss``. The graph is :mod:`prt_torch.transfer.graph`'s ``(pose, light) -> (t, L . t [, t_sss, L . t_sss])``:
the run's exported ``transfer.onnx`` (``prt export``, parity-checked there) when it is the kind compared and the
lighting order matches, else the same graph written into the compare directory by the same function
(re-exported when the model file is newer); run through onnxruntime (:class:`prt_torch.runtime.session.OrtGraph`).
``L``: the player's lighting as world-frame SH (``lighting.sh``, the run's order; the first ``min(C, C6)``
coefficients of ``t`` meet it). Colour: :func:`prt_torch.transfer.shading.transfer_shading` (ONE rule for this
method, ``baked_transfer`` and ``prt play --renderer transfer``): ``albedo`` the tint of each compared BRDF's shipped
RPO, ``sss_tint = albedo / mean(albedo)`` (the baked subsurface already carries its dipole material's reflectance).
A diffuse transfer has no view dependence: the glossy column is that BRDF's diffuse stand-in of the same albedo
(seed 000 is diffuse only), and ``t`` includes the bake's ``bounces`` interreflections and the subsurface light,
which ``sh_truth`` (direct lighting, opaque) has not.

``learned_transfer`` runs ``transfer.json``'s default kind; ``learned_transfer_<kind>`` (opt-in) each trained kind.
``info()`` adds ``transfer_rel_err`` (and ``subsurface_rel_err``): the compared frames' predicted transfer vs the
baked one (held-out dataset frames; ``None`` for frames posed here), the full-sphere relative L2 of
:mod:`prt_torch.transfer.fit`.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from prt_torch.compare.methods.base import CompareRun, FrameBatch, FrameSet, MethodBase, RadianceRequest, register
from prt_torch.errors import DamagedArtifact, check
from prt_torch.shapes import check_shape
from prt_torch.transfer.shading import ARRAYS, light_dot, light_input, transfer_shading

ARRAY = "transfer"
SSS = "subsurface"


def transfer_radiance(t: np.ndarray, light_sh: np.ndarray, albedo: dict[str, np.ndarray],
                      t_sss: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """``{brdf: (B, V, 3)}`` radiance of transfer ``t (B, V, C6)`` (and subsurface transfer ``t_sss``, same shape)
    under world-frame SH lighting ``light_sh (C, 3)``: numpy ``L . t`` (the first ``min(C, C6)`` coefficients),
    coloured by :func:`prt_torch.transfer.shading.transfer_shading`; float32."""
    t = np.asarray(t, dtype=np.float32)
    light_sh = np.asarray(light_sh, dtype=np.float32)
    check_shape(t, "B V C", name="transfer_radiance: t")
    check_shape(light_sh, "C_light 3", name="transfer_radiance: lighting")
    check(t_sss is None or np.shape(t_sss) == t.shape,
          f"transfer_radiance: subsurface transfer {np.shape(t_sss)} != transfer {t.shape}")
    return transfer_shading(light_dot(t, light_sh), albedo, None if t_sss is None else light_dot(t_sss, light_sh))


def transfer_meta(run: CompareRun) -> dict[str, Any] | None:
    """The run's verified ``transfer.json``, or None (not trained with ``train.transfer``, or damaged)."""
    if not run.run.transfer_json.is_file():
        return None
    try:
        return run.run.transfer_meta()
    except DamagedArtifact:
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
        path, source = self._graph(run)
        self.graph = OrtGraph(path, threads=run.threads)
        self.arrays = [a for a in ARRAYS if a in self.graph.outputs]
        self._bytes = initializer_bytes(path)
        self.runtime = (f"onnxruntime ({run.run.relative(path)}: {' + '.join(self.arrays)} and L . t, {source}) "
                        f"+ numpy colour")
        self._light: tuple[int, np.ndarray, dict[str, np.ndarray]] | None = None
        self.rel_err: dict[str, float | None] = {a: None for a in self.arrays}
        if len(frames.rows) and (frames.rows >= 0).all() and all(a in run.dataset for a in self.arrays):
            from prt_torch.transfer.fit import transfer_rel_err

            truth = run.dataset.rows(frames.rows, tuple(self.arrays))
            zero = np.zeros((self.n_light, 3), np.float32)
            outs = [self._run(frames.features[i:i + 64], zero) for i in range(0, frames.n_frames, 64)]
            for j, a in enumerate(self.arrays):
                self.rel_err[a] = transfer_rel_err(np.concatenate([o[2 * j] for o in outs]), truth[a])

    def _graph(self, run: CompareRun) -> tuple[Any, str]:
        """The graph file: the run's exported ``transfer.onnx`` when it serves this kind and lighting order, else
        one written into the compare directory (:func:`prt_torch.transfer.graph.write_transfer_graph`)."""
        from prt_torch.export.onnx_file import read_metadata
        from prt_torch.transfer.graph import load_models, write_transfer_graph
        from prt_torch.transfer.shading import exported_transfer

        entry = exported_transfer(run.run)
        if entry is not None and entry.get("kind") == self.kind_used and entry.get("n_light") == self.n_light:
            return run.run.inside(entry["file"]), "exported by prt export"
        arrays = [a for a in ARRAYS if a in self.meta.get("arrays", {})
                  and run.run.transfer_model_path(self.kind_used, a).is_file()]
        model_file = run.run.transfer_model_path(self.kind_used, ARRAY)
        path = run.run.compare_graph_path(f"{ARRAY}_{self.kind_used}")
        newest = max(run.run.transfer_model_path(self.kind_used, a).stat().st_mtime for a in arrays)
        if path.is_file() and path.stat().st_mtime >= newest:
            md = read_metadata(path)
            if md.get("prt.n_light") == str(self.n_light) and md.get("prt.arrays") == ",".join(arrays):
                return path, "written by prt compare"
        write_transfer_graph(load_models(run.run, self.kind_used, arrays), self.n_light, path,
                             {"prt.model_kind": self.kind_used, "prt.model_file": run.run.relative(model_file)})
        return path, "written by prt compare"

    def _run(self, features: np.ndarray, light: np.ndarray) -> list[np.ndarray]:
        """The graph's outputs (per array: transfer, L . t) for ``features (B, A)`` and ``light (n_light, 3)``."""
        return self.graph.run_unchecked({"pose": np.ascontiguousarray(features, dtype=np.float32), "light": light})

    def radiance(self, batch: FrameBatch, shading: RadianceRequest) -> dict[str, np.ndarray]:
        if self._light is None or self._light[0] != id(shading.lighting):
            albedo = {b: np.asarray(r.tint, dtype=np.float32) for b, r in shading.rpos.items()}
            self._light = (id(shading.lighting), light_input(shading.lighting.sh, self.n_light), albedo)
        out = self._run(batch.features, self._light[1])
        return transfer_shading(out[1], self._light[2], out[3] if SSS in self.arrays else None)

    def bytes(self) -> int:
        return int(self._bytes)

    def info(self) -> dict[str, Any]:
        arr = self.meta["arrays"][ARRAY]
        bake = self.meta.get("bake", {})
        return {"kind": self.kind_used, "transfer_rel_err": self.rel_err.get(ARRAY),
                "subsurface_rel_err": self.rel_err.get(SSS), "arrays": list(self.arrays),
                "output_pca": arr.get("output_pca"), "reduced_inputs": arr.get("reduced_inputs"),
                "output_dims": arr.get("output_dims"), "bounces": bake.get("bounces"),
                "subsurface": bake.get("subsurface") if SSS in self.arrays else None}


class BakedTransfer(MethodBase):
    """``baked_transfer`` (opt-in): the dataset's own baked transfer (and subsurface transfer, when the run learned
    it, or has no learned transfer and the store has it) of the compared frames, shaded by the same rule
    (:func:`transfer_radiance`): the ceiling of ``learned_transfer`` (what a perfect regressor would score);
    held-out dataset frames only."""

    name = "baked_transfer"
    output = "radiance"
    default = False
    runtime = "numpy (baked transfer read ahead) + albedo * (L . t) [+ sss_tint * (L . t_sss)]"

    @classmethod
    def available(cls, run: CompareRun) -> bool:
        return ARRAY in run.dataset

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        check(len(frames.rows) > 0 and bool((frames.rows >= 0).all()),
              "baked_transfer compares baked dataset frames only (not --clip / --motion)")
        meta = transfer_meta(run)
        sss = SSS in run.dataset and (meta is None or SSS in meta.get("arrays", {}))
        data = run.dataset.rows(frames.rows, (ARRAY, SSS) if sss else (ARRAY,))
        self.t = data[ARRAY].astype(np.float32)
        self.t_sss = data[SSS].astype(np.float32) if sss else None

    def radiance(self, batch: FrameBatch, shading: RadianceRequest) -> dict[str, np.ndarray]:
        albedo = {b: np.asarray(r.tint, dtype=np.float32) for b, r in shading.rpos.items()}
        return transfer_radiance(self.t[batch.index], shading.lighting.sh, albedo,
                                 None if self.t_sss is None else self.t_sss[batch.index])

    def info(self) -> dict[str, Any]:
        return {"arrays": [ARRAY] + ([SSS] if self.t_sss is not None else [])}


register(LearnedTransfer)
register(BakedTransfer)
for _kind in ("linear", "quadratic", "mlp"):
    register(type(f"LearnedTransfer{_kind.capitalize()}", (LearnedTransfer,),
                  {"name": f"learned_transfer_{_kind}", "kind": _kind, "default": False, "__module__": __name__,
                   "__doc__": f"learned_transfer with the {_kind} model (opt-in)."}))
