"""The scene player: a ground plane and several characters with cast shadows (numpy + onnxruntime, no torch).

Per frame (:meth:`ScenePlayer.compute`), for every character ``k`` (each through its run's
:class:`~prt_torch.player.player.Player` public API only: ``pose``, ``visibility``, ``shade``, ``colors``)::

    placed locals (prt_torch.scene.scene.Actor) --Player.pose--> positions, frames, view dirs, pose features
    Player.visibility(features) = learned self-visibility (B=1, V_k, C)
    FK -> skin -> blocker sphere centres (prt_torch.blockers.pose_spheres)
    SHEXP of the OTHER characters' spheres at its vertices: one compiled pass, culled per block of vertices
        (prt_torch.scene.shexp_kernel.CompiledShexp, the numbers of the run's shexp.onnx, whose tables it reads)
    in-scene visibility = Composer.in_scene(self, frames, ground, others)   (prt_torch.scene.compose)
    radiance = Player.shade(state, visibility=in-scene)

and for the ground: SHEXP of ALL spheres at the ground vertices (ground frame = world; the same compiled pass: a
block of floor vertices far from every character is the constant 1 at the cost of its distance tests), shaded by
the primary player's ``shade`` with the run's diffuse RPO (``lambert``) times the ground albedo: the same shading graph,
lighting and view directions, the ground's vertices packed into batches of the graph's vertex count.

**Peak lights** (issue 27; ``peaks``, ``peak_kind`` as :class:`Player`'s): each Player's ``lighting`` is then the
RESIDUAL of the light split (the SH path above shades it: the sun is not counted twice) and the peaks add their
direct term with soft shadows (:mod:`prt_torch.scene.peaks`):

* character ``k``: its own peak visibility (``Player.peak_source``: learned blockers, blocker spheres) times the
  fraction the OTHER characters' blockers of the same kind (capsules, or spheres as capsules with ``a == b``:
  :func:`prt_torch.blockers.capsules.posed_blockers`) leave of each disc, times the share of the disc above
  the floor (with a floor); ``exact``: Embree against every posed character and the floor at once. Shaded by
  ``Player.shade_peaks`` (the run's analytic BRDF) and added to the residual radiance;
* floor: ``albedo / pi * E_p * max(l_p . z, 0) * V_p`` with ``V_p`` the floor vertices' visibility under EVERY
  character's posed blockers together (``exact``: Embree against the merged posed meshes). One tone
map for everything (``auto_tonemap`` of the first frame's radiance of all meshes; ``Player.colors``), one
:class:`~prt_torch.player.render.MeshRenderer` with one mesh per character plus the ground, the camera of
:func:`~prt_torch.player.player.camera_eye` around the placed characters' rest meshes.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.player.player import Player, camera_eye, camera_target
from prt_torch.player.posing import PoseBatch
from prt_torch.player.timing import FrameTimer
from prt_torch.rig.clip import Clip
from prt_torch.rundir import RunDir
from prt_torch.scene.compose import Composer
from prt_torch.scene.config import GroundConfig, SceneConfig, run_scene
from prt_torch.scene.ground import Ground
from prt_torch.scene.scene import Actor, check_separated, placement_matrix, scene_ground, spheres_above
from prt_torch.scene.shexp_kernel import CompiledShexp, ShexpTables

#: the run's diffuse RPO, used for the ground
GROUND_BRDF = "lambert"
#: the compute steps of a scene frame (FrameTimer names)
SCENE_STEPS = ("pose", "characters", "ground")


def shexp_graph_path(run: RunDir) -> Path | None:
    """The run's SHEXP graph (``RunDir.shexp_path``, written by ``prt export``), or ``None`` when it has none."""
    p = run.shexp_path
    return p if p.is_file() else None


def blockers_path(run: RunDir) -> Path | None:
    """The run's blocker spheres (``RunDir.blockers_path``), or ``None`` when it has none."""
    p = run.blockers_path
    return p if p.is_file() else None


def compiled_kernel(positions: np.ndarray, normals: np.ndarray, ends_a: np.ndarray, ends_b: np.ndarray,
                    radii: np.ndarray, directions: np.ndarray, angular_radii: np.ndarray) -> np.ndarray:
    """The player's compiled cone kernel (:func:`prt_torch.blockers.cones.capsule_visibility_soa`, the same numbers
    as :func:`prt_torch.blockers.capsule_cones.capsule_peak_visibility`) with the latter's signature, ``(V, 3)`` or
    ``(B, V, 3)`` receivers (a :data:`prt_torch.scene.peaks.Kernel`)."""
    from prt_torch.blockers.cones import capsule_visibility_soa

    one = np.ndim(positions) == 2
    pos = np.asarray(positions)[None] if one else np.asarray(positions)
    nrm = np.asarray(normals)[None] if one else np.asarray(normals)
    ea = np.asarray(ends_a)[None] if one else np.asarray(ends_a)
    eb = np.asarray(ends_b)[None] if one else np.asarray(ends_b)
    out = capsule_visibility_soa(pos.transpose(0, 2, 1), nrm.transpose(0, 2, 1), ea, eb, radii, directions,
                                 angular_radii)
    return out[0] if one else out


def load_spheres(run: RunDir) -> Any:
    """The run's :class:`prt_torch.blockers.SphereSet` (one-line error when the export has none)."""
    from prt_torch.blockers import SphereSet

    p = blockers_path(run)
    check(p is not None, f"{run.path}: no blocker spheres: run `prt export {run.path}` (cast shadows need them)")
    return SphereSet.load(p)


@dataclass
class SceneFrame:
    """One computed scene frame: per character ``states`` (placed :class:`PoseBatch`, B = 1) and ``radiance``
    ``(1, V_k, 3)``; ``visibility`` the in-scene ``(1, V_k, C)``; the ground's ``ground_radiance (G, 3)`` and
    ``ground_visibility (G, C)`` (``None`` without a floor); with peak lights, per character ``peak_visibility
    (1, V_k, P)`` (in-scene) and the floor's ``ground_peak_visibility (G, P)`` (``None`` without peaks or floor)."""

    states: list[PoseBatch]
    radiance: list[np.ndarray]
    visibility: list[np.ndarray]
    ground_radiance: np.ndarray | None
    ground_visibility: np.ndarray | None
    peak_visibility: list[np.ndarray] | None = None
    ground_peak_visibility: np.ndarray | None = None


class ScenePlayer:
    """Plays a scene (see the module docstring).

    Args:
        run_dir: the primary exported run (its lighting shades the ground; ``run: null`` entries use it).
        scene: the scene; ``None``: the run's recorded scene (``RunDir.scene_json``), else one character.
        ground: force a floor (``GroundConfig()`` defaults) when the scene has none (``prt play --ground``).
        clip: the clip of entries without one (a name or a :class:`Clip`); ``None``: their ``clip`` must be set.
        motion: a motion file (``.bvh``, a humanoid ``.glb``/``.gltf``) played by the entries without a clip
            instead, retargeted onto each one's character (:func:`prt_torch.rig.retarget.retarget_file`, once per
            run; ``motion_fps``: its rate, default the character's clips'); not with ``clip``.
        fps: the scene's frame rate (default: the primary character's clip rate).
        env, brdf, threads, window_size: as :class:`Player` (one Player per distinct run).
        peaks, peak_kind: the peak lights and their visibility, as :class:`Player` (module docstring).
    """

    def __init__(self, run_dir: str | os.PathLike[str] | RunDir, scene: SceneConfig | None = None,
                 ground: bool = False, clip: str | Clip | None = None, fps: float | None = None,
                 env: str | os.PathLike[str] | None = None, brdf: str | None = None, threads: int = 2,
                 window_size: tuple[int, int] = (480, 640), peaks: int | str | None = None,
                 peak_kind: str | None = None, motion: str | os.PathLike[str] | None = None,
                 motion_fps: float | None = None) -> None:
        check(clip is None or motion is None, "scene: give a clip or a motion file, not both")
        self.run = RunDir.of(run_dir)
        self._motion = (motion, motion_fps)
        #: per run, the motion file retargeted onto its character, and the retargeting report
        self.motions: dict[Path, tuple[Clip, Any]] = {}
        self._peak_args = {"peaks": peaks, "peak_kind": peak_kind}
        if scene is None:
            scene = run_scene(self.run) or SceneConfig()
        if ground and scene.ground is None:
            scene = scene.model_copy(update={"ground": GroundConfig()})
        self.scene = scene
        self.window_size = window_size
        self._renderer: Any = None
        self.players: dict[Path, Player] = {}
        self.actors: list[Actor] = []
        self.actor_players: list[Player] = []
        try:
            self._build(clip, fps, env, brdf, threads)
        except BaseException:
            self.close()
            raise

    def _retargeted(self, p: Player) -> Clip:
        """The motion file retargeted onto ``p``'s character (once per run)."""
        from prt_torch.rig.retarget import retarget_file

        key = p.bundle.run.path.resolve()
        if key not in self.motions:
            path, fps = self._motion
            assert path is not None
            self.motions[key] = retarget_file(path, p.character, fps=fps)
        return self.motions[key][0]

    def _player(self, run_path: str | None, env: Any, brdf: str | None, threads: int) -> Player:
        key = (self.run.path if run_path is None else Path(run_path)).resolve()
        if key not in self.players:
            self.players[key] = Player(key, env=env, brdf=brdf, graph="split", threads=threads,
                                       window_size=self.window_size, **self._peak_args)
        return self.players[key]

    def _build(self, clip: str | Clip | None, fps: float | None, env: Any, brdf: str | None, threads: int) -> None:
        entries = self.scene.entries()
        for k, e in enumerate(entries):
            p = self._player(e.run, env, brdf, threads)
            name = e.clip if e.clip is not None else clip
            if name is None and self._motion[0] is not None:
                name = self._retargeted(p)
            if name is None:
                raise PrtError(f"scene character {k}: no clip (set scene.characters[{k}].clip or pass --clip)")
            c = p.character.clip(name) if isinstance(name, str) else name
            rate = float(fps if fps is not None else (c.fps if k == 0 else self.fps))
            if k == 0:
                self.fps = rate
            local = p.clip_locals(c, rate)
            bundle = p.bundle
            spheres = load_spheres(bundle.run) if (len(entries) > 1 or self.scene.ground is not None) else None
            self.actors.append(Actor(p.character, Clip(c.name, rate, local), placement_matrix(e.offset, e.yaw_deg),
                                     e.time_offset, bundle.cluster, bundle.cluster_axis, bundle.cluster_bone,
                                     spheres, name=f"character {k} ({bundle.run.path.name}, {c.name})"))
            self.actor_players.append(p)
        self.primary = self.actor_players[0]
        orders = {p.order for p in self.actor_players}
        check(len(orders) == 1, f"scene: the characters' runs have different SH orders {sorted(orders)}")
        self.order = self.primary.order
        self.n_frames = int(np.asarray(self.actors[0].clip.local).shape[0])
        self.ground: Ground | None = None
        if self.scene.ground is not None:
            self.ground = scene_ground(self.scene.ground, self.actors, self.fps, self.n_frames)
        self.composers = [Composer(self.order, p.bundle.below_horizon) for p in self.actor_players]
        #: the compiled SHEXP of each character's vertices (others' spheres) and of the floor's (everyone's)
        self.shexp: list[CompiledShexp] = []
        self.ground_shexp: CompiledShexp | None = None
        if len(self.actors) > 1 or self.ground is not None:
            gp = shexp_graph_path(self.primary.bundle.run)
            check(gp is not None, f"{self.run.path}: no shexp graph: run `prt export {self.run.path}` "
                                  "(cast shadows need it)")
            tables = ShexpTables.from_graph(gp)
            check(tables.order == self.order, f"{gp}: SHEXP order {tables.order}, the run's is {self.order}")
            self.shexp = [CompiledShexp(tables, a.rest_vertices()) for a in self.actors]
            if self.ground is not None:
                self.ground_shexp = CompiledShexp(tables, self.ground.vertices)
        # the camera: around every placed rest mesh; every player looks from it
        rest = np.concatenate([a.rest_vertices() for a in self.actors]).astype(np.float32)
        self.center, self.radius = camera_target(rest)
        for p in self.players.values():
            p.center, p.radius = self.center, self.radius
            if self.scene.camera is not None:
                p.camera_azimuth = float(np.radians(self.scene.camera.azimuth_deg))
                p.camera_elevation = float(np.radians(self.scene.camera.elevation_deg))
        self._ground_rpo = self.primary.bundle.rpo(GROUND_BRDF) if GROUND_BRDF in self.primary.bundle.brdf_names \
            else self.primary.rpo
        self.exposure: Any = None
        self._build_peaks()

    def _build_peaks(self) -> None:
        """The peak lights (the primary player's split; every player has the same lighting) and, per character, the
        occluders of its peaks as others and the floor see them (module docstring). A run without peak blockers
        (``Player.peak_source`` ``None``) casts no peak shadow on anything."""
        pk = self.primary.peaks
        self.n_peaks = len(pk.peaks)
        self.peak_kind: str | None = None
        #: per character, the blocker set its peaks' occluders come from (a CapsuleSet or a SphereSet)
        self.peak_blockers: list[Any] = []
        if self.n_peaks == 0:
            return
        kinds = {None if p.peak_source is None else p.peak_source.kind for p in self.actor_players}
        check(len(kinds) == 1, f"scene: the characters' peak visibilities differ: {sorted(map(str, kinds))}")
        self.peak_kind = kinds.pop()
        if self.peak_kind in ("spheres", "learned"):
            self.peak_blockers = [p.peak_source.blockers for p in self.actor_players]

    @property
    def eye(self) -> np.ndarray:
        return camera_eye(self.center, self.radius, self.primary.camera_azimuth, self.primary.camera_elevation)

    # -- per frame -------------------------------------------------------------------------------------------
    def compute(self, frame: int, timer: FrameTimer | None = None) -> SceneFrame:
        """Everything of scene frame ``frame`` (module docstring)."""
        from prt_torch.blockers import pose_spheres

        t0 = time.perf_counter()
        idx = np.array([int(frame)])
        states, selfvis, centers, radii = [], [], [], []
        for a, p in zip(self.actors, self.actor_players, strict=True):
            local = a.locals(idx, self.fps)
            st = p.pose(local)
            states.append(st)
            selfvis.append(p.visibility(st.features, checked=False))
            if self.shexp:
                centers.append(pose_spheres(a.spheres, st.skin))  # (1, S_k, 3), the Poser's skinning matrices
                radii.append(np.asarray(a.spheres.radius, dtype=np.float32))
        if len(self.actors) > 1:
            check_separated([c[0] for c in centers], radii, [a.name for a in self.actors], frame)
        occ = self._peak_occluders(states)
        t1 = time.perf_counter()
        vis, rad, pvis = [], [], []
        for k, (st, p) in enumerate(zip(states, self.actor_players, strict=True)):
            frames = st.frames_vx33()
            others = rows = None
            if len(self.actors) > 1:
                oc = np.concatenate([c[0] for j, c in enumerate(centers) if j != k])
                orad = np.concatenate([r for j, r in enumerate(radii) if j != k])
                sx = self.shexp[k]
                others = sx(st.positions_vx3(0), frames[0], oc, orad)[None]
                rows = sx.occluded
            v = self.composers[k].in_scene(selfvis[k], frames, ground=self.ground is not None, others=others,
                                           others_rows=rows)
            vis.append(v)
            r = p.shade(st, visibility=v, checked=False)
            if self.n_peaks:
                pv = self.character_peak_visibility(k, st, occ)
                pvis.append(pv)
                r = r + p.shade_peaks(st, pv)
            rad.append(r)
        t2 = time.perf_counter()
        g_rad = g_vis = g_pvis = None
        if self.ground is not None:
            g = self.ground
            allc = np.concatenate(centers, axis=1)
            allr = np.concatenate(radii)[None]
            allc, allr = spheres_above(allc, allr, g.height)
            assert self.ground_shexp is not None
            g_vis = self.ground_shexp(g.vertices, None, allc[0], allr[0])  # the ground frame is the world's
            g_rad = self.shade_ground(g_vis)
            if self.n_peaks:
                g_pvis = self.floor_peak_visibility(occ)
                g_rad = g_rad + self.shade_ground_peaks(g_pvis)
        if timer is not None:
            timer.add("pose", t1 - t0)
            timer.add("characters", t2 - t1)
            timer.add("ground", time.perf_counter() - t2)
        return SceneFrame(states, rad, vis, g_rad, g_vis, pvis if self.n_peaks else None, g_pvis)

    # -- peak lights -----------------------------------------------------------------------------------------
    def _peak_geometry(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(directions (P, 3), angular radii (P,), powers (P, 3))`` of the primary player's peaks, the directions
        turned about z by its ``light_angle`` (``Player.rotate_light``), as it shades them."""
        p = self.primary
        c, s = np.cos(p.light_angle), np.sin(p.light_angle)
        rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return p.peaks.directions @ rz.T, p.peaks.angular_radii, p.peaks.powers

    def _peak_occluders(self, states: list[PoseBatch]) -> list[Any]:
        """Per character what occludes the peaks for the others and the floor: ``(ends_a (1, S_k, 3), ends_b (1,
        S_k, 3), radii (S_k,))`` of its posed peak blockers (:func:`prt_torch.blockers.capsules.posed_blockers`),
        or (``exact``) its posed mesh ``(vertices (V_k, 3), faces)``; ``[]`` without peaks."""
        from prt_torch.blockers.capsules import posed_blockers

        if not self.n_peaks or self.peak_kind is None or (len(self.actors) == 1 and self.ground is None):
            return []
        if self.peak_kind == "exact":
            return [(st.positions_vx3(0), np.asarray(a.character.faces)) for a, st in zip(self.actors, states,
                                                                                          strict=True)]
        return [(*posed_blockers(s, st.skin), np.asarray(s.radius, dtype=np.float32))
                for s, st in zip(self.peak_blockers, states, strict=True)]

    def character_peak_visibility(self, k: int, state: PoseBatch, occ: list[Any]) -> np.ndarray:
        """``(1, V_k, P)`` in-scene peak visibility of character ``k`` (module docstring): its own
        (``Player.peak_source``) x the other characters' sphere occlusion x the share above the floor; ``exact``:
        Embree against every posed character and the floor."""
        from prt_torch.scene.peaks import above_floor_share, others_peak_visibility

        p = self.actor_players[k]
        d, a, _ = self._peak_geometry()
        pos = np.ascontiguousarray(state.positions.transpose(0, 2, 1))  # (1, V, 3)
        nrm = np.ascontiguousarray(state.normals.transpose(0, 2, 1))
        if self.peak_kind == "exact" and (len(self.actors) > 1 or self.ground is not None):
            from prt_torch.bake.embree import RayScene
            from prt_torch.bake.peaks import exact_peak_visibility
            from prt_torch.scene.truth import merged_mesh

            meshes = occ + ([(self.ground.vertices, self.ground.faces)] if self.ground is not None else [])
            src = p.peak_source
            v = exact_peak_visibility(pos[0], nrm[0], d, a, src.offset, scene=RayScene(*merged_mesh(meshes)),
                                      side=src.side)
            return v[None]
        v = p.peak_visibility(state)  # its own (Player.peak_source; no blockers: the horizon share only)
        if len(self.actors) > 1 and occ:
            oa = np.concatenate([o[0] for j, o in enumerate(occ) if j != k], axis=1)
            ob = np.concatenate([o[1] for j, o in enumerate(occ) if j != k], axis=1)
            orad = np.concatenate([o[2] for j, o in enumerate(occ) if j != k])
            v = v * others_peak_visibility(pos, oa, ob, orad, d, a, kernel=compiled_kernel)
        if self.ground is not None:
            v = v * above_floor_share(d, a)
        return v

    def floor_peak_visibility(self, occ: list[Any]) -> np.ndarray:
        """``(G, P)`` peak visibility of the floor under every character (module docstring)."""
        from prt_torch.scene.peaks import floor_exact_peak_visibility, floor_peak_visibility

        g = self.ground
        assert g is not None
        d, a, _ = self._peak_geometry()
        if not occ:  # no peak blockers: no shadow (the floor faces up: the share of each disc above the horizon)
            from prt_torch.scene.peaks import above_floor_share

            return np.broadcast_to(above_floor_share(d, a), (g.n_vertices, len(a))).copy()
        if self.peak_kind == "exact":
            src = self.primary.peak_source
            return floor_exact_peak_visibility(g.vertices, occ, d, a, src.offset, side=src.side)
        ea = np.concatenate([o[0][0] for o in occ])
        eb = np.concatenate([o[1][0] for o in occ])
        r = np.concatenate([o[2] for o in occ])
        return floor_peak_visibility(g.vertices, ea, eb, r, d, a, kernel=compiled_kernel)

    def shade_ground_peaks(self, visibility: np.ndarray) -> np.ndarray:
        """``(G, 3)`` the floor's peak radiance for ``visibility (G, P)``: Lambert, albedo / pi x E x cos x V."""
        from prt_torch.scene.peaks import floor_peak_radiance

        assert self.ground is not None
        d, _, e = self._peak_geometry()
        return floor_peak_radiance(self.ground.albedo, d, e, visibility)

    def shade_ground(self, visibility: np.ndarray) -> np.ndarray:
        """``(G, 3)`` radiance of the ground with ``visibility (G, C)`` (ground frame): the primary player's
        ``shade`` with the diffuse RPO, times the ground albedo (the lambert RPO has albedo 1)."""
        g = self.ground
        assert g is not None
        p = self.primary
        v_graph = p.bundle.n_vertices
        n = g.n_vertices
        b = -(-n // v_graph)
        pad = b * v_graph - n

        def packed(x: np.ndarray) -> np.ndarray:  # (n, d) -> (B, d, V_graph) vertex-last, edge-padded
            x = np.concatenate([x, np.repeat(x[-1:], pad, axis=0)]) if pad else x
            return np.ascontiguousarray(x.reshape(b, v_graph, -1).transpose(0, 2, 1), dtype=np.float32)

        pos = g.vertices
        view = self.eye[None].astype(np.float64) - pos
        view /= np.maximum(np.linalg.norm(view, axis=-1, keepdims=True), 1e-12)
        frames9 = np.broadcast_to(g.frames()[0].reshape(1, 9), (n, 9))
        state = PoseBatch(packed(pos), packed(g.normals()), packed(frames9), packed(view),
                          np.zeros((b, p.bundle.n_features), np.float32))
        vis = packed(visibility).transpose(0, 2, 1)  # (B, V_graph, C)
        out = p.shade(state, visibility=np.ascontiguousarray(vis), checked=False, rpo=self._ground_rpo)
        return out.reshape(b * v_graph, 3)[:n] * g.albedo[None]

    def colors(self, f: SceneFrame) -> tuple[list[np.ndarray], np.ndarray | None]:
        """uint8 colours of every character and the ground under ONE tone map (fixed on the first call from all
        radiance of that frame: each character's surface radiance - times its own base colour - and the ground's,
        whose albedo is in its radiance already; :func:`~prt_torch.player.tonemap.auto_tonemap`, applied by
        ``Player.tone``)."""
        surface = [p.surface_radiance(r[0]) for p, r in zip(self.actor_players, f.radiance, strict=True)]
        if self.exposure is None:
            from prt_torch.player.tonemap import auto_tonemap

            parts = surface + ([f.ground_radiance] if f.ground_radiance is not None else [])
            self.exposure = auto_tonemap(np.concatenate(parts))
        for p in self.players.values():
            p.exposure = self.exposure
        cols = [p.tone(r) for p, r in zip(self.actor_players, surface, strict=True)]
        gcol = self.primary.tone(f.ground_radiance) if f.ground_radiance is not None else None
        return cols, gcol

    # -- rendering -------------------------------------------------------------------------------------------
    def renderer(self, off_screen: bool = True):  # -> MeshRenderer
        from prt_torch.player.render import MeshRenderer

        if self._renderer is None:
            a0 = self.actors[0]
            r = MeshRenderer(a0.rest_vertices(), a0.character.faces,
                             window_size=(self.window_size[1], self.window_size[0]), off_screen=off_screen)
            for a in self.actors[1:]:
                r.add_mesh(a.rest_vertices(), a.character.faces)
            if self.ground is not None:
                r.add_mesh(self.ground.vertices, self.ground.faces)
            self._renderer = r
        self._renderer.set_camera(self.eye, self.center)
        return self._renderer

    def render(self, f: SceneFrame) -> np.ndarray:
        """``(H, W, 3)`` uint8 image of a computed frame (offscreen)."""
        cols, gcol = self.colors(f)
        r = self.renderer()
        for k, (st, c) in enumerate(zip(f.states, cols, strict=True)):
            r.update(st.positions_vx3(0), c, index=k)
        if gcol is not None:
            r.update(self.ground.vertices, gcol, index=len(self.actors))
        return r.render()

    def play(self, out: str | os.PathLike[str] | None = None, png_dir: str | os.PathLike[str] | None = None,
             max_frames: int | None = None, timings: str | os.PathLike[str] | None = None) -> dict[str, Any]:
        """Play the scene offscreen into an MP4 (``out``) and/or PNG frames; returns the timing summary with
        ``frames`` and ``outputs``."""
        from prt_torch.player.video import VideoWriter, write_png

        n = self.n_frames if max_frames is None else max(0, min(int(max_frames), self.n_frames))
        check(n > 0, f"scene: nothing to play (max_frames={max_frames})")
        timer = FrameTimer()
        writer = VideoWriter(out, fps=self.fps) if out is not None else None
        if png_dir is not None:
            Path(png_dir).mkdir(parents=True, exist_ok=True)
        outputs: list[Path] = []
        try:
            for i in range(n):
                f = self.compute(i, timer)
                if writer is None and png_dir is None:
                    continue
                with timer.step("render"):
                    img = self.render(f)
                with timer.step("write"):
                    if writer is not None:
                        writer.append(img)
                    if png_dir is not None:
                        write_png(Path(png_dir) / f"frame_{i:05d}.png", img)
        except BaseException:
            if writer is not None:
                writer.abort()
            raise
        if writer is not None:
            outputs.append(writer.close())
        if png_dir is not None:
            outputs.append(Path(png_dir))
        summary = timer.summary(SCENE_STEPS)
        if timings is not None:
            timer.write_json(timings, extra={"scene_characters": len(self.actors), "ground": self.ground is not None,
                                             "ground_vertices": 0 if self.ground is None else self.ground.n_vertices})
            outputs.append(Path(timings))
        return {**summary, "frames": n, "outputs": [str(p) for p in outputs]}

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        for p in self.players.values():
            p.close()
        self.players.clear()
