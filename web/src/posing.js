// Posing in JS: FK, LBS, vertex frames and pose features, the rule of prt_torch.player.posing.Poser
// (numpy reference: prt_torch.rig.skeleton.forward_kinematics, rig.skinning, rig.vertex_frames.vertex_frames,
// rig.features.pose_features). Matrices are row-major 4x4 float64 (Float64Array(16) per joint); per-vertex
// outputs are float32, vertex-major: positions/normals (V, 3), frames (V, 9) with entry 3i + j = F[i][j],
// rows (t, b, n). tests/web/test_posing_parity.py checks every output against the numpy reference.

export const FALLBACK_BELOW = 0.3;   // rig.vertex_frames.FALLBACK_BELOW
export const DEGENERATE_BELOW = 1e-6; // rig.vertex_frames.DEGENERATE_BELOW

function matmul4(a, ao, b, bo, out, oo) {
  for (let i = 0; i < 4; i++) {
    for (let j = 0; j < 4; j++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[ao + 4 * i + k] * b[bo + 4 * k + j];
      out[oo + 4 * i + j] = s;
    }
  }
}

// rotation_part: the 3x3 block with its columns normalised (scale removed)
function rotationPart(m, o) {
  const r = new Float64Array(9);
  for (let j = 0; j < 3; j++) {
    const n = Math.hypot(m[o + j], m[o + 4 + j], m[o + 8 + j]);
    for (let i = 0; i < 3; i++) r[3 * i + j] = m[o + 4 * i + j] / n;
  }
  return r;
}

// fallback_axes: cross(a, e) with e the world axis least aligned with a (first minimum, as np.argmin)
export function fallbackAxis(a) {
  const ab = [Math.abs(a[0]), Math.abs(a[1]), Math.abs(a[2])];
  let k = 0;
  if (ab[1] < ab[k]) k = 1;
  if (ab[2] < ab[k]) k = 2;
  const e = [0, 0, 0]; e[k] = 1;
  const p = [a[1] * e[2] - a[2] * e[1], a[2] * e[0] - a[0] * e[2], a[0] * e[1] - a[1] * e[0]];
  const n = Math.hypot(p[0], p[1], p[2]);
  return [p[0] / n, p[1] / n, p[2] / n];
}

export class Poser {
  // arrays: rest_vertices (V*3 f32), rest_normals, skin_joints (V*K u32), skin_weights (V*K f32),
  // bind_local, inverse_bind (J*16 f64), cluster (V u32), cluster_axis (Kc*3 f32), cluster_bone (Kc u32)
  constructor(parents, arrays, nInfluences) {
    this.parents = Int32Array.from(parents);
    this.J = this.parents.length;
    this.rest = arrays.rest_vertices;
    this.restN = arrays.rest_normals;
    this.V = this.rest.length / 3;
    this.K = nInfluences;
    this.joints = arrays.skin_joints;
    this.weights = arrays.skin_weights;
    this.inverseBind = arrays.inverse_bind;
    this.labels = arrays.cluster;
    this.bones = arrays.cluster_bone;
    const kc = this.bones.length;
    this.axes = new Float64Array(kc * 3);
    this.fallback = new Float64Array(kc * 3);
    for (let c = 0; c < kc; c++) {
      const a = [arrays.cluster_axis[3 * c], arrays.cluster_axis[3 * c + 1], arrays.cluster_axis[3 * c + 2]];
      this.axes.set(a, 3 * c);
      this.fallback.set(fallbackAxis(a), 3 * c);
    }
    // pose features: non-root joints in index order, rel = R_bind^T R_local, columns 0 and 1
    this.featureJoints = [];
    for (let j = 0; j < this.J; j++) if (this.parents[j] >= 0) this.featureJoints.push(j);
    this.bindRot = [];
    for (let j = 0; j < this.J; j++) this.bindRot.push(rotationPart(arrays.bind_local, 16 * j));
    this.nFeatures = 6 * this.featureJoints.length;
    this.world = new Float64Array(this.J * 16);
    this.skin = new Float64Array(this.J * 16);
    this.skin32 = new Float32Array(this.J * 12);
    this.ap = new Float32Array(kc * 6); // per cluster: carried axis a (3), fallback p (3), float32 as the reference
  }

  // clip frame (F, J, 12) float32 rows 0..2 of each local 4x4 -> Float64Array(J*16)
  static localFromClip(clip, frame, J) {
    const out = new Float64Array(J * 16);
    const base = frame * J * 12;
    for (let j = 0; j < J; j++) {
      for (let e = 0; e < 12; e++) out[16 * j + e] = clip[base + 12 * j + e];
      out[16 * j + 15] = 1;
    }
    return out;
  }

  features(local) {
    const f = new Float32Array(this.nFeatures);
    this.featureJoints.forEach((j, i) => {
      const b = this.bindRot[j];
      const r = rotationPart(local, 16 * j);
      for (let col = 0; col < 2; col++) {
        for (let row = 0; row < 3; row++) {
          // (B^T R)[row][col] = sum_k B[k][row] R[k][col]
          f[6 * i + 3 * col + row] = b[row] * r[col] + b[3 + row] * r[3 + col] + b[6 + row] * r[6 + col];
        }
      }
    });
    return f;
  }

  // positions (V*3), normals (V*3), frames (V*9): float32 outputs written into `out` (allocated when absent)
  pose(local, out) {
    const { J, V, K, parents } = this;
    const world = this.world, skin = this.skin, s32 = this.skin32;
    for (let j = 0; j < J; j++) {
      if (parents[j] < 0) world.set(local.subarray(16 * j, 16 * j + 16), 16 * j);
      else matmul4(world, 16 * parents[j], local, 16 * j, world, 16 * j);
      matmul4(world, 16 * j, this.inverseBind, 16 * j, skin, 16 * j);
      for (let e = 0; e < 12; e++) s32[12 * j + e] = skin[16 * j + e];
    }
    out = out || { positions: new Float32Array(V * 3), normals: new Float32Array(V * 3), frames: new Float32Array(V * 9) };
    // cluster axes carried by their dominant bones (float64, normalised, then float32)
    const kc = this.bones.length, ap = this.ap;
    for (let c = 0; c < kc; c++) {
      const o = 16 * this.bones[c];
      for (let h = 0; h < 2; h++) {
        const src = h === 0 ? this.axes : this.fallback;
        const x = src[3 * c], y = src[3 * c + 1], z = src[3 * c + 2];
        const r0 = skin[o] * x + skin[o + 1] * y + skin[o + 2] * z;
        const r1 = skin[o + 4] * x + skin[o + 5] * y + skin[o + 6] * z;
        const r2 = skin[o + 8] * x + skin[o + 9] * y + skin[o + 10] * z;
        const n = Math.max(Math.sqrt(r0 * r0 + r1 * r1 + r2 * r2), 1e-12);
        ap[6 * c + 3 * h] = r0 / n; ap[6 * c + 3 * h + 1] = r1 / n; ap[6 * c + 3 * h + 2] = r2 / n;
      }
    }
    const P = out.positions, N = out.normals, Fr = out.frames;
    const rest = this.rest, restN = this.restN, jt = this.joints, wt = this.weights, lab = this.labels;
    const m = new Float64Array(12);
    for (let v = 0; v < V; v++) {
      m.fill(0);
      for (let k = 0; k < K; k++) {
        const w = wt[v * K + k];
        if (w === 0) continue;
        const o = 12 * jt[v * K + k];
        for (let e = 0; e < 12; e++) m[e] += w * s32[o + e];
      }
      const x = rest[3 * v], y = rest[3 * v + 1], z = rest[3 * v + 2];
      const nx0 = restN[3 * v], ny0 = restN[3 * v + 1], nz0 = restN[3 * v + 2];
      P[3 * v] = m[0] * x + m[1] * y + m[2] * z + m[3];
      P[3 * v + 1] = m[4] * x + m[5] * y + m[6] * z + m[7];
      P[3 * v + 2] = m[8] * x + m[9] * y + m[10] * z + m[11];
      let nx = m[0] * nx0 + m[1] * ny0 + m[2] * nz0;
      let ny = m[4] * nx0 + m[5] * ny0 + m[6] * nz0;
      let nz = m[8] * nx0 + m[9] * ny0 + m[10] * nz0;
      const nl = 1 / Math.max(Math.sqrt(nx * nx + ny * ny + nz * nz), 1e-12);
      nx *= nl; ny *= nl; nz *= nl;
      N[3 * v] = nx; N[3 * v + 1] = ny; N[3 * v + 2] = nz;
      // vertex frame: t = ta + w tp, w = clip(1 - |ta| / FALLBACK_BELOW, 0, 1), b = n x t
      const c = 6 * lab[v];
      const ax = ap[c], ay = ap[c + 1], az = ap[c + 2], px = ap[c + 3], py = ap[c + 4], pz = ap[c + 5];
      const da = ax * nx + ay * ny + az * nz, dp = px * nx + py * ny + pz * nz;
      const tax = ax - da * nx, tay = ay - da * ny, taz = az - da * nz;
      const tpx = px - dp * nx, tpy = py - dp * ny, tpz = pz - dp * nz;
      const la = Math.sqrt(tax * tax + tay * tay + taz * taz);
      const w = Math.min(Math.max(1 - la / FALLBACK_BELOW, 0), 1);
      let tx = tax + w * tpx, ty = tay + w * tpy, tz = taz + w * tpz;
      let lt = Math.sqrt(tx * tx + ty * ty + tz * tz);
      if (lt < DEGENERATE_BELOW) { // measure-zero coincidence: t = n x e_k, e_k the axis least aligned with n
        const ab = [Math.abs(nx), Math.abs(ny), Math.abs(nz)];
        let k = 0; if (ab[1] < ab[k]) k = 1; if (ab[2] < ab[k]) k = 2;
        const ek = [0, 0, 0]; ek[k] = 1;
        tx = ny * ek[2] - nz * ek[1]; ty = nz * ek[0] - nx * ek[2]; tz = nx * ek[1] - ny * ek[0];
        lt = Math.sqrt(tx * tx + ty * ty + tz * tz);
      }
      tx /= lt; ty /= lt; tz /= lt;
      const o9 = 9 * v;
      Fr[o9] = tx; Fr[o9 + 1] = ty; Fr[o9 + 2] = tz;
      Fr[o9 + 3] = ny * tz - nz * ty; Fr[o9 + 4] = nz * tx - nx * tz; Fr[o9 + 5] = nx * ty - ny * tx;
      Fr[o9 + 6] = nx; Fr[o9 + 7] = ny; Fr[o9 + 8] = nz;
    }
    return out;
  }
}
