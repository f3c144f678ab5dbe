"""A textured copy of a test run: the checker texture, planar UVs and the material the player and compare tests of
a textured character use (one copy of the recipe)."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.rig.material import Material

#: the checker material: a warm base-colour factor, not metallic, roughness 0.4 (a Cook-Torrance RPO unlike the
#: catalogue's)
CHECKER_FACTOR = (1.0, 0.9, 0.8, 1.0)
CHECKER_ROUGHNESS = 0.4


def checker_texture() -> np.ndarray:
    """64 x 64 sRGB texture: red and green ramps, blue 8-texel checker (high contrast inside triangles)."""
    yy, xx = np.mgrid[0:64, 0:64]
    return np.stack([(xx * 4) % 256, (yy * 4) % 256, 255 * (((xx // 8) + (yy // 8)) % 2)], -1).astype(np.uint8)


def planar_uv(ch: Any) -> np.ndarray:
    """Per-corner UVs ``(T, 3, 2)`` float32: the front (x, z) projection of the rest pose, ``v`` down from the top."""
    lo, hi = ch.rest_vertices.min(0), ch.rest_vertices.max(0)
    x, z = ch.rest_vertices[:, 0], ch.rest_vertices[:, 2]
    uv = np.stack([(x - lo[0]) / (hi[0] - lo[0]), (hi[2] - z) / (hi[2] - lo[2])], 1)
    return uv[ch.faces].astype(np.float32)


def textured_copy(src: Path, dst: Path, ignore: tuple[str, ...] = ("compare", "report", "*.mp4")) -> Path:
    """Copy the run ``src`` to ``dst`` (``ignore``: patterns left out) and give its character the checker material
    with planar UVs; the material is not part of the character hash, so the copy's export still verifies."""
    from prt_torch.rundir import RunDir

    shutil.copytree(src, dst, ignore=shutil.ignore_patterns(*ignore))
    run = RunDir(dst)
    ch = run.character()
    ch.uv = planar_uv(ch)
    ch.material = Material("checker", CHECKER_FACTOR, 0.0, CHECKER_ROUGHNESS, checker_texture())
    ch.save(run.character_path)
    return dst
