// The browser player: assets -> posing (posing.js) -> onnxruntime-web: the run's latent graph (pose -> z per cluster;
// the GPU decode, below) or, for an export without one, the whole visibility graph (and, for a lighting with peak
// lights, the run's peaks.onnx: each peak's visible fraction per vertex) -> upload -> the vertex shader decodes the
// visibility from the static basis texture and z (GPU decode) and shades: RPO shading of the (residual) lighting
// plus the peaks' analytic term (prt_shading.glsl). Per frame the page uploads positions, frames (and peak
// visibility) per vertex and z (a few hundred floats per character), not the visibility.
// ?characters=K (1..64): K instances of the character in one draw on a grid, each with its own pose (clip c % #clips,
// 3 c frames later), the latent graph run once with batch K; ?texwidth=W forces the texture width (shading.js). A site without peaks.onnx shades its peaks unshadowed (V = 1:
// only the BRDF's horizon). window.prt is the page's scripting interface (used by `prt web --check` and tests/web).
import * as THREE from 'three';
import * as ort from 'onnxruntime-web';
import { Poser } from './posing.js';
import { MAX_PEAKS, PEAK_TEXEL, RADIANCE_WIDTH, TEXTURE_WIDTH, VIS_TEXEL, itemTexture, makeMaterial, rpoTexture, stateLayout,
  texelLayout } from './shading.js';

const $ = (id) => document.getElementById(id);
const ASSETS = 'assets/';
const DTYPES = { float32: Float32Array, float64: Float64Array, uint32: Uint32Array, int32: Int32Array, uint8: Uint8Array,
  float16: Uint16Array }; // float16: the raw bits, uploaded as HALF_FLOAT
const MAX_CHARACTERS = 64;

class AssetError extends Error {}

function showError(message) {
  const el = $('error');
  el.hidden = false;
  el.textContent = `The player could not start:\n\n${message}`;
  $('stats').textContent = 'error';
  window.prt.error = String(message);
}

async function fetchOk(name, what) {
  let res;
  try {
    res = await fetch(ASSETS + name);
  } catch (e) {
    throw new AssetError(`${what} (${ASSETS}${name}) could not be fetched: ${e.message}`);
  }
  if (!res.ok) throw new AssetError(`${what} (${ASSETS}${name}) is missing: HTTP ${res.status} ${res.statusText}`);
  return res;
}

function need(cond, message) {
  if (!cond) throw new AssetError(message);
}

// the bytes of a fetched asset against its manifest entry ({bytes, sha256}; either may be absent in older sites)
async function checkBytes(buf, entry, file, what) {
  if (Number.isInteger(entry.bytes)) {
    need(buf.byteLength === entry.bytes, `${what} (${ASSETS}${file}) has ${buf.byteLength} bytes, the manifest says ${entry.bytes} (truncated or stale: re-run \`prt web\`)`);
  }
  if (typeof entry.sha256 === 'string' && self.crypto && crypto.subtle) { // secure contexts only (127.0.0.1 is one)
    const hex = Array.from(new Uint8Array(await crypto.subtle.digest('SHA-256', buf)), (b) => b.toString(16).padStart(2, '0')).join('');
    need(hex === entry.sha256, `${what} (${ASSETS}${file}) does not match the manifest's sha256 (damaged or stale: re-run \`prt web\`)`);
  }
}

// onnxruntime-web's own runtime files (fetched by it, not by this page): the first one the server does not have
const ORT_RUNTIME = ['vendor/ort/ort-wasm-simd-threaded.mjs', 'vendor/ort/ort-wasm-simd-threaded.wasm'];
async function missingRuntime() {
  for (const f of ORT_RUNTIME) {
    let res;
    try {
      res = await fetch(f, { method: 'HEAD' });
    } catch (e) {
      return `onnxruntime-web's wasm runtime (${f}) could not be fetched: ${e.message}`;
    }
    if (!res.ok) return `onnxruntime-web's wasm runtime (${f}) is missing: HTTP ${res.status} ${res.statusText} (re-run \`prt web\`)`;
  }
  return null;
}

async function loadManifest() {
  const res = await fetchOk('manifest.json', 'the run manifest');
  const text = await res.text();
  let m;
  try {
    m = JSON.parse(text);
  } catch (e) {
    throw new AssetError(`the run manifest (${ASSETS}manifest.json) is malformed JSON: ${e.message}`);
  }
  need(m && typeof m === 'object', 'the run manifest is not a JSON object');
  need(m.format === 'prt_torch.web/1', `the run manifest has format ${JSON.stringify(m.format)}, expected "prt_torch.web/1" (re-run \`prt web\`)`);
  for (const key of ['n_vertices', 'order', 'n_terms', 'n_features', 'parents', 'clips', 'rpos', 'lights', 'camera', 'data', 'model', 'unshadowed', 'gaunt']) {
    need(key in m, `the run manifest has no "${key}" (re-run \`prt web\`)`);
  }
  need(Number.isInteger(m.order) && m.order >= 1 && m.order <= 8, `unsupported SH order ${m.order} (1..8)`);
  need(m.clips.length > 0 && m.rpos.length > 0 && m.lights.length > 0, 'the run manifest lists no clip, BRDF or lighting');
  return m;
}

async function loadArrays(m) {
  const res = await fetchOk(m.data.file, 'the character data');
  const buf = await res.arrayBuffer();
  need(Number.isInteger(m.data.bytes), 'the run manifest gives no size of the character data (re-run `prt web`)');
  await checkBytes(buf, m.data, m.data.file, 'the character data');
  const out = {};
  for (const [name, e] of Object.entries(m.data.arrays)) {
    const T = DTYPES[e.dtype];
    need(T, `array ${name}: unknown dtype ${e.dtype}`);
    const count = e.shape.reduce((a, b) => a * b, 1);
    need(count * T.BYTES_PER_ELEMENT === e.bytes && e.offset % 8 === 0 && e.offset + e.bytes <= buf.byteLength,
      `array ${name} does not fit ${ASSETS}${m.data.file} (offset ${e.offset}, ${e.bytes} bytes)`);
    out[name] = new T(buf, e.offset, count);
  }
  const V = m.n_vertices;
  for (const [name, len] of [['rest_vertices', 3 * V], ['rest_normals', 3 * V], ['cluster', V], ['base_color', 3 * V]]) {
    need(out[name] && out[name].length === len, `array ${name} is missing or has the wrong size`);
  }
  return out;
}

async function loadTexture(name) {
  const res = await fetchOk(name, 'the base-colour texture');
  const bitmap = await createImageBitmap(await res.blob(), { imageOrientation: 'none', premultiplyAlpha: 'none', colorSpaceConversion: 'none' });
  const tex = new THREE.Texture(bitmap);
  tex.flipY = false; // glTF: v = 0 is the image's top row
  tex.wrapS = tex.wrapT = THREE.RepeatWrapping;
  tex.colorSpace = THREE.SRGBColorSpace; // SRGB8_ALPHA8: decoded to linear before filtering, as the Python player does
  tex.needsUpdate = true;
  return tex;
}

function cameraEye(cam, azimuth, elevation, scale = 1) {
  // prt_torch.player.player.camera_eye: orbit the centre at distance * radius, in front (-y) at azimuth 0 (scale: a
  // crowd's grid, the camera pulled back)
  const d = [Math.sin(azimuth) * Math.cos(elevation), -Math.cos(azimuth) * Math.cos(elevation), Math.sin(elevation)];
  const r = cam.distance * cam.radius * scale;
  return [cam.center[0] + r * d[0], cam.center[1] + r * d[1], cam.center[2] + r * d[2]];
}

// round z as the CPU path does (prt_torch.player.frame_kernels.quantize_latent: onnxruntime's int8 MatMulNBits input
// rounding): per block of `block` entries, s = max |z| / 127 (float32), z -> rint_even(z / s) * s; block 0: z as is.
// z (nChars, Gz, Kz) flat -> out: row c * G + g (g: the site's clusters), tz texels (4 tz floats) per row
function roundHalfEven(x) {
  const r = Math.round(x);
  return (Math.abs(x % 1) === 0.5 && r % 2 !== 0) ? r - 1 : r;
}
function quantizeLatent(z, zDims, groups, out, tz, nChars) {
  const gz = zDims[1], kz = zDims[2], f = Math.fround, ng = groups.length;
  for (let c = 0; c < nChars; c++) {
    for (let g = 0; g < ng; g++) {
      const { row, k_used: ku, block } = groups[g];
      const src = (c * gz + row) * kz, dst = (c * ng + g) * tz * 4;
      if (!block) { for (let k = 0; k < ku; k++) out[dst + k] = z[src + k]; continue; }
      for (let b0 = 0; b0 < ku; b0 += block) {
        const b1 = Math.min(ku, b0 + block);
        let amax = 0;
        for (let k = b0; k < b1; k++) amax = Math.max(amax, Math.abs(z[src + k]));
        const sc = f(amax / 127);
        for (let k = b0; k < b1; k++) out[dst + k] = sc > 0 ? f(roundHalfEven(f(z[src + k] / sc)) * sc) : 0;
      }
    }
  }
  return out;
}

class App {
  constructor(m, arrays, session, glsl, texture, peakSession, latentSession, options = {}) {
    this.m = m;
    this.a = arrays;
    this.session = session; // the visibility graph (GPU decode: loaded on demand, window.prt.visibility)
    this.latentSession = latentSession; // the latent graph (null: no GPU decode, the visibility graph per frame)
    this.decode = latentSession ? m.decode : null;
    this.peakSession = peakSession; // the run's peaks.onnx (null: peaks unshadowed)
    const V = m.n_vertices, nc = m.order * m.order;
    this.V = V;
    this.nc = nc;
    const nChars = options.characters || 1;
    need(Number.isInteger(nChars) && nChars >= 1 && nChars <= MAX_CHARACTERS, `characters must be 1..${MAX_CHARACTERS}, not ${options.characters}`);
    this.nChars = nChars;
    this.texWidth = options.texWidth || TEXTURE_WIDTH;
    const K = arrays.skin_weights.length / V;
    this.poser = new Poser(m.parents, arrays, K);
    need(this.poser.nFeatures === m.n_features, `the skeleton gives ${this.poser.nFeatures} pose features, the model takes ${m.n_features}`);
    if (this.decode) {
      const d = this.decode;
      need(arrays[d.basis] && arrays[d.basis].length === V * 4 * d.texels && arrays[d.rows] && arrays[d.rows].length === 2 * V,
        'the GPU decode\'s arrays are missing or have the wrong size (re-run `prt web`)');
    }
    this.posed = Array.from({ length: nChars }, () => null);
    this.visibility = new Float32Array(nChars * V * nc);
    this.peakVis = new Float32Array(nChars * V * MAX_PEAKS).fill(1); // (K, V, 4): peak p's visible fraction at vertex v
    this.skins = new Float32Array(nChars * m.n_joints * 16); // (K, J, 4, 4) each character's skinning matrices
    this.offsets = this.gridOffsets(nChars);
    this.hasPeaks = m.lights.some((l) => l.peaks);
    this.peaksOn = this.hasPeaks; // on by default when the site has peaks
    this.peakDirs = new Float32Array(0); // (P, 3) the active peaks' directions, turned with the light
    // settings
    this.clip = 0;
    this.frame = 0;
    this.playing = true;
    this.lightAngle = 0;
    this.light = 0;
    this.brdf = Math.max(0, m.rpos.findIndex((r) => r.name === m.default_brdf));
    this.unshadowed = false;
    this.azimuth = m.camera.azimuth;
    this.elevation = m.camera.elevation;
    this.exposure = null; // {exposure, white}: fixed per lighting preset by `prt web` (the Python player's rule)
    // pose_ms: posing (JS: features + LBS + frames), visibility_ms: the wasm inference (latent or visibility graph),
    // peaks_ms: the peak graph, render_ms: upload + draw (waited for when syncGpu), step_ms: their sum
    this.stats = { pose_ms: 0, visibility_ms: 0, peaks_ms: 0, render_ms: 0, step_ms: 0, fps: 0, steps: 0, characters: nChars };
    this.hasTexture = Boolean(texture) && Boolean(arrays.uv);
    this.perPixel = this.hasTexture;
    this.initThree(glsl, texture);
  }

  // (K*3) world offsets of K characters on a square grid, 1.5 x the rest mesh's horizontal extent apart, centred
  gridOffsets(n) {
    const rest = this.a.rest_vertices;
    const lo = [Infinity, Infinity], hi = [-Infinity, -Infinity];
    for (let v = 0; v < this.V; v++) for (let e = 0; e < 2; e++) { lo[e] = Math.min(lo[e], rest[3 * v + e]); hi[e] = Math.max(hi[e], rest[3 * v + e]); }
    const step = 1.5 * Math.max(hi[0] - lo[0], hi[1] - lo[1]);
    const cols = Math.ceil(Math.sqrt(n)), rows = Math.ceil(n / cols);
    this.gridScale = n > 1 ? 1 + step * (cols - 1) / this.m.camera.radius : 1;
    const out = new Float32Array(3 * n);
    for (let c = 0; c < n; c++) {
      out[3 * c] = (c % cols - (cols - 1) / 2) * step;
      out[3 * c + 1] = (Math.floor(c / cols) - (rows - 1) / 2) * step;
    }
    return out;
  }

  initThree(glsl, texture) {
    const m = this.m;
    THREE.ColorManagement.enabled = false; // the shader writes display colours itself
    const canvas = $('canvas');
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
    const gl = this.renderer.getContext();
    const maxSize = gl.getParameter(gl.MAX_TEXTURE_SIZE);
    this.layout = stateLayout(this.nChars * this.V, this.nc, Boolean(this.decode), this.texWidth, maxSize);
    this.state = new Float32Array(this.layout.width * this.layout.height * 4);
    this.stateTex = itemTexture(this.state, this.layout);
    this.decodeOptions = null;
    if (this.decode) {
      const d = this.decode, ng = d.groups.length;
      this.basisLayout = texelLayout(this.V, d.texels, this.texWidth, maxSize, 'the GPU decode\'s basis texture');
      this.basisTex = itemTexture(this.a[d.basis], this.basisLayout);
      this.tz = Math.max(1, Math.ceil(d.k_max / 4));
      this.latent = new Float32Array(this.tz * 4 * ng * this.nChars);
      this.latentTex = itemTexture(this.latent, { width: this.tz, height: ng * this.nChars });
      this.decodeOptions = { layout: this.basisLayout, latentRows: ng };
    }
    this.renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
    this.renderer.setPixelRatio(1);
    this.renderer.setSize(m.camera.width, m.camera.height, false);
    this.renderer.debug.onShaderError = (gl, program, vs, fs) => {
      const log = gl.getShaderInfoLog(vs) + '\n' + gl.getShaderInfoLog(fs) + '\n' + gl.getProgramInfoLog(program);
      throw new AssetError(`the RPO shader failed to compile:\n${log}`);
    };
    const bg = m.background;
    this.renderer.setClearColor(new THREE.Color(bg[0], bg[1], bg[2]), 1);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(m.camera.view_angle, m.camera.width / m.camera.height, 0.01 * m.camera.radius,
      20 * m.camera.radius * this.gridScale);
    this.camera.up.set(...m.camera.up);
    const sizes = { order: m.order, nTerms: m.n_terms, nLobes: m.lights[0].dirs.length };
    for (const l of m.lights) {
      need(l.dirs.length === sizes.nLobes && (!l.peaks || l.peaks.dirs.length === sizes.nLobes),
        `lighting ${l.name}: every lighting (and its residual) must have ${sizes.nLobes} lobes`);
      need(!l.peaks || l.peaks.directions.length <= MAX_PEAKS, `lighting ${l.name}: at most ${MAX_PEAKS} peaks`);
    }
    this.sizes = sizes;
    this.glsl = glsl;
    this.matrixForm = new URLSearchParams(location.search).get('form') === 'matrix';
    this.material = makeMaterial(glsl, sizes, this.layout, m.gaunt, this.matrixForm, { decode: this.decodeOptions,
      fromRadiance: true });
    const u = this.material.uniforms;
    u.u_state.value = this.stateTex;
    u.u_nVertices.value = this.V;
    if (this.decode) { u.u_basis.value = this.basisTex; u.u_latent.value = this.latentTex; }
    u.u_unshadowedVis.value.set(m.unshadowed);
    u.u_gamma.value = m.tonemap.gamma;
    const mat = m.material || {};
    u.u_baseFactor.value.set(...(mat.base_color || [1, 1, 1]).slice(0, 3));
    u.u_baseTex.value = texture || null;
    this.rpoTex = m.rpos.map((r) => rpoTexture(this.a[r.M], m.n_terms, this.nc));
    // geometry: indexed (one shading per vertex); non-indexed per corner when a texture needs corner UVs
    const g = new THREE.InstancedBufferGeometry(); // one instance per character (a_instance)
    g.instanceCount = this.nChars;
    g.setAttribute('a_instance', new THREE.InstancedBufferAttribute(Float32Array.from({ length: this.nChars }, (_, i) => i), 1));
    const faces = this.a.faces, base = this.a.base_color, rest = this.a.rest_vertices;
    const rows = this.decode ? this.a[this.decode.rows] : null;
    if (this.hasTexture) {
      const n = faces.length;
      const vid = new Float32Array(n), uv = new Float32Array(2 * n), b3 = new Float32Array(3 * n), p3 = new Float32Array(3 * n);
      const dec = new Float32Array(2 * n);
      for (let c = 0; c < n; c++) {
        const v = faces[c];
        vid[c] = v;
        uv[2 * c] = this.a.uv[2 * c]; uv[2 * c + 1] = this.a.uv[2 * c + 1];
        for (let e = 0; e < 3; e++) { b3[3 * c + e] = base[3 * v + e]; p3[3 * c + e] = rest[3 * v + e]; }
        if (rows) { dec[2 * c] = rows[2 * v]; dec[2 * c + 1] = rows[2 * v + 1]; }
      }
      g.setAttribute('position', new THREE.BufferAttribute(p3, 3));
      g.setAttribute('a_vid', new THREE.BufferAttribute(vid, 1));
      g.setAttribute('a_uv', new THREE.BufferAttribute(uv, 2));
      g.setAttribute('a_base', new THREE.BufferAttribute(b3, 3));
      if (rows) g.setAttribute('a_decode', new THREE.BufferAttribute(dec, 2));
    } else {
      const vid = new Float32Array(this.V);
      for (let v = 0; v < this.V; v++) vid[v] = v;
      g.setAttribute('position', new THREE.BufferAttribute(rest, 3));
      g.setAttribute('a_vid', new THREE.BufferAttribute(vid, 1));
      g.setAttribute('a_uv', new THREE.BufferAttribute(new Float32Array(2 * this.V), 2));
      g.setAttribute('a_base', new THREE.BufferAttribute(base, 3));
      if (rows) g.setAttribute('a_decode', new THREE.BufferAttribute(rows, 2));
      g.setIndex(new THREE.BufferAttribute(faces, 1));
    }
    this.initShadingPass();
    this.mesh = new THREE.Mesh(g, this.material);
    this.mesh.frustumCulled = false; // positions come from the state texture
    this.scene.add(this.mesh);
    this.applyBrdf();
    this.applyLight();
    this.applyCamera();
  }

  // the frame's first pass: every character's vertices decoded + shaded once, one point each, into a float target
  // (RADIANCE_WIDTH x ceil(K V / RADIANCE_WIDTH)) the mesh pass reads
  initShadingPass() {
    const n = this.nChars * this.V;
    this.shadeRows = Math.ceil(n / RADIANCE_WIDTH);
    const mat = makeMaterial(this.glsl, this.sizes, this.layout, this.m.gaunt, this.matrixForm,
      { radianceOut: true, uniforms: this.material.uniforms, decode: this.decodeOptions });
    const g = new THREE.InstancedBufferGeometry();
    g.instanceCount = this.nChars;
    g.setAttribute('a_instance', new THREE.InstancedBufferAttribute(Float32Array.from({ length: this.nChars }, (_, i) => i), 1));
    const vid = new Float32Array(this.V);
    for (let v = 0; v < this.V; v++) vid[v] = v;
    g.setAttribute('position', new THREE.BufferAttribute(this.a.rest_vertices, 3));
    g.setAttribute('a_vid', new THREE.BufferAttribute(vid, 1));
    g.setAttribute('a_uv', new THREE.BufferAttribute(new Float32Array(2 * this.V), 2));
    g.setAttribute('a_base', new THREE.BufferAttribute(this.a.base_color, 3));
    if (this.decode) g.setAttribute('a_decode', new THREE.BufferAttribute(this.a[this.decode.rows], 2));
    const pts = new THREE.Points(g, mat);
    pts.frustumCulled = false;
    this.shadeScene = new THREE.Scene();
    this.shadeScene.add(pts);
    this.shadeTarget = new THREE.WebGLRenderTarget(RADIANCE_WIDTH, this.shadeRows, { type: THREE.FloatType,
      format: THREE.RGBAFormat, minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter, depthBuffer: false });
    this.material.uniforms.u_radianceTex.value = this.shadeTarget.texture;
  }

  // the shading pass (decode + shade every vertex once) into its target
  shadePass() {
    const r = this.renderer;
    this.material.uniforms.u_radianceRows.value = this.shadeRows;
    const clear = new THREE.Color();
    r.getClearColor(clear);
    const alpha = r.getClearAlpha();
    r.setRenderTarget(this.shadeTarget);
    r.setClearColor(new THREE.Color(0, 0, 0), 0);
    r.clear();
    r.render(this.shadeScene, this.camera);
    r.setRenderTarget(null);
    r.setClearColor(clear, alpha);
  }

  // draw the frame: the shading pass, then the mesh on the canvas
  draw() {
    this.shadePass();
    this.renderer.render(this.scene, this.camera);
  }

  get clipInfo() { return this.m.clips[this.clip]; }

  applyBrdf() {
    const r = this.m.rpos[this.brdf];
    const u = this.material.uniforms;
    u.u_rpoM.value = this.rpoTex[this.brdf];
    u.u_rpoW.value.set(this.a[r.w]);
    u.u_rpoU.value.set(this.a[r.u]);
    u.u_tint.value.set(...r.tint);
    this.brdfAnalytic = r.brdf || null; // null: an RPO of no known BRDF, no peak term
    if (r.brdf) {
      u.u_brdfKind.value = r.brdf.kind;
      u.u_brdfParams.value.set(...r.brdf.params);
    }
    this.applyLight();
  }

  // the lighting's peaks when they are shaded (toggle on, the lighting has some, the BRDF is analytic), else null
  activePeaks() {
    const pk = this.m.lights[this.light].peaks;
    return this.peaksOn && pk && this.brdfAnalytic ? pk : null;
  }

  applyLight() {
    const lt = this.m.lights[this.light];
    const u = this.material.uniforms;
    const c = Math.cos(this.lightAngle), s = Math.sin(this.lightAngle);
    const pk = this.activePeaks();
    const lobes = pk || lt; // peaks on: the residual's lobes on the SH path
    lobes.dirs.forEach((d, k) => { // dirs @ R^T, R = rotation about z by lightAngle (Player.rotate_light)
      u.u_lobeDir.value[k].set(c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]);
    });
    lobes.coeffs.forEach((bands, k) => bands.forEach((rgb, l) => u.u_lobeG.value[k * this.m.order + l].set(...rgb)));
    const n = pk ? pk.directions.length : 0;
    u.u_nPeaks.value = n;
    this.peakDirs = new Float32Array(3 * n);
    for (let p = 0; p < n; p++) {
      const d = pk.directions[p];
      this.peakDirs.set([c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]], 3 * p);
      u.u_peakDir.value[p].set(...this.peakDirs.subarray(3 * p, 3 * p + 3));
      u.u_peakPower.value[p].set(...pk.powers[p]);
    }
    const tm = this.exposure || (pk && pk.tonemap) || lt.tonemap;
    u.u_exposure.value = tm.exposure;
    u.u_white.value = tm.white;
  }

  applyCamera() {
    const eye = cameraEye(this.m.camera, this.azimuth, this.elevation, this.gridScale);
    this.eye = eye;
    this.camera.position.set(...eye);
    this.camera.lookAt(...this.m.camera.center);
    this.material.uniforms.u_eye.value.set(...eye);
  }

  // character c's local transforms now: clip (clip + c) % #clips, frame (frame + 3 c) % its frames
  localNow(c = 0) {
    const clips = this.m.clips, ci = clips[(this.clip + c) % clips.length];
    return Poser.localFromClip(this.a[ci.array], (this.frame + 3 * c) % ci.frames, this.m.n_joints);
  }

  async runVisibility(features, batch = 1) {
    if (!this.session) this.session = await createSession(this.m.model, 'the visibility model');
    const input = new ort.Tensor('float32', features, [batch, this.m.n_features]);
    const out = await this.session.run({ [this.m.model.input]: input });
    return out[this.m.model.output].data;
  }

  // z (batch, Gz, Kz) of the latent graph for pose features (batch * A): {data, dims}
  async runLatent(features, batch = 1) {
    const d = this.decode;
    const input = new ort.Tensor('float32', features, [batch, this.m.n_features]);
    const out = (await this.latentSession.run({ [d.input]: input }))[d.output];
    return { data: out.data, dims: out.dims };
  }

  // the latent texture from z of nChars characters (rounded as the CPU path does, quantizeLatent)
  fillLatent(z, nChars = this.nChars) {
    need(z.dims.length === 3 && z.dims[0] >= nChars && this.decode.groups.every((g) => g.row < z.dims[1] && g.k_used <= z.dims[2]),
      `the latent graph returned z of shape [${z.dims}], the site's decode needs ${nChars} x clusters x k`);
    quantizeLatent(z.data, z.dims, this.decode.groups, this.latent, this.tz, nChars);
    this.lastLatent = z; // z as the graph returned it (window.prt.crowd)
    this.latentTex.needsUpdate = true;
  }

  // peak visibility (B, V, P) of posed positions / normals (B*V*3) and skinning matrices (B*J*16, row-major 4x4)
  async runPeaks(positions, normals, skin, directions, radii, batch = 1) {
    const V = positions.length / (3 * batch), P = radii.length, J = this.m.n_joints;
    const f32 = (a) => (a instanceof Float32Array ? a : Float32Array.from(a));
    const feeds = {
      positions: new ort.Tensor('float32', f32(positions), [batch, V, 3]),
      normals: new ort.Tensor('float32', f32(normals), [batch, V, 3]),
      skin: new ort.Tensor('float32', f32(skin), [batch, J, 4, 4]),
      directions: new ort.Tensor('float32', f32(directions), [P, 3]),
      angular_radii: new ort.Tensor('float32', f32(radii), [P]),
    };
    const out = await this.peakSession.run(feeds);
    return out[this.m.peaks_model.output].data;
  }

  // character c's items of the state texture from per-vertex arrays: positions (V*3, moved by the character's grid
  // offset), frames (V*9), visibility (V*NC; GPU decode: unused), peak visibility (V*4, peak p of vertex v at 4v + p);
  // visibility null leaves the coefficients as they are
  // (target: {layout, state, stateTex}, default the page's own state; visInput's holds the coefficients)
  fillState(c, pos, fr, vis, peakVis, target = this) {
    const { P, R } = target.layout;
    const st = target.state, nc = this.nc, V = this.V;
    const ox = this.offsets[3 * c], oy = this.offsets[3 * c + 1], oz = this.offsets[3 * c + 2];
    const withVis = vis && P > VIS_TEXEL;
    for (let v = 0; v < V; v++) {
      const i = c * V + v;
      const o = 4 * ((Math.floor(i / R) * R * P) + (i % R) * P);
      st[o] = pos[3 * v] + ox; st[o + 1] = pos[3 * v + 1] + oy; st[o + 2] = pos[3 * v + 2] + oz;
      for (let r = 0; r < 3; r++) {
        st[o + 4 * (r + 1)] = fr[9 * v + 3 * r];
        st[o + 4 * (r + 1) + 1] = fr[9 * v + 3 * r + 1];
        st[o + 4 * (r + 1) + 2] = fr[9 * v + 3 * r + 2];
      }
      const q = o + 4 * PEAK_TEXEL;
      for (let p = 0; p < MAX_PEAKS; p++) st[q + p] = peakVis[MAX_PEAKS * v + p];
      if (withVis) for (let k = 0; k < nc; k++) st[o + 4 * VIS_TEXEL + k] = vis[v * nc + k];
    }
    target.stateTex.needsUpdate = true;
  }

  // with the GPU decode: a state texture of character 0 with the visibility coefficients in it (window.prt.radiance
  // of a given visibility: the shading checked on its own), drawn by a material without PRT_GPU_DECODE
  get visInput() {
    if (!this._visInput) {
      const layout = stateLayout(this.V, this.nc, false, this.texWidth, this.renderer.getContext().getParameter(
        this.renderer.getContext().MAX_TEXTURE_SIZE));
      const state = new Float32Array(layout.width * layout.height * 4);
      this._visInput = { layout, state, stateTex: itemTexture(state, layout) };
    }
    return this._visInput;
  }

  // one step: pose the current frame of every character (features, then LBS + frames), run the model once for all
  // of them (latent graph, or the visibility graph) and the peak graph, upload, render; each part timed apart
  async step() {
    const t0 = performance.now();
    const K = this.nChars, V = this.V, A = this.m.n_features, nc = this.nc;
    const locals = [], feats = new Float32Array(K * A);
    for (let c = 0; c < K; c++) { locals.push(this.localNow(c)); feats.set(this.poser.features(locals[c]), c * A); }
    const tf = performance.now();
    if (!this.unshadowed) {
      if (this.decode) this.fillLatent(await this.runLatent(feats, K));
      else this.visibility = await this.runVisibility(feats, K);
    }
    const t1 = performance.now();
    const J16 = 16 * this.m.n_joints;
    for (let c = 0; c < K; c++) {
      this.posed[c] = this.poser.pose(locals[c], this.posed[c]);
      this.skins.set(this.poser.skin, c * J16);
    }
    const t2 = performance.now();
    const pk = this.activePeaks();
    if (pk && this.peakSession && !this.unshadowed) {
      const n = pk.directions.length;
      const cat = (key) => { const o = new Float32Array(K * 3 * V); this.posed.forEach((p, c) => o.set(p[key], c * 3 * V)); return o; };
      const pv = await this.runPeaks(cat('positions'), cat('normals'), this.skins, this.peakDirs, pk.angular_radii, K);
      for (let i = 0; i < K * V; i++) for (let p = 0; p < n; p++) this.peakVis[MAX_PEAKS * i + p] = pv[n * i + p];
    } else {
      this.peakVis.fill(1); // unshadowed, or no peak graph: the BRDF's horizon only
    }
    const t2p = performance.now();
    for (let c = 0; c < K; c++) {
      this.fillState(c, this.posed[c].positions, this.posed[c].frames,
        this.unshadowed ? null : this.visibility.subarray(c * V * nc, (c + 1) * V * nc),
        this.peakVis.subarray(c * V * MAX_PEAKS, (c + 1) * V * MAX_PEAKS));
    }
    const u = this.material.uniforms;
    u.u_unshadowed.value = this.unshadowed;
    u.u_perPixel.value = this.perPixel && this.hasTexture;
    this.draw();
    if (this.syncGpu) { // wait for the draw itself, not just its submission: read one pixel back
      const gl = this.renderer.getContext();
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, this.onePixel || (this.onePixel = new Uint8Array(4)));
    }
    const t3 = performance.now();
    const s = this.stats;
    s.pose_ms = (tf - t0) + (t2 - t1); s.visibility_ms = t1 - tf; s.peaks_ms = t2p - t2; s.render_ms = t3 - t2p;
    s.step_ms = t3 - t0;
    s.steps += 1;
    return { ...s };
  }

  // per-vertex radiance (V*3, before the base colour) of the state texture as it is: the same vertex shader, one
  // point per vertex into a float target
  // (fromVisibility: of the visInput state, the coefficients given, not decoded, character 0; else the shading
  // pass of the state as it is, character `instance`'s vertices)
  radiance(fromVisibility = false, instance = 0) {
    need(Number.isInteger(instance) && instance >= 0 && instance < (fromVisibility ? 1 : this.nChars), `no character ${instance}`);
    const r = this.renderer, V = this.V;
    const u = this.material.uniforms;
    u.u_unshadowed.value = this.unshadowed;
    if (!(fromVisibility && this.decode)) {
      this.shadePass();
      const px = new Float32Array(RADIANCE_WIDTH * this.shadeRows * 4);
      r.readRenderTargetPixels(this.shadeTarget, 0, 0, RADIANCE_WIDTH, this.shadeRows, px);
      const out = new Float32Array(3 * V);
      for (let v = 0; v < V; v++) for (let e = 0; e < 3; e++) out[3 * v + e] = px[4 * (instance * V + v) + e];
      return out;
    }
    if (!this.visScene) {
      const rows = Math.ceil(V / RADIANCE_WIDTH);
      const uniforms = { ...this.material.uniforms, u_state: { value: this.visInput.stateTex } };
      const mat = makeMaterial(this.glsl, this.sizes, this.visInput.layout, this.m.gaunt, this.matrixForm,
        { radianceOut: true, uniforms });
      const g = new THREE.BufferGeometry();
      const vid = new Float32Array(V);
      for (let v = 0; v < V; v++) vid[v] = v;
      g.setAttribute('position', new THREE.BufferAttribute(this.a.rest_vertices, 3));
      g.setAttribute('a_vid', new THREE.BufferAttribute(vid, 1));
      g.setAttribute('a_uv', new THREE.BufferAttribute(new Float32Array(2 * V), 2));
      g.setAttribute('a_base', new THREE.BufferAttribute(this.a.base_color, 3));
      g.setAttribute('a_instance', new THREE.BufferAttribute(new Float32Array(V), 1)); // character 0
      const pts = new THREE.Points(g, mat);
      pts.frustumCulled = false;
      this.visScene = new THREE.Scene();
      this.visScene.add(pts);
      this.visTarget = new THREE.WebGLRenderTarget(RADIANCE_WIDTH, rows, { type: THREE.FloatType,
        format: THREE.RGBAFormat, minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter, depthBuffer: false });
      this.visRows = rows;
    }
    u.u_radianceRows.value = this.visRows;
    const clear = new THREE.Color();
    r.getClearColor(clear);
    const alpha = r.getClearAlpha();
    r.setRenderTarget(this.visTarget);
    r.setClearColor(new THREE.Color(0, 0, 0), 0);
    r.clear();
    r.render(this.visScene, this.camera);
    const px = new Float32Array(RADIANCE_WIDTH * this.visRows * 4);
    r.readRenderTargetPixels(this.visTarget, 0, 0, RADIANCE_WIDTH, this.visRows, px);
    r.setRenderTarget(null);
    r.setClearColor(clear, alpha);
    const out = new Float32Array(3 * V);
    for (let v = 0; v < V; v++) for (let e = 0; e < 3; e++) out[3 * v + e] = px[4 * v + e];
    return out;
  }
  readPixels() {
    const gl = this.renderer.getContext();
    const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
    const px = new Uint8Array(w * h * 4);
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
    let bin = '';
    for (let i = 0; i < px.length; i += 0x8000) bin += String.fromCharCode.apply(null, px.subarray(i, i + 0x8000));
    return { width: w, height: h, rgba: btoa(bin) };
  }
}

// -- UI ---------------------------------------------------------------------------------------------------
function bindUi(app) {
  const m = app.m;
  $('title').textContent = `${m.name} (${m.n_vertices} vertices, SH order ${m.order})`;
  const fill = (sel, names) => { sel.innerHTML = ''; names.forEach((n, i) => sel.add(new Option(n, i))); };
  fill($('clip'), m.clips.map((c) => c.name));
  fill($('env'), m.lights.map((l) => l.name));
  fill($('brdf'), m.rpos.map((r) => r.name));
  $('brdf').value = app.brdf;
  $('texRow').hidden = !app.hasTexture;
  $('peaksRow').hidden = !app.hasPeaks;
  const sync = () => {
    $('clip').value = app.clip;
    $('frame').max = app.clipInfo.frames - 1;
    $('frame').value = app.frame;
    $('frameLabel').textContent = `${app.frame} / ${app.clipInfo.frames - 1}`;
    $('play').textContent = app.playing ? 'pause' : 'play';
    const deg = Math.round(((app.lightAngle * 180 / Math.PI) % 360 + 540) % 360 - 180);
    $('light').value = deg;
    $('lightLabel').textContent = `${deg}\u00b0`;
    $('env').value = app.light;
    $('brdf').value = app.brdf;
    $('unshadowed').checked = app.unshadowed;
    $('peaks').checked = app.peaksOn;
  };
  app.sync = sync;
  $('clip').onchange = (e) => { app.clip = Number(e.target.value); app.frame = 0; sync(); };
  $('frame').oninput = (e) => { app.frame = Number(e.target.value); app.playing = false; sync(); };
  $('play').onclick = () => { app.playing = !app.playing; sync(); };
  $('light').oninput = (e) => { app.lightAngle = Number(e.target.value) * Math.PI / 180; app.applyLight(); sync(); };
  $('env').onchange = (e) => { app.light = Number(e.target.value); app.applyLight(); sync(); };
  $('brdf').onchange = (e) => { app.brdf = Number(e.target.value); app.applyBrdf(); sync(); };
  $('unshadowed').onchange = (e) => { app.unshadowed = e.target.checked; sync(); };
  $('peaks').onchange = (e) => { app.peaksOn = e.target.checked; app.applyLight(); sync(); };
  $('perPixel').onchange = (e) => { app.perPixel = e.target.checked; };
  // keyboard shortcuts of the Python player (Player._bind_keys) plus playback keys
  window.addEventListener('keydown', (e) => {
    if (e.target instanceof HTMLInputElement && e.target.type !== 'checkbox' && e.target.type !== 'range') return;
    const k = e.key;
    if (k === 'l') { app.lightAngle += 15 * Math.PI / 180; app.applyLight(); }
    else if (k === 'b') { app.brdf = (app.brdf + 1) % m.rpos.length; app.applyBrdf(); }
    else if (k === 'e') { app.light = (app.light + 1) % m.lights.length; app.applyLight(); }
    else if (k === 'u') app.unshadowed = !app.unshadowed;
    else if (k === 'p' && app.hasPeaks) { app.peaksOn = !app.peaksOn; app.applyLight(); }
    else if (k === ' ') app.playing = !app.playing;
    else if (k === ',') { app.playing = false; app.frame = Math.max(0, app.frame - 1); }
    else if (k === '.') { app.playing = false; app.frame = Math.min(app.clipInfo.frames - 1, app.frame + 1); }
    else if (k === 'ArrowLeft') { app.azimuth -= 10 * Math.PI / 180; app.applyCamera(); }
    else if (k === 'ArrowRight') { app.azimuth += 10 * Math.PI / 180; app.applyCamera(); }
    else if (k === 'ArrowUp') { app.elevation = Math.min(1.2, app.elevation + 8 * Math.PI / 180); app.applyCamera(); }
    else if (k === 'ArrowDown') { app.elevation = Math.max(-1.2, app.elevation - 8 * Math.PI / 180); app.applyCamera(); }
    else if (k === 'r') { app.azimuth = m.camera.azimuth; app.elevation = m.camera.elevation; app.applyCamera(); }
    else return;
    e.preventDefault();
    sync();
  });
  sync();
}

function loop(app) {
  let last = performance.now(), acc = 0, frames = 0, fpsT0 = last, busy = false;
  const tick = async () => {
    requestAnimationFrame(tick);
    if (busy || app.paused) return;
    busy = true;
    try {
      const now = performance.now();
      if (app.playing) {
        acc += (now - last) / 1000 * app.clipInfo.fps;
        const adv = Math.floor(acc);
        if (adv > 0) { acc -= adv; app.frame = (app.frame + adv) % app.clipInfo.frames; app.sync(); }
      }
      last = now;
      const s = await app.step();
      frames += 1;
      if (now - fpsT0 > 500) { app.stats.fps = frames * 1000 / (now - fpsT0); frames = 0; fpsT0 = now; }
      $('stats').textContent = `${app.clipInfo.name} ${app.frame}  ${app.m.rpos[app.brdf].name}  ${app.m.lights[app.light].name}` +
        `${app.unshadowed ? '  UNSHADOWED' : ''}${app.activePeaks() ? `  ${app.activePeaks().directions.length} peak(s)` : ''}` +
        `\n${app.nChars > 1 ? `${app.nChars} characters  ` : ''}step ${s.step_ms.toFixed(1)} ms (pose ${s.pose_ms.toFixed(1)}, ` +
        `${app.decode ? 'latent (GPU decode)' : 'visibility'} ${s.visibility_ms.toFixed(1)}, ` +
        `peaks ${s.peaks_ms.toFixed(1)}, draw submit ${s.render_ms.toFixed(1)})  ${app.stats.fps.toFixed(1)} fps`;
    } catch (e) {
      app.paused = true;
      showError(e.message || String(e));
    } finally {
      busy = false;
    }
  };
  requestAnimationFrame(tick);
}

// an onnxruntime-web session of the graph of a manifest entry {file, bytes, sha256}
async function createSession(entry, what) {
  const bytes = await (await fetchOk(entry.file, what)).arrayBuffer();
  await checkBytes(bytes, entry, entry.file, what);
  try {
    return await ort.InferenceSession.create(new Uint8Array(bytes), { executionProviders: ['wasm'] });
  } catch (e) {
    const runtime = await missingRuntime(); // ort's own message for a missing runtime file names no file
    throw new AssetError(runtime || `${what} (${ASSETS}${entry.file}) could not be loaded by onnxruntime-web: ${e.message || e}`);
  }
}

async function start() {
  const m = await loadManifest();
  const arrays = await loadArrays(m);
  const glsl = await (await fetchOk('../prt_shading.glsl', 'the shading source')).text();
  ort.env.wasm.wasmPaths = new URL('./vendor/ort/', location.href).href;
  ort.env.wasm.numThreads = self.crossOriginIsolated ? Math.min(4, navigator.hardwareConcurrency || 1) : 1;
  window.prt.wasmThreads = ort.env.wasm.numThreads; // threads need cross-origin isolation (prt web --serve sends it)
  const params = new URLSearchParams(location.search);
  // GPU decode: the latent graph per frame (the visibility graph only on demand); ?decode=cpu: the whole visibility
  // graph per frame as for an export without a latent graph
  const gpuDecode = Boolean(m.decode) && params.get('decode') !== 'cpu';
  const latentSession = gpuDecode ? await createSession(m.decode, 'the latent model') : null;
  const session = gpuDecode ? null : await createSession(m.model, 'the visibility model');
  let peakSession = null;
  if (m.peaks_model) {
    const pm = await (await fetchOk(m.peaks_model.file, 'the peak visibility model')).arrayBuffer();
    await checkBytes(pm, m.peaks_model, m.peaks_model.file, 'the peak visibility model');
    try {
      peakSession = await ort.InferenceSession.create(new Uint8Array(pm), { executionProviders: ['wasm'] });
    } catch (e) {
      throw new AssetError(`the peak visibility model (${ASSETS}${m.peaks_model.file}) could not be loaded by onnxruntime-web: ${e.message || e}`);
    }
  }
  const texture = m.material && m.material.texture ? await loadTexture(m.material.texture) : null;
  const app = new App(m, arrays, session, glsl, texture, peakSession, latentSession,
    { characters: params.has('characters') ? Number(params.get('characters')) : 1,
      texWidth: params.has('texwidth') ? Number(params.get('texwidth')) : TEXTURE_WIDTH });
  window.prt.app = app;
  bindUi(app);
  if (params.has('paused')) { app.playing = false; app.paused = true; }
  await app.step(); // compiles the shader: errors surface here
  loop(app);
  return app;
}

// scripting interface: prt.ready resolves once the first frame is drawn
window.prt = {
  error: null,
  app: null,
  ready: null,
  async setState(s) {
    const app = this.app;
    if ('clip' in s) app.clip = typeof s.clip === 'number' ? s.clip : app.m.clips.findIndex((c) => c.name === s.clip);
    if (app.clip < 0) throw new Error(`unknown clip ${s.clip}`);
    if ('frame' in s) app.frame = s.frame;
    if ('playing' in s) app.playing = s.playing;
    if ('paused' in s) app.paused = s.paused;
    if ('lightAngle' in s) app.lightAngle = s.lightAngle;
    if ('light' in s) app.light = typeof s.light === 'number' ? s.light : app.m.lights.findIndex((l) => l.name === s.light);
    if ('brdf' in s) app.brdf = typeof s.brdf === 'number' ? s.brdf : app.m.rpos.findIndex((r) => r.name === s.brdf);
    if (app.light < 0 || app.brdf < 0) throw new Error('unknown lighting or BRDF');
    if ('unshadowed' in s) app.unshadowed = s.unshadowed;
    if ('peaks' in s) app.peaksOn = Boolean(s.peaks) && app.hasPeaks;
    if ('perPixel' in s) app.perPixel = s.perPixel;
    if ('tonemap' in s) app.exposure = s.tonemap;
    if ('syncGpu' in s) app.syncGpu = s.syncGpu;
    app.applyBrdf(); app.applyLight(); app.applyCamera();
    if (app.sync) app.sync();
  },
  async render() { return this.app.step(); },
  stats() { return { ...this.app.stats }; },
  readPixels() { return this.app.readPixels(); },
  async visibility(features, batch) { return Array.from(await this.app.runVisibility(Float32Array.from(features), batch)); },
  // onnxruntime-web's peak visibility (B*V*P) of given inputs (flat arrays; skin row-major 4x4 per joint)
  async peakVisibility(a) {
    need(this.app.peakSession, 'the site has no peak visibility model');
    return Array.from(await this.app.runPeaks(a.positions, a.normals, a.skin, a.directions, a.angular_radii, a.batch || 1));
  },
  // per-vertex radiance (V*3, before the base colour) of character 0 as last rendered, or of given per-vertex inputs
  // {positions (V*3), frames (V*9), visibility (V*NC), peakVisibility (V*4)} under the current settings; with the GPU
  // decode, no visibility but {latent (Gz*Kz, z of one character), latentDims [1, Gz, Kz]} or {features (A)} (the
  // latent graph run here): the visibility decoded on the GPU
  async radiance(inputs) {
    const app = this.app;
    const fromVis = Boolean(inputs && inputs.visibility && app.decode);
    if (inputs) {
      if (app.decode && inputs.features) app.fillLatent(await app.runLatent(Float32Array.from(inputs.features), 1), 1);
      else if (app.decode && inputs.latent) app.fillLatent({ data: Float32Array.from(inputs.latent), dims: inputs.latentDims }, 1);
      app.fillState(0, inputs.positions, inputs.frames, inputs.visibility, inputs.peakVisibility, fromVis ? app.visInput : app);
    }
    return Array.from(app.radiance(fromVis));
  },
  // per-vertex radiance (V*3) of character c as last rendered (a crowd page)
  radianceOf(c) { return Array.from(this.app.radiance(false, c)); }, // (re-shaded from the state as it is)
  // the crowd: the camera's eye, each character's grid offset (K*3) and pose {clip, frame} now, and the last z the
  // latent graph returned {data (K*Gz*Kz), dims} (GPU decode; else null)
  crowd() {
    const app = this.app, clips = app.m.clips;
    const z = app.lastLatent;
    return { eye: app.eye, offsets: Array.from(app.offsets), latent: z ? { data: Array.from(z.data), dims: Array.from(z.dims) } : null,
      poses: Array.from({ length: app.nChars }, (_, c) => {
      const ci = clips[(app.clip + c) % clips.length];
      return { clip: ci.name, frame: (app.frame + 3 * c) % ci.frames };
    }) };
  },
  // the latent graph's z (B*Gz*Kz) in onnxruntime-web for pose features (B*A): {data, dims}
  async latent(features, batch) {
    need(this.app.decode, 'the page runs no latent graph (no GPU decode)');
    const z = await this.app.runLatent(Float32Array.from(features), batch);
    return { data: Array.from(z.data), dims: Array.from(z.dims) };
  },
  // what the page is: decode path, characters, texture layouts, the GL renderer string
  info() {
    const app = this.app, gl = app.renderer.getContext();
    const e = gl.getExtension('WEBGL_debug_renderer_info');
    return { decode: app.decode ? 'gpu' : 'visibility graph', characters: app.nChars, state: app.layout,
      basis: app.basisLayout || null, renderer: e ? gl.getParameter(e.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER),
      maxTextureSize: gl.getParameter(gl.MAX_TEXTURE_SIZE), wasmThreads: this.wasmThreads };
  },
  activePeaks() { const pk = this.app.activePeaks(); return pk ? { directions: Array.from(this.app.peakDirs), angular_radii: pk.angular_radii } : null; },
  skin() { return Array.from(this.app.poser.skin); },
  pose(clip, frame) {
    const app = this.app;
    const c = app.m.clips.findIndex((x) => x.name === clip);
    const local = Poser.localFromClip(app.a[app.m.clips[c].array], frame, app.m.n_joints);
    const p = app.poser.pose(local);
    return { positions: Array.from(p.positions), normals: Array.from(p.normals), frames: Array.from(p.frames),
      features: Array.from(app.poser.features(local)) };
  },
};
window.addEventListener('error', (e) => { if (!window.prt.error) showError(e.message); });
window.addEventListener('unhandledrejection', (e) => { if (!window.prt.error) showError(e.reason && e.reason.message || String(e.reason)); });
window.prt.ready = start().catch((e) => { showError(e.message || String(e)); return null; });
