"""Write the browser player's self-contained static site for an exported run (``prt web RUN --out DIR``).

Site layout (every file written atomically)::

    DIR/index.html, *.js, prt_shading.glsl       the page (copied from the repository's web/src): prt-character.js
                                                 is the three.js module (PRTCharacter) the page (main.js) and
                                                 example.html (two characters in one three.js scene) are built on
    DIR/vendor/three/three.module.js, three.core.js           three.js (web/node_modules, pinned)
    DIR/vendor/ort/ort.wasm.min.mjs, ort-wasm-simd-threaded.{mjs,wasm}   onnxruntime-web, wasm backend
    DIR/assets/manifest.json                     sizes, names, conventions, lighting presets, camera, material,
                                                 the offset / dtype / shape of every array in data.bin, and the
                                                 size and sha256 of data.bin and of the model (the page checks both)
                                                 and what the page opens on (``start``: :func:`start_entry`)
    DIR/assets/data.bin                          little-endian arrays (8-byte aligned), see SITE_ARRAYS
    DIR/assets/pose_to_visibility.onnx           the run's visibility graph, byte for byte (the page's decode when
                                                 the export has no compiled path; else loaded only on demand by
                                                 ``window.prt.visibility``, the tests' and ``--check``'s comparison)
    DIR/assets/latent.onnx                       the run's latent graph ``pose (B, A) -> z (B, G, K)``, byte for
                                                 byte, when the export ships the compiled frame path
                                                 (:mod:`prt_torch.export.compiled`); the page decodes on the GPU
    DIR/assets/peak_visibility.onnx              the peak lights' visibility graph (:func:`write_peak_graph`: the
                                                 run's learned one, else its blocker spheres'), when a lighting has
                                                 peaks
    DIR/assets/basecolor.png                     the material's base-colour texture (when it has one)

The arrays are what :class:`prt_torch.player.posing.Poser` and the shading graph take: rest mesh, sparse
skin weights, bind / inverse-bind transforms (float64, as the numpy FK uses them), cluster labels / axes /
bones (vertex frames), every clip's local joint transforms (float32, rows 0..2 of each 4x4: ``(F, J, 12)``),
the RPO catalogue (``M (k, C, C)``, ``w (k, C)`` zero-padded to the graph's ``k``), the material's per-vertex
base colour and UVs; with ``latent.onnx``, the GPU decode's per-vertex bases (:func:`decode_texture`, manifest key
``decode``). Lighting presets are the player's own (:func:`prt_torch.scoring.lighting.shipping_lights`:
the procedural sky and the env maps of the shared data, 3 ZH lobes each) plus any ``--env`` files.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.io import atomic_path, atomic_write_bytes, atomic_write_json
from prt_torch.rig.material import analytic_brdf
from prt_torch.shapes import check_shape
from prt_torch.web.peaks import MAX_PAGE_PEAKS, brdf_entry, peaks_entry

#: version of the site format (manifest key ``format``)
SITE_FORMAT = "prt_torch.web/1"
ASSETS = "assets"
MANIFEST = "manifest.json"
DATA = "data.bin"
MODEL = "pose_to_visibility.onnx"
LATENT_MODEL = "latent.onnx"
PEAKS_MODEL = "peak_visibility.onnx"
TEXTURE = "basecolor.png"

#: npm files copied into the site: (package-relative source under web/node_modules, site-relative target)
VENDOR_FILES = (
    ("three/build/three.module.js", "vendor/three/three.module.js"),
    ("three/build/three.core.js", "vendor/three/three.core.js"),
    ("onnxruntime-web/dist/ort.wasm.min.mjs", "vendor/ort/ort.wasm.min.mjs"),
    ("onnxruntime-web/dist/ort-wasm-simd-threaded.mjs", "vendor/ort/ort-wasm-simd-threaded.mjs"),
    ("onnxruntime-web/dist/ort-wasm-simd-threaded.wasm", "vendor/ort/ort-wasm-simd-threaded.wasm"),
)

#: page files copied from web/src (every other file there is ignored)
PAGE_SUFFIXES = (".html", ".js", ".mjs", ".glsl", ".css")


def web_root() -> Path:
    """The repository's ``web/`` folder (page sources ``src/``, pinned npm packages ``node_modules/``)."""
    env = os.environ.get("PRT_WEB_ROOT")
    root = Path(env) if env else Path(__file__).resolve().parents[2] / "web"
    check((root / "src").is_dir(), f"browser player sources not found at {root}/src (run from a clone of the "
                                   f"repository, or set PRT_WEB_ROOT)")
    return root


def vendor_sources(root: Path | None = None) -> list[tuple[Path, str]]:
    """``[(source file, site path)]`` of the npm files the site needs; one-line error when not installed."""
    root = web_root() if root is None else root
    out = []
    for src, dst in VENDOR_FILES:
        p = root / "node_modules" / src
        check(p.is_file(), f"{p} missing: run `npm ci` in {root} (scripts/setup.sh does)")
        out.append((p, dst))
    return out


@dataclass
class _Blob:
    """Arrays packed into one little-endian buffer, 8-byte aligned, with their manifest entries."""

    parts: list[bytes] = field(default_factory=list)
    entries: dict[str, dict[str, Any]] = field(default_factory=dict)
    size: int = 0

    def add(self, name: str, a: np.ndarray, dtype: str) -> None:
        check(name not in self.entries, f"duplicate site array {name!r}")
        a = np.ascontiguousarray(np.asarray(a).astype(np.dtype(dtype).newbyteorder("<")))
        check(bool(np.isfinite(a).all()) if a.dtype.kind == "f" else True, f"site array {name!r} has NaN or Inf")
        raw = a.tobytes()
        self.entries[name] = {"offset": self.size, "dtype": dtype, "shape": list(a.shape), "bytes": len(raw)}
        pad = (-len(raw)) % 8
        self.parts.append(raw + b"\0" * pad)
        self.size += len(raw) + pad

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def _lighting_entry(name: str, lighting: Any) -> dict[str, Any]:
    return {"name": name, "source": str(lighting.source), "rel_error": float(lighting.rel_error),
            "dirs": np.asarray(lighting.dirs, np.float32).astype(float).tolist(),
            "coeffs": np.asarray(lighting.coeffs, np.float32).astype(float).tolist()}


def site_light_sources(env: list[str] | tuple[str, ...] = (), presets: bool = True) -> dict[str, Path | None]:
    """``{name: env map path, or None for the procedural sky}``: the player's presets (:data:`prt_torch.scoring.
    lighting.PLAYER_LIGHT`, the shared env maps of :data:`~prt_torch.scoring.lighting.ENVMAPS` found) and the
    ``env`` files (named by stem)."""
    from prt_torch.scoring.lighting import ENVMAPS, PLAYER_LIGHT, shared_data_dir

    out: dict[str, Path | None] = {PLAYER_LIGHT: None}
    data = shared_data_dir() if presets else None
    for name, file in ENVMAPS.items():
        if data is not None and (data / "envmaps" / file).is_file():
            out[name] = data / "envmaps" / file
    for e in env:
        out[Path(e).stem] = Path(e)
    return out


def site_lightings(order: int, env: list[str] | tuple[str, ...] = (), presets: bool = True) -> dict[str, Any]:
    """``{name: Lighting}``: the player's presets (sky, shared env maps) and the ``env`` files (named by stem)."""
    from prt_torch.player.lighting import load_lighting

    return {name: load_lighting(src, order) for name, src in site_light_sources(env, presets).items()}


def site_peak_lightings(order: int, env: list[str] | tuple[str, ...] = (), presets: bool = True) -> dict[str, Any]:
    """``{name: PeakLighting}`` of the same presets, split by :func:`prt_torch.player.peaks.load_peak_lighting`
    (``peaks="auto"``: the sky's sun, a map's detected peaks; no peak: an empty split)."""
    from prt_torch.player.peaks import load_peak_lighting

    return {name: load_peak_lighting(src, order, "auto") for name, src in site_light_sources(env, presets).items()}


def write_site(run: str | os.PathLike[str], out: str | os.PathLike[str], env: tuple[str, ...] = (),
               material_rpo: bool = True, motions: tuple[str, ...] = (), env_presets: bool = True) -> dict[str, Any]:
    """Write the site of exported run ``run`` into ``out`` (created; existing site files are replaced).

    Args:
        run: an exported run directory (anything ``prt play`` plays).
        out: the site directory.
        env: extra HDR environment maps offered as lighting presets.
        motions: motion files (BVH / glTF) retargeted onto the character (:func:`prt_torch.rig.retarget.retarget_file`,
            as ``prt play --motion`` does), offered as clips named ``motion:<stem>``.
        env_presets: offer the shared data's env maps (:data:`prt_torch.scoring.lighting.ENVMAPS`) besides the sky.
        material_rpo: add the character material's own RPO (Cook-Torrance with its roughness, cached) to the
            catalogue as ``material`` (building it needs scikit-learn, the ``export`` extra; skipped without it).

    Returns:
        the manifest (also written to ``out/assets/manifest.json``).
    """
    from prt_torch.player.bundle import RunBundle
    from prt_torch.player.compiled import has_compiled_path
    from prt_torch.player.follow import clip_follow
    from prt_torch.player.lighting import hemisphere_visibility
    from prt_torch.player.material import vertex_base_color
    from prt_torch.player.player import CAMERA_AZIMUTH, CAMERA_DISTANCE, CAMERA_ELEVATION, camera_target
    from prt_torch.player.tonemap import GAMMA
    from prt_torch.rig.material import character_material

    root = web_root()
    vendor = vendor_sources(root)
    bundle = RunBundle(run, threads=1, graphs=("visibility",))
    ch = bundle.character
    order, c = bundle.order, bundle.order ** 2
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    blob = _Blob()
    blob.add("rest_vertices", ch.rest_vertices, "float32")
    blob.add("rest_normals", ch.rest_normals, "float32")
    blob.add("faces", ch.faces, "uint32")
    blob.add("skin_joints", ch.joints, "uint32")
    blob.add("skin_weights", ch.weights, "float32")
    blob.add("bind_local", ch.bind_local, "float64")
    blob.add("inverse_bind", ch.inverse_bind, "float64")
    blob.add("cluster", bundle.cluster, "uint32")
    blob.add("cluster_axis", bundle.cluster_axis, "float32")
    blob.add("cluster_bone", bundle.cluster_bone, "uint32")
    clips = []
    follow: dict[str, list[float]] = {}  # the follow camera per clip (prt_torch.player.follow): 4 floats a frame
    sources = [(name, ch.clip(name)) for name in ch.clips]
    if motions:
        from prt_torch.rig.retarget import retarget_file

        for path in motions:
            motion, _ = retarget_file(path, ch)
            sources.append((f"motion:{motion.name}", motion))
    for name, clip in sources:
        local = np.asarray(clip.local, dtype=np.float64)
        check_shape(local, ("F", ch.num_joints, 4, 4), name=f"clip {name!r}: local transforms")
        key = f"clip:{name}"
        blob.add(key, local[:, :, :3, :].reshape(len(local), ch.num_joints, 12), "float32")
        clips.append({"name": name, "fps": float(clip.fps), "frames": int(len(local)), "array": key})
        follow[name] = clip_follow(ch, clip).flat()
    check(bool(clips), f"{bundle.run_dir}: the character has no clips to play")
    names = list(bundle.brdf_names)
    rpo_entries = []
    rpos = [(n, bundle.rpo(n), bundle.run.rpo_path(n)) for n in names]
    material = character_material(ch)
    if material_rpo:
        mat = _material_rpo(material, order, bundle.n_terms, bundle.run)
        if mat is not None:
            from prt_torch.player.bundle import load_rpo_tensors

            rpos.append(("material", load_rpo_tensors(mat, order, bundle.n_terms), mat))
    from prt_torch.brdf.rpo import RPO

    for name, r, path in rpos:
        u = np.zeros((bundle.n_terms, c), np.float32)
        u_file = np.asarray(RPO.load(path).u, np.float32)
        u[:len(u_file)] = u_file
        blob.add(f"rpo:{name}:M", r.M, "float32")
        blob.add(f"rpo:{name}:u", u, "float32")
        blob.add(f"rpo:{name}:w", r.w, "float32")
        rpo_entries.append({"name": name, "tint": r.tint.astype(float).tolist(), "M": f"rpo:{name}:M",
                            "u": f"rpo:{name}:u", "w": f"rpo:{name}:w",
                            "brdf": brdf_entry(analytic_brdf(name, material))})
    base = vertex_base_color(ch)
    blob.add("base_color", base if base is not None else np.ones((ch.num_vertices, 3), np.float32), "float32")
    texture = None
    if material.texture is not None and ch.uv is not None:
        blob.add("uv", ch.uv, "float32")
        import cv2

        ok, png = cv2.imencode(".png", np.ascontiguousarray(material.texture[..., :3][..., ::-1]))
        check(bool(ok), "could not encode the base-colour texture as PNG")
        atomic_write_bytes(out / ASSETS / TEXTURE, png.tobytes())
        texture = TEXTURE
    lights = site_lightings(order, tuple(env), env_presets)
    peak_lights = site_peak_lightings(order, tuple(env), env_presets)
    peak_source = write_peak_graph(bundle.run, ch, out / ASSETS / PEAKS_MODEL) \
        if any(pl.peaks for pl in peak_lights.values()) else None
    peak_graph = out / ASSETS / PEAKS_MODEL if peak_source is not None else None
    start = start_entry(bundle, [c["name"] for c in clips], [r["name"] for r in rpo_entries])
    # the tone map per lighting as the Python player fixes it for what the page opens on (its BRDF, its clip)
    tonemaps = player_tonemaps(bundle.run_dir, lights, start["brdf"], ch, start["clip"], peak_lights, peak_graph,
                               material)
    peaks_model = None
    if peak_graph is not None:
        peak_bytes = peak_graph.read_bytes()
        peaks_model = {"file": PEAKS_MODEL, "source": peak_source,
                       "inputs": ["positions", "normals", "skin", "directions", "angular_radii"],
                       "output": "peak_visibility", "bytes": len(peak_bytes),
                       "sha256": hashlib.sha256(peak_bytes).hexdigest()}
    decode = None
    if has_compiled_path(bundle):
        basis, rows, groups = decode_texture(bundle)
        blob.add("decode_basis", basis, "float16")
        blob.add("decode_rows", rows, "float32")
        latent_bytes = bundle.run.latent_graph_path.read_bytes()
        atomic_write_bytes(out / ASSETS / LATENT_MODEL, latent_bytes)
        decode = {"file": LATENT_MODEL, "input": "pose", "output": "latent", "bytes": len(latent_bytes),
                  "sha256": hashlib.sha256(latent_bytes).hexdigest(), "basis": "decode_basis", "rows": "decode_rows",
                  "basis_dtype": "float16", "k_max": int(basis.shape[1] // (4 * _texels(c)) - 1),
                  "texels": int(basis.shape[1] // 4), "groups": groups}
    else:
        (out / ASSETS / LATENT_MODEL).unlink(missing_ok=True)
    data = blob.bytes()
    atomic_write_bytes(out / ASSETS / DATA, data)
    model_bytes = bundle.run.graph_path("visibility").read_bytes()
    atomic_write_bytes(out / ASSETS / MODEL, model_bytes)
    center, radius = camera_target(ch.rest_vertices)
    manifest: dict[str, Any] = {
        "format": SITE_FORMAT,
        "name": ch.name,
        "run": str(bundle.run_dir),
        "n_vertices": int(ch.num_vertices),
        "n_faces": int(len(ch.faces)),
        "n_joints": int(ch.num_joints),
        "joint_names": list(ch.joint_names),
        "parents": [int(p) for p in ch.parents],
        "order": order,
        "n_coeffs": c,
        "n_features": bundle.n_features,
        "n_terms": bundle.n_terms,
        "below_horizon": bundle.below_horizon,
        "gaunt": gaunt_table(order),
        "unshadowed": hemisphere_visibility(order, bundle.below_horizon).astype(float).tolist(),
        "model": {"file": MODEL, "input": "pose", "output": "visibility", "bytes": len(model_bytes),
                  "sha256": hashlib.sha256(model_bytes).hexdigest()},
        "data": {"file": DATA, "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest(),
                 "arrays": blob.entries},
        "clips": clips,
        "rpos": rpo_entries,
        "default_brdf": names[0],
        "start": start,
        "lights": [{**_lighting_entry(n, lt), "tonemap": tonemaps[n]["whole"],
                    "peaks": _with_tonemap(peaks_entry(peak_lights[n]), tonemaps[n].get("peaks"))}
                   for n, lt in lights.items()],
        "peaks_model": peaks_model,
        "decode": decode,
        "max_peaks": MAX_PAGE_PEAKS,
        "camera": {"center": center.astype(float).tolist(), "radius": radius, "azimuth": CAMERA_AZIMUTH,
                   "elevation": CAMERA_ELEVATION, "distance": CAMERA_DISTANCE, "view_angle": 30.0,
                   "up": [0.0, 0.0, 1.0], "width": 640, "height": 480, "follow": follow},
        "background": [0.08, 0.08, 0.1],
        "tonemap": {"middle": 0.3, "white_percentile": 99.5, "gamma": GAMMA},
        "material": {**material.summary(), "texture": texture},
        "conventions": bundle.meta.get("conventions", ""),
    }
    atomic_write_json(out / ASSETS / MANIFEST, manifest)
    _copy_page(root, out, vendor)
    return manifest


def start_entry(bundle: Any, clips: list[str], brdfs: list[str]) -> dict[str, str]:
    """What the page opens on: ``{"brdf", "clip", "clip_why"}``. The BRDF is the Python player's default
    (:func:`prt_torch.player.material.default_brdf`: the character's own material when it has one and the site
    carries its RPO, else the catalogue's first). The clip is the run's first held-out clip (what the model never
    saw: the honest first view), else its first training clip, else the site's first clip; ``clip_why`` says which
    and why in a few words (the page shows it)."""
    from prt_torch.errors import MissingArtifact
    from prt_torch.player.material import default_brdf

    brdf = default_brdf(bundle)
    brdf = brdf if brdf in brdfs else brdfs[0]
    sets: dict[str, list[str]] = {}
    try:
        ds = bundle.run.dataset()
    except (MissingArtifact, PrtError):
        ds = None
    cfg = ds.run_config() if ds is not None else None
    if cfg is not None:
        from prt_torch.rig.config import as_clip_range

        for key in ("heldout_clips", "train_clips"):
            names = []
            for e in getattr(cfg.character, key):
                try:  # a split entry names frames of a character clip: the page plays that clip
                    names.append(ds.clip_by_name(as_clip_range(e).dataset_name, bundle.character).source)
                except PrtError:
                    continue
            sets[key] = [n for n in names if n in clips]
    if sets.get("heldout_clips"):
        return {"brdf": brdf, "clip": sets["heldout_clips"][0],
                "clip_why": "held out of training (the model never saw it)"}
    if sets.get("train_clips"):
        return {"brdf": brdf, "clip": sets["train_clips"][0],
                "clip_why": "a training clip (the run holds no clip out)"}
    return {"brdf": brdf, "clip": clips[0], "clip_why": "the first clip (the run records no training split)"}


def _texels(n_coeffs: int) -> int:
    """RGBA texels holding ``n_coeffs`` floats (4 per texel, zero padded)."""
    return -(-n_coeffs // 4)


def decode_texture(bundle: Any) -> tuple[np.ndarray, np.ndarray, list[dict[str, int]]]:
    """The page's GPU decode data from the run's ``decode.npz`` (:mod:`prt_torch.export.compiled`), per vertex in
    the ORIGINAL vertex order:

    * ``basis (V, 4 T (K + 1))`` float16, ``T = ceil(C / 4)`` texels per C-vector, ``K`` the largest ``k_used``:
      texels ``0 .. T-1`` the mean ``(C,)``, texels ``(k + 1) T .. (k + 2) T - 1`` basis row ``k`` of the vertex's
      cluster (its ``C`` coefficients, zero padded to ``4 T``; rows ``>= k_used`` zero). int8 bases dequantized
      (``q * scale`` of the row's block, the products ``MatMulNBits`` forms), float ones as stored. Row-major, the
      vertices' texels back to back: the page's texel layout (``shading.js`` ``texelLayout``) puts texel ``p`` of
      vertex ``v`` at flat texel ``v P + p`` of its texture, so this array is the texture's data as it is.
    * ``rows (V, 2)`` float32: the vertex's cluster (its index in ``groups``) and the cluster's ``k_used``.
    * ``groups``: ``[{"row", "k_used", "block"}]`` per cluster with vertices: ``row`` its row of ``z`` (``z[:, row,
      :]``, ``decode.npz``'s ``clusters``); the page rounds ``z`` per block of ``block`` entries as
      the CPU path does (:func:`prt_torch.player.frame_kernels.quantize_latent`; ``block`` 0: float bases, ``z`` as
      is), so that its products equal the CPU's within float rounding.

    Float16 (10-bit mantissa, relative rounding <= 2^-11) halves the bytes a vertex fetches and the site's size; an
    int8 basis entry ``q s`` is already rounded to ``s / 2 <= |block max| / 254``, 8x coarser than float16's rounding
    of the largest entry, and the int8 export's mean is float16 already. A float entry beyond float16's range is an
    error (not seen: visibility SH coefficients are O(1))."""
    with np.load(bundle.run.decode_path, allow_pickle=False) as z:
        d = {k: z[k] for k in z.files}
    c = int(d["n_coeffs"])
    v = int(d["n_used"].sum())
    check(d["mean"].shape == (c, v) and v == bundle.n_vertices and bundle.vertex_order is not None,
          f"{bundle.run.decode_path}: does not match the run ({bundle.n_vertices} vertices): run "
          f"`prt export {bundle.run.path} --force`")
    t = _texels(c)
    k_max = int(d["k_used"].max(initial=0))
    out = np.zeros((v, k_max + 1, 4 * t), np.float32)  # cluster-sorted positions first
    out[:, 0, :c] = d["mean"].T
    int8 = "q" in d
    groups = []
    rows = np.zeros((v, 2), np.float32)
    for g in range(len(d["n_used"])):  # clusters (tens), each vectorised over its vertices
        n, kg, blk, s0 = int(d["n_used"][g]), int(d["k_used"][g]), int(d["blocks"][g]), int(d["starts"][g])
        if int8 and blk:
            nb = -(-kg // blk)
            q = d["q"][d["q_offsets"][g]:d["q_offsets"][g] + c * n * nb * blk].reshape(c * n, nb * blk)
            s = d["scales"][d["scale_offsets"][g]:d["scale_offsets"][g] + c * n * nb].reshape(c * n, nb)
            w = (q[:, :kg].astype(np.float32) * np.repeat(s, blk, axis=1)[:, :kg]).reshape(c, n, kg)
        else:
            w = d["weights"][d["q_offsets"][g]:d["q_offsets"][g] + kg * c * n].reshape(kg, c, n).transpose(1, 2, 0)
            blk = 0
        out[s0:s0 + n, 1:kg + 1, :c] = w.transpose(1, 2, 0)
        rows[s0:s0 + n] = (len(groups), kg)
        groups.append({"row": int(d["clusters"][g]), "k_used": kg, "block": blk})
    basis = np.empty_like(out)
    basis[bundle.vertex_order] = out  # position i holds original vertex vertex_order[i]
    by_vertex = np.empty_like(rows)
    by_vertex[bundle.vertex_order] = rows
    half = basis.astype(np.float16)
    check(bool(np.isfinite(half).all()), f"{bundle.run.decode_path}: a basis entry exceeds float16's range")
    return half.reshape(v, -1), by_vertex, groups


def gaunt_table(order: int) -> dict[str, list[Any]]:
    """The non-zero real Gaunt coefficients ``Gamma_ijk = int y_i y_j y_k`` of ``order`` (every index
    permutation listed): ``{"i", "j", "k", "g"}`` lists (:func:`prt_torch.sh.product.gaunt_tensor`)."""
    from prt_torch.sh.product import gaunt_tensor

    d = gaunt_tensor(order).dense()
    i, j, k = np.nonzero(np.abs(d) > 1e-12)
    return {"i": i.tolist(), "j": j.tolist(), "k": k.tolist(), "g": d[i, j, k].astype(float).tolist()}


def site_local(character: Any, clip: str, frames: Any) -> np.ndarray:
    """``(B, J, 4, 4)`` float64 local transforms of ``clip`` at ``frames`` exactly as the site stores them
    (rows 0..2 rounded to float32, row 3 = (0, 0, 0, 1)): the Python side of every page comparison uses these."""
    local = np.asarray(character.clip(clip).local, dtype=np.float64)[np.atleast_1d(frames)]
    out = np.zeros_like(local)
    out[:, :, :3, :] = local[:, :, :3, :].astype(np.float32)
    out[:, :, 3, 3] = 1.0
    return out


def write_peak_graph(run: Any, character: Any, path: Path) -> str | None:
    """Write the page's peak-visibility graph to ``path`` and say which it is, by the Python player's rule (its
    default :class:`~prt_torch.player.peaks.PeakVisibility`): ``"learned"`` - the run's ``peaks.onnx``, byte for
    byte; else ``"spheres"`` - the run's blocker spheres (``blockers.npz``) through the same cone kernel
    (:func:`prt_torch.export.peaks_graph.export_peak_graph`; needs torch, the ``export`` extra); else ``None`` (no
    graph: the page's peaks cast no shadow) and a stale graph at ``path`` is removed."""
    if run.peak_graph_path.is_file():
        atomic_write_bytes(path, run.peak_graph_path.read_bytes())
        return "learned"
    path.unlink(missing_ok=True)
    if not run.blockers_path.is_file():
        return None
    try:
        import torch  # noqa: F401
    except ImportError:
        return None
    from prt_torch.blockers.spheres import SphereSet
    from prt_torch.export.peaks_graph import example_peaks, export_peak_graph

    dirs, radii = example_peaks()
    v = character.rest_vertices
    ex = {"positions": np.asarray(v, np.float32)[None], "normals": np.asarray(character.rest_normals, np.float32)[None],
          "skin": np.broadcast_to(np.eye(4, dtype=np.float32), (1, character.num_joints, 4, 4)),
          "directions": dirs, "angular_radii": radii}
    export_peak_graph(SphereSet.load(run.blockers_path), path, ex, {"prt.source": run.blockers_path.name})
    return "spheres"


def player_tonemaps(run: Path, lights: dict[str, Any], brdf: str, character: Any, clip: str,
                    peak_lights: dict[str, Any] | None = None, peak_graph: Path | None = None,
                    material: Any = None) -> dict[str, Any]:
    """``{light: {"whole": {exposure, white}, "peaks": {exposure, white}}}``: the tone map the Python player fixes
    from the first frame of ``clip`` (:func:`prt_torch.player.tonemap.auto_tonemap` of its radiance times the base
    colour) under each lighting, whole on the SH path, and (``"peaks"``, for a lighting of ``peak_lights`` with
    peaks) the page's peaks-on radiance (:func:`prt_torch.web.peaks.page_radiance`, ``peak_graph`` its visibility)."""
    from prt_torch.player.player import Player
    from prt_torch.web.peaks import PeakGraph, page_radiance

    p = Player(run, brdf=brdf, threads=1, graph="split")
    graph = PeakGraph(peak_graph) if peak_graph is not None else None
    analytic = analytic_brdf(brdf, material)
    try:
        local = site_local(character, clip, 0)
        out: dict[str, Any] = {}
        for name, lt in lights.items():
            out[name] = {}
            split = (peak_lights or {}).get(name)
            for key, pl in (("whole", None), ("peaks", split)):
                if key == "peaks" and (pl is None or not pl.peaks):
                    continue
                p.exposure = None
                _, rad, _ = page_radiance(p, local, lt, pl, 0.0, graph, analytic)
                p.colors(rad[0])
                out[name][key] = {"exposure": float(p.exposure.exposure), "white": float(p.exposure.white)}
        return out
    finally:
        p.close()


def _with_tonemap(entry: dict[str, Any] | None, tonemap: dict[str, float] | None) -> dict[str, Any] | None:
    return None if entry is None else {**entry, "tonemap": tonemap}


def _material_rpo(material: Any, order: int, n_terms: int, run: Any = None) -> Path | None:
    """The material's Cook-Torrance RPO file, cached in the run (the Python player's: the one rule,
    :func:`prt_torch.rig.material.material_rpo_file`), or ``None`` when it is not cached and cannot be built
    (no scikit-learn: a player-only install)."""
    from prt_torch.rig.material import material_rpo_file

    try:
        return material_rpo_file(material, order, n_terms, run=run)
    except PrtError:
        return None


def _copy_page(root: Path, out: Path, vendor: list[tuple[Path, str]]) -> None:
    for p in sorted((root / "src").iterdir()):
        if p.is_file() and p.suffix in PAGE_SUFFIXES:
            atomic_write_bytes(out / p.name, p.read_bytes())
    for src, dst in vendor:
        target = out / dst
        target.parent.mkdir(parents=True, exist_ok=True)
        if target.is_file() and target.stat().st_size == src.stat().st_size and \
                target.stat().st_mtime >= src.stat().st_mtime:
            continue  # unchanged npm file (the wasm binary is 14 MB)
        with atomic_path(target) as tmp:
            shutil.copyfile(src, tmp)


def read_manifest(site: str | os.PathLike[str]) -> dict[str, Any]:
    """The manifest of a written site (one-line error when missing or not a site)."""
    p = Path(site) / ASSETS / MANIFEST
    check(p.is_file(), f"not a prt web site (no {ASSETS}/{MANIFEST}): {site}")
    try:
        m = json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise PrtError(f"{p}: unreadable manifest ({exc})") from None
    check(isinstance(m, dict) and m.get("format") == SITE_FORMAT, f"{p}: not a {SITE_FORMAT} manifest")
    return m
