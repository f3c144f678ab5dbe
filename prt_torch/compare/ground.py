"""``prt compare``'s cast-shadow section: the run's scene (a floor, several characters) against whole-scene truth.

Whenever the run records a scene with a floor or more than one character (``RunDir.scene_json``, written by
``prt demo`` from the config's ``scene:`` section; or a :class:`~prt_torch.scene.config.SceneConfig` passed in),
the compared frames are replayed as that scene: the run's character shows each compared frame (its clip and
frame index), other characters their own clips at the same scene time, all placed by the scene
(:mod:`prt_torch.scene.scene`). Per frame:

* **truth**: Embree over ground + every posed character (:class:`prt_torch.scene.truth.SceneTracer`, the
  bake's ``trace_frame``, ray count, offset and seed), for the ground vertices and each character's vertices;
* **ground**: SHEXP of all characters' posed blocker spheres at the ground vertices (the scene player's compiled,
  culled pass, :class:`prt_torch.scene.shexp_kernel.CompiledShexp`, with the tables of the run's ``shexp.onnx``);
* **each character**: ``self_only`` = its learned self-visibility (its run's ``visibility.onnx``), and
  ``in_scene`` = that composed with the ground half-space and the other characters' SHEXP
  (:class:`prt_torch.scene.compose.Composer`, the player's rule).

Scores (``compare.json``): ``ground.{vis_rel_err, radiance_rel_rmse, psnr_image}`` (ground vertices; radiance
= the shipping path's diffuse RPO times the ground albedo; image PSNR over the ground's pixels rendered alone
from the scene camera, one tone map from the truth) and ``scene.characters[k].{self_only, in_scene}.
{vis_rel_err, radiance_rel_rmse}`` (both shipped BRDFs pooled), plus ``scene.ms_per_frame`` / ``fps``: the
median run-time visibility path of a whole scene frame (every character's learned model, SHEXP ground and
others, composition; onnxruntime + numpy, no shading). ``compare/ground.png``: the ground at the strip frame,
truth | SHEXP | 4x difference (with peaks: | the ceiling | the last ``+peaks`` row | 4x difference; with a
reference: | the Monte-Carlo floor).

**Peak lights** (issue 27; ``lights`` a :class:`~prt_torch.compare.reference.CompareLights` with peaks):
``ground.with_peaks`` holds the floor's ``+peaks`` rows, each with the ground figures' keys: the residual lighting on
the same SH path (Embree SH truth or SHEXP) plus the floor's peak term ``albedo / pi x E_p x max(l_p . z, 0) x V_p``
(:mod:`prt_torch.scene.peaks`, the scene player's rule), ``V_p`` by ``exact`` (Embree to disc samples against the
posed characters), ``spheres`` (every character's blocker spheres) or ``learned`` (their learned peak blockers);
``truth+peaks_exact`` is the ceiling the others are scored against, ``peak_vis_rel_err`` their peak visibility vs
the exact one, ``ms_per_frame`` the floor's peak visibility alone.

**Reference** (``reference_frames > 0`` and ``lights``): the floor's outgoing radiance by Monte-Carlo
(:func:`~prt_torch.compare.reference.reference_radiance` on the floor vertices, traced against the floor and every
posed character, Lambert x albedo, ``lights.reference``: the residual at full resolution + every peak as a disk of
its angular radius), two estimates; the SHEXP floor gains ``vs_reference`` and so does every ``with_peaks`` row;
``ground.reference`` has the Embree SH truth's figures (``truth``) and the estimates' ``noise``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch import metrics as M
from prt_torch.bake.store import recorded_fps
from prt_torch.errors import PrtError, check
from prt_torch.rundir import RunDir
from prt_torch.scene.compose import Composer
from prt_torch.scene.config import SceneConfig, run_scene
from prt_torch.scene.scene import (
    Actor,
    check_separated,
    placement_matrix,
    pose_actor,
    scene_ground,
    spheres_above,
)
from prt_torch.scene.shexp_kernel import CompiledShexp, ShexpTables
from prt_torch.scene.truth import GROUND_BELOW_HORIZON, GROUND_TRUTH_RAYS, SceneTracer
from prt_torch.scoring.images import Camera, ImageRenderer
from prt_torch.scoring.rpos import DIFFUSE
from prt_torch.scoring.sampling import evenly_spaced
from prt_torch.scoring.shading import ShippingShader
from prt_torch.scoring.statistics import ImageStats, RadianceStats
from prt_torch.scoring.strips import abs_diff_image, image_strip, write_png

#: the floor's ceiling with peaks (Embree SH visibility for the residual, Embree disc visibility for the peaks)
PEAK_TRUTH = "truth+peaks_exact"
#: the Monte-Carlo reference's name in the floor's images
REFERENCE = "reference"


def wants_scene(scene: SceneConfig | None) -> bool:
    """Whether a scene adds anything to the compare (a floor or a second character)."""
    return scene is not None and (scene.ground is not None or len(scene.characters) > 1)


def _actors(ctx: Any, scene: SceneConfig, first_clip: str, fps: float, threads: int) -> tuple[list[Actor], list[Any]]:
    """Actors of the scene and, per actor, its run's :class:`prt_torch.player.bundle.RunBundle` (visibility graph,
    frame data, ``below_horizon``)."""
    from prt_torch.player.bundle import RunBundle
    from prt_torch.player.scene import load_spheres
    from prt_torch.rig.clip import Clip

    actors, bundles = [], []
    cache: dict[Path, Any] = {}
    for k, e in enumerate(scene.entries()):
        path = (ctx.run.path if e.run is None else Path(e.run)).resolve()
        if path not in cache:
            cache[path] = RunBundle(path, threads=threads, graphs=("visibility",))
        b = cache[path]
        ch = ctx.character if path == ctx.run.path.resolve() else b.character
        name = first_clip if k == 0 else (e.clip or first_clip)
        c = ch.clip(name)
        c = c.resample(fps) if c.fps != fps else c
        actors.append(Actor(ch, Clip(c.name, fps, np.asarray(c.local)), placement_matrix(e.offset, e.yaw_deg),
                            e.time_offset, b.cluster, b.cluster_axis, b.cluster_bone, load_spheres(b.run),
                            name=f"character {k} ({path.name}, {c.name})"))
        bundles.append(b)
    return actors, bundles


def compare_scene(ctx: Any, fs: Any, lighting: Any, rpos: dict[str, Any], scene: SceneConfig | None = None,
                  image_frames: int = 8, threads: int = 2, window_hw: tuple[int, int] = (480, 640),
                  log: Callable[[str], None] | None = None, lights: Any = None, reference_frames: int = 0,
                  reference_rays: int = 512) -> dict[str, Any]:
    """The cast-shadow section of ``compare.json`` (module docstring): ``{"ground": ..., "scene": ...}``, or
    ``{}`` when the run has no scene with a floor or a second character.

    Args:
        ctx: the :class:`~prt_torch.compare.methods.CompareRun`; fs: its :class:`~prt_torch.compare.methods.FrameSet`.
        lighting: the player's :class:`~prt_torch.player.lighting.Lighting`; rpos: the shipped RPOs.
        scene: the scene (default: the run's recorded one).
        image_frames: frames rendered for the ground image PSNR (evenly spaced).
        lights: the run's :class:`~prt_torch.compare.reference.CompareLights` (``None``: no peak rows and no
            reference): its peaks give the floor's ``+peaks`` rows (``ground.with_peaks``), its ``reference`` light
            the floor's Monte-Carlo reference.
        reference_frames: floor frames of the Monte-Carlo reference (``vs_reference`` figures; 0: none);
            reference_rays: hemisphere rays per floor vertex of each of its two estimates (at least
            :data:`~prt_torch.scene.truth.GROUND_TRUTH_RAYS`).
    """
    from prt_torch.player.player import camera_eye, camera_target
    from prt_torch.player.scene import shexp_graph_path
    from prt_torch.rig.features import pose_features

    note = log or (lambda s: None)
    scene = scene if scene is not None else run_scene(ctx.run)
    if not wants_scene(scene):
        return {}
    run: RunDir = ctx.run
    gp = shexp_graph_path(run)
    if gp is None:
        raise PrtError(f"{run.path}: its scene needs the shexp graph and blocker spheres: run `prt export {run.path}`")
    check(fs.local is not None and fs.sources is not None,
          f"{run.path}: a scene's compare needs the posed frames of a skinned character")
    fps = float(recorded_fps(ctx.dataset.attrs) or ctx.character.clip(fs.sources[0]).fps)
    actors, bundles = _actors(ctx, scene, fs.sources[0], fps, threads)  # the character clip the frames are cut from
    n_f = fs.n_frames
    ground = scene_ground(scene.ground, actors, fps, int(max(fs.frame_index) + 1)) if scene.ground else None
    tables = ShexpTables.from_graph(gp)  # the scene player's pass: what ships is what is scored
    check(tables.order == ctx.order, f"{gp}: SHEXP order {tables.order}, the run's is {ctx.order}")
    shexp = [CompiledShexp(tables, a.rest_vertices()) for a in actors]
    composers = [Composer(ctx.order, b.below_horizon) for b in bundles]
    bake = ctx.bake
    tracer = SceneTracer(ctx.order, int(bake["n_rays"]), float(bake["ray_offset_world"]), int(bake.get("seed", 0)))
    rest = np.concatenate([a.rest_vertices() for a in actors]).astype(np.float32)
    center, radius = camera_target(rest)
    camera = Camera(np.asarray(camera_eye(center, radius), np.float64), np.asarray(center, np.float64),
                    tuple(window_hw))
    names = [a.name for a in actors]
    k_n = len(actors)
    truth_c: list[list[np.ndarray]] = [[] for _ in actors]
    insc: list[list[np.ndarray]] = [[] for _ in actors]
    selfv: list[list[np.ndarray]] = [[] for _ in actors]
    posed_c: list[list[Any]] = [[] for _ in actors]
    g_truth, g_shexp = [], []
    g_shexp_pass = CompiledShexp(tables, ground.vertices) if ground is not None else None
    secs = []
    fp = FloorPeaks.of(lights, bundles, ctx.bake) if ground is not None else None
    g_meshes: list[list[tuple[np.ndarray, np.ndarray]]] = []
    note(f"scene: {k_n} character(s){', ground ' + str(ground.n_vertices) + ' vertices' if ground else ''}; "
         f"whole-scene Embree truth on {n_f} frames")
    for f in range(n_f):
        t_scene = np.array([int(fs.frame_index[f])])
        locs = []
        for k, a in enumerate(actors):
            if k == 0:  # the compared frame's own pose (compare's one clip-name rule)
                locs.append(a.place(np.asarray(fs.local[f:f + 1])))
            else:
                locs.append(a.locals(t_scene, fps))
        posed = [pose_actor(a, loc) for a, loc in zip(actors, locs, strict=True)]
        spheres = [a.spheres for a in actors]
        from prt_torch.blockers import pose_spheres

        centers = [pose_spheres(s, p.skin) for s, p in zip(spheres, posed, strict=True)]  # (1, S_k, 3)
        radii = [np.asarray(s.radius, np.float32) for s in spheres]
        if k_n > 1:
            check_separated([c[0] for c in centers], radii, names, f)
        # -- the run-time path (timed): learned self-visibility, SHEXP, composition
        t0 = time.perf_counter()
        feats = [np.ascontiguousarray(pose_features(loc, a.character.bind_local, a.character.parents), np.float32)
                 for a, loc in zip(actors, locs, strict=True)]
        sv = [b.graphs["visibility"].run_unchecked({"pose": x})[0] for b, x in zip(bundles, feats, strict=True)]
        out = []
        for k in range(k_n):
            others = None
            if k_n > 1:
                oc = np.concatenate([c for j, c in enumerate(centers) if j != k], axis=1)
                orad = np.concatenate([r for j, r in enumerate(radii) if j != k])[None]
                others = shexp[k](posed[k].positions[0], posed[k].frames[0], oc[0], orad[0])[None]
            out.append(composers[k].in_scene(sv[k], posed[k].frames, ground=ground is not None, others=others))
        if ground is not None:
            gc, gr = spheres_above(np.concatenate(centers, axis=1), np.concatenate(radii)[None], ground.height)
            gv = g_shexp_pass(ground.vertices, None, gc[0], gr[0])  # the ground frame is the world's
        secs.append(time.perf_counter() - t0)
        # -- the truth
        meshes = ([(ground.vertices, ground.faces)] if ground is not None else []) + \
            [(p.positions[0], a.character.faces) for a, p in zip(actors, posed, strict=True)]
        receivers = [(p.positions[0], p.frames[0], b.below_horizon) for p, b in zip(posed, bundles, strict=True)]
        if ground is not None:
            receivers.append((ground.vertices, ground.frames(), GROUND_BELOW_HORIZON,
                          max(GROUND_TRUTH_RAYS, tracer.n_rays)))
        tv = tracer.frame(meshes, receivers)
        if ground is not None:
            g_meshes.append(meshes)
            if fp is not None:
                fp.add_frame(ground, meshes[1:], posed)
        for k in range(k_n):
            truth_c[k].append(tv[k])
            insc[k].append(out[k][0])
            selfv[k].append(sv[k][0])
            posed_c[k].append(posed[k])
        if ground is not None:
            g_truth.append(tv[-1])
            g_shexp.append(gv)
    result: dict[str, Any] = {}
    ms = float(np.median(secs) * 1e3)
    chars = []
    for k, a in enumerate(actors):
        t = np.stack(truth_c[k])
        pos = np.concatenate([p.positions for p in posed_c[k]])
        frm = np.concatenate([p.frames for p in posed_c[k]])
        vis = {"truth": t, "self_only": np.stack(selfv[k]), "in_scene": np.stack(insc[k])}
        shader = ShippingShader({"light": lighting}, rpos, camera.eye, paths=("lobes",))
        stats = {n: RadianceStats() for n in ("self_only", "in_scene")}
        for _, res in shader.shade(vis, frm, pos):
            for b in rpos:
                d = res[("light", b, "lobes")]
                for n in stats:
                    stats[n].add(d[n], d["truth"])
        chars.append({"name": a.name, "clip": a.clip.name if k else "the compared frames",
                      **{n: {"vis_rel_err": M.vis_rel_err(vis[n], t), "radiance_rel_rmse": stats[n].rel_rmse}
                         for n in stats}})
    result["scene"] = {
        "characters": chars, "frames": n_f, "ground": ground is not None,
        "ms_per_frame": ms, "fps": 1e3 / ms if ms > 0 else float("inf"),
        "timing": "median ms of a whole scene frame's run-time visibility path (every character's visibility "
                  "graph, the SHEXP graph for the ground and for the other characters, the composition; no shading)",
        "truth": "Embree over ground + every posed character (the bake's trace_frame, rays, offset, seed)",
        "self_only": "the learned self-visibility alone vs the whole-scene truth",
        "in_scene": "learned self-visibility x ground half-space x SHEXP of the other characters (SH products)",
    }
    if ground is not None:
        ref = GroundReference(lights.reference, int(reference_frames), max(int(reference_rays), GROUND_TRUTH_RAYS),
                              float(bake["ray_offset_world"]), g_meshes) if lights is not None else None
        result["ground"] = _ground_scores(ground, np.stack(g_shexp), np.stack(g_truth), lighting, rpos, camera,
                                          image_frames, run, fp, ref)
    return result


@dataclass
class FloorPeaks:
    """The floor's peak visibility ``(G, P)`` per compared frame for every kind the scene's runs have (``exact``:
    Embree against the posed characters, :func:`prt_torch.scene.peaks.floor_exact_peak_visibility`; ``spheres``:
    every character's blocker spheres, ``learned``: every character's learned peak blockers (capsules or spheres),
    through :func:`prt_torch.scene.peaks.floor_peak_visibility`), the medians of their run times, and the peaks and
    residual lighting they are shaded with (:class:`~prt_torch.compare.reference.CompareLights`)."""

    directions: np.ndarray
    radii: np.ndarray
    powers: np.ndarray
    residual: Any
    #: per kind, every character's blocker set (``None``: exact)
    blockers: dict[str, list[Any] | None]
    offset: float
    side: int
    vis: dict[str, list[np.ndarray]] = field(default_factory=dict)
    secs: dict[str, list[float]] = field(default_factory=dict)

    @classmethod
    def of(cls, lights: Any, bundles: list[Any], bake: Any) -> FloorPeaks | None:
        """From the compare's lights and the scene's run bundles; ``None`` without peaks."""
        from prt_torch.bake.peaks import DEFAULT_DISC_SIDE
        from prt_torch.blockers.capsules import load_blocker_set
        from prt_torch.player.peaks import learned_blockers_path
        from prt_torch.player.scene import load_spheres

        if lights is None or not lights.peaks:
            return None
        blockers: dict[str, list[Any] | None] = {"exact": None, "spheres": [load_spheres(b.run) for b in bundles]}
        learned = [learned_blockers_path(b.run) for b in bundles]
        if all(p is not None for p in learned):
            blockers["learned"] = [load_blocker_set(p) for p in learned]  # capsules or spheres, as the scene casts
        pk = lights.peaks
        return cls(np.array([p.direction for p in pk], np.float64).reshape(-1, 3),
                   np.array([p.angular_radius for p in pk], np.float64), np.array([p.power for p in pk], np.float64),
                   lights.residual, blockers, float(bake["ray_offset_world"]), DEFAULT_DISC_SIDE)

    def add_frame(self, ground: Any, meshes: list[tuple[np.ndarray, np.ndarray]], posed: list[Any]) -> None:
        """Every kind's floor peak visibility of one frame (``meshes``: the posed characters; ``posed``: their
        :class:`~prt_torch.scene.scene.PosedMesh`)."""
        from prt_torch.blockers.capsules import posed_blockers
        from prt_torch.scene.peaks import floor_exact_peak_visibility, floor_peak_visibility

        for kind, sph in self.blockers.items():
            t0 = time.perf_counter()
            if sph is None:
                v = floor_exact_peak_visibility(ground.vertices, meshes, self.directions, self.radii, self.offset,
                                                side=self.side)
            else:
                ends = [posed_blockers(x, p.skin) for x, p in zip(sph, posed, strict=True)]
                r = np.concatenate([np.asarray(x.radius, np.float32) for x in sph])
                v = floor_peak_visibility(ground.vertices, np.concatenate([a[0] for a, _ in ends]),
                                          np.concatenate([b[0] for _, b in ends]), r, self.directions, self.radii)
            self.secs.setdefault(kind, []).append(time.perf_counter() - t0)
            self.vis.setdefault(kind, []).append(v)


@dataclass
class GroundReference:
    """The floor's Monte-Carlo reference: the compare's :class:`~prt_torch.compare.reference.ReferenceLight`, how
    many frames, rays per vertex of each of the two estimates, the ray offset and, per compared frame, the scene's
    meshes (floor first, then the posed characters)."""

    light: Any
    frames: int
    rays: int
    offset: float
    meshes: list[list[tuple[np.ndarray, np.ndarray]]]

    def estimates(self, ground: Any, f: int, eye: np.ndarray, albedo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Two independent estimates (seeds 101, 202) of the floor's ``(G, 3)`` outgoing radiance at frame ``f``:
        :func:`prt_torch.compare.reference.reference_radiance` on the floor vertices traced against the floor and
        every posed character, the Lambert BRDF times the floor albedo."""
        from prt_torch.bake.embree import RayScene
        from prt_torch.brdf.rpo import builtin_brdf
        from prt_torch.compare.reference import reference_radiance
        from prt_torch.scene.truth import merged_mesh

        scene = RayScene(*merged_mesh(self.meshes[f]))
        brdf = {"lambert": builtin_brdf("lambert")}
        out = [reference_radiance(ground.vertices, ground.frames(), ground.faces, eye, self.light, brdf, self.rays,
                                  seed, self.offset, scene=scene)["lambert"] * albedo for seed in (101, 202)]
        return out[0], out[1]


def _figures(stats: RadianceStats, img: ImageStats) -> dict[str, Any]:
    return {"psnr_image": img.psnr, "radiance_rel_rmse": stats.rel_rmse, "psnr_vertex": stats.psnr}


def _ground_scores(ground: Any, shexp_v: np.ndarray, truth: np.ndarray, lighting: Any, rpos: dict[str, Any],
                   camera: Camera, image_frames: int, run: RunDir, fp: FloorPeaks | None = None,
                   ref: GroundReference | None = None) -> dict[str, Any]:
    """Ground figures (diffuse RPO x albedo; with peaks, the residual's + the floor's peak term per kind, vs the
    ceiling ``truth+peaks_exact``; with a reference, every row vs the Monte-Carlo floor) and ``compare/ground.png``."""
    from prt_torch.scene.peaks import floor_peak_radiance
    from prt_torch.scoring.statistics import image_sse

    check(DIFFUSE in rpos, f"the ground is shaded with the diffuse RPO {DIFFUSE!r}, not among {list(rpos)}")
    n_f = truth.shape[0]
    frames = ground.frames((n_f,))
    pos = np.broadcast_to(ground.vertices, (n_f, ground.n_vertices, 3))
    shader = ShippingShader({"light": lighting}, {DIFFUSE: rpos[DIFFUSE]}, camera.eye, paths=("lobes",))
    rad = shader.shade_all({"truth": truth, "shexp": shexp_v}, frames, pos)[("light", DIFFUSE, "lobes")]
    rad = {n: r * ground.albedo for n, r in rad.items()}
    stats = RadianceStats()
    stats.add(rad["shexp"], rad["truth"])
    prow: dict[str, np.ndarray] = {}  # the +peaks rows, PEAK_TRUTH first
    if fp is not None:
        res = ShippingShader({"light": fp.residual}, {DIFFUSE: rpos[DIFFUSE]}, camera.eye, paths=("lobes",))
        res_rad = {n: r * ground.albedo for n, r in res.shade_all({"truth": truth, "shexp": shexp_v}, frames, pos)[
            ("light", DIFFUSE, "lobes")].items()}
        exact = np.stack(fp.vis["exact"])
        prow[PEAK_TRUTH] = res_rad["truth"] + floor_peak_radiance(ground.albedo, fp.directions, fp.powers, exact)
        for kind, v in fp.vis.items():
            prow[f"shexp+peaks_{kind}"] = res_rad["shexp"] + floor_peak_radiance(ground.albedo, fp.directions,
                                                                                 fp.powers, np.stack(v))
    pstats = {n: RadianceStats() for n in prow}
    for n in prow:
        pstats[n].add(prow[n], prow[PEAK_TRUTH])
    # the image strip frame: the largest shadow (truth darkest relative to its mean; with peaks: the peaks' truth)
    strip_f = int(np.argmax(np.ptp((prow[PEAK_TRUTH] if prow else rad["truth"]).sum(-1), axis=1)))
    img_idx = evenly_spaced(n_f, max(image_frames, 1), must=[strip_f])
    ref_idx = evenly_spaced(n_f, ref.frames, must=[strip_f]) if ref is not None and ref.frames > 0 else \
        np.zeros(0, np.int64)
    img = ImageStats()
    pimg = {n: ImageStats() for n in prow}
    rows = {"truth": rad["truth"], "shexp": rad["shexp"], **prow}
    ref_img = {n: ImageStats() for n in [*rows, "estimate_b"]}
    ref_rad = {n: RadianceStats() for n in [*rows, "estimate_b"]}
    strip_ref = None
    with ImageRenderer(ground.vertices, ground.faces, camera) as r:
        mask = r.mask(ground.vertices)
        for f in np.union1d(img_idx, ref_idx):
            if f in img_idx:
                fi = r.frame_images(ground.vertices, {"truth": rad["truth"][f], "shexp": rad["shexp"][f]}, "truth",
                                    mask=mask)
                img.add(*fi.sse["shexp"])
                if prow:
                    pi = r.frame_images(ground.vertices, {n: x[f] for n, x in prow.items()}, PEAK_TRUTH, mask=mask)
                    for n in prow:
                        pimg[n].add(*pi.sse[n])
                if f == strip_f:
                    strip_imgs = [fi.images["truth"], fi.images["shexp"]]
                    strip_names = ["ground: Embree truth", "ground: SHEXP"]
                    strip_diff = [None, abs_diff_image(fi.images["shexp"], fi.images["truth"])]
                    strip_lab = ["", "4x |SHEXP - truth|"]
                    if prow:
                        last = list(prow)[-1]
                        strip_imgs += [pi.images[PEAK_TRUTH], pi.images[last]]
                        strip_names += [f"ground: {PEAK_TRUTH}", f"ground: {last}"]
                        strip_diff += [None, abs_diff_image(pi.images[last], pi.images[PEAK_TRUTH])]
                        strip_lab += ["", f"4x |{last} - {PEAK_TRUTH}|"]
            if f in ref_idx:
                assert ref is not None
                ea, eb = ref.estimates(ground, int(f), camera.eye, ground.albedo)
                mean = 0.5 * (ea + eb)
                cand = {REFERENCE: mean, "estimate_a": ea, "estimate_b": eb, **{n: x[f] for n, x in rows.items()}}
                fr = r.frame_images(ground.vertices, cand, REFERENCE, mask=mask)
                for n in rows:
                    ref_img[n].add(*fr.sse[n])
                    ref_rad[n].add(rows[n][f], mean)
                ref_img["estimate_b"].add(*image_sse(fr.images["estimate_b"], fr.images["estimate_a"], fr.mask))
                ref_rad["estimate_b"].add(eb, ea)
                if f == strip_f:
                    strip_ref = fr.images[REFERENCE]
    if strip_ref is not None:
        strip_imgs.append(strip_ref)
        strip_names.append("ground: Monte-Carlo reference")
        strip_diff.append(None)
        strip_lab.append("")
    strip = image_strip(strip_imgs, strip_names, strip_diff, strip_lab)
    run.compare_dir.mkdir(parents=True, exist_ok=True)
    write_png(run.compare_ground, strip)
    has_ref = len(ref_idx) > 0
    out: dict[str, Any] = {
        "psnr_image": img.psnr, "radiance_rel_rmse": stats.rel_rmse, "vis_rel_err": M.vis_rel_err(shexp_v, truth),
        "psnr_vertex": stats.psnr, "vertices": ground.n_vertices, "frames": n_f, "image_frames": int(len(img_idx)),
        "strip_frame": strip_f, "albedo": [float(x) for x in ground.albedo],
        "method": "SHEXP (the scene player's compiled, culled pass; the run's SHEXP graph's tables) of every "
                  "character's posed blocker spheres, diffuse RPO x albedo",
        "image": "the ground's pixels rendered alone from the scene camera, one tone map from the truth"}
    if has_ref:
        out["vs_reference"] = _figures(ref_rad["shexp"], ref_img["shexp"])
    if prow:
        exact = np.stack(fp.vis["exact"])  # type: ignore[union-attr]
        wp: dict[str, Any] = {}
        for n in prow:
            kind = n.split("+peaks_")[-1]
            ms = float(np.median(fp.secs[kind]) * 1e3)  # type: ignore[union-attr]
            wp[n] = {**_figures(pstats[n], pimg[n]),
                     "vis_rel_err": 0.0 if n == PEAK_TRUTH else M.vis_rel_err(shexp_v, truth),
                     "peak_vis_rel_err": M.vis_rel_err(np.stack(fp.vis[kind]), exact),  # type: ignore[union-attr]
                     "ms_per_frame": ms, "fps": 1e3 / ms if ms > 0 else float("inf")}
            if has_ref:
                wp[n]["vs_reference"] = _figures(ref_rad[n], ref_img[n])
        out["with_peaks"] = wp
        out["peaks_method"] = ("the residual lighting on the same SH path (truth: Embree SH visibility; shexp: SHEXP) "
                               "+ albedo / pi x E_p x max(l_p . z, 0) x V_p, V_p the floor's visible fraction of each "
                               "peak's disc under every character (exact: Embree to disc samples; spheres: the blocker "
                               "spheres; learned: the learned peak blockers; cone-sphere kernel); ms_per_frame: the "
                               "floor's peak visibility (median)")
    if has_ref:
        assert ref is not None
        out["reference"] = {
            "frames": int(len(ref_idx)), "frame_indices": [int(i) for i in ref_idx], "rays_per_estimate": ref.rays,
            "estimates": 2, "lighting": ref.light.source, "truth": _figures(ref_rad["truth"], ref_img["truth"]),
            "noise": _figures(ref_rad["estimate_b"], ref_img["estimate_b"]),
            "sampling": "reference_radiance on the floor vertices, traced against the floor and every posed "
                        "character, Lambert x albedo; mean of two independent estimates (noise: b vs a)"}
    return out


def scene_markdown(result: dict[str, Any]) -> list[str]:
    """Markdown lines for the cast-shadow section of ``table.md`` (empty without one)."""
    sc = result.get("scene")
    if not sc:
        return []
    lines = ["", f"Cast shadows ({sc['frames']} frames, whole-scene Embree truth; scene visibility path "
             f"{sc['ms_per_frame']:.3g} ms per frame, {sc['fps']:.3g} frames/s):", "",
             "| receiver | vis_rel_err | radiance_rel_rmse | psnr_image |", "| --- | ---: | ---: | ---: |"]
    g = result.get("ground")
    if g:
        p = g.get("psnr_image")
        lines.append(f"| ground (SHEXP) | {g['vis_rel_err']:.4f} | {g['radiance_rel_rmse']:.4f} | "
                     f"{'-' if p is None else f'{p:.2f}'} |")
        for n, w in g.get("with_peaks", {}).items():
            p = w.get("psnr_image")
            lines.append(f"| ground ({n}) | {w['peak_vis_rel_err']:.4f} (peaks) | {w['radiance_rel_rmse']:.4f} | "
                         f"{'-' if p is None else f'{p:.2f}'} |")
    for c in sc["characters"]:
        for n in ("self_only", "in_scene"):
            lines.append(f"| {c['name']}: {n} | {c[n]['vis_rel_err']:.4f} | {c[n]['radiance_rel_rmse']:.4f} | - |")
    if g and "reference" in g:
        ref = g["reference"]
        lines += ["", f"The floor vs its Monte-Carlo reference ({ref['frames']} frames, "
                  f"{ref['rays_per_estimate']} rays per vertex and estimate; {ref['lighting']}):", "",
                  "| floor | radiance_rel_rmse | psnr_vertex | psnr_image |", "| --- | ---: | ---: | ---: |"]
        named = {"truth (Embree SH, whole light)": ref["truth"], "shexp": g["vs_reference"], "noise (estimate b vs a)":
                 ref["noise"], **{n: w["vs_reference"] for n, w in g.get("with_peaks", {}).items()}}
        for n, x in named.items():
            p = x.get("psnr_image")
            lines.append(f"| {n} | {x['radiance_rel_rmse']:.4f} | {x['psnr_vertex']:.2f} | "
                         f"{'-' if p is None else f'{p:.2f}'} |")
    return lines
