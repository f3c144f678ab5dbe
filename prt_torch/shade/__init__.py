"""Shading (torch): RPO shading of local-frame visibility under ZH lighting lobes rotated into vertex frames
(seed 003 eq. 11), the cosine product matrix (eq. 14) and diffuse PRT shading (seed 000)."""

from prt_torch.shade.cosine import cosine_product_matrix
from prt_torch.shade.diffuse import shade_diffuse_prt
from prt_torch.shade.lobes import lobes_in_frames, rotate_lobes_to_frames
from prt_torch.shade.rpo_shading import METHODS, RPOShader, RPOTensors, shade_rpo
from prt_torch.shade.triple_product import (
    gather_product,
    gaunt_flat,
    gaunt_gather_tables,
    gaunt_gather_tensors,
    outer_product_sh,
)

__all__ = [
    "METHODS",
    "RPOShader",
    "RPOTensors",
    "cosine_product_matrix",
    "gather_product",
    "gaunt_flat",
    "gaunt_gather_tables",
    "gaunt_gather_tensors",
    "lobes_in_frames",
    "outer_product_sh",
    "rotate_lobes_to_frames",
    "shade_diffuse_prt",
    "shade_rpo",
]
