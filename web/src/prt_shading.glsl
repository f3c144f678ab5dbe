// prt_shading.glsl - RPO shading with ZH lighting lobes (seed 003 eq. 11), the reference GPU shader of prt_torch.
//
// This file is the document an engine programmer ports. It holds only functions (GLSL ES 3.00); the page's
// vertex shader (shading.js) #defines ORDER, NC, NTERMS, NLOBES and PRT_GAUNT_PRODUCT (plus the optional
// unrolled bodies), includes this file and per vertex calls prtLobesInFrame() then prtRadianceFused() (or
// prtRadianceMatrix() with ?form=matrix), adds prtPeakRadiance() when the lighting has peaks, then prtToneMap().
// It computes exactly what prt_torch.shade.shade_rpo(v, rotate_lobes_to_frames(...), wo, rpo) and the
// exported shading.onnx compute (tests/web checks the page's frame against the Python player's).
//
// CONVENTIONS
//   World: right-handed, z up.
//   SH: real, orthonormal on the sphere, NO Condon-Shortley phase (Ramamoorthi-Hanrahan 2001);
//       flat index i = l*(l+1) + m for band l < ORDER, -l <= m <= l; NC = ORDER*ORDER coefficients.
//       y_l0 = K_l0 P_l^0(z), y_lm = sqrt2 K_lm cos(m phi) P_l^m(z), y_l-m = sqrt2 K_lm sin(m phi) P_l^m(z),
//       K_lm = sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!); band 1 = sqrt(3/(4 pi)) (y, z, x).
//       Evaluated as polynomials: (x + i y)^m = c_m + i s_m, P_l^m = sin^m Q_l^m with the three-term recurrence.
//   Vertex frame F: a 3x3 matrix whose ROWS are (t, b, n) in world coordinates (n = posed smooth normal,
//       t = the cluster's PCA axis carried by its bone, projected into the tangent plane, b = n x t).
//       A world direction w has local coordinates F w = (t.w, b.w, n.w); local +z is the normal.
//   Visibility v[NC]: SH of the binary visibility over the whole sphere in the local frame (the learned model's
//       output: decoded per vertex as mean + sum_k z_k basis_k from the run's per-cluster bases and the latent z
//       onnxruntime-web computes per frame - the page's GPU decode, shading.js - or, for an export without a latent
//       graph, the whole visibility graph's output), or the unshadowed constant (hemisphere indicator / sqrt(4 pi) e_0).
//   Lighting lobes: NLOBES zonal-harmonic lobes (s_k, g_k): unit world axis s_k, band coefficients g_k[l] (RGB),
//       SH coefficients f_lm = g_kl y_lm(s_k) (no sqrt(4 pi/(2l+1)) inside g). In the vertex frame a lobe only
//       moves its axis: l_local[i] = sum_k g_k[band(i)] y_i(F s_k). Light rotation rotates the axes s_k.
//   RPO (radiance-transfer BRDF operator) with NTERMS terms b: M_b (NC x NC) = sum_k u_bk Gamma_{.,.,k}
//       (Gaunt tensor), w_b[NC] the SH of the view factor, tint (RGB). Outgoing radiance toward wo (local):
//           L(wo) = tint * sum_b (w_b . y(wo)) (l . (M_b v))
//       prtRadianceMatrix evaluates it as written: s = sum_b W_b (M_b v), L = tint * sum_i l[i] s[i], W_b = w_b . y(wo)
//       (M in an RGBA32F texture, row b*NC + i = M_b[i][0..NC-1] packed 4 per texel, zero padded);
//       prtRadianceFused (the default) evaluates the same sum with one SH product per vertex (see there).
//       w_b and u_b are uniform arrays indexed b*NC + i; unused terms (zero padding) contribute nothing.

#ifndef ORDER
#error "ORDER (number of SH bands) must be defined"
#endif
#define PRT_PI 3.14159265358979323846

// K_lm (times sqrt 2 for m > 0): the orthonormalisation constant
float prtShNorm(int l, int m) {
  float ratio = 1.0;  // (l-m)! / (l+m)!
  for (int i = l - m + 1; i <= l + m; i++) ratio /= float(i);
  float k = sqrt(float(2 * l + 1) / (4.0 * PRT_PI) * ratio);
  return m > 0 ? k * sqrt(2.0) : k;
}

// y[i] = y_i(d) for the unit direction d (local or world), i = l*(l+1) + m
// (shading.js passes the same recurrence unrolled into straight-line code as PRT_SH_BASIS_UNROLLED: software GL
// runs it ~5x faster than the loops, which index local arrays dynamically; GPUs run either at full speed.)
void prtShBasis(vec3 d, out float y[NC]) {
#ifdef PRT_SH_BASIS_UNROLLED
  PRT_SH_BASIS_UNROLLED
#else
  float c[ORDER];
  float s[ORDER];
  c[0] = 1.0;
  s[0] = 0.0;
  for (int m = 1; m < ORDER; m++) {
    c[m] = c[m - 1] * d.x - s[m - 1] * d.y;
    s[m] = s[m - 1] * d.x + c[m - 1] * d.y;
  }
  for (int m = 0; m < ORDER; m++) {
    float qmm = 1.0;  // Q_m^m = (2m-1)!!
    for (int i = 1; i < 2 * m; i += 2) qmm *= float(i);
    float qPrev2 = 0.0;
    float qPrev = qmm;
    for (int l = m; l < ORDER; l++) {
      float q;
      if (l == m) {
        q = qmm;
      } else if (l == m + 1) {
        q = d.z * float(2 * m + 1) * qmm;
      } else {
        q = (float(2 * l - 1) * d.z * qPrev - float(l + m - 1) * qPrev2) / float(l - m);
      }
      if (l > m) {
        qPrev2 = qPrev;
        qPrev = q;
      }
      float k = prtShNorm(l, m);
      if (m == 0) {
        y[l * (l + 1)] = k * q;
      } else {
        y[l * (l + 1) + m] = k * q * c[m];
        y[l * (l + 1) - m] = k * q * s[m];
      }
    }
  }
#endif
}

int prtBand(int i) {
  return int(floor(sqrt(float(i)) + 1e-4));
}

// local-frame SH lighting of the lobes: l[i] = sum_k g_k[band(i)] y_i(F s_k); F rows (t, b, n)
void prtLobesInFrame(vec3 t, vec3 b, vec3 n, vec3 lobeDir[NLOBES], vec3 lobeG[NLOBES * ORDER], out vec3 l[NC]) {
  for (int i = 0; i < NC; i++) l[i] = vec3(0.0);
  float y[NC];
  for (int k = 0; k < NLOBES; k++) {
    vec3 s = lobeDir[k];
    prtShBasis(vec3(dot(t, s), dot(b, s), dot(n, s)), y);
#ifdef PRT_LOBE_ACCUM_UNROLLED
    PRT_LOBE_ACCUM_UNROLLED  // the same sum with constant indices
#else
    for (int i = 0; i < NC; i++) l[i] += lobeG[k * ORDER + prtBand(i)] * y[i];
#endif
  }
}

// (a x b)_k = sum_ij Gamma_ijk a_i b_j: the SH product projected back to order ORDER (Gamma = real Gaunt
// coefficients, int y_i y_j y_k over the sphere). PRT_GAUNT_PRODUCT is the Gaunt table unrolled into straight-line
// code, one statement per non-zero (i, j, k) - every index permutation - of prt_torch.sh.product.gaunt_tensor(ORDER):
//     q[k] += Gamma_ijk * a[i] * b[j];        (353 statements at order 4; shading.js writes it from the manifest)
void prtShProduct(float a[NC], float b[NC], out float q[NC]) {
  for (int k = 0; k < NC; k++) q[k] = 0.0;
  PRT_GAUNT_PRODUCT
}

// eq. 11, fused evaluation order (the page's default): with W_b = w_b . y(wo),
//     u~ = sum_b W_b u_b,   q = u~ x v,   L = tint * sum_i l[i] q[i]
// equal to prtRadianceMatrix because Gamma is symmetric: l . (M(u_b) v) = u_b . (l x v) = l . (u_b x v).
// u_b[NC] (the light factor's SH; M_b = sum_k u_bk Gamma_.,.,k) in the uniform array rpoU[b*NC + i].
vec3 prtRadianceFused(float v[NC], vec3 l[NC], vec3 wo, float rpoU[NTERMS * NC], float rpoW[NTERMS * NC], vec3 tint) {
  float yo[NC];
  prtShBasis(wo, yo);
  float u[NC];
  for (int i = 0; i < NC; i++) u[i] = 0.0;
  for (int bt = 0; bt < NTERMS; bt++) {
    float W = 0.0;
    for (int i = 0; i < NC; i++) W += rpoW[bt * NC + i] * yo[i];
    for (int i = 0; i < NC; i++) u[i] += W * rpoU[bt * NC + i];
  }
  float q[NC];
  prtShProduct(u, v, q);
  vec3 L = vec3(0.0);
  for (int i = 0; i < NC; i++) L += l[i] * q[i];
  return tint * L;
}

#ifdef PRT_MATRIX_FORM
// eq. 11 as written (k matrix-vector products, NTERMS*NC*NC multiply-adds per vertex): radiance toward the local
// view direction wo, for visibility v and local lighting l. Selected by the page's ?form=matrix.
vec3 prtRadianceMatrix(float v[NC], vec3 l[NC], vec3 wo, highp sampler2D rpoM, float rpoW[NTERMS * NC], vec3 tint) {
  float yo[NC];
  prtShBasis(wo, yo);
  float s[NC];
  for (int i = 0; i < NC; i++) s[i] = 0.0;
  const int TEXELS = (NC + 3) / 4;
  for (int bt = 0; bt < NTERMS; bt++) {
    float W = 0.0;  // W_b = w_b . y(wo)
    for (int i = 0; i < NC; i++) W += rpoW[bt * NC + i] * yo[i];
    if (W == 0.0) continue;  // zero-padded terms
    for (int i = 0; i < NC; i++) {
      float mv = 0.0;  // (M_b v)_i
      for (int q = 0; q < TEXELS; q++) {
        vec4 m = texelFetch(rpoM, ivec2(q, bt * NC + i), 0);
        int j = 4 * q;
        mv += m.x * v[j];
        if (j + 1 < NC) mv += m.y * v[j + 1];
        if (j + 2 < NC) mv += m.z * v[j + 2];
        if (j + 3 < NC) mv += m.w * v[j + 3];
      }
      s[i] += W * mv;
    }
  }
  vec3 L = vec3(0.0);
  for (int i = 0; i < NC; i++) L += l[i] * s[i];
  return tint * L;
}
#endif

// -- peak lights (issue 27): the sun and other small bright discs, shaded apart from the SH path ---------------------
//   Per peak p (at most PRT_MAX_PEAKS): unit world direction s_p (towards the light), RGB power E_p (radiance x the
//   disc's solid angle) and the disc's visible fraction V_p in [0, 1] per vertex (the run's peaks.onnx in
//   onnxruntime-web; its angular radius enters there). Reflected radiance toward wo (local), with the analytic BRDF
//   the RPO was built from (prt_torch.brdf.analytic, tint the RPO's):
//       L_peaks(wo) = tint * sum_p E_p s(wi_p, wo) max(wi_p.z, 0) V_p,   wi_p = F s_p
//   what prt_torch.brdf.direct.peak_radiance computes. With peaks on, the SH path shades the residual lighting (the
//   lighting without its peaks) and the two add.
#define PRT_MAX_PEAKS 4
#define PRT_BRDF_LAMBERT 0
#define PRT_BRDF_PHONG 1
#define PRT_BRDF_BLINN 2
#define PRT_BRDF_COOK_TORRANCE 3
#define PRT_BRDF_WARD 4

// the BRDF shape s(wi, wo) (no tint) of prt_torch.brdf.analytic, local unit directions; 0 below either horizon.
// prm = (kd, ks, p1, p2): Lambert (1, 0, 0, 0) [shape 1/pi]; Phong (kd, ks, exponent, 0); Blinn-Phong (kd, ks,
// exponent, norm); Cook-Torrance (kd, ks, alpha = roughness^2, f0); Ward (kd, ks, alpha, 0).
float prtBrdfShape(int kind, vec4 prm, vec3 wi, vec3 wo) {
  if (wi.z <= 0.0 || wo.z <= 0.0) return 0.0;
  float diffuse = prm.x / PRT_PI;
  if (kind == PRT_BRDF_PHONG) {  // normalised modified Phong: mirror of wo about the normal
    float c = max(-wi.x * wo.x - wi.y * wo.y + wi.z * wo.z, 0.0);
    return diffuse + prm.y * (prm.z + 2.0) / (2.0 * PRT_PI) * pow(c, prm.z);
  }
  vec3 h = wi + wo;
  float hl = length(h);
  h = hl > 0.0 ? h / hl : h;
  if (kind == PRT_BRDF_BLINN) {
    return diffuse + prm.y * prm.w * pow(max(h.z, 0.0), prm.z);
  }
  if (kind == PRT_BRDF_COOK_TORRANCE) {  // GGX D, separable Smith G, Schlick F
    float a2 = prm.z * prm.z;
    float ch = max(h.z, 0.0);
    float dd = ch * ch * (a2 - 1.0) + 1.0;
    float D = a2 / (PRT_PI * dd * dd);
    float ci = wi.z, co = wo.z;
    float G = 2.0 * ci / (ci + sqrt(a2 + (1.0 - a2) * ci * ci)) * 2.0 * co / (co + sqrt(a2 + (1.0 - a2) * co * co));
    float F = prm.w + (1.0 - prm.w) * pow(1.0 - clamp(dot(wi, h), 0.0, 1.0), 5.0);
    return diffuse + prm.y * D * G * F / (4.0 * ci * co);
  }
  if (kind == PRT_BRDF_WARD) {
    float c2 = max(h.z, 1e-12);
    c2 *= c2;
    float a2 = prm.z * prm.z;
    return diffuse + prm.y * exp(-((1.0 - c2) / c2) / a2) / (4.0 * PRT_PI * a2 * sqrt(wi.z * wo.z));
  }
  return diffuse;  // Lambert: kd = 1
}

// L_peaks(wo) above: frame rows (t, b, n), peak directions / powers, per-vertex visibility vis[p] (nPeaks <= 4)
vec3 prtPeakRadiance(vec3 t, vec3 b, vec3 n, vec3 wo, int nPeaks, vec3 peakDir[PRT_MAX_PEAKS],
                     vec3 peakPower[PRT_MAX_PEAKS], vec4 vis, int kind, vec4 prm, vec3 tint) {
  vec3 L = vec3(0.0);
  for (int p = 0; p < PRT_MAX_PEAKS; p++) {
    if (p >= nPeaks) break;
    vec3 s = peakDir[p];
    vec3 wi = vec3(dot(t, s), dot(b, s), dot(n, s));
    L += peakPower[p] * (prtBrdfShape(kind, prm, wi, wo) * max(wi.z, 0.0) * vis[p]);
  }
  return tint * L;
}

// the player's tone map (prt_torch.player.tonemap): exposure, Reinhard's extended curve, gamma; radiance < 0 -> 0
vec3 prtToneMap(vec3 radiance, float exposure, float white, float gamma) {
  vec3 x = max(radiance * exposure, 0.0);
  x = x * (1.0 + x / (white * white)) / (1.0 + x);
  return pow(min(x, 1.0), vec3(1.0 / gamma));
}
