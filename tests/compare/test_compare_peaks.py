"""``prt compare`` with the light split (issue 27): the ``<method>+peaks_<kind>`` rows, the ``peaks`` JSON, the
reference's peak disks against closed forms, the silhouette rule on every row, ``--peaks`` errors."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from prt_torch.cli import main

KEYS = {"vis_rel_err", "radiance_rel_rmse", "psnr_image_diffuse", "psnr_image_glossy", "bytes", "ms_per_frame", "fps",
        "runtime", "output"}
BASE = ("sh_truth", "unshadowed", "learned_linear")


@pytest.fixture(scope="module")
def sky_compared(peak_run: Path) -> dict[str, Any]:
    from prt_torch.compare import run_compare

    return run_compare(peak_run, methods=["unshadowed", "learned_linear"], max_frames=3, image_frames=1,
                       reference_frames=1, reference_rays=128)


def test_peaks_rows_and_schema(sky_compared: dict[str, Any]) -> None:
    from prt_torch.compare.run import peaks_row

    r = sky_compared
    rows = list(r["methods"])
    want = [*BASE, "sh_truth+peaks_exact"] + [peaks_row(n, k) for n in BASE for k in ("spheres", "learned")]
    assert rows == want
    assert r["peak_kinds"] == ["exact", "spheres", "learned"]
    for n in want:
        m = r["methods"][n]
        assert KEYS <= set(m), n
        assert KEYS - {"runtime", "output"} <= set(m["vs_reference"]), n
        assert np.isfinite(m["vs_reference"]["psnr_image_diffuse"]) and m["ms_per_frame"] > 0
        if "+peaks_" not in n:
            continue
        base = r["methods"][m["base_method"]]
        assert n == peaks_row(m["base_method"], m["peak_kind"]) and m["truth"] == "sh_truth+peaks_exact"
        assert m["vis_rel_err"] == base["vis_rel_err"]
        assert m["ms_per_frame"] == pytest.approx(base["ms_per_frame"] + m["peak_ms_per_frame"])
        assert m["bytes"] == base["bytes"] + m["peak_bytes"] and m["runtime"].startswith(base["runtime"] + " + ")
        assert m["vs_reference"]["ms_per_frame"] == m["ms_per_frame"]
    assert r["methods"]["unshadowed+peaks_learned"]["peak_bytes"] > 0
    # the ceiling is its own truth
    t = r["methods"]["sh_truth+peaks_exact"]
    assert t["radiance_rel_rmse"] == 0.0 and t["psnr_image_diffuse"] == float("inf")
    assert "peak disk" in r["reference"]["lighting"] and "silhouette" in r["reference"]["vertices"]


def test_peaks_json_round_trips(sky_compared: dict[str, Any]) -> None:
    """``peaks``: the procedural sky's sun, the player's direction and the real sun's radius and power."""
    from prt_torch.player.lighting import DEFAULT_SUN_COLOR, DEFAULT_SUN_DIRECTION
    from prt_torch.sg.split import PeakLight

    peaks = [PeakLight.from_dict(p) for p in sky_compared["peaks"]]
    assert len(peaks) == 1 and peaks[0].to_dict() == sky_compared["peaks"][0]
    d = np.asarray(DEFAULT_SUN_DIRECTION) / np.linalg.norm(DEFAULT_SUN_DIRECTION)
    np.testing.assert_allclose(peaks[0].direction, d, atol=1e-12)
    assert math.degrees(peaks[0].angular_radius) == pytest.approx(0.53 / 2)
    np.testing.assert_allclose(peaks[0].power, DEFAULT_SUN_COLOR, rtol=1e-9)


def test_exact_peaks_beat_the_sh_sun_under_a_sun(peak_run: Path) -> None:
    """A real property: under a 2-degree sun disk, the SH path smears the sun (no sharp shadow); the ceiling
    (ray-traced SH for the residual + Embree disc visibility) is closer to the Monte-Carlo reference, diffuse and
    glossy, in images and per vertex; ``--peaks 0`` has no ``+peaks`` row and an empty ``peaks``."""
    from prt_torch.compare import run_compare

    r = run_compare(peak_run, methods=["unshadowed"], max_frames=2, image_frames=1, reference_frames=1,
                    reference_rays=128, light="sun", peak_kinds=["exact"])
    assert list(r["methods"]) == ["sh_truth", "unshadowed", "sh_truth+peaks_exact", "unshadowed+peaks_exact"]
    assert len(r["peaks"]) == 1 and r["peaks"][0]["angular_radius_deg"] == pytest.approx(2.0)
    sh, ceil = r["methods"]["sh_truth"]["vs_reference"], r["methods"]["sh_truth+peaks_exact"]["vs_reference"]
    for k in ("psnr_image_diffuse", "psnr_image_glossy"):
        assert ceil[k] > sh[k] + 1.0, (k, ceil[k], sh[k])
    assert ceil["radiance_rel_rmse"] < sh["radiance_rel_rmse"]
    r0 = run_compare(peak_run, methods=["unshadowed"], max_frames=2, image_frames=1, reference_frames=0,
                     light="sun", peaks=0)
    assert list(r0["methods"]) == ["sh_truth", "unshadowed"] and r0["peaks"] == [] and r0["peak_kinds"] == []


def test_silhouette_rule_on_every_row(peak_run: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every row (methods, +peaks rows) and the reference are 0 at vertices whose normal faces away from the camera
    (computed here from the frames); without the rule the RPO rows are not."""
    from prt_torch.compare import run as run_mod
    from prt_torch.compare.run import heldout_frames, load_compare_run
    from prt_torch.scoring.images import ImageRenderer, player_camera

    ctx = load_compare_run(peak_run)
    fs = heldout_frames(ctx, max_frames=2)
    eye = player_camera(ctx.character).eye
    seen: list[tuple[np.ndarray, dict[str, np.ndarray]]] = []
    orig = ImageRenderer.frame_images

    def spy(self: Any, positions: np.ndarray, radiance: dict[str, np.ndarray], truth: str, mask: Any = None) -> Any:
        seen.append((np.array(positions), {k: np.array(v) for k, v in radiance.items()}))
        return orig(self, positions, radiance, truth, mask=mask)

    monkeypatch.setattr(ImageRenderer, "frame_images", spy)
    for rule in (True, False):
        seen.clear()
        run_mod.run_compare(peak_run, methods=["unshadowed"], max_frames=2, image_frames=2, reference_frames=1,
                            reference_rays=32, peak_kinds=["spheres"], silhouette=rule)
        names: set[str] = set()
        leak = 0.0
        for pos, rad in seen:
            f = next(i for i in range(fs.n_frames) if np.array_equal(fs.positions[i], pos))
            n = fs.frames[f][:, 2].astype(np.float64)
            back = np.einsum("vi,vi->v", n, eye - pos.astype(np.float64)) <= 0
            assert back.sum() > 10
            names |= set(rad)
            for k, v in rad.items():
                if rule or k.startswith("estimate") or k == "reference":
                    assert np.all(v[back] == 0), (rule, k)
                else:
                    leak = max(leak, float(np.abs(v[back]).max()))
        assert {"sh_truth", "unshadowed", "sh_truth+peaks_exact", "unshadowed+peaks_spheres", "reference"} <= names
        if not rule:
            assert leak > 0


def test_reference_disk_light_closed_form() -> None:
    """An unoccluded Lambert vertex under a uniform disk light of radiance ``L`` and half-angle ``r`` whose centre is
    ``theta`` from the normal (the cap wholly above the horizon): irradiance ``pi L sin^2 r cos theta`` exactly, so
    radiance ``L sin^2 r cos theta``; an occluder over the vertex blocks it."""
    from prt_torch.brdf.rpo import builtin_brdf
    from prt_torch.compare.reference import ReferenceLight, reference_radiance

    thetas = np.radians([0.0, 25.0, 50.0])
    # one vertex per tilt, normal tilted about x by -theta (the light along +z stays theta from it)
    frames = np.stack([np.array([[1.0, 0, 0], [0, math.cos(t), -math.sin(t)], [0, math.sin(t), math.cos(t)]])
                       for t in thetas])
    pos = np.array([[0.0, 0, 0], [5.0, 0, 0], [0.0, 5, 0]])
    faces = np.array([[0, 1, 2]])
    eye = np.array([0.3, -2.0, 10.0])
    lam = {"lambert": builtin_brdf("lambert")}
    rad = np.array([3.0, 2.0, 1.0])
    for r_deg in (0.5, 10.0, 30.0):
        r = math.radians(r_deg)
        light = ReferenceLight(lambda d: np.zeros((len(d), 3)), [], "disk", [(np.array([0.0, 0, 1]), r, rad)])
        out = reference_radiance(pos, frames, faces, eye, light, lam, n_rays=8, seed=3, offset=1e-4,
                                 disk_rays=256)["lambert"]
        want = rad[None, :] * math.sin(r) ** 2 * np.cos(thetas)[:, None]
        np.testing.assert_allclose(out, want, rtol=5e-3 if r_deg > 1 else 1e-4)
    # a roof over vertex 0 (normal +z) blocks the whole 30-degree disk
    pos2 = np.vstack([pos, [[-3.0, -3.0, 1.0], [3.0, -3.0, 1.0], [0.0, 3.0, 1.0]]])
    frames2 = np.concatenate([frames, np.broadcast_to(np.eye(3), (3, 3, 3))])
    out = reference_radiance(pos2, frames2, np.array([[0, 1, 2], [3, 4, 5]]), eye, light, lam, n_rays=8, seed=3,
                             offset=1e-4)["lambert"]
    assert np.all(out[0] == 0) and out[1, 0] > 0


def test_split_reference_is_the_split(tmp_path: Path) -> None:
    """The reference light of ``--light sky``: the procedural sky's residual is :func:`~prt_torch.light.sources.
    sky_envmap` (sampled at its pixel centres) and its sun a disk of the peak's radius and radiance; a map's residual
    is the residual map's pixels, its peak the detected disk, and the two carry the map's power."""
    from prt_torch.compare.reference import split_reference
    from prt_torch.light.envmap import EnvMap
    from prt_torch.light.sources import sky_envmap
    from prt_torch.player.lighting import DEFAULT_SUN_DIRECTION
    from prt_torch.player.peaks import load_split
    from prt_torch.sg.split import split_envmap

    split = load_split(None)
    ref = split_reference(split, None)
    sun = np.asarray(DEFAULT_SUN_DIRECTION) / np.linalg.norm(DEFAULT_SUN_DIRECTION)
    env = sky_envmap(sun, height=32)
    dirs = env.directions().reshape(-1, 3)
    np.testing.assert_allclose(ref.radiance(dirs), env.image.reshape(-1, 3), rtol=1e-5, atol=1e-6)
    (d, half, rad), = ref.disks
    p = split.peaks[0]
    assert half == p.angular_radius and np.array_equal(d, p.direction) and np.array_equal(rad, p.radiance)
    assert ref.deltas == []
    # a map: a uniform background 0.5 plus a 3-degree disk of radiance 200
    h = 128
    m = EnvMap(np.full((h, 2 * h, 3), 0.5, np.float32), "latlong", "synthetic")
    md = m.directions()
    axis = np.array([0.3, 0.4, 0.866])
    axis /= np.linalg.norm(axis)
    m.image[md @ axis >= math.cos(math.radians(3.0))] = 200.0
    pytest.importorskip("healpy")
    sp = split_envmap(m, 1)
    ref = split_reference(sp, tmp_path / "synthetic.hdr")
    np.testing.assert_allclose(ref.radiance(md.reshape(-1, 3)), sp.residual.image.reshape(-1, 3), rtol=1e-6)
    (d, half, rad), = ref.disks
    assert float(d @ axis) > math.cos(math.radians(0.5))
    total = (m.solid_angles().reshape(-1) @ m.image.reshape(-1, 3).astype(np.float64))
    got = sp.residual.solid_angles().reshape(-1) @ sp.residual.image.reshape(-1, 3).astype(np.float64)
    got = got + rad * 2 * math.pi * (1 - math.cos(half))
    np.testing.assert_allclose(got, total, rtol=1e-2)


@pytest.mark.parametrize("args, msg", [
    (["--peaks", "7"], "--peaks must be an integer in 0..4"),
    (["--peaks", "many"], "--peaks must be 'auto' or an integer"),
    (["--peaks", "-1"], "--peaks must be 'auto' or an integer"),
    (["--peak-kinds", "exact,nope"], "unknown peak kind 'nope'"),
    (["--peak-kinds", "exact", "--peaks", "0"], "--peak-kinds needs peaks"),
    (["--peaks", "2", "--light", "smooth"], "--light smooth has no peak light"),
])
def test_bad_peaks_arguments(tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], msg: str) -> None:
    assert main(["compare", str(tmp_path), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and msg in err[0], err
