"""The browser page's peak lights (issue 27 item 3), and the same computation in Python (the page's reference).

With peaks on, the page shades per vertex the residual lighting's RPO radiance (its ZH lobes on the SH path) plus,
per peak ``p`` (at most :data:`MAX_PAGE_PEAKS`), ``E_p f_r(l_p, v) max(n . l_p, 0) V_p``
(:func:`prt_torch.brdf.direct.peak_radiance`) with the analytic BRDF the RPO was built from
(:func:`prt_torch.rig.material.analytic_brdf`: the catalogue's by name, the glTF material's Cook-Torrance for
``material``), the base colour multiplying both. ``V_p`` is the run's learned peak visibility ``peaks.onnx``
(onnxruntime-web on the page, onnxruntime here: :class:`PeakGraph`); a run without it shades its peaks unshadowed
(``V_p = 1``: only the BRDF's horizon), the rule :func:`page_peak_visibility` implements for both sides. Peaks off:
the whole lighting on the SH path, as before.

The manifest describes each BRDF as :func:`brdf_entry` (``kind`` and parameters, what ``prt_shading.glsl``'s
``prtPeakBrdf`` evaluates) and each lighting preset's split as :func:`peaks_entry`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import check
from prt_torch.shapes import check_shape

#: peak uniforms in the page's shader (``prt_shading.glsl``'s ``PRT_MAX_PEAKS``)
MAX_PAGE_PEAKS = 4
#: the shader's BRDF kinds (``u_brdfKind``), by analytic BRDF class name
BRDF_KINDS = {"Lambert": 0, "Phong": 1, "BlinnPhong": 2, "CookTorrance": 3, "Ward": 4}


def brdf_entry(brdf: Any) -> dict[str, Any] | None:
    """The manifest's description of an analytic BRDF: ``{"kind": int (:data:`BRDF_KINDS`), "class", "params":
    [kd, ks, p1, p2], "tint"}`` with ``p1, p2`` = Phong ``(exponent, 0)``, Blinn-Phong ``(exponent, norm)``,
    Cook-Torrance ``(alpha = roughness^2, f0)``, Ward ``(alpha, 0)``; Lambert ``[1, 0, 0, 0]``. ``None`` in, out."""
    if brdf is None:
        return None
    cls = type(brdf).__name__
    check(cls in BRDF_KINDS, f"the page cannot shade peaks with a {cls} BRDF (known: {', '.join(BRDF_KINDS)})")
    if cls == "Lambert":
        params = [1.0, 0.0, 0.0, 0.0]
    elif cls == "Phong":
        params = [brdf.kd, brdf.ks, brdf.exponent, 0.0]
    elif cls == "BlinnPhong":
        params = [brdf.kd, brdf.ks, brdf.exponent, brdf.norm]
    elif cls == "CookTorrance":
        params = [brdf.kd, brdf.ks, brdf.alpha, brdf.f0]
    else:
        params = [brdf.kd, brdf.ks, brdf.alpha, 0.0]
    return {"kind": BRDF_KINDS[cls], "class": cls, "params": [float(p) for p in params],
            "tint": np.asarray(brdf.tint, np.float64).astype(float).tolist()}


def peaks_entry(peak_lighting: Any) -> dict[str, Any] | None:
    """The manifest's split of one lighting preset (``None`` without peaks): ``{"directions" (P, 3),
    "angular_radii" (P,) radians, "powers" (P, 3) RGB, "radiance" (P, 3), "dirs", "coeffs", "rel_error"}``; the last
    three are the residual's ZH lobes (the SH path with peaks on), laid out as the preset's own."""
    if not peak_lighting.peaks:
        return None
    n = len(peak_lighting.peaks)
    check(n <= MAX_PAGE_PEAKS, f"the page shades at most {MAX_PAGE_PEAKS} peaks, the lighting has {n}")
    res = peak_lighting.lighting
    return {"directions": np.asarray(peak_lighting.directions, np.float32).astype(float).tolist(),
            "angular_radii": np.asarray(peak_lighting.angular_radii, np.float32).astype(float).tolist(),
            "powers": np.asarray(peak_lighting.powers, np.float32).astype(float).tolist(),
            "radiance": [np.asarray(p.radiance, np.float32).astype(float).tolist() for p in peak_lighting.peaks],
            "dirs": np.asarray(res.dirs, np.float32).astype(float).tolist(),
            "coeffs": np.asarray(res.coeffs, np.float32).astype(float).tolist(),
            "rel_error": float(res.rel_error), "source": str(res.source)}


class PeakGraph:
    """The run's ``peaks.onnx`` in onnxruntime (the graph the page runs in onnxruntime-web): ``__call__(positions
    (B, V, 3), normals (B, V, 3), skin (B, J, 4, 4), directions (P, 3), angular_radii (P,)) -> (B, V, P)`` float32."""

    def __init__(self, path: str | Path) -> None:
        import onnxruntime as ort

        self.path = Path(path)
        check(self.path.is_file(), f"peak visibility graph not found: {self.path}")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        self.session = ort.InferenceSession(str(self.path), opts, providers=["CPUExecutionProvider"])

    def __call__(self, positions: np.ndarray, normals: np.ndarray, skin: np.ndarray, directions: np.ndarray,
                 angular_radii: np.ndarray) -> np.ndarray:
        feeds = {"positions": positions, "normals": normals, "skin": skin, "directions": directions,
                 "angular_radii": angular_radii}
        feeds = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in feeds.items()}
        check_shape(feeds["positions"], "B V 3", name="peak graph positions")
        return self.session.run(["peak_visibility"], feeds)[0]


def page_peak_visibility(graph: PeakGraph | None, state: Any, directions: np.ndarray,
                         angular_radii: np.ndarray) -> np.ndarray:
    """``(B, V, P)`` peak visibility of a posed :class:`~prt_torch.player.posing.PoseBatch` as the page computes it:
    ``graph`` (the run's ``peaks.onnx``) on the posed positions, normals and skinning matrices, or all ones when the
    run has no peak graph."""
    pos = np.ascontiguousarray(state.positions.transpose(0, 2, 1), dtype=np.float32)
    if graph is None:
        return np.ones((*pos.shape[:2], len(directions)), np.float32)
    check(state.skin is not None, "page peak visibility needs the skinning matrices of the pose")
    nrm = np.ascontiguousarray(state.normals.transpose(0, 2, 1), dtype=np.float32)
    return graph(pos, nrm, np.asarray(state.skin, np.float32), directions, angular_radii)


def page_peak_radiance(state: Any, peak_lighting: Any, visibility: np.ndarray, brdf: Any) -> np.ndarray:
    """``(B, V, 3)`` the peaks' radiance of a posed batch (the page's peak term before the base colour): ``peak_
    lighting`` a :class:`~prt_torch.player.peaks.PeakLighting` (already rotated), ``visibility (B, V, P)``."""
    if brdf is None or not peak_lighting.peaks:
        b, _, v = state.positions.shape
        return np.zeros((b, v, 3), np.float32)
    from prt_torch.brdf.direct import peak_radiance

    view = np.ascontiguousarray(state.view_dirs.transpose(0, 2, 1))
    return peak_radiance(state.frames_vx33(), view, peak_lighting.directions, peak_lighting.powers, visibility, brdf)



def page_radiance(player: Any, local: np.ndarray, lighting: Any, peak_lighting: Any, angle: float,
                  graph: PeakGraph | None, brdf: Any) -> tuple[Any, np.ndarray, np.ndarray | None]:
    """What the page computes for ``local (B, J, 4, 4)`` with the light turned by ``angle``: ``(state, radiance
    (B, V, 3), peak visibility (B, V, P) or None)``. ``peak_lighting=None`` (peaks off): ``lighting`` (the whole
    lighting) on the SH path; otherwise its residual lobes on the SH path plus :func:`page_peak_radiance` with
    :func:`page_peak_visibility`. ``player`` (a split-graph :class:`~prt_torch.player.player.Player` with the BRDF's
    RPO selected) shades the SH path with its learned visibility; its lighting is left set to the one used."""
    player.lighting = lighting if peak_lighting is None else peak_lighting.lighting
    player.light_angle = 0.0
    player.rotate_light(angle)
    state = player.pose(local)
    rad = player.shade(state)
    if peak_lighting is None or not peak_lighting.peaks:
        return state, rad, None
    turned = peak_lighting.rotated_about_z(angle)
    vis = page_peak_visibility(graph, state, turned.directions, turned.angular_radii)
    return state, rad + page_peak_radiance(state, turned, vis, brdf), vis
