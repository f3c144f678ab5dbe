// The three.js material that runs prt_shading.glsl per vertex (RawShaderMaterial, GLSL ES 3.00).
//
// TEXEL LAYOUT (the one rule of every per-vertex texture, texelLayout below; the shader's prtItemTexel is the same
// formula): item i (a vertex of the basis texture, instance * V + vertex of the state texture) owns P consecutive
// RGBA texels; a row of the texture holds R = floor(W / P) items (width R P <= W); texel p of item i sits at
//     (x, y) = ((i % R) P + p, floor(i / R)),   flat texel index y (R P) + x = i P + p,
// so a texture's data is its items' texels back to back (the site writes the GPU decode's bases that way) and a
// character of n items needs ceil(n / R) <= MAX_TEXTURE_SIZE rows: W = min(4096, MAX_TEXTURE_SIZE), or ?texwidth=W
// (tests: a narrow W puts a small character on many rows).
//
// Per-frame state (RGBA32F): per item P = 5 texels with the GPU decode - position, t, b, n (xyz each), the visible
// fractions of the (up to 4) peak lights - and, without it (an export with no latent graph: the page runs the whole
// visibility graph), the NC visibility coefficients after them, packed 4 per texel (P = 5 + ceil(NC / 4)).
//
// GPU decode (PRT_GPU_DECODE): the basis texture (RGBA16F, static) holds per vertex P = T (K + 1) texels, T =
// ceil(NC / 4): the mean, then the vertex's cluster's K basis rows (prt_torch.web.site.decode_texture); the latent
// texture (RGBA32F, per frame) holds z: row c * G + g = character c's cluster row g, ceil(Kz / 4) texels of its
// rounded latent (the CPU path's int8 rounding, main.js quantizeLatent). The vertex shader forms
//     vis = mean + sum_{k < k_used} z[row, k] basis_k          (prtDecodeVisibility)
// and shades as before.
//
// A frame is two passes: makeMaterial(..., {radianceOut: true}) decodes and shades each vertex once, drawing item i
// (instance * V + vertex) as one point at pixel (i % RADIANCE_WIDTH, i / RADIANCE_WIDTH) of a float target, its
// radiance before the base colour (also window.prt.radiance's readback); makeMaterial(..., {fromRadiance: true})
// then draws the mesh, each corner fetching its vertex's radiance from that target (a vertex shared by 6 triangles
// is shaded once, not once per corner: software GL has no post-transform cache to lean on).
import * as THREE from 'three';

export const TEXTURE_WIDTH = 4096;
export const RADIANCE_WIDTH = 1024;
export const PEAK_TEXEL = 4;
export const VIS_TEXEL = 5;
export const MAX_PEAKS = 4;

// the texel layout of n items of P texels each in textures at most `width` wide (the rule above); `maxSize` the
// context's MAX_TEXTURE_SIZE: more rows than that is an error naming the sizes
export function texelLayout(nItems, P, width = TEXTURE_WIDTH, maxSize = Infinity, what = 'a per-vertex texture') {
  const W = Math.min(width, maxSize);
  if (!(P <= W)) throw new Error(`${what}: ${P} texels per vertex do not fit a texture row of ${W} texels`);
  const R = Math.floor(W / P);
  const rows = Math.max(1, Math.ceil(nItems / R));
  if (rows > maxSize) throw new Error(`${what}: ${nItems} vertices need ${rows} rows of ${R}, more than MAX_TEXTURE_SIZE ${maxSize}`);
  return { P, R, width: R * P, height: rows };
}

export function stateLayout(nItems, nCoeffs, gpuDecode = false, width = TEXTURE_WIDTH, maxSize = Infinity) {
  return texelLayout(nItems, VIS_TEXEL + (gpuDecode ? 0 : Math.ceil(nCoeffs / 4)), width, maxSize, 'the state texture');
}

const PRECISION = 'precision highp float;\nprecision highp int;\nprecision highp sampler2D;\n';

const VERTEX = `
uniform mat4 modelViewMatrix;
uniform mat4 projectionMatrix;
uniform highp sampler2D u_state;
uniform highp sampler2D u_rpoM;
uniform float u_rpoW[NTERMS * NC];
uniform float u_rpoU[NTERMS * NC];
uniform vec3 u_tint;
uniform vec3 u_lobeDir[NLOBES];
uniform vec3 u_lobeG[NLOBES * ORDER];
uniform vec3 u_eye;
uniform bool u_unshadowed;
uniform float u_unshadowedVis[NC];
uniform float u_exposure;
uniform float u_white;
uniform float u_gamma;
uniform bool u_perPixel;
uniform vec3 u_baseFactor;
uniform int u_nPeaks;
uniform vec3 u_peakDir[PRT_MAX_PEAKS];
uniform vec3 u_peakPower[PRT_MAX_PEAKS];
uniform int u_brdfKind;
uniform vec4 u_brdfParams;
uniform int u_radianceRows;
uniform int u_nVertices;
uniform highp sampler2D u_radianceTex;
#ifdef PRT_GPU_DECODE
uniform highp sampler2D u_basis;
uniform highp sampler2D u_latent;
in vec2 a_decode;  // (the vertex's row of z, its cluster's k_used)
#endif
in vec3 position;
in float a_vid;
in float a_instance;
in vec2 a_uv;
in vec3 a_base;
out vec3 v_color;
out vec3 v_radiance;
out vec2 v_uv;

// texel p of item i of a texture laid out with P texels per item, R items per row (shading.js texelLayout)
ivec2 prtItemTexel(int i, int p, int P, int R) {
  return ivec2((i % R) * P + p, i / R);
}

vec4 stateTexel(int item, int p) {
  return texelFetch(u_state, prtItemTexel(item, p, STATE_P, STATE_R), 0);
}

#define PRT_T ((NC + 3) / 4)
#ifdef PRT_GPU_DECODE
// vis = mean + sum_k z[row, k] basis_k of vertex vid, character inst (the module doc)
void prtDecodeVisibility(int vid, int inst, out float vis[NC]) {
  int row = int(a_decode.x + 0.5);
  int kUsed = int(a_decode.y + 0.5);
  int zRow = inst * LATENT_ROWS + row;
  vec4 acc[PRT_T];
  for (int q = 0; q < PRT_T; q++) acc[q] = texelFetch(u_basis, prtItemTexel(vid, q, BASIS_P, BASIS_R), 0);
  for (int k = 0; k < kUsed; k++) {
    float z = texelFetch(u_latent, ivec2(k / 4, zRow), 0)[k % 4];
    for (int q = 0; q < PRT_T; q++) acc[q] += z * texelFetch(u_basis, prtItemTexel(vid, (k + 1) * PRT_T + q, BASIS_P, BASIS_R), 0);
  }
  for (int q = 0; q < PRT_T; q++) {
    int j = 4 * q;
    vis[j] = acc[q].x;
    if (j + 1 < NC) vis[j + 1] = acc[q].y;
    if (j + 2 < NC) vis[j + 2] = acc[q].z;
    if (j + 3 < NC) vis[j + 3] = acc[q].w;
  }
}
#endif

void main() {
  int vid = int(a_vid + 0.5);
  int inst = int(a_instance + 0.5);
  int item = inst * u_nVertices + vid;
#ifdef PRT_FROM_RADIANCE
  // the frame's second pass: the radiance the first (one point per vertex) shaded, fetched per corner
  vec3 pos = stateTexel(item, 0).xyz;
  vec3 L = texelFetch(u_radianceTex, ivec2(item % RADIANCE_WIDTH, item / RADIANCE_WIDTH), 0).rgb;
  L *= u_perPixel ? u_baseFactor : a_base;
  v_radiance = L;
  v_uv = a_uv;
  v_color = floor(prtToneMap(L, u_exposure, u_white, u_gamma) * 255.0 + 0.5) / 255.0;
  gl_Position = projectionMatrix * modelViewMatrix * vec4(pos, 1.0);
#else
  vec3 pos = stateTexel(item, 0).xyz;
  vec3 t = stateTexel(item, 1).xyz;
  vec3 b = stateTexel(item, 2).xyz;
  vec3 n = stateTexel(item, 3).xyz;
  float vis[NC];
  if (!u_unshadowed) {
#ifdef PRT_GPU_DECODE
    prtDecodeVisibility(vid, inst, vis);
#else
    for (int q = 0; q < PRT_T; q++) {
      vec4 c = stateTexel(item, VIS_TEXEL + q);
      int j = 4 * q;
      vis[j] = c.x;
      if (j + 1 < NC) vis[j + 1] = c.y;
      if (j + 2 < NC) vis[j + 2] = c.z;
      if (j + 3 < NC) vis[j + 3] = c.w;
    }
#endif
  }
  if (u_unshadowed) {
    for (int i = 0; i < NC; i++) vis[i] = u_unshadowedVis[i];
  }
  vec3 l[NC];
  prtLobesInFrame(t, b, n, u_lobeDir, u_lobeG, l);
  vec3 view = u_eye - pos;
  view /= max(length(view), 1e-12);
  vec3 wo = vec3(dot(t, view), dot(b, view), dot(n, view));
  vec3 base = u_perPixel ? u_baseFactor : a_base;
#ifdef PRT_MATRIX_FORM
  vec3 L = prtRadianceMatrix(vis, l, wo, u_rpoM, u_rpoW, u_tint);
#else
  vec3 L = prtRadianceFused(vis, l, wo, u_rpoU, u_rpoW, u_tint);
#endif
  if (u_nPeaks > 0) {
    vec4 peakVis = u_unshadowed ? vec4(1.0) : stateTexel(item, PEAK_TEXEL);
    L += prtPeakRadiance(t, b, n, wo, u_nPeaks, u_peakDir, u_peakPower, peakVis, u_brdfKind, u_brdfParams, u_tint);
  }
#ifdef PRT_RADIANCE_OUT
  v_radiance = L;  // before the base colour; one point per vertex
  v_color = vec3(0.0);
  v_uv = a_uv;
  gl_PointSize = 1.0;
  gl_Position = vec4((float(item % RADIANCE_WIDTH) + 0.5) / float(RADIANCE_WIDTH) * 2.0 - 1.0,
                     (float(item / RADIANCE_WIDTH) + 0.5) / float(u_radianceRows) * 2.0 - 1.0, 0.0, 1.0);
#else
  L *= base;
  v_radiance = L;
  v_uv = a_uv;
  // 8-bit colours per vertex, interpolated over the triangle: what the Python player's renderer shows
  v_color = floor(prtToneMap(L, u_exposure, u_white, u_gamma) * 255.0 + 0.5) / 255.0;
  gl_Position = projectionMatrix * modelViewMatrix * vec4(pos, 1.0);
#endif
#endif
}
`;

const FRAGMENT = `
uniform bool u_perPixel;
uniform sampler2D u_baseTex;
uniform float u_exposure;
uniform float u_white;
uniform float u_gamma;
in vec3 v_color;
in vec3 v_radiance;
in vec2 v_uv;
out vec4 fragColor;

void main() {
#ifdef PRT_RADIANCE_OUT
  fragColor = vec4(v_radiance, 1.0);
  return;
#endif
  if (u_perPixel) {
    vec3 base = texture(u_baseTex, v_uv).rgb;  // linear: the texture is sRGB-decoded by the sampler
    fragColor = vec4(prtToneMap(v_radiance * base, u_exposure, u_white, u_gamma), 1.0);
  } else {
    fragColor = vec4(v_color, 1.0);
  }
}
`;

// the Gaunt table {i, j, k, g} unrolled: "q[k] += g * a[i] * b[j];" per non-zero (prtShProduct's body)
export function gauntProduct(gaunt) {
  const out = [];
  for (let n = 0; n < gaunt.g.length; n++) {
    out.push(`q[${gaunt.k[n]}] += ${gaunt.g[n].toPrecision(9)} * a[${gaunt.i[n]}] * b[${gaunt.j[n]}];`);
  }
  return out.join(' ');
}

// prtShBasis's recurrence (prt_torch.sh.basis.sh_basis) unrolled: one statement per value, constant indices
export function shBasisUnrolled(order) {
  const st = ['float c0 = 1.0; float s0 = 0.0;'];
  for (let m = 1; m < order; m++) {
    st.push(`float c${m} = c${m - 1} * d.x - s${m - 1} * d.y; float s${m} = s${m - 1} * d.x + c${m - 1} * d.y;`);
  }
  for (let m = 0; m < order; m++) {
    let qmm = 1;
    for (let i = 1; i < 2 * m; i += 2) qmm *= i;
    for (let l = m; l < order; l++) {
      let q;
      if (l === m) q = `${qmm.toFixed(1)}`;
      else if (l === m + 1) q = `d.z * ${((2 * m + 1) * qmm).toFixed(1)}`;
      else q = `(${(2 * l - 1).toFixed(1)} * d.z * q${l - 1}_${m} - ${(l + m - 1).toFixed(1)} * q${l - 2}_${m}) / ${(l - m).toFixed(1)}`;
      st.push(`float q${l}_${m} = ${q};`);
      let ratio = 1;
      for (let i = l - m + 1; i <= l + m; i++) ratio /= i;
      let k = Math.sqrt((2 * l + 1) / (4 * Math.PI) * ratio);
      if (m > 0) k *= Math.SQRT2;
      const ks = k.toPrecision(12);
      if (m === 0) st.push(`y[${l * (l + 1)}] = ${ks} * q${l}_0;`);
      else st.push(`y[${l * (l + 1) + m}] = ${ks} * q${l}_${m} * c${m}; y[${l * (l + 1) - m}] = ${ks} * q${l}_${m} * s${m};`);
    }
  }
  return st.join(' ');
}

export function lobeAccumUnrolled(order) {
  const st = [];
  for (let l = 0; l < order; l++) {
    for (let i = l * l; i < (l + 1) * (l + 1); i++) st.push(`l[${i}] += lobeG[k * ORDER + ${l}] * y[${i}];`);
  }
  return st.join(' ');
}

// layout: the state texture's; options.decode: {layout (the basis texture's), latentRows (G)} for PRT_GPU_DECODE
export function makeMaterial(glsl, sizes, layout, gaunt, matrixForm = false, options = {}) {
  const dec = options.decode;
  const defines = PRECISION + `#define ORDER ${sizes.order}\n#define NC ${sizes.order * sizes.order}\n` +
    `#define NTERMS ${sizes.nTerms}\n#define NLOBES ${sizes.nLobes}\n` +
    `#define STATE_P ${layout.P}\n#define STATE_R ${layout.R}\n` +
    (dec ? `#define PRT_GPU_DECODE\n#define BASIS_P ${dec.layout.P}\n#define BASIS_R ${dec.layout.R}\n` +
      `#define LATENT_ROWS ${dec.latentRows}\n` : '') +
    `#define PEAK_TEXEL ${PEAK_TEXEL}\n#define VIS_TEXEL ${VIS_TEXEL}\n#define RADIANCE_WIDTH ${RADIANCE_WIDTH}\n` +
    (options.radianceOut ? '#define PRT_RADIANCE_OUT\n' : '') + (options.fromRadiance ? '#define PRT_FROM_RADIANCE\n' : '') +
    `#define PRT_GAUNT_PRODUCT ${gauntProduct(gaunt)}\n` +
    `#define PRT_SH_BASIS_UNROLLED ${shBasisUnrolled(sizes.order)}\n` +
    `#define PRT_LOBE_ACCUM_UNROLLED ${lobeAccumUnrolled(sizes.order)}\n` + (matrixForm ? '#define PRT_MATRIX_FORM\n' : '');
  const nc = sizes.order * sizes.order;
  const uniforms = options.uniforms || {
    u_state: { value: null },
    u_rpoM: { value: null },
    u_rpoW: { value: new Float32Array(sizes.nTerms * nc) },
    u_rpoU: { value: new Float32Array(sizes.nTerms * nc) },
    u_tint: { value: new THREE.Vector3(1, 1, 1) },
    u_lobeDir: { value: Array.from({ length: sizes.nLobes }, () => new THREE.Vector3(0, 0, 1)) },
    u_lobeG: { value: Array.from({ length: sizes.nLobes * sizes.order }, () => new THREE.Vector3()) },
    u_eye: { value: new THREE.Vector3() },
    u_unshadowed: { value: false },
    u_unshadowedVis: { value: new Float32Array(nc) },
    u_exposure: { value: 1 },
    u_white: { value: 1 },
    u_gamma: { value: 2.2 },
    u_perPixel: { value: false },
    u_baseFactor: { value: new THREE.Vector3(1, 1, 1) },
    u_baseTex: { value: null },
    u_nPeaks: { value: 0 },
    u_peakDir: { value: Array.from({ length: MAX_PEAKS }, () => new THREE.Vector3(0, 0, 1)) },
    u_peakPower: { value: Array.from({ length: MAX_PEAKS }, () => new THREE.Vector3()) },
    u_brdfKind: { value: 0 },
    u_brdfParams: { value: new THREE.Vector4(1, 0, 0, 0) },
    u_radianceRows: { value: 1 },
    u_nVertices: { value: 0 },
    u_basis: { value: null },
    u_radianceTex: { value: null },
    u_latent: { value: null },
  };
  return new THREE.RawShaderMaterial({
    glslVersion: THREE.GLSL3,
    uniforms,
    vertexShader: defines + glsl + VERTEX,
    fragmentShader: defines + glsl + FRAGMENT,
    side: THREE.DoubleSide,
  });
}

// RPO M (k, C, C) float32 -> RGBA32F texture, row b*C + i = M_b[i][:], 4 per texel, zero padded
export function rpoTexture(M, nTerms, nc) {
  const texels = Math.ceil(nc / 4);
  const data = new Float32Array(texels * 4 * nTerms * nc);
  for (let r = 0; r < nTerms * nc; r++) {
    for (let j = 0; j < nc; j++) data[r * texels * 4 + j] = M[r * nc + j];
  }
  const tex = new THREE.DataTexture(data, texels, nTerms * nc, THREE.RGBAFormat, THREE.FloatType);
  tex.minFilter = tex.magFilter = THREE.NearestFilter;
  tex.generateMipmaps = false;
  tex.needsUpdate = true;
  return tex;
}

// a float texture (RGBA, nearest, no mipmaps) of `layout` from `data` (its items' texels back to back, shorter than
// width * height * 4: zero padded here): Float32Array -> RGBA32F, Uint16Array (float16 bits) -> RGBA16F
export function itemTexture(data, layout) {
  const n = layout.width * layout.height * 4;
  const half = data instanceof Uint16Array;
  let full = data;
  if (data.length !== n) {
    full = half ? new Uint16Array(n) : new Float32Array(n);
    full.set(data.subarray(0, Math.min(data.length, n)));
  }
  const tex = new THREE.DataTexture(full, layout.width, layout.height, THREE.RGBAFormat, half ? THREE.HalfFloatType : THREE.FloatType);
  tex.minFilter = tex.magFilter = THREE.NearestFilter;
  tex.generateMipmaps = false;
  tex.needsUpdate = true;
  return tex;
}
