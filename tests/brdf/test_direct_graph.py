"""The peak term in torch for the exported graphs (:mod:`prt_torch.brdf.direct_graph`) against each analytic BRDF's
own ``cosine_weighted`` (:mod:`prt_torch.brdf.analytic`, a second implementation of every shape) on random frames,
views and lights, with the BRDF swapped as an input of one traced function, and its ONNX export against torch."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from prt_torch.brdf.analytic import BlinnPhong, CookTorrance, Lambert, Phong, Ward
from prt_torch.brdf.direct import brdf_code
from prt_torch.brdf.direct_graph import peak_radiance_graph

BRDFS = [Lambert(tint=(0.8, 0.6, 0.4)), Phong(exponent=16, kd=0.3, ks=0.7), CookTorrance(roughness=0.5, kd=0.4, ks=0.6),
         Ward(alpha=0.3, kd=0.2, ks=0.8), BlinnPhong(exponent=24, kd=0.3, ks=0.6)]


def _scene(seed: int = 0, b: int = 2, v: int = 400, p: int = 3) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    q = np.linalg.qr(rng.normal(size=(b * v, 3, 3)))[0]  # random orthonormal frames (rows t, b, n)
    frames = q.reshape(b, v, 9).transpose(0, 2, 1)
    view = rng.normal(size=(b, 3, v))
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    d = rng.normal(size=(p, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return {"frames": frames, "view": view, "directions": d, "powers": rng.uniform(0.5, 3.0, (p, 3)),
            "visibility": rng.uniform(0.0, 1.0, (b, v, p))}


def _reference(s: dict[str, np.ndarray], brdf) -> np.ndarray:
    """float64: ``sum_p E_p tint f_r(wi, wo) max(n . wi, 0) V_p`` with ``brdf.cosine_weighted`` (0 below either
    horizon), local directions the frame rows times the world ones."""
    b, _, v = s["frames"].shape
    fr = s["frames"].transpose(0, 2, 1).reshape(b, v, 3, 3)
    wo = np.einsum("bvij,bjv->bvi", fr, s["view"])
    out = np.zeros((b, v, 3))
    for p, d in enumerate(s["directions"]):
        wi = np.einsum("bvij,j->bvi", fr, d)
        ok = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        f = np.zeros((b, v))
        f[ok] = brdf.cosine_weighted(wi[ok], wo[ok])
        out += (f * s["visibility"][..., p])[..., None] * (s["powers"][p] * np.asarray(brdf.tint))
    return out


def _args(s: dict[str, np.ndarray], brdf) -> list[torch.Tensor]:
    code, prm = brdf_code(brdf)
    powers = s["powers"] * np.asarray(brdf.tint)[None]
    return [torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)) for x in
            (s["frames"], s["view"], s["directions"], powers, s["visibility"], np.r_[code, prm])]


@pytest.mark.parametrize("brdf", BRDFS, ids=lambda b: type(b).__name__)
def test_graph_peak_term_matches_each_brdf_written_out(brdf) -> None:
    s = _scene()
    ref = _reference(s, brdf)
    got = peak_radiance_graph(*_args(s, brdf)).numpy()
    scale = float(np.abs(ref).max())
    assert scale > 0 and float((ref > 0).mean()) > 0.1  # lit pairs exist
    # float32 of a few products and one pow: relative ~1e-6 per factor; the Phong / Blinn powers (e <= 24) amplify
    # the cosine's rounding by e
    np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-5 * scale)


def test_the_brdf_is_an_input_of_one_onnx_graph(tmp_path) -> None:
    """Traced once with Phong, the exported graph shades every BRDF given at run time (onnxruntime vs the
    reference of each)."""
    import onnxruntime as ort

    s = _scene(1)
    path = tmp_path / "peak.onnx"
    names = ["frames", "view_dirs", "directions", "powers", "visibility", "brdf"]

    class M(torch.nn.Module):
        def forward(self, *a):  # noqa: ANN002
            return peak_radiance_graph(*a)

    torch.onnx.export(M(), tuple(_args(s, BRDFS[1])), str(path), input_names=names, output_names=["radiance"],
                      opset_version=17, dynamo=False,
                      dynamic_axes={"frames": {0: "B", 2: "V"}, "view_dirs": {0: "B", 2: "V"},
                                    "visibility": {0: "B", 1: "V", 2: "P"}, "directions": {0: "P"},
                                    "powers": {0: "P"}})
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    for brdf in BRDFS:
        ref = _reference(s, brdf)
        got = sess.run(None, {k: a.numpy() for k, a in zip(names, _args(s, brdf), strict=True)})[0]
        np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-5 * float(np.abs(ref).max()))
