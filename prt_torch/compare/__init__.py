"""``prt compare``: every visibility method side by side on the shipping path, against two references.

Frames: the dataset's done held-out frames (their baked positions and frames), or a named clip posed with
the bake's code (``--clip``); ``--frames`` caps either (evenly spaced). Methods (:mod:`prt_torch.compare.methods`,
a registry later methods plug into) run round-robin per frame, batch 1, in one process: ``ms_per_frame`` is
the median of each method's own run-time path (onnxruntime for learned models, Embree ``trace_frame`` for
the truth, the constant for ``unshadowed``). Every visibility is shaded by :mod:`prt_torch.scoring`
(the shipped RPOs ``lambert`` and ``phong``, and ``material`` for a character with its own material; the player's
lighting through its ZH lobes, the player's camera, renderer and tone map). The look is the player's, one rule
(:class:`prt_torch.player.material.SurfaceAlbedo`) for every row of the strip, the reference included, and for every
figure: the radiance times the character's base colour (a textured glTF character: per pixel in the images, the
corner mean per vertex in the vertex figures), one tone map per frame fixed from the truth's surface radiance; a
character with its own material is also shaded with its Cook-Torrance RPO (``material``, the file ``prt play``
plays; the reference with the analytic Cook-Torrance it was built from), and the strip shows ``material``. The
built-in character is white and has no material of its own: its figures are those of the catalogue alone.
References:

* ``sh_truth``: visibility ray-traced with the bake's own code and settings (the learning target): every
  top-level figure is against it, so it isolates each method's own error;
* ``reference``: the rendering integral by Monte-Carlo (:mod:`prt_torch.compare.reference`: full-resolution
  lighting, analytic BRDFs, Embree rays) on a few frames (the strip frame + evenly spaced ones, default 4):
  SH truncation, the ZH-lobe fit and the BRDF factorisation count too. Figures under ``vs_reference``.

**Peak lights** (issue 27, ``--peaks auto|0|K``, :func:`prt_torch.compare.reference.compare_lights`): the light is
split into up to ``K`` peak lights (discs: the procedural sky's sun, a map's detected suns by
:func:`prt_torch.player.peaks.load_peak_lighting`, ``--light sun``'s disk; ``--light smooth`` has none) and the
residual. Every method keeps its row (the WHOLE lighting on the SH path, as before) and every visibility method gains
``<method>+peaks_<kind>`` rows: its visibility under the RESIDUAL on the same shipping path, plus per peak
``E f_r(l, v) max(n . l, 0) V_kind`` with the analytic BRDF of each RPO (:func:`prt_torch.brdf.direct.peak_radiance`;
the character's own material: its Cook-Torrance), ``V_kind`` one of :data:`prt_torch.player.peaks.PEAK_KINDS`
(``exact`` Embree disc rays, ``spheres`` the run's blocker spheres, ``learned`` its learned peak blockers), timed per
frame in the same round-robin as the methods. Default kinds (``--peak-kinds``): ``spheres`` and ``learned`` where the
run has them for every visibility method, ``exact`` for ``sh_truth`` only; ``sh_truth+peaks_exact`` (the ceiling) is
always a row with peaks and is the TRUTH of every ``+peaks`` row's top-level figures (the reference is the same for
every row). A ``+peaks`` row has its method's ``vis_rel_err``, ``ms_per_frame`` = the method's + the kind's
(``peak_ms_per_frame``), ``bytes`` = the method's + the kind's (``peak_bytes``), ``base_method``, ``peak_kind``,
``truth``. Radiance methods (``output == "radiance"``: ``sg_vct``, ``s001``, ``learned_transfer``, ...) get no
``+peaks`` rows (their lighting is their own). The residual is shaded WITHOUT the player's sinc window: it only
blurs the smooth residual (measured on the demo run, procedural sky, 4 reference frames, diffuse / glossy image
PSNR vs the reference: ``sh_truth+peaks_exact`` 51.9 / 33.6 dB without, 43.7 / 33.3 with it;
``learned_mlp+peaks_learned`` 32.4 / 31.1 without, 32.3 / 30.9 with; ``run_compare(residual_window=True)``
restores it).

**The silhouette rule** (one rule for every row and the reference, :func:`prt_torch.compare.reference.
silhouette_mask`): a vertex whose normal faces away from the camera (``n . (eye - p) <= 0``) has radiance 0 in every
row, as in the Monte-Carlo reference (its analytic BRDFs vanish there; an RPO's view factor extrapolates below the
horizon). Such vertices are seen only on the silhouette rim, interpolated into front-facing triangles. On the demo
run (procedural sky) the rule moves ``sh_truth+peaks_exact`` from 41.0 / 32.3 to 51.9 / 33.6 dB diffuse / glossy vs
the reference and the methods' own rows by 0.1-0.3 dB (``run_compare(silhouette=False)``: the rule off).

``RUN/compare/compare.json`` (stable; later work adds keys):

=====================================  ==========================================================
key                                    meaning
=====================================  ==========================================================
``frames``                             frames compared ``N``
``clips``                              their clip names
``source``                             held-out frames of the dataset, or a clip posed here
``lighting``, ``lighting_path``        the player's lighting (its source, ZH lobes), ``"lobes"``
``light``                              ``--light``: ``sky`` (the player's sky, default), ``smooth`` (``--env`` or
                                       the sky without its sun), ``sun`` (that plus a small bright disk:
                                       ``--sun-size`` degrees, ``--sun-power``); every method and the reference
                                       see the same light (SH methods its SH, ``sg_vct`` the full-resolution map)
``peaks``                              the peak lights ``[{direction, angular_radius_deg, radiance}]``
                                       (:meth:`prt_torch.sg.split.PeakLight.to_dict`; ``[]``: none, no ``+peaks``
                                       rows), ``peak_kinds`` the kinds timed, ``residual_lighting`` the +peaks
                                       rows' lighting (``null`` without peaks)
``silhouette``                         the silhouette rule (above)
``brdfs``                              the RPOs shaded (``["lambert", "phong"]``, plus ``"material"`` for a
                                       character with its own material: keys tagged ``material``)
``material``                           the character's material (``name``, ``base_color``, ``metallic``,
                                       ``roughness``, ``has_texture``), ``albedo`` (which base colour multiplied
                                       every figure and image), ``strip_brdf``, ``rule``
``image_frames``                       frames rendered for image PSNR (evenly spaced, strip frame included)
``strip_frame``                        ``{index, clip, frame_index, row, brdf}`` of the image strip
``methods.NAME.vis_rel_err``           relative SH L2 error vs ``sh_truth`` (``null`` for radiance methods)
``methods.NAME.radiance_rel_rmse``     vertex (surface) radiance relative RMSE vs ``sh_truth``, the BRDFs pooled
``methods.NAME.psnr_image_diffuse``    image PSNR (dB, character pixels, peak 1) vs ``sh_truth``, lambert
``methods.NAME.psnr_image_glossy``     the same, phong
``methods.NAME.bytes``                 run-time data beyond the character, RPOs, lighting (ONNX initialisers
                                       for learned models, the constant for ``unshadowed``, 0 for ``sh_truth``)
``methods.NAME.ms_per_frame``, ``fps`` median milliseconds per frame and its inverse
``methods.NAME.runtime``, ``output``   what was timed; ``visibility`` or ``radiance``
``methods.NAME.*`` (method info)       extra keys of the method (``MethodBase.info``): e.g. ``sg_vct``'s
                                       ``ms_voxelize_trace_shade``, its grid and cone counts; ``shexp``'s
                                       sphere count; the precision rows' ``precision``
``methods.NAME.*_diffuse|_glossy``     ``radiance_rel_rmse_*``, ``psnr_vertex_*`` per BRDF (``*_material``: the
                                       character's own, with ``psnr_image_material``)
``methods.NAME.vs_reference``          the same keys against the Monte-Carlo reference (vertex figures over
                                       the vertices facing the camera: the analytic BRDF is 0 behind them)
``methods.M+peaks_K``                  the +peaks rows (above): the same keys, vs ``sh_truth+peaks_exact`` at the
                                       top level, plus ``base_method``, ``peak_kind``, ``truth``,
                                       ``peak_ms_per_frame``, ``peak_bytes``
``reference``                          ``{frames, frame_indices, rays_per_estimate, estimates, lighting,
                                       sampling, vertices, noise: {same radiance keys: estimate b vs a}, note}``;
                                       its light is the split at full resolution: the residual (the sky's CIE sky +
                                       ground, a map's residual pixels) + every peak as a disk light of the peak's
                                       own angular radius (also under ``--peaks 0``: the ``auto`` split)
``ground``                             only when the run's scene has a floor (``RunDir.scene_json``, the demo's):
                                       ``{psnr_image, radiance_rel_rmse, vis_rel_err, psnr_vertex, vertices,
                                       ...}`` of the floor's SHEXP visibility vs whole-scene Embree truth
                                       (:mod:`prt_torch.compare.ground`)
``scene``                              with a floor or several characters: ``characters[k].{self_only,
                                       in_scene}.{vis_rel_err, radiance_rel_rmse}`` vs whole-scene truth,
                                       ``ms_per_frame``, ``fps`` of the scene's run-time visibility path
=====================================  ==========================================================

Files (:class:`prt_torch.rundir.RunDir` ``compare_*`` properties): ``compare.json``, ``table.md``,
``index.html``, ``strip.png`` (truth | each method | the shipped learned kind's and ``sh_truth``'s best +peaks rows
| reference, row 2: 4x |difference|, at the frame with the
largest truth vs unshadowed radiance gap), ``psnr_vs_ms.png``, ``ground.png`` (with a floor), and
``<kind>.visibility.onnx`` for learned kinds that are not the exported one.
"""

from __future__ import annotations

from typing import Any

__all__ = ["run_compare"]


def run_compare(*args: Any, **kwargs: Any) -> dict[str, Any]:
    """See :func:`prt_torch.compare.run.run_compare`."""
    from prt_torch.compare.run import run_compare as _run

    return _run(*args, **kwargs)
