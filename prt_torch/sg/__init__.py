"""Spherical Gaussians (seed 004): SG algebra, SG fits of the analytic BRDFs, multiscale HEALPix lighting fits
with peak detection.

* :mod:`~prt_torch.sg.lobes`: :class:`SGLobes` (axis, sharpness, RGB amplitude; save/load).
* :mod:`~prt_torch.sg.algebra`: evaluation, product, integral, inner product, triple product (eq. 4).
* :mod:`~prt_torch.sg.brdf_fit`: :func:`fit_brdf_sg` -> :class:`SGBRDF` (view-warped lobes per normal/view).
* :mod:`~prt_torch.sg.lighting`: :func:`fit_envmap_sg` -> :class:`SGLightFit` (needs ``healpy``: the ``sg`` extra).
* :mod:`~prt_torch.sg.split`: the light split (issue 27), :func:`split_envmap` / :func:`split_sky` ->
  :class:`LightSplit` (up to 4 :class:`PeakLight` discs + a residual map); numpy only at import.

Import the submodules directly; this package does not import healpy.
"""
