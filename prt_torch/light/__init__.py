"""Lighting: HDR environment maps (``.hdr``, ``.exr``, ``.pfm``; lat-long and angular-map layouts) to SH,
directional / disk lights and a procedural sky in SH, and rotation of SH lighting.

World frame z up; images are y up and map to the world by ``(x, y, z) -> (x, -z, y)`` (see
:mod:`prt_torch.light.envmap` for the exact pixel mappings). Lighting is ``(C, 3)`` RGB float64.
numpy only: this package imports without torch.
"""

from prt_torch.light.envmap import (
    EnvMap,
    envmap_to_sh,
    infer_layout,
    latlong_directions,
    latlong_pixel_coords,
    latlong_solid_angles,
    load_envmap,
    probe_directions,
    probe_pixel_coords,
    probe_solid_angles,
    project_samples,
)
from prt_torch.light.readers import read_exr, read_hdr_image, read_pfm, read_radiance_hdr, write_pfm
from prt_torch.light.rotation import check_lighting, rotate_lighting
from prt_torch.light.sources import cap_zh, cie_clear_sky, directional_light_sh, sky_envmap, sky_sh

__all__ = [
    "EnvMap",
    "cap_zh",
    "check_lighting",
    "cie_clear_sky",
    "directional_light_sh",
    "envmap_to_sh",
    "infer_layout",
    "latlong_directions",
    "latlong_pixel_coords",
    "latlong_solid_angles",
    "load_envmap",
    "probe_directions",
    "probe_pixel_coords",
    "probe_solid_angles",
    "project_samples",
    "read_exr",
    "read_hdr_image",
    "read_pfm",
    "read_radiance_hdr",
    "rotate_lighting",
    "sky_envmap",
    "sky_sh",
    "write_pfm",
]
