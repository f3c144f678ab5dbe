"""The compiled (numba) kernels of the player's CPU frame path (:mod:`prt_torch.player.compiled`).

Two passes per frame, each one compiled loop over the mesh, threads over blocks of vertices:

* :func:`pose_pass` - LBS of positions and normals from each vertex's non-zero skin weights, the vertex frame
  (the rule of :func:`prt_torch.rig.vertex_frames.vertex_frames_soa`: the cluster axis carried by its bone, made
  tangent, blended with its fallback axis below :data:`~prt_torch.rig.vertex_frames.FALLBACK_BELOW`) and the unit
  view direction, written vertex-last ``(B, 3|9, V)`` as :class:`~prt_torch.player.posing.Poser` writes them;
* :func:`decode_shade_pass` - per tile of up to :data:`TILE` vertices of one cluster: decode the tile's visibility
  ``(C, T)`` from the latent ``z`` with the cluster's output basis (int8 with per-column block scales, the latent
  rounded per block to int8 as onnxruntime's ``MatMulNBits`` does, integer products summed exactly in float32; or
  float32 weights), every basis stored k-major (``(K_g, C n_g)``: the tile's columns contiguous), then shade it
  while it is in cache with the RPO and the ZH lobes (the arithmetic of :class:`prt_torch.export.graphs.ShadingGraph`),
  writing only radiance ``(B, V, 3)`` in the ORIGINAL vertex order. A crowd reads each basis column once for all
  ``B`` characters.

The RPO step ``zz = sum_b a_b M_b v`` runs in its product form: ``M_b = sum_k u_bk Gamma_{., ., k}`` (the RPO's
definition, :mod:`prt_torch.brdf.rpo`), so ``zz_i = sum_jk Gamma_ijk v_j (sum_b a_b u_bk)``: the Gaunt tensor's
non-zeros (353 at order 4) instead of ``k C^2`` (2048) multiply-adds per vertex. SH of a direction are its
monomials (degree-major, each a lower one times a component: :class:`prt_torch.export.graphs.SHPolynomial`) times a
sparse coefficient table.
"""

from __future__ import annotations

import numba
import numpy as np

from prt_torch.rig.vertex_frames import DEGENERATE_BELOW, FALLBACK_BELOW

#: vertices per tile of the decode + shade pass: its ``(C, T)`` working arrays stay in the L1/L2 cache
TILE = 256
#: vertices per block of the posing pass
POSE_BLOCK = 512


@numba.njit(cache=True, nogil=True, inline="always")
def _monomials(x: np.ndarray, y: np.ndarray, z: np.ndarray, parent: np.ndarray, comp: np.ndarray,
               mono: np.ndarray, n: int) -> None:
    """``mono (P, T)`` monomials of the directions ``(x, y, z)`` (first ``n`` entries): 1, x, y, z, then entry
    ``p >= 4`` = entry ``parent[p]`` times component ``comp[p]``. (Every inner loop of these kernels runs over 1-D
    row views: numba vectorises those, not 2-D indexing - measured 14x on the decode.)"""
    p_count = mono.shape[0]
    m0 = mono[0]
    for i in range(n):
        m0[i] = 1.0
    if p_count > 1:
        m1, m2, m3 = mono[1], mono[2], mono[3]
        for i in range(n):
            m1[i] = x[i]
            m2[i] = y[i]
            m3[i] = z[i]
    for p in range(4, p_count):
        src = mono[parent[p]]
        c = comp[p]
        d = x if c == 0 else (y if c == 1 else z)
        dst = mono[p]
        for i in range(n):
            dst[i] = src[i] * d[i]


@numba.njit(cache=True, nogil=True)
def quantize_latent(z: np.ndarray, rows: np.ndarray, k_used: np.ndarray, blocks: np.ndarray, k_pad: int,
                    nb_max: int) -> tuple[np.ndarray, np.ndarray]:
    """``(zq (B, G, k_pad), zs (B, G, nb_max))``: each cluster's latent rounded as onnxruntime's int8 ``MatMulNBits``
    rounds its input (symmetric, per block of ``blocks[g]`` entries: scale ``max |z_block| / 127``, round half to
    even), ``zq`` the integer values (as float32, zero past ``k_used``), ``zs`` the block scales. A cluster with
    ``blocks[g] == 0`` (float weights) keeps ``z`` as is, scale 1."""
    b_count = z.shape[0]
    g_count = rows.shape[0]
    zq = np.zeros((b_count, g_count, k_pad), np.float32)
    zs = np.ones((b_count, g_count, nb_max), np.float32)
    for b in range(b_count):
        for g in range(g_count):
            kg = k_used[g]
            blk = blocks[g]
            r = rows[g]
            if blk == 0:
                for k in range(kg):
                    zq[b, g, k] = z[b, r, k]
                continue
            nb = (kg + blk - 1) // blk
            for bb in range(nb):
                amax = np.float32(0.0)
                for k in range(bb * blk, min(kg, (bb + 1) * blk)):
                    amax = max(amax, abs(z[b, r, k]))
                s = amax / np.float32(127.0)
                if s > 0:
                    zs[b, g, bb] = s
                    for k in range(bb * blk, min(kg, (bb + 1) * blk)):
                        zq[b, g, k] = np.rint(z[b, r, k] / s)
                else:
                    zs[b, g, bb] = 0.0
    return zq, zs


@numba.njit(cache=True, nogil=True, parallel=True, fastmath=True)
def decode_shade_pass(zq: np.ndarray, zs: np.ndarray, tile_start: np.ndarray, tile_end: np.ndarray,
                      tile_group: np.ndarray, starts: np.ndarray, n_used: np.ndarray, k_used: np.ndarray,
                      blocks: np.ndarray, q_off: np.ndarray, s_off: np.ndarray, q: np.ndarray, scales: np.ndarray,
                      weights: np.ndarray, mean: np.ndarray, frames: np.ndarray, view: np.ndarray,
                      lobe_dirs: np.ndarray, lobe_g: np.ndarray, wm: np.ndarray, u: np.ndarray, g_i: np.ndarray,
                      g_j: np.ndarray, g_k: np.ndarray, g_v: np.ndarray, parent: np.ndarray, comp: np.ndarray,
                      sh_c: np.ndarray, sh_p: np.ndarray, sh_v: np.ndarray, tint: np.ndarray, order: np.ndarray,
                      out: np.ndarray, n_chunks: int) -> None:
    """Decode + shade every tile (module doc). Shapes: ``zq (B, G, Kpad)``, ``zs (B, G, NB)`` (:func:`quantize_latent`);
    per tile ``t``: vertices ``tile_start[t] .. tile_end[t]`` (cluster-sorted positions) of group ``tile_group[t]``;
    per group ``g``: ``starts, n_used, k_used, blocks`` (``decode.npz``), ``q_off, s_off`` the offsets of its
    k-major bases in ``q`` (int8 ``(K_g, C n_g)``) or ``weights`` (float32, same layout) and of its scales ``(NB_g,
    C n_g)`` in ``scales``; ``mean (C, V)``; ``frames
    (B, 9, V)``, ``view (B, 3, V)`` cluster-sorted; ``lobe_dirs (L, 3)``, ``lobe_g (L, C, 3)`` (the lobes' band
    coefficients per SH coefficient); ``wm (k, P)`` view factors on the monomials; ``u (k, C)``; the Gaunt non-zeros
    ``(g_i, g_j, g_k, g_v)``; the monomial recursion ``parent, comp (P,)``; the SH table ``(sh_c, sh_p, sh_v)``
    (``y_c += v * mono_p``); ``tint (3,)``; ``order (V,)`` original vertex of each position; ``out (B, V, 3)``;
    ``n_chunks`` runs of consecutive tiles, one per thread task."""
    b_count = frames.shape[0]
    c_count = mean.shape[0]
    p_count = parent.shape[0]
    k_terms = wm.shape[0]
    n_lobes = lobe_dirs.shape[0]
    n_tiles = tile_start.shape[0]
    width = 1
    for t in range(n_tiles):
        width = max(width, tile_end[t] - tile_start[t])
    for ch in numba.prange(n_chunks):  # a run of consecutive tiles per chunk: its scratch allocated once
        vis = np.empty((b_count, c_count, width), np.float32)
        acc = np.empty((b_count, width), np.float32)
        part = np.empty((b_count, width), np.float32)
        wx = np.empty(width, np.float32)
        wy = np.empty(width, np.float32)
        wz = np.empty(width, np.float32)
        mono = np.empty((p_count, width), np.float32)
        a = np.empty((k_terms, width), np.float32)
        ue = np.empty((c_count, width), np.float32)
        zz = np.empty((c_count, width), np.float32)
        ysh = np.empty((c_count, width), np.float32)
        rad = np.empty((3, width), np.float32)
        for t in range(ch * n_tiles // n_chunks, (ch + 1) * n_tiles // n_chunks):
            g = tile_group[t]
            v0 = tile_start[t]
            n = tile_end[t] - v0
            ng = n_used[g]
            i0 = v0 - starts[g]
            kg = k_used[g]
            blk = blocks[g]
            cn = c_count * ng
            # -- decode: k-major bases, the inner loops along the tile's columns; each row read once for all B
            if blk > 0:
                nb = (kg + blk - 1) // blk
                for c in range(c_count):
                    col0 = c * ng + i0
                    acc[:, :] = 0.0
                    for bb in range(nb):
                        part[:, :] = 0.0
                        for k in range(bb * blk, min(kg, (bb + 1) * blk)):
                            row = q_off[g] + k * cn + col0
                            qr = q[row:row + n]
                            for b in range(b_count):
                                zk = zq[b, g, k]
                                pr = part[b]
                                for i in range(n):
                                    pr[i] += np.float32(qr[i]) * zk  # integer-valued: exact in float32
                        srow = s_off[g] + bb * cn + col0
                        sr = scales[srow:srow + n]
                        for b in range(b_count):
                            sz = zs[b, g, bb]
                            pr = part[b]
                            ar = acc[b]
                            for i in range(n):
                                ar[i] += pr[i] * (sr[i] * sz)
                    mr = mean[c, v0:v0 + n]
                    for b in range(b_count):
                        ar = acc[b]
                        vr = vis[b, c]
                        for i in range(n):
                            vr[i] = ar[i] + mr[i]
            else:
                for b in range(b_count):
                    for c in range(c_count):
                        vr = vis[b, c]
                        mr = mean[c, v0:v0 + n]
                        for i in range(n):
                            vr[i] = mr[i]
                    for k in range(kg):
                        zk = zq[b, g, k]
                        row = q_off[g] + k * cn + i0
                        for c in range(c_count):
                            wr = weights[row + c * ng:row + c * ng + n]
                            vr = vis[b, c]
                            for i in range(n):
                                vr[i] += zk * wr[i]
            # -- shade each character's tile while it is in cache
            for b in range(b_count):
                f = frames[b, :, v0:v0 + n]  # (9, n)
                f0, f1, f2, f3, f4, f5, f6, f7, f8 = f[0], f[1], f[2], f[3], f[4], f[5], f[6], f[7], f[8]
                ox, oy, oz = view[b, 0, v0:v0 + n], view[b, 1, v0:v0 + n], view[b, 2, v0:v0 + n]
                for i in range(n):  # local view direction F @ wo
                    wx[i] = f0[i] * ox[i] + f1[i] * oy[i] + f2[i] * oz[i]
                    wy[i] = f3[i] * ox[i] + f4[i] * oy[i] + f5[i] * oz[i]
                    wz[i] = f6[i] * ox[i] + f7[i] * oy[i] + f8[i] * oz[i]
                _monomials(wx, wy, wz, parent, comp, mono, n)
                for kb in range(k_terms):  # view factors a_b = w_b . y(wo)
                    ar = a[kb]
                    ar[:n] = 0.0
                    for p in range(p_count):
                        w = wm[kb, p]
                        if w != 0.0:
                            mr = mono[p]
                            for i in range(n):
                                ar[i] += w * mr[i]
                for c in range(c_count):  # u_eff = sum_b a_b u_b
                    ur = ue[c]
                    ur[:n] = 0.0
                    for kb in range(k_terms):
                        w = u[kb, c]
                        if w != 0.0:
                            ar = a[kb]
                            for i in range(n):
                                ur[i] += w * ar[i]
                zz[:, :] = 0.0
                vb = vis[b]
                for e in range(g_v.shape[0]):  # zz_i = sum_jk Gamma_ijk v_j u_eff_k
                    gv = g_v[e]
                    zr, vr, ur = zz[g_i[e]], vb[g_j[e]], ue[g_k[e]]
                    for i in range(n):
                        zr[i] += gv * vr[i] * ur[i]
                rad[:, :] = 0.0
                r0, r1, r2 = rad[0], rad[1], rad[2]
                for lb in range(n_lobes):  # L_rgb = sum_{lobe, c} g_lobe[band c, rgb] y_c(F s_lobe) zz_c
                    sx, sy, sz = lobe_dirs[lb, 0], lobe_dirs[lb, 1], lobe_dirs[lb, 2]
                    for i in range(n):
                        wx[i] = f0[i] * sx + f1[i] * sy + f2[i] * sz
                        wy[i] = f3[i] * sx + f4[i] * sy + f5[i] * sz
                        wz[i] = f6[i] * sx + f7[i] * sy + f8[i] * sz
                    _monomials(wx, wy, wz, parent, comp, mono, n)
                    ysh[:, :] = 0.0
                    for e in range(sh_v.shape[0]):
                        sv = sh_v[e]
                        yr, mr = ysh[sh_c[e]], mono[sh_p[e]]
                        for i in range(n):
                            yr[i] += sv * mr[i]
                    for c in range(c_count):
                        g0, g1, g2 = lobe_g[lb, c, 0], lobe_g[lb, c, 1], lobe_g[lb, c, 2]
                        yr, zr = ysh[c], zz[c]
                        for i in range(n):
                            yz = yr[i] * zr[i]
                            r0[i] += g0 * yz
                            r1[i] += g1 * yz
                            r2[i] += g2 * yz
                t0, t1, t2 = tint[0], tint[1], tint[2]
                ob = out[b]
                for i in range(n):
                    o = order[v0 + i]
                    ob[o, 0] = r0[i] * t0
                    ob[o, 1] = r1[i] * t1
                    ob[o, 2] = r2[i] * t2


@numba.njit(cache=True, nogil=True, parallel=True)
def pose_pass(skin: np.ndarray, indptr: np.ndarray, joint: np.ndarray, weight: np.ndarray, rest: np.ndarray,
              rest_n: np.ndarray, labels: np.ndarray, carried: np.ndarray, eye: np.ndarray, pos: np.ndarray,
              nrm: np.ndarray, frames: np.ndarray, view: np.ndarray) -> None:
    """LBS + vertex frames + view directions (module doc). ``skin (B, J, 12)`` float32 rows of each skinning matrix's
    top 3 x 4 (entry ``4r + col``); the skin weights as CSR rows ``indptr (V + 1,)``, ``joint``, ``weight``; ``rest,
    rest_n (3, V)``; ``labels (V,)`` cluster of each vertex; ``carried (B, 2, 3, Kc)`` float32 unit cluster axes and
    fallback axes carried by each cluster's bone; ``eye (3,)``. Writes ``pos, nrm, view (B, 3, V)``, ``frames
    (B, 9, V)`` (entry ``3i + j`` = ``F[i, j]``, rows ``(t, b, n)``); every array in the same vertex order."""
    b_count = skin.shape[0]
    v_count = rest.shape[1]
    n_blocks = (v_count + POSE_BLOCK - 1) // POSE_BLOCK
    inv_fb = np.float32(-1.0 / FALLBACK_BELOW)
    for bk in numba.prange(b_count * n_blocks):
        b = bk // n_blocks
        lo = (bk % n_blocks) * POSE_BLOCK
        hi = min(v_count, lo + POSE_BLOCK)
        m = np.empty(12, np.float32)
        for v in range(lo, hi):
            for e in range(12):
                m[e] = 0.0
            for s in range(indptr[v], indptr[v + 1]):
                j = joint[s]
                w = weight[s]
                for e in range(12):
                    m[e] += w * skin[b, j, e]
            rx, ry, rz = rest[0, v], rest[1, v], rest[2, v]
            px = m[0] * rx + m[1] * ry + m[2] * rz + m[3]
            py = m[4] * rx + m[5] * ry + m[6] * rz + m[7]
            pz = m[8] * rx + m[9] * ry + m[10] * rz + m[11]
            nx0, ny0, nz0 = rest_n[0, v], rest_n[1, v], rest_n[2, v]
            nx = m[0] * nx0 + m[1] * ny0 + m[2] * nz0
            ny = m[4] * nx0 + m[5] * ny0 + m[6] * nz0
            nz = m[8] * nx0 + m[9] * ny0 + m[10] * nz0
            inv = np.float32(1.0) / max(np.sqrt(nx * nx + ny * ny + nz * nz), np.float32(1e-12))
            nx, ny, nz = nx * inv, ny * inv, nz * inv
            pos[b, 0, v], pos[b, 1, v], pos[b, 2, v] = px, py, pz
            nrm[b, 0, v], nrm[b, 1, v], nrm[b, 2, v] = nx, ny, nz
            lab = labels[v]
            ax, ay, az = carried[b, 0, 0, lab], carried[b, 0, 1, lab], carried[b, 0, 2, lab]
            qx, qy, qz = carried[b, 1, 0, lab], carried[b, 1, 1, lab], carried[b, 1, 2, lab]
            d = ax * nx + ay * ny + az * nz
            ax, ay, az = ax - d * nx, ay - d * ny, az - d * nz
            d = qx * nx + qy * ny + qz * nz
            qx, qy, qz = qx - d * nx, qy - d * ny, qz - d * nz
            wf = min(max(np.sqrt(ax * ax + ay * ay + az * az) * inv_fb + np.float32(1.0), np.float32(0.0)),
                     np.float32(1.0))
            tx, ty, tz = ax + wf * qx, ay + wf * qy, az + wf * qz
            lt = np.sqrt(tx * tx + ty * ty + tz * tz)
            if lt < DEGENERATE_BELOW:  # any perpendicular: n x (the world axis least aligned with n)
                anx, any_, anz = abs(nx), abs(ny), abs(nz)
                if anx <= any_ and anx <= anz:
                    tx, ty, tz = np.float32(0.0), nz, -ny
                elif any_ <= anz:
                    tx, ty, tz = -nz, np.float32(0.0), nx
                else:
                    tx, ty, tz = ny, -nx, np.float32(0.0)
                lt = np.sqrt(tx * tx + ty * ty + tz * tz)
            tx, ty, tz = tx / lt, ty / lt, tz / lt
            frames[b, 0, v], frames[b, 1, v], frames[b, 2, v] = tx, ty, tz
            frames[b, 3, v] = ny * tz - nz * ty
            frames[b, 4, v] = nz * tx - nx * tz
            frames[b, 5, v] = nx * ty - ny * tx
            frames[b, 6, v], frames[b, 7, v], frames[b, 8, v] = nx, ny, nz
            ex, ey, ez = eye[0] - px, eye[1] - py, eye[2] - pz
            inv = np.float32(1.0) / max(np.sqrt(ex * ex + ey * ey + ez * ez), np.float32(1e-12))
            view[b, 0, v], view[b, 1, v], view[b, 2, v] = ex * inv, ey * inv, ez * inv


@numba.njit(cache=True, nogil=True)
def skeleton_pass(parents: np.ndarray, local: np.ndarray, inverse_bind: np.ndarray, bind_rot_t: np.ndarray,
                  feature_joints: np.ndarray, skin: np.ndarray, features: np.ndarray) -> bool:
    """FK, skinning matrices and pose features of ``local (B, J, 4, 4)`` float64 in one pass over the joints.

    ``parents (J,)`` (-1: a root; a parent before its child); ``inverse_bind (J, 4, 4)``; ``bind_rot_t (J, 3, 3)`` the
    transposed :func:`~prt_torch.rig.rotations.rotation_part` of each bind-local transform; ``feature_joints (J',)``
    the joints with features. Writes ``skin (B, J, 4, 4)`` = world @ inverse bind and ``features (B, 6 J')`` float32 -
    :func:`prt_torch.rig.features.pose_features`: the first two columns of ``bind_rot^T @ rotation_part(local)``,
    column by column. Returns ``False`` when a joint's local transform has a zero scale (no rotation to extract)."""
    b_count, j_count = local.shape[0], local.shape[1]
    world = np.empty((j_count, 4, 4))
    rot = np.empty((3, 3))
    for b in range(b_count):
        for j in range(j_count):
            p = parents[j]
            if p < 0:
                world[j] = local[b, j]
            else:
                for r in range(4):
                    for c in range(4):
                        world[j, r, c] = (world[p, r, 0] * local[b, j, 0, c] + world[p, r, 1] * local[b, j, 1, c]
                                          + world[p, r, 2] * local[b, j, 2, c] + world[p, r, 3] * local[b, j, 3, c])
            for r in range(4):
                for c in range(4):
                    skin[b, j, r, c] = (world[j, r, 0] * inverse_bind[j, 0, c] + world[j, r, 1] * inverse_bind[j, 1, c]
                                        + world[j, r, 2] * inverse_bind[j, 2, c]
                                        + world[j, r, 3] * inverse_bind[j, 3, c])
        for f in range(feature_joints.shape[0]):
            j = feature_joints[f]
            for c in range(3):
                nc = np.sqrt(local[b, j, 0, c] ** 2 + local[b, j, 1, c] ** 2 + local[b, j, 2, c] ** 2)
                if not nc > 1e-12:
                    return False
                for r in range(3):
                    rot[r, c] = local[b, j, r, c] / nc
            for c in range(2):
                for r in range(3):
                    features[b, 6 * f + 3 * c + r] = (bind_rot_t[j, r, 0] * rot[0, c] + bind_rot_t[j, r, 1] * rot[1, c]
                                                      + bind_rot_t[j, r, 2] * rot[2, c])
    return True
