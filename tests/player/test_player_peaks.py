"""The Python player with peak lights (issue 27 item 3): the residual through the ONNX graphs plus, per peak,
``E f_r(l, v) max(n . l, 0) V`` with the analytic BRDF, against independent computations (the BRDF formulas written
out here, the library's cone-sphere kernel and peak term, the whole lighting's energy), ``--peaks 0`` as the old
player, torch-free playback and one-line errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.player import Player
from prt_torch.player.posing import PoseBatch
from tests.tolerance import assert_bitwise


def _phong(wi: np.ndarray, wo: np.ndarray, exponent: float, kd: float, ks: float) -> np.ndarray:
    """Normalised modified Phong written out (Lafortune & Willems 1994): ``kd / pi + ks (e + 2) / (2 pi)
    max(r(wo) . wi, 0)^e``, ``r(wo) = (-x, -y, z)``; 0 below either horizon."""
    r = wo * np.array([-1.0, -1.0, 1.0])
    c = np.maximum((r * wi).sum(-1), 0.0)
    f = kd / math.pi + ks * (exponent + 2) / (2 * math.pi) * c ** exponent
    return np.where((wi[..., 2] > 0) & (wo[..., 2] > 0), f, 0.0)


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _peak_term_numpy(state: PoseBatch, directions: np.ndarray, powers: np.ndarray, vis: np.ndarray,
                     brdf_params: dict) -> np.ndarray:
    """``sum_p E_p f_r(l_p, v) max(n . l_p, 0) V_p`` per vertex, float64, from the batch's (original order) frames
    and view directions: local directions are the frame rows times the world ones."""
    fr = state.frames_vx33().astype(np.float64)  # (B, V, 3, 3) rows t, b, n
    view = np.swapaxes(state.view_dirs, 1, 2).astype(np.float64)
    wo = _unit(np.einsum("bvij,bvj->bvi", fr, view))
    out = np.zeros(fr.shape[:2] + (3,))
    for p, d in enumerate(directions):
        wi = _unit(np.einsum("bvij,j->bvi", fr, d))
        f = _phong(wi, wo, **brdf_params)
        out += (f * np.maximum(wi[..., 2], 0.0) * vis[..., p])[..., None] * powers[p]
    return out


@pytest.mark.parametrize("graph", ["fused", "split", "overlap"])
def test_radiance_is_the_residual_plus_the_peak_term_written_out(peak_run: Path, graph: str) -> None:
    from prt_torch.blockers.cones import sphere_peak_visibility
    from prt_torch.blockers.spheres import SphereSet, pose_spheres
    from prt_torch.rundir import RunDir

    p = Player(peak_run, brdf="phong", graph=graph)
    try:
        assert p.peak_source is not None and p.peak_source.kind == "learned"  # the run has peak_blockers.npz
        assert len(p.peaks.peaks) == 1 and "without its 1 peak" in p.lighting.source  # the sky's sun, split off
        loc = p.clip_locals("wave")
        for i in (0, len(loc) // 2):
            state, rad = p.compute(loc[i:i + 1])
            # the visibility: the library's cone-sphere kernel on the learned spheres (a second implementation)
            spheres = SphereSet.load(RunDir(peak_run).peak_blockers_path)
            pos, nrm = (np.ascontiguousarray(np.swapaxes(x, 1, 2)) for x in (state.positions, state.normals))
            ref_vis = sphere_peak_visibility(pos, nrm, pose_spheres(spheres, state.skin), spheres.radius,
                                             p.peaks.directions.astype(np.float32),
                                             p.peaks.angular_radii.astype(np.float32))
            np.testing.assert_allclose(state.peak_visibility, ref_vis, rtol=0, atol=2e-4)
            assert 0.05 < float((state.peak_visibility > 0.5).mean()) < 0.95  # a sun-lit side and a dark one
            # the SH path alone is the residual; the rest is the peak term with Phong written out
            np.testing.assert_allclose(state.residual_radiance, p.shade(state), rtol=1e-5,
                                       atol=1e-5 * float(np.abs(rad).max()))
            ref = _peak_term_numpy(state, p.peaks.directions, p.peaks.powers, state.peak_visibility.astype(np.float64),
                                   {"exponent": 16.0, "kd": 0.3, "ks": 0.7})  # brdf.rpo's catalogue 'phong'
            scale = float(np.abs(ref).max())
            assert scale > 0
            np.testing.assert_allclose(rad - state.residual_radiance, ref, rtol=1e-4, atol=1e-5 * scale)
    finally:
        p.close()


def test_peaks_zero_is_the_old_player(peak_run: Path) -> None:
    """``peaks=0``: the whole lighting (``load_lighting``) on the SH path, fed to the fused graph here by hand."""
    from prt_torch.player.lighting import load_lighting

    p = Player(peak_run, brdf="lambert", peaks=0, graph="fused")  # the graph fed by hand below
    try:
        whole = load_lighting(None, p.order)
        assert_bitwise(p.lighting.coeffs, whole.coeffs, why="the same deterministic fit of the same SH")
        assert p.peaks.peaks == [] and p.peak_source is None
        state, rad = p.compute(p.clip_locals("wave")[2:3])
        assert state.peak_visibility.shape == (1, p.bundle.n_vertices, 0)
        o = p.vertex_order
        feeds = {"pose": state.features, "frames": state.in_order("frames", o),
                 "view_dirs": state.in_order("view_dirs", o), "lobe_dirs": whole.dirs, "lobe_coeffs": whole.coeffs,
                 "rpo_M": p.rpo.M, "rpo_w": p.rpo.w, "rpo_tint": p.rpo.tint}
        ref = p.bundle.graphs["fused"].run(feeds)["radiance"]
        if o is not None:
            back = np.empty_like(ref)
            back[:, o] = ref
            ref = back
        assert_bitwise(rad, ref, why="the same graph on the same inputs")
    finally:
        p.close()


def test_the_split_conserves_the_energy_of_an_unoccluded_vertex(peak_run: Path) -> None:
    """Residual (SH path, unshadowed) + the sun's term (unshadowed) vs the whole lighting on the SH path, Lambert,
    averaged over normals of every direction (only band 0 survives the average: the sinc window and the SH
    truncation of the sun, which move single vertices, drop out)."""
    auto = Player(peak_run, brdf="lambert", graph="split")
    whole = Player(peak_run, brdf="lambert", graph="split", peaks=0)
    try:
        state = auto.pose(auto.clip_locals("wave")[:1])
        v = auto.bundle.n_vertices
        k = np.arange(v) + 0.5  # spherical Fibonacci normals
        z = 1 - 2 * k / v
        phi = math.pi * (1 + 5 ** 0.5) * k
        n = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], -1)
        t = _unit(np.cross(n, np.where(np.abs(n[:, 2:]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])))
        frames = np.stack([t, np.cross(n, t), n], 1)  # (V, 3, 3) rows t, b, n
        fr = np.ascontiguousarray(frames.reshape(1, v, 9).transpose(0, 2, 1), dtype=np.float32)
        nv = np.ascontiguousarray(n.T[None], dtype=np.float32)
        synthetic = PoseBatch(state.positions, nv, fr, nv, state.features, skin=state.skin)  # seen from the normal
        hemi = np.broadcast_to(auto.unshadowed, (1, v, auto.order ** 2))
        residual = auto.shade(synthetic, visibility=hemi)
        sun = auto.shade_peaks(synthetic, (n @ auto.peaks.directions.T)[None].astype(np.float32) > 0)
        everything = whole.shade(synthetic, visibility=hemi)
        split_mean, whole_mean = (residual + sun).mean(axis=(0, 1)), everything.mean(axis=(0, 1))
        np.testing.assert_allclose(split_mean, whole_mean, rtol=0.02)
        assert float(sun.max()) > float(residual.max())  # a vertex facing the sun gets more from it than the sky
    finally:
        auto.close()
        whole.close()


def test_compiled_kernels_match_the_library(peak_run: Path) -> None:
    """The player's fused per-vertex kernels vs :func:`~prt_torch.blockers.cones.sphere_peak_visibility` and
    :func:`~prt_torch.brdf.direct.peak_radiance` (several peaks, sun-sized to wide discs, three BRDFs)."""
    from prt_torch.blockers.cones import sphere_peak_visibility, sphere_visibility_soa
    from prt_torch.blockers.spheres import pose_spheres
    from prt_torch.brdf.direct import peak_radiance, peak_radiance_soa
    from prt_torch.brdf.rpo import builtin_brdf

    p = Player(peak_run, brdf="phong", graph="split")
    try:
        state = p.pose(p.clip_locals("wave")[1:3])  # B = 2
        d = _unit(np.array([[0.45, -0.55, 0.7], [-0.3, 0.2, 0.9], [0.9, 0.1, 0.1]]))
        radii = np.radians([0.27, 3.0, 15.0])
        sp = p.peak_source.spheres
        cen = pose_spheres(sp, state.skin)
        pos, nrm = (np.ascontiguousarray(np.swapaxes(x, 1, 2)) for x in (state.positions, state.normals))
        ref = sphere_peak_visibility(pos, nrm, cen, sp.radius, d.astype(np.float32), radii.astype(np.float32))
        for threads in (True, False):
            got = sphere_visibility_soa(state.positions, state.normals, cen, sp.radius, d, radii, threads=threads)
            np.testing.assert_allclose(got, ref, rtol=0, atol=2e-4)
        assert 0.01 < float(((ref > 0.01) & (ref < 0.99)).mean())  # penumbrae and the horizon cut are exercised
        powers = np.array([[3.0, 2.5, 2.0], [1.0, 1.0, 1.2], [0.2, 0.3, 0.4]])
        view = np.ascontiguousarray(np.swapaxes(state.view_dirs, 1, 2))
        from prt_torch.brdf.analytic import Phong
        from prt_torch.rig.material import DEFAULT_MATERIAL, material_brdf

        class Tinted(Phong):  # a subclass: the generic path (its own shape), not the compiled formulas
            pass

        brdfs = [builtin_brdf(n) for n in ("phong", "ggx", "lambert", "ward", "blinn")]
        brdfs += [material_brdf(DEFAULT_MATERIAL), Tinted(tint=[0.9, 0.5, 0.2], exponent=40.0, kd=0.2, ks=0.5)]
        fr = state.frames_vx33().astype(np.float64)  # (B, V, 3, 3) rows t, b, n
        wo = np.einsum("bvij,bvj->bvi", fr, view.astype(np.float64))
        wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
        for brdf in brdfs:
            # independently: the analytic BRDF object (numpy) on every (vertex, peak) pair, summed by hand
            want = np.zeros(wo.shape)
            for k in range(len(d)):
                wi = np.einsum("bvij,j->bvi", fr, d[k])
                wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
                f_r = brdf(wi.reshape(-1, 3), wo.reshape(-1, 3)).reshape(wo.shape)
                want += f_r * np.maximum(wi[..., 2:3], 0.0) * ref[..., k:k + 1] * powers[k]
            np.testing.assert_allclose(peak_radiance(fr, view, d, powers, ref, brdf), want, rtol=1e-4,
                                       atol=1e-6 * float(np.abs(want).max()), err_msg=brdf.name)
            for threads in (True, False):
                got = peak_radiance_soa(state.frames, state.view_dirs, d, powers, ref, brdf, threads=threads)
                np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6 * float(np.abs(want).max()),
                                           err_msg=brdf.name)
    finally:
        p.close()


def test_light_rotation_and_other_kinds(peak_run: Path) -> None:
    from prt_torch.player.timing import FrameTimer

    p = Player(peak_run, brdf="ggx", peak_kind="spheres")
    try:
        assert p.peak_source.kind == "spheres"
        p.rotate_light(0.7)
        want = p.peaks.rotated_about_z(0.7).directions
        np.testing.assert_allclose(p._peak_dirs, want, rtol=0, atol=1e-12)
        timer = FrameTimer()
        loc = p.clip_locals("wave")
        p.compute(loc[:1], timer)
        assert "peaks" in timer.steps and timer.summary()["compute_fps"] > 0
    finally:
        p.close()
    ex = Player(peak_run, brdf="lambert", peak_kind="exact", graph="split")
    try:
        state, _ = ex.compute(ex.clip_locals("wave")[:1])
        v = state.peak_visibility
        assert v.shape == (1, ex.bundle.n_vertices, 1) and 0.0 <= float(v.min()) and float(v.max()) <= 1.0
        n_dot_l = np.swapaxes(state.normals, 1, 2)[0] @ ex.peaks.directions[0]
        assert np.all(v[0, n_dot_l < -0.01, 0] == 0)  # facing away from the sun: dark
    finally:
        ex.close()


def test_cli_plays_with_peaks_without_torch(peak_run: Path, tmp_path: Path) -> None:
    from tests.torchfree import run_cli_without_torch

    for peaks in ("auto", "0"):
        run_cli_without_torch(["play", str(peak_run), "--clip", "wave", "--png", str(tmp_path / peaks),
                               "--max-frames", "1", "--size", "64x48", "--peaks", peaks])
        assert (tmp_path / peaks / "frame_00000.png").is_file()


def test_errors_are_one_line(peak_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from prt_torch.cli import main

    for extra, msg in ((["--peaks", "7"], "--peaks"), (["--peaks", "sun"], "--peaks"),
                       (["--peak-visibility", "cones"], "--peak-visibility")):
        capsys.readouterr()
        assert main(["play", str(peak_run), "--clip", "wave", "--png", str(tmp_path / "x"), *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert msg in err and len(err.splitlines()) == 1, err
        assert not (tmp_path / "x").exists()  # checked before anything is loaded or written
    with pytest.raises(PrtError, match="unknown peak visibility"):
        Player(peak_run, peak_kind="cones")
    # an RPO file of a BRDF that has no analytic form here cannot shade the peaks
    from prt_torch.brdf.analytic import Lambert
    from prt_torch.brdf.rpo import build_rpo

    p = Player(peak_run, brdf="lambert")
    try:
        build_rpo(Lambert(name="velvet"), order=p.order, k=2, name="velvet").save(tmp_path / "velvet.npz")
        with pytest.raises(PrtError, match="analytic BRDF") as exc:
            p.set_brdf(str(tmp_path / "velvet.npz"))
        assert "\n" not in str(exc.value) and p.rpo.name == "lambert"  # not swapped
    finally:
        p.close()
    Player(peak_run, brdf=str(tmp_path / "velvet.npz"), peaks=0).close()  # fine without peaks


def test_fused_peaks_graph_plays_what_the_compiled_peak_path_plays(peak_run: Path) -> None:
    """``graph="fused_peaks"`` (one ORT graph: the fused graph, the learned blockers' torch kernel and the peak term
    with the BRDF an input) vs ``graph="fused"`` + the compiled peak kernels, per BRDF swapped at run time."""
    from prt_torch.export.peaks_graph import PARITY_RTOL

    a, b = Player(peak_run, brdf="phong", graph="fused"), Player(peak_run, brdf="phong", graph="fused_peaks")
    try:
        loc = a.clip_locals("wave")[1:3]
        for name in ("phong", "lambert"):
            a.set_brdf(name)
            b.set_brdf(name)
            sa, ra = a.compute(loc)
            sb, rb = b.compute(loc)
            # float32 trigonometry (the graph) vs float64 scalars (numba) of one cap formula: the export's bound
            np.testing.assert_allclose(sb.peak_visibility, sa.peak_visibility, rtol=0, atol=PARITY_RTOL)
            peak = ra - sa.residual_radiance
            assert float(np.abs(peak).max()) > 0.1 * float(np.abs(ra).max())  # the sun is a visible part
            np.testing.assert_allclose(rb, ra, rtol=0, atol=PARITY_RTOL * float(np.abs(peak).max())
                                       + 1e-5 * float(np.abs(ra).max()))
            assert sb.residual_radiance is None  # the graph returns the sum
    finally:
        a.close()
        b.close()


@pytest.mark.parametrize(("kwargs", "message"), [({"peaks": 0}, "needs peak lights"),
                                                   ({"peak_kind": "spheres"}, "must be 'learned'")])
def test_fused_peaks_graph_refuses_other_peaks_in_one_line(peak_run: Path, kwargs: dict, message: str) -> None:
    with pytest.raises(PrtError, match=message) as e:
        Player(peak_run, brdf="phong", graph="fused_peaks", **kwargs)
    assert "\n" not in str(e.value)
