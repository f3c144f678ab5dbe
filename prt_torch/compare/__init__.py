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
``reference``                          ``{frames, frame_indices, rays_per_estimate, estimates, lighting,
                                       sampling, noise: {same radiance keys: estimate b vs a}, note}``
``ground``                             only when the run's scene has a floor (``RunDir.scene_json``, the demo's):
                                       ``{psnr_image, radiance_rel_rmse, vis_rel_err, psnr_vertex, vertices,
                                       ...}`` of the floor's SHEXP visibility vs whole-scene Embree truth
                                       (:mod:`prt_torch.compare.ground`)
``scene``                              with a floor or several characters: ``characters[k].{self_only,
                                       in_scene}.{vis_rel_err, radiance_rel_rmse}`` vs whole-scene truth,
                                       ``ms_per_frame``, ``fps`` of the scene's run-time visibility path
=====================================  ==========================================================

Files (:class:`prt_torch.rundir.RunDir` ``compare_*`` properties): ``compare.json``, ``table.md``,
``index.html``, ``strip.png`` (truth | each method | reference, row 2: 4x |difference|, at the frame with the
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
