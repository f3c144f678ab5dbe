"""Low-poly characters: the advice when a character has few shading vertices, and the remedy (midpoint subdivision).

The pipeline shades per vertex: visibility is baked, learned and played at the mesh's vertices and interpolated
across each triangle. A character with few vertices (the Khronos RiggedFigure: 130, the Fox: 290) gets one
shadow sample per large triangle: soft shadows turn into blotches that follow the triangulation.
:func:`low_poly_advice` says so (``prt info``, ``prt init``); ``character.subdivide: N`` in a run config
(:func:`subdivide_character`) bakes and shades a copy of the mesh split ``N`` times by edge midpoints
(``4^N`` times the faces), carried by the same skeleton and skin:

* positions, rest normals (renormalised) and the dense skin weights ``(V, J)`` of a new vertex are the means of
  its edge's two endpoints (:func:`trimesh.remesh.subdivide`); the weights keep every influence (at most ``J``
  per vertex: ``K`` grows up to twice per level) and are renormalised, so rows sum to 1 to float rounding;
* the surface is the same flat triangles (midpoints lie on them): only the shading gets denser, the silhouette
  stays as faceted as the file's;
* per-corner UVs follow the same barycentric midpoints, the material is kept.

Linear blend skinning does not commute with the subdivision exactly: skinning the interpolated vertex gives the
midpoint of the skinned endpoints plus ``-1/4 sum_j (w_a - w_b)_j R_j (p_a - p_b)`` (``R_j`` the linear part of
joint ``j``'s skin matrix, ``p`` rest positions, ``w`` weights): zero on rigid parts and where the two endpoints
have the same weights, second order in the edge length elsewhere. That is what a skinned engine mesh of the
finer resolution would do too.
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check
from prt_torch.rig.character import Character

#: below this many shading vertices a character is low-poly (:func:`low_poly_advice`)
LOW_POLY_VERTICES = 2000
#: the most subdivision levels a config may ask for (``4^N`` faces)
MAX_SUBDIVIDE = 4


def suggested_levels(n_vertices: int, target: int = LOW_POLY_VERTICES) -> int:
    """The fewest midpoint subdivision levels that bring ``n_vertices`` to ``target`` or more (a closed mesh of
    ``V`` vertices has about ``4 V`` after one level), at most :data:`MAX_SUBDIVIDE`; 0 when it has them."""
    levels, v = 0, max(int(n_vertices), 1)
    while v < target and levels < MAX_SUBDIVIDE:
        v *= 4
        levels += 1
    return levels


def low_poly_advice(n_vertices: int) -> str | None:
    """One line (without the ``warning:`` prefix) when a character of ``n_vertices`` shading vertices is low-poly
    (fewer than :data:`LOW_POLY_VERTICES`), naming the remedy; ``None`` otherwise."""
    if n_vertices >= LOW_POLY_VERTICES:
        return None
    levels = suggested_levels(n_vertices)
    return (f"only {n_vertices} shading vertices (< {LOW_POLY_VERTICES}): shadows are shaded per vertex and "
            f"interpolated across large triangles (blotches that follow the triangulation); set "
            f"'character.subdivide: {levels}' in the config to bake and shade a subdivided copy "
            f"(~{n_vertices * 4 ** levels} vertices, same skeleton and skin)")


def subdivide_mesh(vertices: np.ndarray, faces: np.ndarray, attributes: dict[str, np.ndarray], levels: int
                   ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """``levels`` rounds of midpoint subdivision (:func:`trimesh.remesh.subdivide`) with per-vertex attributes.

    Args:
        vertices: ``(V, 3)`` positions; faces: ``(T, 3)`` int; attributes: name -> ``(V, d)`` arrays (float64 in,
            float64 out), each interpolated at the edge midpoints as the positions are.
        levels: ``>= 0``.

    Returns:
        ``(vertices (V', 3) float64, faces (T * 4^levels, 3) int64, attributes (V', d), bary (T * 4^levels, 3, 3))``:
        the original vertices come first, in order; new face ``4 t + s`` is sub-triangle ``s`` of face ``t``
        (per level) and ``bary[f, c]`` the barycentric weights of its corner ``c`` in its ORIGINAL face (for
        per-corner data such as UVs).
    """
    import trimesh

    check(int(levels) == levels and levels >= 0, f"subdivision levels must be an integer >= 0, got {levels}")
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    attrs = {k: np.asarray(a, dtype=np.float64).reshape(v.shape[0], -1) for k, a in attributes.items()}
    bary = np.broadcast_to(np.eye(3), (f.shape[0], 3, 3)).copy()
    # sub-triangle s of (c0, c1, c2) in trimesh's order, corners as means of the parent's corners
    sub = np.array([[[1, 0, 0], [.5, .5, 0], [.5, 0, .5]], [[.5, .5, 0], [0, 1, 0], [0, .5, .5]],
                    [[.5, 0, .5], [0, .5, .5], [0, 0, 1]], [[.5, .5, 0], [0, .5, .5], [.5, 0, .5]]])
    for _ in range(int(levels)):
        v, f_new, attrs = trimesh.remesh.subdivide(v, f, vertex_attributes=attrs)
        check(f_new.shape[0] == 4 * f.shape[0], "subdivision: unexpected face count")  # trimesh's documented order
        bary = np.einsum("sck,tkl->tscl", sub, bary).reshape(-1, 3, 3)
        f = np.asarray(f_new, dtype=np.int64)
    return v, f, attrs, bary


def subdivide_character(character: Character, levels: int) -> Character:
    """The character with its mesh subdivided ``levels`` times (see the module docstring); ``levels == 0`` returns
    it unchanged. Skeleton, clips, joint limits and material are shared; positions float32."""
    check(int(levels) == levels and 0 <= levels <= MAX_SUBDIVIDE,
          f"character.subdivide must be an integer in [0, {MAX_SUBDIVIDE}], got {levels}")
    if levels == 0:
        return character
    v, f, a, bary = subdivide_mesh(character.rest_vertices, character.faces,
                                   {"n": character.rest_normals, "w": character.dense_weights}, levels)
    n = a["n"] / np.maximum(np.linalg.norm(a["n"], axis=1, keepdims=True), 1e-30)
    w = a["w"] / a["w"].sum(axis=1, keepdims=True)
    k = max(int((w > 0).sum(axis=1).max()), 1)
    joints = np.argsort(-w, axis=1, kind="stable")[:, :k]  # every influence kept: the largest first
    weights = np.take_along_axis(w, joints, axis=1)
    joints = np.where(weights > 0, joints, 0)
    uv = None
    if character.uv is not None:
        parent = np.repeat(np.arange(character.faces.shape[0]), 4 ** int(levels))
        uv = np.einsum("fck,fkd->fcd", bary, character.uv[parent].astype(np.float64)).astype(np.float32)
    return Character(character.name, list(character.joint_names), character.parents, character.bind_local,
                     character.inverse_bind, v.astype(np.float32), n.astype(np.float32), f, joints,
                     weights.astype(np.float32), dict(character.clips), character.joint_limits, uv, character.material)
